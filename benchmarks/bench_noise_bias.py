"""Coefficients and 95 % bounds of the loop's equation-error fit with 2 % noise on both sensors, 20 seeds.

For each kind (truth in the model): the median of estimate/truth for k, c and the term, plain least
squares against the bias-corrected fit (nifo_core.signal.bias_correction), and how often the 95 % bounds
(random error + the correction's uncertainty) hold the truth. Run:

    PYTHONPATH=. python benchmarks/bench_noise_bias.py [seeds]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from nifo_core.kinds.describing import Term
from nifo_core.predict.heldout import split_records
from nifo_core.loop.state import loop_band
from nifo_core.loop.settings import LoopSettings
from nifo_core.loop.residual import _Evaluator
from nifo_core.simulate import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

M2 = 300.0
CASES = {"coulomb 100 N": (Term("coulomb", {"eps": 0.005}), 100.0),
         "quadratic damping 2000 N·s²/m²": (Term("quadratic_damping"), 2000.0),
         "cubic 2e8 N/m³": (Term("cubic_stiffness"), 2e8),
         "damper knee -700 N·s/m at 0.03 m/s": (Term("velocity_deadzone", {"knee": 0.03}), -700.0)}


def main(seeds: int = 20) -> None:
    for name, (term, coef) in CASES.items():
        t0 = time.time()
        hits, est, plain = [], [], []
        for seed in range(seeds):
            cfg = SimConfig(strut=(StrutForce(term, coef),), road=RandomRoad(rms_m=0.0025), duration_s=60.0,
                            fs_hz=600.0, noise=SensorNoise(relative=0.02))
            sim = simulate(cfg, rng=500 + seed)
            band, _ = loop_band([sim.record])
            ev = _Evaluator(split_records([sim.record], band_hz=(2.0, 30.0)), band, LoopSettings(prediction="none"))
            b = ev.bounds([term])
            v = sim.truth.vehicle
            truth = np.array([v.k2 / M2, v.c2 / M2, coef / M2])
            hits.append(np.abs(b.theta - truth) <= b.half_width)
            est.append(b.theta / truth)
            plain.append(ev.joint([term])[0] / truth)
        f = lambda a: " ".join(f"{x:.3f}" for x in a)  # noqa: E731
        print(f"{name}: estimate/truth median (k, c, θ) corrected {f(np.median(est, 0))}, plain "
              f"{f(np.median(plain, 0))}; 95 % bounds hold the truth in {f(np.mean(hits, 0))} of {seeds} seeds "
              f"({time.time() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
