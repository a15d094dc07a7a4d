#!/usr/bin/env bash
# Run the main job on the bundled sample and screenshot its HTML report into docs/img/report.png.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="$(mktemp -d)"
"$here/.venv/bin/nifo" run --out "$out/run"
chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run --disable-background-networking \
  --disable-component-update --disable-sync --hide-scrollbars --user-data-dir="$out/profile" \
  --window-size=1200,2400 --screenshot="$here/docs/img/report.png" "file://$out/run/report/report.html"
echo "wrote $here/docs/img/report.png"
