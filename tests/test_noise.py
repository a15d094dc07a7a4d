"""Sensor noise per channel from the data (nifo_core.signal.noise) against the simulator's known noise."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nifo_core.kinds.describing import Term
from nifo_core.signal.noise import estimate_noise
from nifo_core.simulate import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate


@pytest.mark.parametrize("term,coef,rms", [(Term("cubic_stiffness"), 2e8, 0.0025),
                                           (Term("coulomb", {"eps": 0.005}), 100.0, 0.007)])
def test_noise_reaching_z_is_estimated_within_30_percent(term, coef, rms):
    rec = simulate(SimConfig(strut=(StrutForce(term, coef),), road=RandomRoad(rms_m=rms), duration_s=60.0,
                             fs_hz=600.0, noise=SensorNoise(relative=0.02)), rng=3).record
    est = estimate_noise(rec)
    assert est.available, est.unavailable
    # the simulator's noise: 2 % of each channel's RMS, white (psd = 2σ²/fs)
    s1, s2 = (2 * (0.02 * np.std(a)) ** 2 / rec.fs_hz for a in (rec.spindle_accel, rec.body_accel))
    ratio_rel, ratio_1 = est.relative_psd / (s1 + s2), est.channel("spindle_accel").psd / s1
    print(f"\n{term.label}: noise reaching z estimated at {ratio_rel:.2f} × the truth, spindle {ratio_1:.2f} ×; "
          f"{est.text()}")
    assert 0.7 < ratio_rel < 1.3 and 0.7 < ratio_1 < 1.3
    assert est.to_dict()["channels"][0]["percent_of_rms"] == pytest.approx(100 * est.channels[0].relative)


def test_a_record_whose_spindle_does_not_move_has_no_estimate_and_says_why():
    rec = simulate(SimConfig(strut=(), road=RandomRoad(rms_m=0.001), duration_s=20.0, fs_hz=600.0), rng=1).record
    rec = dataclasses.replace(rec, spindle_accel=np.zeros(rec.n), spindle_fixed=True, force=np.asarray(rec.body_accel) * 300.0)
    est = estimate_noise(rec)
    assert rec.spindle_fixed
    assert not est.available and "spindle" in est.unavailable
    assert est.stds == (0.0, 0.0)
