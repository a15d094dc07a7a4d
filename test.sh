#!/usr/bin/env bash
# The test command. First use creates .venv and installs nifo with its test extras, and
# (as root) Debian's chromium for the report's browser test; otherwise it says what to run.
#   ./test.sh            the whole suite (what CI runs), on every core: pytest-xdist, a file per worker at a time
#   ./test.sh -k bag     any pytest arguments, in one process (-s shows the figures tests print; add -n auto
#                        --dist loadfile for the cores)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
source "$here/tools/bootstrap.sh"
nifo_need_chromium
nifo_bootstrap "$here" "test"
cd "$here"
[ "$#" -eq 0 ] && set -- -n auto --dist loadfile
exec "$here/.venv/bin/python" -m pytest "$@"
