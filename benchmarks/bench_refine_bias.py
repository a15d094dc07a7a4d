"""The output-error refinement with 2 % noise on both sensors: plain against bias-corrected, 20 seeds.

A cubic strut (2e8 N/m³, in the model family) identified by NIFO on 40 s at 2.5 mm road and refined by
output error (nifo_core.predict.refine) from the noisy spindle signal; then the refinement's bias removed by
simulating it with the estimated sensor noise (nifo_core.predict.refine_bias). Printed per seed and summarised:
refined/truth of the cubic coefficient (median), how often its 95 % bound holds the truth, and the
prediction of another level (5 mm, noise-free) against the variance the bounds state (the ratio
miss/stated: of order one when the bounds are right). Run:

    PYTHONPATH=. python benchmarks/bench_refine_bias.py [seeds]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from nifo_core.kinds.describing import Term
from nifo_core.predict.model import IdentifiedModel, predict_body
from nifo_core.nifo import identify_nifo
from nifo_core.signal.noise import estimate_noise
from nifo_core.predict.prediction_bounds import line_spread, prediction_spread
from nifo_core.predict.prediction_error import band_spectra
from nifo_core.predict.refine import refine_model
from nifo_core.predict.refine_bias import correct_refinement
from nifo_core.simulate import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

FS, BAND, M2, CUBIC = 600.0, (2.0, 30.0), 300.0, 2e8
STRUT = (StrutForce(Term("cubic_stiffness", {}), CUBIC),)


def _sim(rms: float, seed: int, noise: float):
    return simulate(SimConfig(strut=STRUT, road=RandomRoad(rms), duration_s=40.0, fs_hz=FS,
                              noise=SensorNoise(relative=noise)), rng=seed).record


def _ratio(model: IdentifiedModel, clean) -> float:
    a1, y = np.asarray(clean.spindle_accel), np.asarray(clean.body_accel)
    sim = lambda m: predict_body(m, a1, FS).body_accel  # noqa: E731
    spread = prediction_spread(model, sim)
    skip = int(5 * FS)
    y_l, yhat_l = band_spectra(y, sim(model), FS, band_hz=BAND, skip_samples=skip)
    sig = line_spread([band_spectra(y, p, FS, band_hz=BAND, skip_samples=skip)[1] for p in spread.plus],
                      [band_spectra(y, m, FS, band_hz=BAND, skip_samples=skip)[1] for m in spread.minus])
    return float(np.sum(np.abs(y_l - yhat_l) ** 2) / np.sum(sig ** 2))


def main(seeds: int = 20) -> None:
    rows = {"plain": [], "corrected": []}
    for seed in range(1, seeds + 1):
        t0 = time.time()
        rec = _sim(0.0025, seed, 0.02)
        res = identify_nifo(rec, [s.term for s in STRUT])
        ref = refine_model(IdentifiedModel.from_nifo(res), [rec], linear=IdentifiedModel.from_nifo(res, source="h1"))
        cor = correct_refinement(ref, [rec], [estimate_noise(rec)])
        clean = _sim(0.005, 100 + seed, 0.0)
        line = []
        for name, r in (("plain", ref), ("corrected", cor)):
            p = r.parameters[0]
            est, hw = p["after"] * M2, (p["half_width_95"] or 0.0) * M2
            ratio = _ratio(r.model, clean)
            rows[name].append((est / CUBIC, abs(est - CUBIC) <= hw, ratio))
            line.append(f"{name} {est:.3g} ± {hw:.2g} (miss/stated {ratio:.2f})")
        print(f"seed {seed}: " + "; ".join(line) + f" ({time.time() - t0:.0f} s)", flush=True)
    for name, v in rows.items():
        a = np.array(v, float)
        print(f"{name}: cubic refined/truth median {np.median(a[:, 0]):.3f} (range {a[:, 0].min():.3f}-"
              f"{a[:, 0].max():.3f}); 95 % bound holds the truth in {int(a[:, 1].sum())}/{len(a)}; prediction miss "
              f"/ stated variance median {np.median(a[:, 2]):.2f} (range {a[:, 2].min():.2f}-{a[:, 2].max():.2f})")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
