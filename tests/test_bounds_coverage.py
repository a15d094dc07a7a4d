"""Coverage of the ~95 % random-error bounds on the nominal T21 (Bendat & Piersol), in simulation.

20 seeds of a quarter car (60 s at 600 Hz, 2 % sensor noise, paper Table 2
spectra), identified by output-only NIFO; over the lines of 2-30 Hz of all
seeds, the band |T21|·(1 ± k·ε) must hold the true linear |T21| in 90-98 % of
lines (issue 13), k the Student-t factor of the fit's degrees of freedom
(:func:`nifo_core.signal.frf.bound_factor`; 60 s give 5 blocks, where k = 2 held only
91.2 % and 89.5 %). The bounds carry the random error only; a strut whose
describing function sees noise through z (paper §2.2) may add bias: the knee
case measures it.
"""

from __future__ import annotations

import numpy as np
import pytest

from nifo_core.kinds.describing import Term
from nifo_core.nifo.identify import identify_nifo
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

SEEDS = range(20)


def _coverage(strut, terms) -> tuple[float, float]:
    inside = total = 0
    widths = []
    for seed in SEEDS:
        cfg = SimConfig(strut=strut, road=RandomRoad(rms_m=0.0025), duration_s=60.0, fs_hz=600.0,
                        noise=SensorNoise(relative=0.02))
        sim = simulate(cfg, rng=1000 + seed)
        res = identify_nifo(sim.record, terms, on_ill_conditioned="ignore")
        m = (res.freq_hz >= 2.0) & (res.freq_hz <= 30.0)
        lo, hi = res.bounds("t21")
        truth = np.abs(sim.truth.t21(res.freq_hz))
        ok = (truth >= lo) & (truth <= hi)
        assert res.bound_factor() > 2.0      # 60 s: few blocks, a wider factor than the normal quantile
        inside += int(ok[m].sum())
        total += int(m.sum())
        widths.append(float(np.median((hi - lo)[m] / (2 * np.abs(res.t21[m])))))
    return inside / total, float(np.median(widths))


@pytest.mark.slow
def test_t21_bounds_hold_the_truth_in_90_to_98_percent_of_lines_on_a_linear_strut():
    cov, half = _coverage((), [])
    print(f"linear strut: 95 % bounds hold the true |T21| in {100 * cov:.1f} % of lines "
          f"(median half-width {100 * half:.2f} %)")
    assert 0.90 <= cov <= 0.98


@pytest.mark.slow
def test_t21_bounds_hold_the_truth_in_90_to_98_percent_of_lines_with_a_damper_knee():
    cov, half = _coverage((StrutForce(Term("velocity_deadzone", {"knee": 0.03}), -700.0),),
                          [Term("velocity_deadzone", {"knee": 0.03})])
    print(f"damper knee: 95 % bounds hold the true nominal |T21| in {100 * cov:.1f} % of lines "
          f"(median half-width {100 * half:.2f} %)")
    assert 0.90 <= cov <= 0.98
