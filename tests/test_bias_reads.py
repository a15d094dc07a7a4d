"""The loop's bias correction simulates and refits only what its fit reads (issue 29).

The equation-error fit the loop corrects reads the fit part of each held record (its first two thirds after the
transient); the held-out third was simulated, integrated and thrown away in every synthetic record. Now every
synthetic record is cut where the fit part, the integrator's reach and the simulation's look-ahead end
(``simulated_correction(..., reads=...)``). What must hold: the same noise draws whatever the cut, a simulated
response whose first samples do not depend on the input beyond the look-ahead, and fit parts the same to rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

from nifo_core.kinds.describing import make_term
from nifo_core.loop.residual import _Evaluator
from nifo_core.loop.settings import LoopSettings
from nifo_core.predict.heldout import split_records
from nifo_core.predict.linear_part import BodyModel, LinearPart
from nifo_core.predict.timesim import lookahead_samples, simulate_response
from nifo_core.signal.bias_correction import simulated_correction
from nifo_core.signal.integrate import IntegrationBand
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate

from conftest import static_cubic_problem


def test_records_cut_where_the_fit_stops_reading_give_the_same_correction_bit_for_bit():
    """A fit that reads the first 1800 of 3000 samples: cut there, every number of the correction is the uncut one's
    to the last bit (the noise draws are taken for the whole records, so the cut does not move the seed's stream)."""
    m = 1800
    model, fit, recs, noise = static_cubic_problem(5, 3000, read=m)
    theta0 = fit(recs)
    whole = simulated_correction(fit, model, recs, noise, theta0, pairs=2, drive_noise=True)
    seen = []

    def simulate(theta, rec):
        seen.append(rec.n)
        return model(theta, rec)

    cut = simulated_correction(fit, simulate, recs, noise, theta0, pairs=2, drive_noise=True, reads=[m] * 3)
    assert whole is not None and not np.array_equal(whole.theta, theta0)    # a correction was made
    assert set(seen) == {m}                                                 # only the part read was simulated
    for name in ("theta", "noise_bias", "draw_sd", "tail", "drive_sd", "fit_sd"):
        assert np.array_equal(getattr(whole, name), getattr(cut, name)), name
    assert whole.gain == cut.gain


@pytest.mark.parametrize("fs, q", [(600.0, 4), (400.0, 6), (1000.0, 3)])
def test_a_response_does_not_depend_on_input_beyond_the_look_ahead(fs, q):
    """The march is causal, its interpolation and decimation reach ``lookahead_samples(q)`` ahead: a response to an
    input cut k + look-ahead samples on equals the whole input's on its first k samples (to rounding), and one cut
    at k alone does not (the look-ahead is needed)."""
    rng = np.random.default_rng(11)
    n, k = 6000, 4000
    v = rng.standard_normal(n)
    lin = LinearPart("body", body=BodyModel(k=(2 * np.pi * 1.5) ** 2, c=2.0))
    terms, gammas = [make_term("cubic_stiffness"), make_term({"coulomb": {"eps": 0.01}})], [2e4, 0.3]
    full = simulate_response(lin, terms, gammas, v, fs, spindle_accel=v, oversample=q).body_accel
    ahead = lookahead_samples(q)
    cut = simulate_response(lin, terms, gammas, v[:k + ahead], fs, spindle_accel=v[:k + ahead],
                            oversample=q).body_accel
    scale = np.max(np.abs(full))
    assert np.max(np.abs(cut[:k] - full[:k])) <= 1e-12 * scale
    short = simulate_response(lin, terms, gammas, v[:k], fs, spindle_accel=v[:k], oversample=q).body_accel
    assert np.max(np.abs(short[:k] - full[:k])) > 1e-9 * scale


def test_the_loops_fit_parts_are_the_same_from_records_cut_at_what_they_read():
    """The loop's evaluator on two simulated levels: the fit parts made from the records cut at ``_reads()`` equal
    those of the whole records to rounding, while the cut drops the held-out third's work."""
    recs = [simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=60.0, road=RandomRoad(r)), rng=3).record
            for r in (1e-3, 2.5e-3)]
    settings = LoopSettings()
    held = split_records(recs, skip_samples=600, fit_fraction=settings.fit_fraction, band_hz=(2.0, 40.0))
    ev = _Evaluator(held, IntegrationBand(1.5, 120.0), settings)
    reads = ev._reads()
    assert all(k < 0.8 * r.n for k, r in zip(reads, recs))
    full = ev._fit_parts_of(list(held.records))
    cut = ev._fit_parts_of([r.slice(0, k) for r, k in zip(held.records, reads)])
    for a, b in zip(full, cut):
        assert a.y.shape == b.y.shape
        assert np.max(np.abs(a.y - b.y)) <= 1e-11 * np.max(np.abs(a.y))
        for x, y in zip(a.linear, b.linear):
            assert np.max(np.abs(x - y)) <= 1e-12 * np.max(np.abs(x))
