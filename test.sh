#!/usr/bin/env bash
# The test command. First use creates .venv and installs nifo with its test extras, and
# (as root) Debian's chromium for the report's browser test; otherwise it says what to run.
#   ./test.sh            the whole suite (what CI runs)
#   ./test.sh -k bag     any pytest arguments
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
source "$here/tools/bootstrap.sh"
nifo_need_chromium
nifo_bootstrap "$here" "test"
cd "$here"
exec "$here/.venv/bin/python" -m pytest "$@"
