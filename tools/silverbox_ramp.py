"""Silverbox, not periodic and rising in amplitude: a proxy of the benchmark's "arrow" from the multilevel records.

The benchmark's standard test (the "arrow", not in ``../shared``) is filtered noise whose amplitude grows beyond the
training range. From the five multilevel records (Noël & Schoukens, IJC 2018) this builds one record of the last
``--periods`` periods of each level, 5 → 150 mV, joined (no period of its own: ``nifo predict`` simulates it as it
comes), predicts it with each ``--model`` through ``nifo predict`` and prints the raw RMS error of the output
(offset included) with the first period after each join left out — there the measured output is the level's own
steady state, not the circuit's response to the joined input (its start-up decays over ~0.05 s, but the state
jumps by up to 0.4 V). Reproduces the table "Not periodic, amplitude rising" of docs/silverbox.md:

    python tools/silverbox_ramp.py --model sb50/loop sb100/loop sb150/loop
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from pathlib import Path

import numpy as np
import scipy.io

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nifo.cli import main as nifo  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "silverbox_multilevel"
LEVELS = (5, 20, 50, 100, 150)
COLUMNS = "body_disp=ym,force=um@{name:_ym_=_um_},spindle_accel=fixed"


def build(data: Path, out: Path, periods: int) -> tuple[Path, int, float]:
    """The joined record (ym and um files, as the multilevel ones), the period and the rate."""
    ys, us = [], []
    fs = p = None
    for lv in LEVELS:
        um = scipy.io.loadmat(data / f"SNJP_um_full_FNSI_{lv}.mat")
        ym = scipy.io.loadmat(data / f"SNJP_ym_full_FNSI_{lv}.mat")
        fs = float(np.ravel(um["fs"])[0])
        p = np.ravel(um["um"]).size // int(np.ravel(um["P"])[0])      # P: the number of periods
        ys.append(np.ravel(ym["ym"])[-periods * p:])
        us.append(np.ravel(um["um"])[-periods * p:])
    scipy.io.savemat(out / "SNJP_ym_ramp.mat", {"ym": np.concatenate(ys)[:, None]})
    scipy.io.savemat(out / "SNJP_um_ramp.mat", {"um": np.concatenate(us)[:, None], "fs": fs})
    return out / "SNJP_ym_ramp.mat", p, fs


def score(signals: Path, p: int, periods: int) -> dict:
    """Raw RMS error [V] of the model and of its linear twin, the first period after each join left out, and of the
    model on the last level alone."""
    with signals.open() as f:
        rows = list(csv.reader(f))
    head, vals = rows[0], np.array(rows[1:], float)
    y, m, lin = (vals[:, head.index(c)] for c in ("body_disp_measured", "body_disp_model", "body_disp_linear"))
    keep = np.zeros(y.size, bool)
    for k in range(len(LEVELS)):
        keep[k * periods * p + p:(k + 1) * periods * p] = True
    last = slice((len(LEVELS) - 1) * periods * p + p, None)
    return {"model": float(np.sqrt(np.mean((y - m)[keep] ** 2))), "linear": float(np.sqrt(np.mean((y - lin)[keep] ** 2))),
            "last_level": float(np.sqrt(np.mean((y - m)[last] ** 2)))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, nargs="+", required=True, help="model directories (nifo run's loop/)")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--periods", type=int, default=3, help="periods of each level (the last ones)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        rec, p, _ = build(args.data, tmp, args.periods)
        for i, model in enumerate(args.model):
            out = tmp / f"pred{i}"
            code = nifo(["-q", "predict", str(rec), "--columns", COLUMNS, "--model", str(model), "--out", str(out)])
            if code != 0:
                print(f"{model}: nifo predict failed (exit {code})")
                continue
            s = score(out / f"{rec.name}_signals.csv", p, args.periods)
            print(f"{model}: raw RMS error {1e3 * s['model']:.3f} mV (linear twin {1e3 * s['linear']:.3f} mV); "
                  f"the {LEVELS[-1]} mV part {1e3 * s['last_level']:.3f} mV", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
