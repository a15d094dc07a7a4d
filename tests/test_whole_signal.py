"""The predicted signal as the field scores it (docs/method.md §10): the whole signal, offset included, the
distortion at the lines a periodic excitation did not excite, the band a prediction covers and the static part.

Analytic cases first (an offset is all of the error; a prediction that carries the distortion exactly scores 0 %,
predicting none 100 %; a band limit passes its band and nothing else, zero-phase), then the model's static part and
range on simulated records with a known answer.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nifo_core.errors import ConfigError, InputError
from nifo_core.kinds.describing import make_term
from nifo_core.predict.heldout import split_records
from nifo_core.predict.linear_part import BodyModel
from nifo_core.predict.model import IdentifiedModel, predict_body, record_inputs
from nifo_core.predict.time_prediction import Prediction
from nifo_core.predict.output_signal import measured_output, predicted_output
from nifo_core.predict.periodic import model_lines, periodic_prediction, steady_state
from nifo_core.predict.scope import Offsets, PeriodicResponse, PredictionBand, Validity
from nifo_core.predict.scope_fit import fit_scope
from nifo_core.predict.whole_signal import distortion_error, excited_lines, whole_signal_error
from nifo_core.signal.band import band_limit, fraction_outside
from nifo_core.signal.record import Record

FS = 400.0


def test_an_offset_is_the_whole_error_and_its_nmse_is_against_the_variance():
    t = np.arange(4000) / FS
    s = np.sin(2 * np.pi * 5 * t)
    e = whole_signal_error(0.3 + s, s, skip=100)
    assert e.rms_error == pytest.approx(0.3) and e.offset_error == pytest.approx(0.3)
    assert e.nmse_percent == pytest.approx(100 * 0.09 / 0.5, rel=1e-3) and e.after_samples == 100
    with pytest.raises(InputError, match="nothing is left"):
        whole_signal_error(s, s, skip=s.size)


def _multisine(period: int, lines, rng) -> np.ndarray:
    spec = np.zeros(period // 2 + 1, complex)
    spec[lines] = np.exp(2j * np.pi * rng.random(len(lines)))
    return np.fft.irfft(spec, period)


def test_the_distortion_predicted_exactly_scores_zero_and_none_scores_a_hundred():
    rng = np.random.default_rng(1)
    p = 1024
    u = np.tile(_multisine(p, np.arange(10, 60, 2), rng), 6)        # odd-like grid: every other line
    y = u + 0.2 * u ** 2                                              # even distortion on the lines between
    f_band = (10 * FS / p, 60 * FS / p)
    exc = excited_lines(u[:p], FS, f_band)
    assert exc[10:60:2].all() and not exc[11:60:2].any() and not exc[0]
    exact = distortion_error(y, y, u, FS, period_samples=p, band_hz=f_band, skip=p)
    none = distortion_error(y, u, u, FS, period_samples=p, band_hz=f_band, skip=p)
    assert exact.percent_of_none == pytest.approx(0.0, abs=1e-9) and none.percent_of_none == pytest.approx(100.0)
    assert 0 < none.share_percent < 100 and none.measured_rms > 0 and none.lines > 0


def test_a_prediction_that_wanders_from_period_to_period_is_named_not_periodic():
    rng = np.random.default_rng(2)
    p = 1024
    u = np.tile(_multisine(p, np.arange(10, 60, 2), rng), 6)
    y = u + 0.01 * rng.standard_normal(u.size)                        # the structure: periodic up to its noise
    f_band = (10 * FS / p, 60 * FS / p)
    steady = distortion_error(y, u, u, FS, period_samples=p, band_hz=f_band, skip=p)
    assert steady.period_variation_rms == pytest.approx(0.0, abs=1e-12)
    # noise about the average of 5 periods: √(4/5) of its RMS
    assert steady.measured_period_variation_rms == pytest.approx(0.01 * np.sqrt(4 / 5), rel=0.05)
    assert not steady.not_periodic()
    # a model whose response changes from one period to the next (a play slipping on some cycles): 0.05 RMS
    wander = u * (1 + 0.05 * np.repeat(rng.standard_normal(6), p) / np.std(u))
    wanders = distortion_error(y, wander, u, FS, period_samples=p, band_hz=f_band, skip=p)
    assert wanders.period_variation_rms > 2 * wanders.measured_period_variation_rms
    assert wanders.not_periodic() and wanders.not_periodic(steady) and not wanders.not_periodic(wanders)
    assert distortion_error(y[: 2 * p], u[: 2 * p], u[: 2 * p], FS, period_samples=p, band_hz=f_band,
                            skip=p).to_dict()["period_variation_rms"] is None          # one period: no variation


def test_a_band_limit_passes_its_band_zero_phase_and_removes_the_rest():
    t = np.arange(8192) / FS                                  # a whole number of periods of both tones
    inside, outside = np.sin(2 * np.pi * 6.25 * t + 0.7), 0.5 * np.sin(2 * np.pi * 50 * t)
    out = band_limit(inside + outside + 3.0, FS, (2.0, 15.0), period_samples=8192)
    np.testing.assert_allclose(out, inside, atol=1e-9)
    assert fraction_outside(inside + outside, FS, (2.0, 15.0)) == pytest.approx(0.2, rel=1e-6)
    with pytest.raises(ConfigError, match="lower value|0 <= lo < hi"):
        band_limit(inside, FS, (15.0, 2.0))


# -------------------------------------------------------------------------------------------------
# the static part and the range, on a simulated one-mass body with a cubic spring
# -------------------------------------------------------------------------------------------------
BODY = BodyModel(k=(2 * np.pi * 3.0) ** 2, c=2 * 0.08 * 2 * np.pi * 3.0)
CUBIC = make_term("cubic_stiffness")


def _model(gamma: float = 4e6) -> IdentifiedModel:
    return IdentifiedModel.from_body(BODY, [CUBIC], [gamma], fs_hz=FS, analysis_band_hz=(1.0, 30.0))


def _record(seed: int, rms: float, *, a1_bias=0.0, a2_bias=0.0, seconds=60.0, model=None) -> Record:
    """A spindle-driven record whose body is exactly ``model`` (the truth), sensors biased as given."""
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    a1 = band_limit(rng.standard_normal(n), FS, (1.0, 30.0))
    a1 *= rms / a1.std()
    truth = predict_body(model or _model(), a1, FS)
    return Record(FS, a1 + a1_bias, np.asarray(truth.body_accel) + a2_bias, source=f"sim{seed}")


def test_a_spindle_bias_does_not_deflect_the_strut_and_the_body_bias_is_carried():
    clean = _record(3, 2.0)
    biased = replace(clean, spindle_accel=clean.spindle_accel + 0.5, body_accel=clean.body_accel + 0.2)
    m = _model()
    p0 = predict_body(m, *record_inputs(clean, m)[:1], FS)
    p1 = predict_body(m, *record_inputs(biased, m)[:1], FS)
    # a 0.5 m/s² bias would otherwise sit as a static deflection of -0.5/k = -1.4 mm under a cubic spring
    np.testing.assert_allclose(p1.z, p0.z, atol=1e-12)
    held = split_records([biased], band_hz=(1.0, 30.0))
    scoped = fit_scope(m, held)
    assert scoped.offsets.output == pytest.approx(0.2 - 0.5, abs=1e-3)      # the body's bias beyond the common mode
    y = predicted_output(scoped, biased, p1)
    e = whole_signal_error(measured_output(biased).values, y, skip=p1.valid.start)
    assert e.rms_error < 1e-3 * biased.body_accel.std() and abs(e.offset_error) < 1e-4


@pytest.mark.parametrize("offset", [1e-3, 1.0, 1e3, 1e6])
def test_offsets_of_any_size_give_the_same_prediction_and_are_carried(offset):
    clean = _record(4, 2.0)
    shifted = replace(clean, spindle_accel=clean.spindle_accel + offset, body_accel=clean.body_accel + offset)
    m = _model()
    p0 = predict_body(m, *record_inputs(clean, m)[:1], FS)
    p1 = predict_body(m, *record_inputs(shifted, m)[:1], FS)
    np.testing.assert_allclose(p1.body_accel, p0.body_accel, atol=1e-9 * max(1.0, offset))
    scoped = fit_scope(m, split_records([shifted], band_hz=(1.0, 30.0)))
    e = whole_signal_error(shifted.body_accel, predicted_output(scoped, shifted, p1), skip=p1.valid.start)
    assert e.rms_error < 1e-3 * clean.body_accel.std() + 1e-12 * offset


def test_a_force_is_driven_about_the_training_mean_and_the_output_offset_is_what_the_dynamics_leave():
    """A force with a DC offset on a single mass whose displacement sensor reads an offset of its own (a circuit's
    operating point): the model is driven about the identification records' mean force, the prediction of another
    level carries the measured offset."""
    m2 = 2.0
    model = replace(_model(3e4), force_gain=1 / m2)      # the cubic ≈ 30 % of the linear spring at 40 N RMS
    n = int(60 * FS)

    def rec(rms, f_mean, seed):
        f = band_limit(np.random.default_rng(seed).standard_normal(n), FS, (1.0, 30.0))
        f = f * rms / f.std() + f_mean
        truth = predict_body(model, None, FS, force=f - 0.7)      # the system's own operating force is 0.7 N
        return Record(FS, None, np.asarray(truth.body_accel), force=f, body_disp=np.asarray(truth.z) + 0.01,
                      source=f"force{seed}")

    train, test = rec(40.0, 0.7, 1), rec(15.0, 0.7, 2)
    scoped = fit_scope(model, split_records([train], band_hz=(1.0, 30.0)))
    assert scoped.offsets.force == pytest.approx(0.7, abs=0.01) and scoped.offsets.output_name == "body_disp"
    p = predict_body(scoped, None, FS, force=record_inputs(test, scoped)[1])
    e = whole_signal_error(measured_output(test).values, predicted_output(scoped, test, p), skip=p.valid.start)
    assert abs(e.offset_error) < 1e-3 * 0.01 and e.nmse_percent < 0.01


def test_the_validity_names_a_record_mostly_outside_the_band_or_beyond_the_amplitudes():
    recs = [_record(6, 1.0), _record(7, 3.0)]
    v = Validity.of_inputs([r.spindle_accel for r in recs], FS, (1.0, 30.0), input_name="spindle_accel")
    assert v.rms == pytest.approx((1.0, 3.0), rel=0.01) and v.outside_fraction < 0.05   # the taper edges
    inside = v.check(_record(8, 2.0).spindle_accel, FS)
    assert not inside.outside and inside.message == ""
    t = np.arange(int(60 * FS)) / FS
    broadband = np.sin(2 * np.pi * 80 * t) + 0.3 * np.sin(2 * np.pi * 5 * t)
    out = v.check(broadband, FS)
    assert out.outside and "outside 1-30 Hz" in out.message and out.outside_fraction > 0.9
    louder = v.check(_record(9, 6.0).spindle_accel, FS)
    assert louder.outside and "2.00× the highest identified" in louder.message


def test_the_prediction_band_is_chosen_by_the_held_out_whole_signal_error():
    """A linear part whose gain outside the band it was fitted on is wrong (a cubic of the wrong sign there stands
    in for it): the truth has energy out of band; a model that gets it wrong is limited to its band, one that gets it
    right is not."""
    truth = _model()
    recs = [_record(10, 2.0, seconds=60.0, model=truth)]
    held = split_records(recs, band_hz=(2.0, 10.0))
    right = fit_scope(replace(truth, analysis_band_hz=(2.0, 10.0)), held)
    assert right.prediction_band.policy == "whole", right.prediction_band.reason
    wrong_body = BodyModel(k=BODY.k, c=BODY.c * 0.2)           # a resonance at 3 Hz nearly undamped: wrong out of band
    wrong = IdentifiedModel.from_body(wrong_body, [CUBIC], [4e6], fs_hz=FS, analysis_band_hz=(4.5, 30.0))
    limited = fit_scope(wrong, split_records(recs, band_hz=(4.5, 30.0)))
    assert limited.prediction_band.policy == "band", limited.prediction_band.reason
    s = limited.prediction_band.held_out
    assert s["band"] <= 0.98 * s["whole"]


def test_model_json_round_trip_keeps_the_static_part_the_band_and_the_range():
    m = replace(_model(), offsets=Offsets(force=None, output=0.25, output_name="body_accel", how="test"),
                prediction_band=PredictionBand("band", (1.0, 30.0), "chosen", {"whole": 2.0, "band": 1.0}),
                validity=Validity((1.0, 30.0), "spindle_accel", (1.0, 3.0), (3.0, 9.0), 0.01, 2))
    back = IdentifiedModel.from_dict(m.to_dict())
    assert back.offsets == m.offsets and back.prediction_band.policy == "band"
    assert back.validity.rms == (1.0, 3.0) and back.validity.peak == (3.0, 9.0)


# -------------------------------------------------------------------------------------------------
# the periodic response: a periodic input's prediction is the model's periodic steady state when the data say so
# -------------------------------------------------------------------------------------------------
def test_the_steady_state_never_adds_to_the_error_against_a_periodic_response():
    rng = np.random.default_rng(21)
    p = 512
    y = np.tile(_multisine(p, np.arange(5, 40, 2), rng), 7)                     # the structure: periodic
    wander = y + np.repeat(rng.standard_normal(7), p) * 0.1 + 0.05 * rng.standard_normal(y.size)
    ss = steady_state(wander, p, p)
    np.testing.assert_array_equal(ss[:p], wander[:p])                        # the start-up as it was simulated
    periods = ss[p: p + 6 * p].reshape(6, p)
    np.testing.assert_allclose(periods, np.broadcast_to(periods[0], periods.shape), atol=1e-12)
    e_sim, e_ss = (whole_signal_error(y, x, skip=p) for x in (wander, ss))
    # Σ|y - ŷ|² = Σ|y - ŷ_sync|² + Σ|ŷ - ŷ_sync|² over whole periods of a periodic y
    var = distortion_error(y, wander, y, FS, period_samples=p, band_hz=(1.0, 30.0), skip=p).period_variation_rms
    assert e_ss.rms_error ** 2 + var ** 2 == pytest.approx(e_sim.rms_error ** 2, rel=1e-9)
    np.testing.assert_array_equal(steady_state(wander[: 2 * p + 10], p, p), wander[: 2 * p + 10])   # one period


def test_a_model_that_rings_across_periods_predicts_its_periodic_response_and_says_so():
    """A periodic multisine through the cubic body (the structure, periodic); a model whose resonance is nearly
    undamped rings from its start-up through every period, its linear twin does not: the held-out whole-signal error
    chooses the periodic response, and the prediction after the first period is periodic and closer to the
    measurement."""
    rng = np.random.default_rng(22)
    p = 2048
    u = np.tile(_multisine(p, np.arange(6, 60, 3), rng), 8)
    u *= 2.0 / u.std()
    truth = _model()
    rec = Record(FS, u, np.asarray(predict_body(truth, u, FS).body_accel) + 0.002 * rng.standard_normal(u.size),
                 source="periodic")
    held = split_records([rec], band_hz=(1.0, 30.0), period_samples=p)
    ringing = IdentifiedModel.from_body(BodyModel(k=BODY.k, c=BODY.c * 0.03), [CUBIC], [4e6], fs_hz=FS,
                                        analysis_band_hz=(1.0, 30.0))
    twin = fit_scope(IdentifiedModel.from_body(BODY, [], [], fs_hz=FS, analysis_band_hz=(1.0, 30.0)), held,
                     choose_band=False)
    assert twin.periodic_response is None                     # a linear model's response is periodic as it comes
    scoped = fit_scope(ringing, held, choose_band=False, linear=twin)
    pr = scoped.periodic_response
    assert pr.policy == "periodic" and pr.held_out["periodic"] < pr.held_out["simulated"], pr.reason
    sim = predict_body(scoped, record_inputs(rec, scoped)[0], FS)
    lin = predict_body(twin, record_inputs(rec, twin)[0], FS)
    per = periodic_prediction(sim, lin, period_samples=p, start=p)
    e_per, e_sim = (whole_signal_error(rec.body_accel, predicted_output(scoped, rec, x), skip=p) for x in (per, sim))
    assert e_per.rms_error < 0.5 * e_sim.rms_error
    np.testing.assert_allclose(per.body_accel[p:2 * p], per.body_accel[-p:], atol=0.01 * np.std(per.body_accel))
    np.testing.assert_array_equal(per.body_accel[:p], sim.body_accel[:p])      # the start-up as simulated
    assert IdentifiedModel.from_dict(scoped.to_dict()).periodic_response == pr
    # random data choose nothing: the prediction is the simulation as it comes
    assert fit_scope(truth, split_records([_record(23, 2.0)], band_hz=(1.0, 30.0)), linear=twin).periodic_response \
        is None
    with pytest.raises(ConfigError, match="periodic"):
        PeriodicResponse("averaged")


def test_the_periodic_response_keeps_what_the_input_itself_varies():
    """A measured input is not exactly periodic: the part of the response its own variation causes is kept (the
    linear twin's response to it), where averaging the simulation would throw it away."""
    rng = np.random.default_rng(24)
    p = 2048
    periodic = np.tile(_multisine(p, np.arange(6, 60, 3), rng), 6)
    u = 2.0 * periodic / periodic.std() + band_limit(0.2 * rng.standard_normal(periodic.size), FS, (1.0, 30.0))
    truth = _model(3e4)          # the linear twin (no cubic) off by 9 % of the output: the twin is an approximation
    rec = Record(FS, u, np.asarray(predict_body(truth, u, FS).body_accel), source="nearly periodic")
    twin = IdentifiedModel.from_body(BODY, [], [], fs_hz=FS, analysis_band_hz=(1.0, 30.0))
    a1 = record_inputs(rec, truth)[0]
    sim, lin = predict_body(truth, a1, FS), predict_body(twin, a1, FS)
    per = periodic_prediction(sim, lin, period_samples=p, start=p)
    e_per = whole_signal_error(rec.body_accel, per.body_accel, skip=p)
    e_avg = whole_signal_error(rec.body_accel, steady_state(sim.body_accel, p, p), skip=p)
    assert e_per.rms_error < 0.2 * e_avg.rms_error and e_per.nmse_percent < 0.1
    # its period average is the model's: every figure read from it is unchanged
    np.testing.assert_allclose(steady_state(per.body_accel, p, p), steady_state(sim.body_accel, p, p), atol=1e-12)


def test_the_model_s_distortion_can_give_way_to_the_linear_model_s_on_the_lines_not_excited():
    """``keep``: the model's period average on the lines the input excited (and DC), its linear twin's on the
    others — a model whose distortion did not predict the identification records' better than its twin's."""
    rng = np.random.default_rng(25)
    p = 512
    u = _multisine(p, np.arange(5, 40, 2), rng)                      # odd lines excited
    excited = excited_lines(u, FS, (4 * FS / p, 40 * FS / p))
    assert excited[5] and not excited[6] and not excited[0]
    model_distortion, linear_distortion = _multisine(p, [6, 8], rng), _multisine(p, [10, 12], rng)
    m = np.tile(u + model_distortion + 0.3, 4)
    lin = np.tile(0.9 * u + linear_distortion, 4)
    sim = Prediction(m, m, m, 0, 0.0, "test", 0)
    twin = Prediction(lin, lin, lin, 0, 0.0, "test", 0)
    keep = excited.copy()
    keep[0] = True
    got = periodic_prediction(sim, twin, period_samples=p, start=p, keep=keep).body_accel
    np.testing.assert_allclose(got[p:2 * p], u + linear_distortion + 0.3, atol=1e-12)
    # the lines kept: those excited in the band, and every line outside it (there the prediction band decides)
    kept = model_lines(np.tile(u, 4), p, p, FS, (4 * FS / p, 11 * FS / p))
    assert kept[0] and kept[5] and kept[7] and not kept[6] and not kept[8] and kept[12] and kept[13]
    np.testing.assert_allclose(periodic_prediction(sim, twin, period_samples=p, start=p).body_accel[p:2 * p],
                               u + model_distortion + 0.3, atol=1e-12)
