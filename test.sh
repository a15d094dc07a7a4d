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
if [ "$#" -eq 0 ]; then
  set -- -n auto --dist loadfile --no-loadscope-reorder   # files in tests/durations.json order
  # the workers are the parallelism (as a fleet's are): nifo's simulations stay on one thread in each, so the
  # ROS graph tests beside them keep their cores (tests/test_parallel.py sets its own threads)
  export NIFO_THREADS="${NIFO_THREADS:-1}"
  # and render their figures in the test's own process: helper processes beside two busy workers only add their
  # start-up (tests/test_figure_writer.py and tests/test_kill.py run with the helpers a user's nifo has)
  export NIFO_FIGURE_WORKERS="${NIFO_FIGURE_WORKERS:-0}"
fi
exec "$here/.venv/bin/python" -m pytest "$@"
