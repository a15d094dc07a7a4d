#!/usr/bin/env bash
# Regenerate the bundled sample in bags/sample/ (deterministic: fixed seeds).
# A simulated shaker-rig quarter car with the paper's strut (0.43 mm backlash at
# 8 kN/m + a damper that blows off from 1400 to 700 N·s/m above 0.03 m/s),
# random road at three levels (0.5, 1 and 2.5 mm RMS) with a displacement
# spectrum that falls as 1/f above 1 Hz like a real road (ISO 8608): at 0.5 mm
# the play is seen apart from the damper knee, at 2.5 mm the knee dominates
# (the paper's two-step procedure, §3.3). 120 s at 600 Hz, 2 % sensor noise,
# tire patch recorded. Each bag is a rosbag2 directory (metadata.yaml +
# zstd-chunked MCAP); its truth (vehicle, strut forces, seed) sits beside it as
# <name>.truth.json. nifo simulate writes a CRC-32 per chunk. The bags in the
# repository were made before that and got their CRCs from tools/add_chunk_crcs.py
# (samples identical; regenerating gives the same samples with a current start time).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
nifo="${NIFO:-$here/.venv/bin/nifo}"
out="$here/bags/sample"
mkdir -p "$out"
common=(--preset paper --road-spectrum iso8608 --duration 120 --noise 0.02)
"$nifo" simulate --out "$out/road_0p5mm" --road-rms 0.5 --seed 100 "${common[@]}"
"$nifo" simulate --out "$out/road_1mm" --road-rms 1.0 --seed 101 "${common[@]}"
"$nifo" simulate --out "$out/road_2p5mm" --road-rms 2.5 --seed 102 "${common[@]}"
