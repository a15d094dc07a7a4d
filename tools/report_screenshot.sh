#!/usr/bin/env bash
# Run the main job on the bundled sample and screenshot the first screen (1400 x 900 px) of its HTML report into
# docs/img/report.png (the README's).
#   tools/report_screenshot.sh                 with the checkout's .venv (./nifo.sh makes it)
#   NIFO="python -m nifo.cli" tools/report_screenshot.sh   with another interpreter
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="$(mktemp -d)"
# as a user runs it (./nifo.sh: results/ in the working directory), so the report names results/, not a scratch path
(cd "$out" && ${NIFO:-"$here/.venv/bin/nifo"} run --out results)
chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run --disable-background-networking \
  --disable-component-update --disable-sync --hide-scrollbars --user-data-dir="$out/profile" \
  --window-size=1400,900 --screenshot="$here/docs/img/report.png" "file://$out/results/report/report.html"
echo "wrote $here/docs/img/report.png"
