#!/usr/bin/env python
"""F-16 ground vibration test: run the loop from a linear model across levels (docs/f16_loop.md).

Data: Noël & Schoukens (2017), *F-16 aircraft benchmark based on ground
vibration test data*, Workshop on Nonlinear System Identification Benchmarks
(nonlinearbenchmark.org; ``../shared/data/f16``). Row 1 of ``Acceleration``
(wing side of the wing-payload interface) plays the spindle, row 2 (payload)
the body. Full-grid random-phase multisines 2-15 Hz, 9 periods × 8192 samples
at 400 Hz (fs read from the file's ``Fs``), levels 1, 3, 5, 7.

Processing: the transient first period is dropped; each level is split in
time (first 2/3 fits, last 1/3 held out: 5.3 and 2.7 periods); integration
band 1.5-40 Hz (no mode below 2 Hz, excitation from 2 Hz; as docs/f16_nifo.md);
spectra one period per block, boxcar, no overlap (leakage-free for the
periodic excitation); declared model: linear; M2 unknown (coefficients per
unit "body" mass).

Run: ``.venv/bin/python tools/f16_loop.py [--data DIR] [--out DIR] [--img docs/img]``
(prints the report, writes loop.json and the figures).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nifo.io.loader import load_record  # noqa: E402
from nifo_core.integrate import IntegrationBand  # noqa: E402
from nifo_core.loop import LoopSettings, close_loop  # noqa: E402
from nifo_core.spectral import SpectralSettings  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "f16"
PERIOD = 8192
BAND = IntegrationBand(1.5, 40.0)
LEVELS = (1, 3, 5, 7)
COLUMNS = {"spindle_accel": "Acceleration[1]", "body_accel": "Acceleration[2]", "fs": "Fs"}


def load_levels(data: Path = DATA, levels=LEVELS):
    """Steady-state periods 2-9 of each full multisine level, as Records."""
    out = []
    for lv in levels:
        r = load_record(data / f"F16Data_FullMSine_Level{lv}.mat", columns=COLUMNS)
        r = r.slice(PERIOD, r.n)
        out.append(r)
    return out


def run_loop(records, *, max_rounds: int = 4, prediction: str = "equation",
             analysis_band_hz: tuple[float, float] = (4.0, 10.0)):
    settings = LoopSettings(max_rounds=max_rounds, spectral=SpectralSettings(block=PERIOD, overlap=0.0,
                                                                             window="boxcar"),
                            analysis_band_hz=analysis_band_hz, prediction=prediction)
    return close_loop(records, (), band=BAND, settings=settings)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--out", type=Path, default=Path("/tmp/f16_loop"))
    ap.add_argument("--img", type=Path, default=ROOT / "docs" / "img")
    args = ap.parse_args(argv)
    recs = load_levels(args.data)
    res = run_loop(recs)
    doc = res.to_dict()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "loop.json").write_text(json.dumps(doc, indent=2) + "\n")
    from nifo.plots.loop import plot_errors, plot_round_evidence
    args.img.mkdir(parents=True, exist_ok=True)
    plot_errors(doc, args.img / "f16_loop_errors.png")
    for r in doc["rounds"]:
        if r.get("added") and r.get("evidence"):
            plot_round_evidence(r, args.img / f"f16_loop_round{r['round']}.png")
    print(res.report())
    for r in res.rounds:
        print(f"round {r.index} ranked:", [(c.term.label, round(c.err, 3), c.present, c.failed[:2]) for c in r.ranked[:4]])
        for t in r.trials:
            print("   tried", t.candidate.term.label, t.accepted, t.failed, "group θ", t.candidate.group_theta)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
