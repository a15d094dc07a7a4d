"""The loop's bias correction prepares each noise draw once (issue 58: work computed twice, computed once).

The equation-error fit the loop corrects reads integrated and band-passed columns of each synthetic record, and a
synthetic record is a simulated body plus ± a noise draw: its columns are the clean record's plus ± the draw's.
:class:`~nifo_core.signal.bias_correction.LinearFit` says so, and the correction then prepares each step's clean
records and each draw once instead of every noisy record. What must hold: the same correction as fitting every noisy
record whole, to rounding, with fewer preparations.
"""

from __future__ import annotations

import numpy as np

from nifo_core.kinds.describing import make_term
from nifo_core.loop.residual import BIAS_PAIRS, _Evaluator, _parts_sum
from nifo_core.loop.settings import LoopSettings
from nifo_core.predict.heldout import split_records
from nifo_core.predict.model import predict_body
from nifo_core.signal.bias_correction import DRIVE_PAIRS, FULL_STEPS, LinearFit, simulated_correction
from nifo_core.signal.integrate import IntegrationBand
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, preset, simulate


def test_a_linear_fits_correction_prepares_each_draw_once_and_equals_the_whole_fits():
    recs = [simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=40.0, road=RandomRoad(r),
                               noise=SensorNoise(relative=0.02)), rng=7).record for r in (1.5e-3, 3e-3)]
    settings = LoopSettings()
    held = split_records(recs, skip_samples=600, fit_fraction=settings.fit_fraction, band_hz=(2.0, 40.0))
    ev = _Evaluator(held, IntegrationBand(1.5, 120.0), settings)
    terms = (make_term("cubic_stiffness"), make_term({"velocity_deadzone": {"knee": 0.03}}))
    spectral, band_hz = settings.spectral, settings.analysis_band_hz

    def body(theta, rec):
        return predict_body(ev._model_of(terms, theta, spectral, band_hz), np.asarray(rec.spindle_accel),
                            rec.fs_hz).body_accel

    prepared = []

    def prepare(rs):
        prepared.append(len(rs))
        return ev._fit_parts_of(rs)

    def whole(rs):
        prepared.append(len(rs))
        return ev._lstsq(ev._fit_parts_of(rs), terms)

    theta0 = ev._lstsq(ev.fit_parts, terms)
    kw = dict(seed=3, iterations=3, pairs=BIAS_PAIRS, drive_noise=True, reads=ev._reads())
    plain = simulated_correction(whole, body, list(held.records), ev.noise, theta0, **kw)
    n_plain = len(prepared)
    prepared.clear()
    linear = simulated_correction(LinearFit(prepare, _parts_sum, lambda parts: ev._lstsq(parts, terms)), body,
                                  list(held.records), ev.noise, theta0, **kw)
    assert plain is not None and linear is not None
    assert not np.allclose(plain.theta, theta0, rtol=1e-6)          # a correction was made
    for name in ("theta", "noise_bias", "draw_sd", "tail", "drive_sd", "fit_sd"):
        a, b = getattr(plain, name), getattr(linear, name)
        assert np.allclose(a, b, rtol=1e-9, atol=1e-12 * np.max(np.abs(theta0))), name
    # three steps: one pair's two noisy fits, then every pair's (the last FULL_STEPS), the noise-free fit at the last,
    # the drive's; against each step's clean records, each draw and each drive prepared once
    steps, drives = 3, 2 * DRIVE_PAIRS
    assert n_plain == 2 * (steps - FULL_STEPS) + 2 * BIAS_PAIRS * FULL_STEPS + 1 + drives
    assert len(prepared) == steps + BIAS_PAIRS + drives
