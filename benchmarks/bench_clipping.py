#!/usr/bin/env python
"""Where nifo draws the line on clipping (:mod:`nifo_core.signal.clipping`): measured, not guessed.

1. No false alarm: the fraction of samples in flat runs at each channel's extremes on clean data — the bundled
   sample (simulated, every channel), the F-16 benchmark (every level, multisine and sweep: the three accelerations
   and the force) and the Silverbox (input and output at every level). Real data are quantised (the F-16's
   accelerations hold 26 166 distinct values in 108 477 samples), so a continuous signal's extreme is not enough:
   only runs of ``MIN_RUN`` samples at it count.
2. What clipping does: the sample's two road levels with the spindle or the body clipped at ±kσ, identified by NIFO
   with the sample's model (play + damper knee): the change of each coefficient against the unclipped record, per
   fraction flat. The refusal threshold (``REFUSE_FRACTION``) is where the coefficients start to move by more than
   their own scatter.

Run: ``python benchmarks/bench_clipping.py`` (about a minute; prints both tables).
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.io

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nifo.io.loader import load_record  # noqa: E402
from nifo_core.kinds.describing import make_term  # noqa: E402
from nifo_core.nifo.identify import identify_nifo  # noqa: E402
from nifo_core.signal.clipping import MIN_RUN, REFUSE_FRACTION, clipping  # noqa: E402
from nifo_core.signal.spectral import SpectralSettings  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SAMPLE = ROOT / "bags" / "sample"
#: the sample's strut (bags/README.md): a play and a damper knee
TERMS = [{"kind": "backlash", "params": {"deadband": 0.00043}}, {"kind": "velocity_deadzone", "params": {"knee": 0.03}}]


def clean_channels():
    """(file, channel, signal) of every clean channel at hand."""
    for bag in sorted(p for p in SAMPLE.iterdir() if p.is_dir()):
        r = load_record(bag)
        for ch in ("spindle_accel", "body_accel", "tire_patch_disp"):
            if getattr(r, ch) is not None:
                yield bag.name, ch, getattr(r, ch)
    for f in sorted((DATA / "f16").glob("*.mat")):
        m = scipy.io.loadmat(f)
        for i in range(3):
            yield f.name, f"Acceleration[{i}]", m["Acceleration"][i]
        yield f.name, "Force", m["Force"][0]
    for f in sorted((DATA / "silverbox_multilevel").glob("*.mat")):
        key = "um" if "_um_" in f.name else "ym"
        yield f.name, key, scipy.io.loadmat(f)[key].ravel()


def main() -> int:
    worst = 0.0
    print(f"1. clean data: fraction of samples in flat runs (>= {MIN_RUN} samples) at the channel's extremes")
    for name, ch, x in clean_channels():
        c = clipping(x)
        worst = max(worst, c.fraction)
        print(f"  {name:34s} {ch:16s} {100 * c.fraction:.4f} %  ({c.n} samples)")
    print(f"  largest: {100 * worst:.4f} %")
    print(f"\n2. the sample clipped at ±kσ: NIFO's coefficients against the unclipped record "
          f"(refused above {100 * REFUSE_FRACTION:g} %)")
    terms = [make_term(t) for t in TERMS]
    spec = SpectralSettings()
    warnings.simplefilter("ignore")
    for bag in ("road_2p5mm", "road_1mm"):
        r = load_record(SAMPLE / bag)
        ref = identify_nifo(r, terms, settings=spec, analysis_band_hz=(2.0, 30.0), on_ill_conditioned="ignore")
        c0 = ref.static.c_over_m2
        for ch in ("spindle_accel", "body_accel"):
            x = getattr(r, ch)
            for k in (4.0, 3.5, 3.0, 2.75, 2.5, 2.0):
                xc = np.clip(x, -k * x.std(), k * x.std())
                res = identify_nifo(replace(r, **{ch: xc}), terms, settings=spec, analysis_band_hz=(2.0, 30.0),
                                    on_ill_conditioned="ignore")
                change = 100 * np.abs(res.static.c_over_m2 / c0 - 1)
                frac = clipping(xc).fraction
                verdict = "refused" if frac > REFUSE_FRACTION else "warned" if frac > 0 else "silent"
                print(f"  {bag:10s} {ch:13s} ±{k:<4g}σ  {100 * frac:6.3f} % flat  play {change[0]:5.1f} %  "
                      f"knee {change[1]:5.1f} %  -> {verdict}")
    return 0 if worst == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
