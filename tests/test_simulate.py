"""The quarter-car simulator: linear truth, library-consistent forces, reproducibility, lift-off, errors."""

import json

import numpy as np
import pytest
from scipy import signal

from nifo_core.kinds.describing import Term
from nifo_core.errors import ConfigError
from nifo_core.simulate.quarter_car import (PHASE_FFT, PRESETS, ChirpRoad, RandomRoad, SensorNoise, SimConfig,
                                            StrutForce, antialias_taps, decimate, interpolate, preset,
                                            simulate)
from nifo_core.simulate.vehicle import QuarterCar

#: one of every kind and side, at levels that a 2.5 mm road exercises
EVERY_FORM = (
    StrutForce(Term("cubic_stiffness"), 2e7),
    StrutForce(Term("clearance", {"gap": 0.002}), 5e3),
    StrutForce(Term("saturation", {"limit": 0.001}), 4e3),
    StrutForce(Term("bump_stop", {"gap": 0.003, "side": "compression", "offset": 0.0005}), 5e4),
    StrutForce(Term("bump_stop", {"gap": 0.003, "side": "rebound"}), 2e4),
    StrutForce(Term("backlash", {"deadband": 0.00043}), 8e3),
    StrutForce(Term("velocity_deadzone", {"knee": 0.05}), -700.0),
    StrutForce(Term("velocity_saturation", {"limit": 0.05}), 300.0),
    StrutForce(Term("coulomb", {"eps": 0.005}), 80.0),
    StrutForce(Term("quadratic_damping"), 500.0),
    StrutForce(Term("asymmetric_damping", {"side": "rebound"}), 1400.0),
    StrutForce(Term("asymmetric_damping", {"side": "compression"}), 200.0),
)


def _library_force(truth):
    return sum(s.coefficient * s.term.evaluate(truth.z, truth.zdot) for s in truth.strut)


@pytest.mark.slow
def test_linear_simulation_h1_matches_quarter_car_t21_within_1_percent():
    sim = simulate(SimConfig(duration_s=300.0, fs_hz=600.0), rng=2)
    r = sim.record
    f, g11 = signal.csd(r.spindle_accel, r.spindle_accel, fs=r.fs_hz, nperseg=6144)
    _, g12 = signal.csd(r.spindle_accel, r.body_accel, fs=r.fs_hz, nperseg=6144)
    band = (f >= 2) & (f <= 30)
    h1 = g12[band] / g11[band]
    t21 = QuarterCar().t21(f[band])
    np.testing.assert_array_less(np.abs(np.abs(h1) / np.abs(t21) - 1), 0.01)
    np.testing.assert_array_less(np.abs(np.angle(h1 / t21)), 0.01)  # rad


def test_simulator_strut_force_equals_library_force_for_every_form():
    # oversample=1 commits the play state once per recorded sample, as play_operator does
    sim = simulate(SimConfig(strut=EVERY_FORM, duration_s=10.0, fs_hz=3000.0, oversample=1), rng=3)
    t = sim.truth
    for s in EVERY_FORM:  # each form is actually exercised (not identically zero or linear)
        assert np.ptp(s.term.evaluate(t.z, t.zdot)) > 0, s.label
    settle = int(0.2 * t.fs_hz)  # the library's play operator starts at y0 = z[0]; ours is older
    np.testing.assert_allclose(t.strut_force_n[settle:], _library_force(t)[settle:], rtol=1e-12, atol=1e-9)


def test_memoryless_forces_match_library_exactly_when_oversampled():
    smooth = tuple(s for s in EVERY_FORM if s.term.kind != "backlash")
    t = simulate(SimConfig(strut=smooth, duration_s=5.0), rng=4).truth
    np.testing.assert_allclose(t.strut_force_n, _library_force(t), rtol=1e-12, atol=1e-9)


def test_oversampled_backlash_differs_from_library_only_by_extrema_missed_between_samples():
    t = simulate(SimConfig(strut=preset("paper_backlash"), duration_s=10.0), rng=4).truth
    zddot = np.gradient(t.zdot, 1 / t.fs_hz)
    missed = 0.5 * np.max(np.abs(zddot)) * (0.5 / t.fs_hz) ** 2  # m, largest overshoot between samples
    diff = np.abs(t.strut_force_n - _library_force(t))[int(t.fs_hz):]
    assert diff.max() <= 8e3 * 2 * missed
    assert np.mean(diff < 1e-9) > 0.5  # identical while sliding on the same edge


def test_nonlinear_simulation_is_bit_reproducible_and_seeds_differ():
    cfg = SimConfig(strut=preset("all"), duration_s=5.0, noise=SensorNoise(relative=0.02))
    a, b, c = simulate(cfg, rng=7), simulate(cfg, rng=7), simulate(cfg, rng=8)
    for name in ("spindle_accel", "body_accel", "tire_patch_disp"):
        assert np.array_equal(getattr(a.record, name), getattr(b.record, name))
        assert not np.allclose(getattr(a.record, name), getattr(c.record, name))
    assert np.array_equal(a.truth.strut_force_n, b.truth.strut_force_n)
    assert a.record.meta["simulator"]["seed"] == 7


def test_generator_and_no_seed_are_accepted_and_a_fresh_seed_is_recorded():
    cfg = SimConfig(duration_s=2.0)
    s = simulate(cfg, rng=np.random.default_rng(1))
    assert s.truth.seed is None
    fresh = simulate(cfg)
    again = simulate(cfg, rng=fresh.truth.seed)
    assert np.array_equal(fresh.record.body_accel, again.record.body_accel)


@pytest.mark.parametrize("name", list(PRESETS))
def test_every_preset_runs_and_gives_a_finite_record(name):
    sim = simulate(SimConfig(strut=preset(name), road=RandomRoad(0.005), duration_s=3.0), rng=1)
    r = sim.record
    assert r.n == 1800 and r.source == "simulator" and r.has_tire_patch
    assert np.std(r.body_accel) > 0 and np.all(np.isfinite(sim.truth.strut_force_n))
    assert (np.ptp(sim.truth.strut_force_n) > 0) == (name != "linear")


def test_paper_backlash_visibly_changes_the_transmissibility_at_1mm():
    def h1(strut):
        r = simulate(SimConfig(strut=strut, road=RandomRoad(0.001), duration_s=60.0), rng=5).record
        f, g11 = signal.csd(r.spindle_accel, r.spindle_accel, fs=r.fs_hz, nperseg=2048)
        _, g12 = signal.csd(r.spindle_accel, r.body_accel, fs=r.fs_hz, nperseg=2048)
        band = (f >= 2) & (f <= 10)
        return np.abs(g12[band] / g11[band])
    change = np.max(np.abs(h1(preset("paper_backlash")) / h1(()) - 1))
    assert change > 0.1


def test_tire_lift_off_clamps_dynamic_tire_force_at_static_load():
    road = RandomRoad(0.007, 0.5, 40.0)
    static = QuarterCar().static_tire_load_n
    free = simulate(SimConfig(road=road, duration_s=10.0), rng=6).truth
    assert free.tire_force_n.min() < -static and free.lift_off_fraction == 0
    lifted = simulate(SimConfig(road=road, duration_s=10.0, tire_lift_off=True), rng=6).truth
    assert lifted.lift_off_fraction > 0
    assert lifted.tire_force_n.min() >= -static
    assert np.mean(lifted.tire_force_n <= -static) == pytest.approx(lifted.lift_off_fraction, abs=0.01)


def test_random_road_has_the_requested_rms_and_band():
    sim = simulate(SimConfig(road=RandomRoad(0.003, 1.0, 20.0), duration_s=60.0), rng=9)
    xb = sim.truth.xb
    assert np.sqrt(np.mean(xb**2)) == pytest.approx(0.003, rel=0.05)
    f, p = signal.welch(xb, fs=600.0, nperseg=4096)
    assert p[(f > 30) & (f < 200)].max() < 1e-6 * p.max()
    np.testing.assert_allclose(sim.record.tire_patch_disp, xb, atol=1e-5 * 0.003)  # flat anti-alias filter


def test_chirp_duration_defaults_to_the_sweep_and_follows_the_formula():
    road = ChirpRoad(0.001, 0.0, 15.0, rate_hz_per_s=0.5)
    cfg = SimConfig(road=road, fs_hz=300.0)
    assert cfg.duration == pytest.approx(30.0)
    sim = simulate(cfg, rng=0)
    t = sim.record.time_s()
    np.testing.assert_allclose(sim.truth.xb, 0.001 * np.sin(np.pi * 0.5 * t**2), atol=1e-12)


def test_sensor_noise_is_relative_to_each_channel_rms():
    cfg = SimConfig(duration_s=20.0)
    clean = simulate(cfg, rng=11).record
    noisy = simulate(SimConfig(duration_s=20.0, noise=SensorNoise(relative=0.1)), rng=11).record
    for name in ("spindle_accel", "body_accel", "tire_patch_disp"):
        x, y = getattr(clean, name), getattr(noisy, name)
        assert np.std(y - x) / np.sqrt(np.mean(x**2)) == pytest.approx(0.1, rel=0.05)


def test_record_starts_settled():
    sim = simulate(SimConfig(strut=preset("paper"), duration_s=20.0), rng=12)
    a = sim.record.body_accel
    first, rest = np.std(a[:600]), np.std(a[600:])
    assert 0.5 < first / rest < 1.5


def test_truth_and_meta_are_json_and_config_round_trips():
    cfg = SimConfig(strut=preset("all"), tire_lift_off=True, road=ChirpRoad(0.002, 0.5, 10.0, 0.5),
                    duration_s=2.0, noise=SensorNoise(0.01, 0.001))
    sim = simulate(cfg, rng=1)
    doc = json.loads(json.dumps(sim.truth.to_dict()))
    assert doc["strut"][4] == {"kind": "backlash", "params": {"deadband": 0.00043}, "coefficient": 8000.0}
    json.dumps(dict(sim.record.meta))
    assert SimConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    np.testing.assert_array_equal(sim.truth.t21([1.0, 10.0]), QuarterCar().t21([1.0, 10.0]))
    with pytest.raises(ValueError):
        sim.truth.z[0] = 1.0


@pytest.mark.parametrize("make, match", [
    (lambda: RandomRoad(-0.001), "road RMS -0.001 m must be finite and positive"),
    (lambda: RandomRoad(2.5), "more than 100 mm"),
    (lambda: RandomRoad(0.002, 10.0, 5.0), "f_lo < f_hi"),
    (lambda: SimConfig(fs_hz=100.0), "fs_hz=100 is too low for a road with energy up to 50 Hz"),
    (lambda: SimConfig(road=ChirpRoad(0.001, 0, 50.0), fs_hz=100.0), "too low"),
    (lambda: ChirpRoad(0.001, 10.0, 5.0), "sweep upwards"),
    (lambda: SimConfig(oversample=0), "oversample=0 must be a whole number"),
    (lambda: SimConfig(duration_s=-1.0), "duration_s=-1.0 must be positive"),
    (lambda: SimConfig(strut=preset("friction"), oversample=1), "too coarse.*use oversample >= 4"),
    (lambda: SimConfig(strut=("coulomb",)), "must hold StrutForce"),
    (lambda: preset("paper_friction"), "unknown preset 'paper_friction'.*use one of linear"),
    (lambda: StrutForce(Term("coulomb"), float("nan")), "coefficient nan must be finite"),
    (lambda: SensorNoise(relative=-0.1), "relative=-0.1 must be finite and non-negative"),
    (lambda: simulate(SimConfig(duration_s=1.0), rng=-3), "rng=-3"),
    (lambda: SimConfig(duration_s=1e6), "integration steps"),
])
def test_bad_configs_raise_config_error_saying_what_to_do(make, match):
    with pytest.raises(ConfigError, match=match):
        make()


def test_command_parses_nonlinearities_and_rejects_bad_specs(tmp_path, capsys):
    from nifo.cli import main
    from nifo.commands.simulate import config_from_args, parse_nonlinearity
    s = parse_nonlinearity("bump_stop:gap=0.008,side=rebound:coef=5e4")
    assert s == StrutForce(Term("bump_stop", {"gap": 0.008, "side": "rebound"}), 5e4)
    assert parse_nonlinearity("coulomb:coef=100").term.params["eps"] == 0.005
    for bad, msg in [("coulomb", "needs one numeric coef"), ("coulomb:eps:coef=1", "not key=value"),
                     ("spring:coef=1", "unknown nonlinearity kind 'spring'")]:
        with pytest.raises(ConfigError, match=msg):
            parse_nonlinearity(bad)
    assert main(["simulate", "--out", str(tmp_path / "x.csv"), "--nonlinearity", "play:coef=1"]) == 9
    assert "needs parameter 'deadband'" in capsys.readouterr().err
    assert main(["simulate", "--out", str(tmp_path / "x.csv"), "--road-rms", "-1"]) == 9
    assert not list(tmp_path.iterdir())
    import argparse
    from nifo.commands.simulate import add_arguments
    p = argparse.ArgumentParser()
    add_arguments(p)
    cfg = config_from_args(p.parse_args(["--out", "x", "--preset", "paper", "--chirp", "1", "--noise", "0.02",
                                         "--nonlinearity", "coulomb:coef=50", "--tire-lift-off"]))
    assert cfg.road == ChirpRoad(0.001) and len(cfg.strut) == 3 and cfg.tire_lift_off and cfg.duration == 600


def test_command_writes_record_and_truth(tmp_path, capsys):
    loader = pytest.importorskip("nifo.io.loader")
    from nifo.cli import main
    out = tmp_path / "sim.mcap"
    assert main(["simulate", "--out", str(out), "--preset", "paper", "--duration", "5", "--seed", "3"]) == 0
    truth = json.loads((tmp_path / "sim.mcap.truth.json").read_text())
    assert truth["seed"] == 3 and truth["strut"][0]["kind"] == "backlash"
    rec = loader.load_record(out)
    assert rec.n == 3000
    assert "lift-off" in capsys.readouterr().out


@pytest.mark.parametrize("q", [2, 4, 8, 16])
def test_decimate_is_the_antialias_convolution_at_the_fine_rate_read_every_qth_sample(q):
    # the polyphase blocks of decimate against the plain definition: the zero-phase FIR over the whole fine-rate
    # signal (zeros beyond its ends), every q-th output kept; one signal and several rows, lengths from one sample
    # up, across block edges (PHASE_FFT)
    rng = np.random.default_rng(q)
    taps = antialias_taps(q)
    for n in (1, q - 1, 77, 5000, 9 * PHASE_FFT * q + 3):
        x = rng.standard_normal(n)
        want = signal.oaconvolve(x, taps, mode="same")[::q]
        got = decimate(x, q)
        assert got.shape == want.shape
        assert np.max(np.abs(got - want)) <= 1e-13 * np.max(np.abs(want))
    rows = rng.standard_normal((3, 40_001))
    want = signal.oaconvolve(rows, taps[None, :], mode="same", axes=1)[:, ::q]
    assert np.max(np.abs(decimate(rows, q) - want)) <= 1e-13 * np.max(np.abs(want))


@pytest.mark.parametrize("q", [2, 4, 8, 16])
def test_interpolate_is_resample_poly_with_the_antialias_taps(q):
    # the phases' blocks of interpolate against scipy's polyphase filter of the stuffed zeros, across block edges
    rng = np.random.default_rng(q + 100)
    taps = antialias_taps(q)
    for n in (1, 3, 77, 5000, 3 * PHASE_FFT + 11):
        x = rng.standard_normal(n)
        want = signal.resample_poly(x, q, 1, window=taps)
        got = interpolate(x, q)
        assert got.shape == want.shape
        assert np.max(np.abs(got - want)) <= 1e-13 * np.max(np.abs(want))
