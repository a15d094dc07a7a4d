"""Restoring-force data, slicing and the automatic characterization (nifo_core.characterize.restoring / .characterize).

Analytic cases first (band-pass = derivative of the integrated velocity, a
chirp's frequency, slices), then the simulator at the paper's settings with
2 % sensor noise: a linear strut gives a planar surface and no candidate; each
strut nonlinearity alone is ranked first with its key parameter within 20 %.
"""

from __future__ import annotations

import numpy as np
import pytest

from nifo_core.characterize.automatic import (DEFAULT_KINDS, Thresholds, candidate_grid, characterize,
                                    characterize_restoring)
from nifo_core.kinds.describing import Term
from nifo_core.errors import ConfigError, InputError
from nifo_core.signal.integrate import IntegrationBand, integrate
from nifo_core.signal.record import Record
from nifo_core.characterize.restoring import (amplitude_slices, bandpass, bandpass_settle_samples, frequency_slices,
                                 restoring_force, suggest_band, track_frequency)
from nifo_core.simulate.quarter_car import ChirpRoad, RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

M2 = 300.0  # QuarterCar default sprung mass [kg]


def _sim(strut=(), *, rms_m=0.0025, noise=0.02, seed=1, duration_s=300.0):
    cfg = SimConfig(strut=tuple(strut), road=RandomRoad(rms_m=rms_m), duration_s=duration_s, fs_hz=600.0,
                    noise=SensorNoise(relative=noise))
    return simulate(cfg, rng=seed)


# --------------------------------------------------------------------------------------------
# analytic
# --------------------------------------------------------------------------------------------
def test_bandpass_equals_the_derivative_of_the_integrated_velocity():
    fs, band = 200.0, IntegrationBand(1.0, 60.0)
    rng = np.random.default_rng(0)
    a = rng.standard_normal(40_000)
    v = integrate(a, fs, band=band).velocity
    dv = np.gradient(v, 1 / fs)
    b = bandpass(a, fs, band)
    s = slice(5000, -5000)
    # np.gradient is a 2nd-order difference: compare where it is accurate (below 5 Hz: 0.4 %)
    lo = IntegrationBand(1.0, 5.0)
    assert np.std(bandpass(b - dv, fs, lo)[s]) < 0.01 * np.std(bandpass(b, fs, lo)[s])


def test_bandpass_passes_a_sine_in_band_and_stops_one_outside():
    fs, band = 300.0, IntegrationBand(1.0, 50.0)
    t = np.arange(60_000) / fs
    inside, outside = np.sin(2 * np.pi * 7.0 * t), np.sin(2 * np.pi * 0.2 * t)
    s = slice(bandpass_settle_samples(fs, band), -bandpass_settle_samples(fs, band))
    np.testing.assert_allclose(bandpass(inside, fs, band)[s], inside[s], atol=5e-3)
    assert np.max(np.abs(bandpass(outside, fs, band)[s])) < 5e-3


def test_bandpass_does_not_mutate_its_input():
    x = np.random.default_rng(1).standard_normal(5000)
    x0 = x.copy()
    bandpass(x, 100.0, IntegrationBand(2.0, 30.0))
    np.testing.assert_array_equal(x, x0)


def test_bandpass_remembers_by_content_the_same_bits_and_never_a_stale_result():
    """The loop band-passes the same g(z, ż) again and again: an earlier result is returned for an equal array (the
    same bits as computing it), never for a changed one (the memo keys on content, not identity), and is read-only."""
    from nifo_core.characterize import restoring

    fs, band = 200.0, IntegrationBand(1.0, 60.0)
    x = np.random.default_rng(2).standard_normal((2, 8000))
    first = bandpass(x, fs, band)
    fresh = restoring._bandpassed(x.copy(), fs, 1.0, 60.0)
    np.testing.assert_array_equal(first, fresh)
    again = bandpass(x.copy(), fs, band)
    assert again is first and not again.flags.writeable        # found by content
    x[1, 4000] += 1.0                                           # the same array object, changed in place
    changed = bandpass(x, fs, band)
    assert changed is not first and np.abs(changed - first).max() > 1e-3
    np.testing.assert_array_equal(changed, restoring._bandpassed(x.copy(), fs, 1.0, 60.0))
    assert bandpass(x, fs, IntegrationBand(2.0, 60.0)) is not changed   # another band: another result


def test_track_frequency_follows_a_chirp_and_flags_it_as_a_sweep():
    fs = 300.0
    t = np.arange(int(200 * fs)) / fs
    f0, rate = 1.0, 0.05
    x = np.sin(2 * np.pi * (f0 * t + 0.5 * rate * t**2))
    tr = track_frequency(x, fs, weight="acceleration")
    inner = slice(int(10 * fs), int(190 * fs))
    np.testing.assert_allclose(tr.freq_hz[inner], (f0 + rate * t)[inner], rtol=0.01)
    assert tr.is_sweep
    noise = np.random.default_rng(2).standard_normal(t.size)
    assert not track_frequency(noise, fs).is_sweep


def test_frequency_slices_are_windows_of_the_instantaneous_frequency():
    sim = simulate(SimConfig(road=ChirpRoad(amplitude_m=0.0005, f0_hz=0.0, f1_hz=15.0, rate_hz_per_s=0.05),
                             fs_hz=300.0, noise=SensorNoise(relative=0.02)), rng=3)
    rf = restoring_force(sim.record, band=IntegrationBand(1.5, 100.0))
    tr = track_frequency(rf.spindle_accel, rf.fs_hz)
    assert tr.is_sweep
    sl = frequency_slices(rf, [3.8, 5.0, 8.4, 14.2, 40.0], inst_freq_hz=tr.freq_hz)
    assert [s.centre for s in sl] == [3.8, 5.0, 8.4, 14.2]  # 40 Hz is never reached
    for s in sl:
        assert np.all(np.diff(s.index) == 1)  # one contiguous pass of the sweep
        true_f = 0.05 * (rf.time_s[s.index])  # the road's frequency at those samples (f0 = 0)
        assert abs(np.median(true_f) - s.centre) < 0.1 * s.centre
        assert s.n >= 6 * rf.fs_hz / s.centre


def test_amplitude_slices_partition_the_samples_by_local_amplitude():
    rf = restoring_force(_sim(duration_s=120.0, seed=4).record, band=IntegrationBand(1.5, 200.0))
    sl = amplitude_slices(rf, 4)
    assert len(sl) == 4
    idx = np.concatenate([s.index for s in sl])
    assert np.array_equal(np.sort(idx), np.arange(rf.n))
    assert [s.centre for s in sl] == sorted(s.centre for s in sl)


def test_candidate_grids_scale_with_the_observed_motion():
    small = candidate_grid("clearance", z_range=1e-3, zdot_range=0.1)
    large = candidate_grid("clearance", z_range=1e-2, zdot_range=0.1)
    np.testing.assert_allclose([t.params["gap"] for t in large], [10 * t.params["gap"] for t in small])
    knees = [t.params["knee"] for t in candidate_grid("velocity_deadzone", z_range=1e-3, zdot_range=0.2)]
    assert min(knees) > 0 and max(knees) < 0.2
    sides = {t.params["side"] for t in candidate_grid("bump_stop", z_range=1e-3, zdot_range=0.1)}
    assert sides == {"compression", "rebound"}
    with pytest.raises(InputError, match="motion range"):
        candidate_grid("clearance", z_range=0.0, zdot_range=0.1)


def test_suggest_band_raises_the_lower_edge_where_integrated_noise_dominates():
    clean = suggest_band(_sim(noise=0.0, duration_s=120.0, seed=5).record)
    noisy = suggest_band(_sim(noise=0.02, duration_s=120.0, seed=5).record)
    assert clean.band.f_lo_hz < 0.6
    assert 1.0 < noisy.band.f_lo_hz < 2.5
    assert noisy.snr_db_at_hz[3.0] > 10 > noisy.snr_db_at_hz[0.5]
    assert "above the integrated accelerometer noise" in noisy.reason


def test_suggest_band_judges_several_records_together_whatever_their_order():
    # a friction that nearly locks the strut at 1 mm road: alone, that record's z is noisy up to ~4 Hz; with the
    # 6 mm record beside it the stacked regression sees z out of the noise from lower down, in either order
    # (benchmarks/bench_loop.py's four levels: 3.96 Hz from the 1 mm record alone, 1.61 Hz together)
    strut = (StrutForce(Term("velocity_deadzone", {"knee": 0.03}), -700.0),
             StrutForce(Term("coulomb", {"eps": 0.005}), 100.0))
    low, high = (_sim(strut, rms_m=r, duration_s=120.0, seed=3).record for r in (0.001, 0.006))
    alone = suggest_band(low).band.f_lo_hz
    both = suggest_band([low, high])
    print(f"1 mm alone {alone} Hz, 6 mm alone {suggest_band(high).band.f_lo_hz} Hz, together {both.band.f_lo_hz} Hz")
    assert both.band == suggest_band([high, low]).band
    # measured: 1 mm alone 3.81 Hz, 6 mm alone 1.61 Hz, together 2.53 Hz (the sum's noise floor is both records')
    assert suggest_band(high).band.f_lo_hz <= both.band.f_lo_hz < alone - 1.0
    assert "2 records' spectra summed" in both.reason
    with pytest.raises(InputError, match="no records"):
        suggest_band([])


# --------------------------------------------------------------------------------------------
# simulator: negative controls
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def linear_sim():
    """150 s, half the paper's 300 s (issue 58). Measured on 2026-12-06, seeds 11, 111, 211 (seed 11 on 300 s in
    brackets): R² 0.9987 (0.9988), k / truth 0.981-0.985 (0.988; tolerance 10 %), c / truth 0.9996-0.9997 (0.9998;
    2 %), nothing found, the first candidate's err 0.0042-0.0100 (0.0019; limit 0.02), the static candidates' at the
    low band edge at most 0.0007 (0.0001; limit 0.005)."""
    return _sim(seed=11, duration_s=150.0)


def test_linear_strut_gives_a_planar_restoring_force_surface(linear_sim):
    rec = linear_sim.record
    rf = restoring_force(rec, band=suggest_band(rec).band)
    k, c, r2 = rf.linear_fit()
    assert r2 > 0.99
    car = linear_sim.truth.vehicle
    assert k == pytest.approx(car.k2 / car.m2, rel=0.1)
    assert c == pytest.approx(car.c2 / car.m2, rel=0.02)


def test_linear_strut_reports_no_nonlinear_candidate(linear_sim):
    ch = characterize(linear_sim.record, m2_kg=M2)
    assert ch.nothing_found
    assert not any(c.present for c in ch.candidates)
    assert ch.candidates[0].err < Thresholds().min_err
    assert ch.linear["r2"] > 0.99
    assert "no nonlinear candidate" in ch.notes[0]


def test_noise_free_linear_strut_reports_nothing_though_its_residual_is_only_rounding():
    ch = characterize(_sim(noise=0.0, duration_s=120.0, seed=12).record)
    assert ch.nothing_found


def test_static_candidates_explain_nothing_on_a_linear_strut_even_at_a_low_band_edge(linear_sim):
    # the integrator's low transition band holds most of z's integrated noise; y, z, ż and every g
    # get the same final filter, so a static g(z) cannot pick that noise up (module docstring)
    ch = characterize(linear_sim.record, band=IntegrationBand(0.67, 200.0),
                      kinds=("clearance", "cubic_stiffness", "bump_stop", "velocity_deadzone"))
    assert all(c.err < 0.005 for c in ch.candidates)


# --------------------------------------------------------------------------------------------
# simulator: each nonlinearity alone is ranked first with its key parameter
# --------------------------------------------------------------------------------------------
CASES = {
    # name: (strut, road RMS [m], expected kind, key, true value, rel. tolerance)
    "velocity_deadzone": ((StrutForce(Term("velocity_deadzone", {"knee": 0.03}), -700.0),), 0.0025,
                          "velocity_deadzone", "knee", 0.03, 0.2),
    "coulomb": ((StrutForce(Term("coulomb", {"eps": 0.005}), 100.0),), 0.0025, "coulomb", "coefficient", 100.0, 0.2),
    "cubic": ((StrutForce(Term("cubic_stiffness"), 2e8),), 0.0025, "cubic_stiffness", "coefficient", 2e8, 0.3),
    # backlash dominates at low level (paper §3.3: 0.5-1.0 mm)
    "backlash": ((StrutForce(Term("backlash", {"deadband": 0.00043}), 8e3),), 0.0005, "backlash", "deadband",
                 0.00043, 0.2),
    "bump_stop": ((StrutForce(Term("bump_stop", {"gap": 0.008, "side": "compression"}), 50e3),), 0.007,
                  "bump_stop", "gap", 0.008, 0.2),
    "bump_stop_small_gap": ((StrutForce(Term("bump_stop", {"gap": 0.004, "side": "compression"}), 50e3),), 0.0025,
                            "bump_stop", "gap", 0.004, 0.2),
}


@pytest.mark.parametrize("name", list(CASES))
def test_a_single_strut_nonlinearity_is_ranked_first_with_its_key_parameter(name):
    """On 150 s, half the paper's 300 s (issue 58: half the CPU). Measured on 2026-12-06 with this test's seed and
    the seeds 100 and 200 after it, every assertion holding on all three (key parameter / truth): knee 1.067-1.093
    (1.076 on 300 s), Coulomb 1.013-1.017 (1.018), cubic 0.926-0.971 (0.935; tolerance 30 %), backlash 0.909-0.995
    (0.948), bump stop gap 0.980-0.999 (1.006), small gap 0.997-1.000 (1.002)."""
    strut, rms, kind, key, truth, tol = CASES[name]
    ch = characterize(_sim(strut, rms_m=rms, seed=20 + list(CASES).index(name), duration_s=150.0).record, m2_kg=M2)
    top = ch.candidates[0]
    assert top.kind == kind, [(c.term.label, round(c.err, 4)) for c in ch.candidates[:3]]
    assert top.present and top.status == "suggested"
    assert ch.suggested[0].term == top.term
    value = top.coefficient if key == "coefficient" else top.term.params[key]
    assert value == pytest.approx(truth, rel=tol)
    if kind == "bump_stop":
        assert top.term.params["side"] == "compression" and top.coefficient > 0
    # correlated near-duplicates are alternatives, not suggested beside it
    assert all(c.status != "suggested" for c in ch.candidates[1:] if c.alternative_to == top.term.label)


def test_exact_equivalents_and_near_duplicates_are_named_not_suggested():
    ch = characterize(_sim(CASES["velocity_deadzone"][0], seed=30, duration_s=200.0).record, m2_kg=M2)
    top = ch.candidates[0]
    assert top.equivalent.startswith("velocity_saturation(limit=")
    coulomb = ch.candidate("coulomb")
    assert coulomb.status == "alternative" and coulomb.alternative_to == top.term.label
    assert [c.kind for c in ch.suggested] == ["velocity_deadzone"]
    assert top.coefficient == pytest.approx(-700, rel=0.2)
    assert "digressive" in top.describe()


# --------------------------------------------------------------------------------------------
# results, options and errors
# --------------------------------------------------------------------------------------------
def test_result_serialises_and_model_reproduces_the_fit(linear_sim):
    rf = restoring_force(linear_sim.record, band=IntegrationBand(1.5, 200.0))
    ch = characterize_restoring([rf], kinds=("cubic_stiffness", "coulomb"), grid_points=6)
    d = ch.to_dict()
    assert d["band"] == {"f_lo_hz": 1.5, "f_hi_hz": 200.0}
    assert {c["kind"] for c in d["candidates"]} == {"cubic_stiffness", "coulomb"}
    assert d["records"][0]["linear_r2"] > 0.99
    f = ch.model.force(rf.z, rf.zdot, fs_hz=rf.fs_hz, band=rf.band)
    assert np.corrcoef(f, rf.force)[0, 1] > 0.99


def test_characterize_does_not_mutate_the_record(linear_sim):
    rec = linear_sim.record
    before = rec.body_accel.copy()
    characterize(rec, band=IntegrationBand(1.5, 200.0), kinds=("coulomb",), grid_points=4)
    np.testing.assert_array_equal(rec.body_accel, before)


def test_records_at_several_levels_form_the_stability_groups():
    strut = CASES["coulomb"][0]
    recs = [_sim(strut, rms_m=r, seed=40 + i, duration_s=120.0).record for i, r in enumerate((0.0015, 0.004))]
    ch = characterize(recs, band=IntegrationBand(2.0, 200.0), m2_kg=M2, kinds=("coulomb", "cubic_stiffness"))
    top = ch.candidates[0]
    assert top.kind == "coulomb" and len(top.group_theta) == 2
    assert top.spread < 0.2
    assert len(ch.records) == 2 and ch.records[1].z_rms_m > ch.records[0].z_rms_m


def test_characterize_refuses_bad_options(linear_sim):
    rec = linear_sim.record
    rf1 = restoring_force(rec, band=IntegrationBand(1.5, 200.0))
    rf2 = restoring_force(rec, band=IntegrationBand(2.0, 200.0))
    with pytest.raises(ConfigError, match="different bands"):
        characterize_restoring([rf1, rf2])
    with pytest.raises(ConfigError, match="m2_kg"):
        characterize_restoring([rf1], m2_kg=-1.0)
    with pytest.raises(ConfigError, match="unknown nonlinearity kind"):
        characterize_restoring([rf1], kinds=("warp_drive",))
    with pytest.raises(InputError, match="selected"):
        characterize(rec, band=IntegrationBand(1.5, 200.0), freq_window_hz=(100.0, 101.0))
    with pytest.raises(InputError, match="no records"):
        characterize([])
    short = Record(600.0, rec.spindle_accel[:3000], rec.body_accel[:3000], source="short.csv")
    with pytest.raises(InputError, match="short.csv"):
        characterize(short, band=IntegrationBand(1.5, 200.0))


def test_default_kinds_are_all_in_the_library():
    from nifo_core.kinds.describing import KINDS

    assert set(DEFAULT_KINDS) <= set(KINDS)


def test_body_stiffness_fits_a_rig_restraint_k3_from_the_body_displacement():
    from nifo_core.simulate.vehicle import QuarterCar

    sim = simulate(SimConfig(vehicle=QuarterCar(k3=10e3), road=RandomRoad(0.0025), duration_s=120.0,
                             noise=SensorNoise(relative=0.02)), rng=3)
    ch = characterize(sim.record, body_stiffness=True, m2_kg=M2, kinds=("cubic_stiffness", "clearance"))
    assert ch.linear["k3_n_per_m"] == pytest.approx(10e3, rel=0.1)
    assert ch.linear["k2_n_per_m"] == pytest.approx(22e3, rel=0.1)
    assert ch.nothing_found


# --------------------------------------------------------------------------------------------
# bump stops are measured from the static position; quadratic damping is named
# --------------------------------------------------------------------------------------------
def test_mean_shift_solves_the_force_balance_of_the_mean():
    from nifo_core.characterize.static import mean_shift

    t = np.linspace(0.0, 20.0, 20_001)
    z = 0.006 * np.sin(2 * np.pi * 1.3 * t)           # zero-mean: measured from its mean
    m_true, k, stop = 0.0012, 70.0, Term("bump_stop", {"gap": 0.004, "side": "compression"})
    g = stop.evaluate(z + m_true, 0 * z)               # the stop in static coordinates
    theta = -k * m_true / float(np.mean(g))            # θ for which the mean force vanishes at m_true
    assert mean_shift(z, 0 * z, k, [(stop, theta)]) == pytest.approx(m_true, rel=1e-6)
    assert mean_shift(z, 0 * z, k, []) == 0.0          # nothing one-sided: the mean is the static position
    # sought first around a nearby value (a fixed point's step before), the same root to the solver's tolerance
    for near in (m_true, 0.5 * m_true, -m_true, 0.0):
        assert mean_shift(z, 0 * z, k, [(stop, theta)], near=near) == pytest.approx(m_true, rel=1e-6)


@pytest.mark.parametrize("term", [Term("cubic_stiffness"), Term("quadratic_stiffness"),
                                  Term("clearance", {"gap": 2e-3}), Term("saturation", {"limit": 2e-3}),
                                  Term("bump_stop", {"gap": 4e-3}),
                                  Term("bump_stop", {"gap": 3e-3, "side": "rebound", "offset": 1e-3}),
                                  Term("backlash", {"deadband": 1e-3}), Term("coulomb", {"eps": 0.01})],
                         ids=lambda t: t.label)
def test_a_records_means_at_any_shift_are_its_samples_means(term):
    """The balance's means from a record's sorted z (a kind given as pieces of a polynomial: two binary searches),
    from ż once (it does not move with the shift), or sample by sample (a play): the samples' own mean, to rounding.
    Each kind's pieces are its g: a piece that drifted from ``func`` fails here."""
    from nifo_core.characterize.static import RecordMeans

    rng = np.random.default_rng(7)
    z, zdot = rng.normal(0.0, 3e-3, 50_000), rng.normal(0.0, 0.05, 50_000)
    means = RecordMeans(z, zdot)
    scale = float(np.mean(np.abs(term.evaluate(z, zdot))))
    for m in (0.0, 7e-4, -1.3e-3, 2.5e-3):
        assert means.mean(term, m) == pytest.approx(float(np.mean(term.evaluate(z + m, zdot))), abs=1e-12 * scale)
    if term.spec.pieces is not None:    # every piece is g on its interval, g is 0 outside them
        x = np.linspace(-0.02, 0.02, 4001)
        got = np.zeros_like(x)
        for lo, hi, a in term.spec.pieces(term.params):
            inside = (x >= lo) & (x < hi)
            got[inside] = np.polynomial.polynomial.polyval(x[inside], a)
        assert got == pytest.approx(term.evaluate(x, 0 * x), abs=1e-15)


def test_bump_stop_gap_is_measured_from_the_static_position_at_every_level():
    # a stiff stop pushes the mean position into rebound, more at the higher level: measured from the
    # mean the gap read 8.5 and 9.9 mm; from the static position it is one gap, with one offset per level
    strut = (StrutForce(Term("bump_stop", {"gap": 0.008, "side": "compression"}), 2e5),)
    sims = [simulate(SimConfig(strut=strut, road=RandomRoad(rms_m=r), duration_s=120.0, fs_hz=600.0,
                               noise=SensorNoise(relative=0.02)), rng=7 + i) for i, r in enumerate((0.005, 0.007))]
    for recs in ([sims[1].record], [s.record for s in sims]):
        ch = characterize(recs, m2_kg=M2)
        stop = ch.suggested[0]
        assert stop.kind == "bump_stop" and stop.term.params["side"] == "compression"
        assert stop.term.params["gap"] == pytest.approx(0.008, rel=0.1)
        true_mean = [float(np.mean(s.truth.z)) for s in (sims[1:] if len(recs) == 1 else sims)]
        np.testing.assert_allclose(-np.array(stop.offsets), true_mean, atol=0.3e-3)
        assert "from the static position" in stop.describe()
        assert stop.to_dict()["offset_per_record_m"] == list(stop.offsets)


@pytest.mark.parametrize("spectrum,rms", [("flat", 0.0025), ("iso8608", 0.0025), ("flat", 0.0005)])
def test_quadratic_damping_is_named_not_a_rising_knee(spectrum, rms):
    strut = (StrutForce(Term("quadratic_damping"), 2000.0),)
    sim = simulate(SimConfig(strut=strut, road=RandomRoad(rms_m=rms, spectrum=spectrum), duration_s=120.0,
                             fs_hz=600.0, noise=SensorNoise(relative=0.02)), rng=5)
    ch = characterize(sim.record, m2_kg=M2)
    assert [c.kind for c in ch.suggested] == ["quadratic_damping"]
    assert ch.suggested[0].coefficient == pytest.approx(2000.0, rel=0.1)
    assert ch.candidate("velocity_deadzone").status in ("alternative", "redundant", "weak")


def test_quadratic_stiffness_is_evaluated_from_the_static_position_at_every_level():
    # z² pushes the mean position by m = -θ·mean z²/k, more at the higher level; (z + m)² = z² + 2m·z + m²
    # is a stiffness 2θm that differs per level. Evaluated on z from the static position, one k holds
    # every level: the offsets are the records' true mean positions and no level-dependent term is added.
    strut = (StrutForce(Term("velocity_deadzone", {"knee": 0.03}), -700.0),
             StrutForce(Term("quadratic_stiffness"), 3e5))
    sims = [simulate(SimConfig(strut=strut, road=RandomRoad(rms_m=r), duration_s=60.0,
                               noise=SensorNoise(relative=0.02)), rng=31 + i) for i, r in enumerate((0.0025, 0.006))]
    ch = characterize([s.record for s in sims], m2_kg=M2)
    assert sorted(c.kind for c in ch.suggested) == ["quadratic_stiffness", "velocity_deadzone"]
    quad = next(c for c in ch.suggested if c.kind == "quadratic_stiffness")
    true_mean = [float(np.mean(s.truth.z)) for s in sims]
    print("mean position from static per record", [round(1e3 * m, 3) for m in true_mean], "mm; fitted",
          [round(-1e3 * o, 3) for o in quad.offsets], "coefficient", quad.coefficient)
    assert abs(true_mean[1]) > 3 * abs(true_mean[0])               # the levels' mean positions differ
    np.testing.assert_allclose(-np.array(quad.offsets), true_mean, atol=0.15 * max(abs(m) for m in true_mean))
    assert quad.coefficient == pytest.approx(3e5, rel=0.15)
    assert any("from the static position" in n for n in ch.notes)


def test_a_grid_search_in_a_new_frame_takes_the_forms_of_zdot_from_the_last_and_gives_the_same_bits(monkeypatch):
    """The characterization's frame passes (every form of z from the static position) search the grid again; the
    forms of ż are the same in every frame, so the search takes them from the search before (issue 58) instead of
    evaluating and band-passing them again: the same columns, terms and scores to the bit, fewer columns computed."""
    from nifo_core.characterize.data import GridSearch, RegressionData, framed
    from nifo_core.kinds.describing import kind

    rec = _sim((StrutForce(Term("cubic_stiffness"), 2e8),), duration_s=60.0).record
    rf = restoring_force(rec, band=IntegrationBand(2.0, 120.0))
    data = RegressionData([rf], n_groups=4, body_stiffness=False)
    first = GridSearch(data, DEFAULT_KINDS, 24, None)
    moved = data.in_frame([-0.3 * float(np.std(rf.z))])
    computed = []
    real = RegressionData._compute

    def counted(self, term, offsets):
        computed.append(term.kind)
        return real(self, term, offsets)

    monkeypatch.setattr(RegressionData, "_compute", counted)
    fresh = GridSearch(moved, DEFAULT_KINDS, 24, None)
    n_fresh = len(computed)
    computed.clear()
    taken = GridSearch(moved.in_frame(moved.frame), DEFAULT_KINDS, 24, None, prior=first)
    assert [t.label for t in taken.terms] == [t.label for t in fresh.terms]
    assert np.array_equal(taken.gt, fresh.gt) and np.array_equal(taken.norm2, fresh.norm2)
    assert np.array_equal(taken.gp2, fresh.gp2)
    assert computed and all(framed(kind(k)) for k in computed)
    assert len(computed) < n_fresh and any(not framed(kind(k)) for k in DEFAULT_KINDS)
