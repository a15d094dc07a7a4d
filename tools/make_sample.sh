#!/usr/bin/env bash
# Regenerate the bundled sample in bags/sample/ (deterministic: fixed seeds).
# A simulated shaker-rig quarter car with the paper's strut (0.43 mm backlash at
# 8 kN/m + a damper that blows off from 1400 to 700 N·s/m above 0.03 m/s),
# random road at two levels, 120 s at 600 Hz, 2 % sensor noise, tire patch recorded.
# Each bag is a rosbag2 directory (metadata.yaml + zstd-chunked MCAP); its truth
# (vehicle, strut forces, seed) sits beside it as <name>.truth.json.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
nifo="$here/.venv/bin/nifo"
out="$here/bags/sample"
mkdir -p "$out"
"$nifo" simulate --out "$out/road_1mm" --preset paper --road-rms 1.0 --duration 120 --noise 0.02 --seed 101
"$nifo" simulate --out "$out/road_2p5mm" --preset paper --road-rms 2.5 --duration 120 --noise 0.02 --seed 102
