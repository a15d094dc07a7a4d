#!/usr/bin/env bash
# Make the F-16 figures and tables of docs/f16.md with `nifo characterize`.
#
# Data: the F-16 ground vibration test (Noël & Schoukens 2017, nonlinearbenchmark.org), sine sweeps
# 15 -> 2 Hz at four force levels; Acceleration row 1 = wing side of the payload interface (the
# "spindle"), row 2 = payload side (the "body"), fs from key Fs (400 Hz).
#
#   tools/f16_characterize.sh [OUT_DIR]      (default docs/img/f16; data from $NIFO_SHARED_DATA or ../shared/data)
#
# Per level: one characterization fitted around the 7.3 Hz torsion mode (6.8-7.8 Hz of the sweep), with
# frequency slices at 5.3, 7.3, 9.2 and 12 Hz. Then all four levels together: the amplitude figure at 7.3 Hz.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
data="${NIFO_SHARED_DATA:-$here/../shared/data}/f16"
out="${1:-$here/docs/img/f16}"
nifo="$here/.venv/bin/nifo"
[ -x "$nifo" ] || { source "$here/tools/bootstrap.sh"; nifo_bootstrap "$here" "test"; }
[ -d "$data" ] || { echo "F-16 data not found at $data (set NIFO_SHARED_DATA)" >&2; exit 3; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cols="spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"
common=(--columns "$cols" --band 5 160 --freq-window 6.8 7.8)
mkdir -p "$out"
for level in 1 3 5 7; do
    echo "== level $level" >&2
    "$nifo" characterize "$data/F16Data_SineSw_Level$level.mat" --out "$work/L$level" "${common[@]}" \
        --slices-hz 5.3 7.3 9.2 12 | grep -v "^wrote " > "$out/level$level.txt"
    cat "$out/level$level.txt"
    cp "$work/L$level/suggested_model.yaml" "$out/level${level}_model.yaml"
    cp "$work/L$level/characterize.json" "$out/level$level.json"
    case $level in
        1|7) cp "$work/L$level/restoring_frequency.png" "$out/level${level}_frequency.png" ;;
    esac
    case $level in
        3|7) cp "$work/L$level/characteristic.png" "$out/level${level}_characteristic.png"
             cp "$work/L$level/ranking.png" "$out/level${level}_ranking.png" ;;
    esac
done
echo "== all levels, amplitude slices at 7.3 Hz" >&2
"$nifo" characterize "$data"/F16Data_SineSw_Level{1,3,5,7}.mat --out "$work/all" "${common[@]}" \
    --slices-hz 7.3 | grep -v "^wrote " > "$out/all_levels.txt"
cat "$out/all_levels.txt"
cp "$work/all/restoring_amplitude.png" "$out/levels_7.3Hz.png"
cp "$work/all/characterize.json" "$out/all_levels.json"
cp "$work/all/suggested_model.yaml" "$out/all_levels_model.yaml"
echo "wrote $out" >&2
