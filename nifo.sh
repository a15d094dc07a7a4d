#!/usr/bin/env bash
# The main command. First use creates .venv and installs nifo into it.
#   ./nifo.sh            run the whole job on the bundled sample (bags/)
#   ./nifo.sh CMD ...    any nifo command, e.g. ./nifo.sh identify my.mcap --model m.yaml --out out/
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
source "$here/tools/bootstrap.sh"
nifo_bootstrap "$here" ""
if [ $# -eq 0 ]; then
  exec "$here/.venv/bin/nifo" run
fi
exec "$here/.venv/bin/nifo" "$@"
