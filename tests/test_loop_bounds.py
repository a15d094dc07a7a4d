"""Coverage of the loop's coefficient bounds (nifo_core.signal.uncertainty) over 20 simulated seeds.

The equation-error fit of the loop (k, c, θ of the true term) on 60 s records
with 2 % noise on both sensors; the 95 % bound must hold the truth in at least
18 of 20 seeds. A Coulomb term's plain fit is biased (noise reaching tanh(ż/ε)
through ż, paper §2.2, and the band-limited ż: -4.5 %, c +1.5 %); the loop
removes the bias by simulating its fit (:mod:`nifo_core.signal.bias_correction`) and
its bound holds the correction's uncertainty too.

Issue 28's acceptance, measured with these tests (20 seeds, 2 % noise on both sensors, 2.5 mm road):
coefficient median / truth and how often the 95 % bound holds the truth — cubic 2e8 N/m³ 1.005, 20/20;
damper knee -700 N·s/m beyond 0.03 m/s 1.002, 20/20; quadratic damping 2000 N·s²/m² 1.001, 20/20; Coulomb
100 N 1.005, 18/20; bump stop 2e5 N/m beyond 4 mm 0.981, 19/20 (seeds 500-509 10/10, median 0.980;
510-519 9/10, median 0.988). Before issue 28's bump-stop work: 0.956, 16/20 (two steps of the correction
and a geometric tail stopped 1-2 % short of its fixed point; the fixed point itself sits -2.5 % low from the
estimated noise level and the noise in the measured drive; the bound missed the gain on the correction's
own error, the synthetic fits' scatter and Student's t: :mod:`nifo_core.signal.bias_correction`).
"""

from __future__ import annotations

import numpy as np
import pytest

from nifo_core.kinds.describing import Term
from nifo_core.predict.heldout import split_records
from nifo_core.loop.state import loop_band
from nifo_core.loop.settings import LoopSettings
from nifo_core.loop.residual import _Evaluator
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

M2 = 300.0


def _coverage(term: Term, coef: float) -> tuple[np.ndarray, np.ndarray]:
    hits, est = [], []
    for seed in range(20):
        cfg = SimConfig(strut=(StrutForce(term, coef),), road=RandomRoad(rms_m=0.0025), duration_s=60.0,
                        fs_hz=600.0, noise=SensorNoise(relative=0.02))
        sim = simulate(cfg, rng=500 + seed)
        band, _ = loop_band([sim.record])
        held = split_records([sim.record], band_hz=(2.0, 30.0))
        ev = _Evaluator(held, band, LoopSettings(prediction="none"))
        b = ev.bounds([term])
        v = sim.truth.vehicle
        truth = np.array([v.k2 / M2, v.c2 / M2, coef / M2])
        hits.append(np.abs(b.theta - truth) <= b.half_width)
        est.append(b.theta[-1] * M2)
    return np.mean(hits, axis=0), np.array(est)


@pytest.mark.slow
def test_quadratic_damping_bounds_hold_the_truth_in_18_of_20_seeds():
    cov, est = _coverage(Term("quadratic_damping"), 2000.0)
    print(f"quadratic damping: coverage k {cov[0]:.2f}, c {cov[1]:.2f}, θ {cov[2]:.2f}; θ·M2 median {np.median(est):.0f}")
    assert np.all(cov >= 0.9)


@pytest.mark.slow
@pytest.mark.parametrize("term,coef", [(Term("cubic_stiffness"), 2e8),
                                       (Term("velocity_deadzone", {"knee": 0.03}), -700.0)],
                         ids=["cubic", "damper_knee"])
def test_cubic_and_knee_within_10_percent_and_bounds_hold_the_truth_in_18_of_20_seeds(term, coef):
    cov, est = _coverage(term, coef)
    print(f"{term.label}: coverage k {cov[0]:.2f}, c {cov[1]:.2f}, θ {cov[2]:.2f}; median/truth "
          f"{np.median(est) / coef:.3f}")
    assert np.all(cov >= 0.9)
    assert abs(np.median(est) / coef - 1) < 0.1


@pytest.mark.slow
def test_bump_stop_within_10_percent_and_its_bound_holds_the_truth_in_18_of_20_seeds():
    """Measured 19 of 20, median 0.981 (seeds 500-509 10/10, 0.980; 510-519 9/10, 0.988; the miss 0.886 ± 0.092).

    The correction's fixed point sits -2.5 % low on average (estimated noise level 0.89 × the truth, the
    measured drive's own noise), within the bound now that it carries what the correction's error does."""
    cov, est = _coverage(Term("bump_stop", {"gap": 0.004, "side": "compression"}), 2e5)
    print(f"bump stop: coverage k {cov[0]:.2f}, c {cov[1]:.2f}, θ {cov[2]:.2f}; median/truth {np.median(est) / 2e5:.3f}")
    assert np.all(cov >= 0.9)
    assert abs(np.median(est) / 2e5 - 1) < 0.1


@pytest.mark.slow
def test_coulomb_bounds_hold_the_truth():
    cov, est = _coverage(Term("coulomb", {"eps": 0.005}), 100.0)
    print(f"coulomb: coverage k {cov[0]:.2f}, c {cov[1]:.2f}, θ {cov[2]:.2f}; θ·M2 median {np.median(est):.1f} N")
    assert np.all(cov >= 0.9)
    assert abs(np.median(est) / 100.0 - 1) < 0.1
