"""The second, independently written simulator (nifo_core.simulate.independent): linear truth, its own integrator
converged, its forces the library's physics, its sensors as configured."""

import numpy as np
import pytest

from nifo_core.errors import ConfigError
from nifo_core.kinds.describing import Term
from nifo_core.signal.frf import h1
from nifo_core.signal.spectral import SpectralSettings, cross_spectra
from nifo_core.simulate.independent import (Corner, Element, HarmonicRoad, IndependentConfig, Sensors,
                                            SimulationStoppedError, simulate_independent)

CORNER = Corner(m1=45.0, m2=320.0, k1=230e3, c1=150.0, k2=24e3, c2=1500.0)
EVERY = (Element("velocity_deadzone", -700.0, 0.03), Element("quadratic_damping", 800.0),
         Element("coulomb", 30.0, 0.002), Element("asymmetric_damping", 400.0, 0.0, 1),
         Element("cubic_stiffness", 5e7), Element("quadratic_stiffness", 3e5), Element("clearance", 4e3, 0.002),
         Element("bump_stop", 1e5, 0.004, -1), Element("backlash", 8e3, 0.00043))


def test_a_linear_record_has_the_analytical_transmissibility_within_1_percent():
    # Hann blocks of 6.8 s: the flattop's wide main lobe leaks the steep road spectrum into the lowest lines
    run = simulate_independent(IndependentConfig(corner=CORNER, road=HarmonicRoad(0.003), duration_s=240.0), seed=4)
    r = run.record
    sp = cross_spectra(np.stack([r.spindle_accel, r.body_accel]), r.fs_hz,
                       SpectralSettings(block=4096, window="hann", overlap=0.5))
    t = h1(sp, 0, 1)
    m = (sp.freq_hz >= 2) & (sp.freq_hz <= 30)
    w = 2 * np.pi * sp.freq_hz[m]
    zs = CORNER.k2 + 1j * w * CORNER.c2
    t21 = zs / (-w ** 2 * CORNER.m2 + zs)                       # paper Eq. 7, written out here
    err = np.abs(t[m] / t21 - 1)
    print(f"\nlinear corner, 240 s: |H1/T21 - 1| median {100 * np.median(err):.3f} %, max {100 * err.max():.3f} %")
    assert np.median(err) < 0.003 and err.max() < 0.015


def test_the_adaptive_integrator_converges_with_every_element():
    cfg = IndependentConfig(corner=CORNER, elements=EVERY, road=HarmonicRoad(0.004), duration_s=20.0)
    a = simulate_independent(cfg, seed=5)
    b = simulate_independent(IndependentConfig(**{**cfg.__dict__, "rtol": 1e-10}), seed=5)
    for ch in ("spindle_accel", "body_accel"):
        x, y = getattr(a.record, ch), getattr(b.record, ch)
        rel = float(np.std(x - y) / np.std(y))
        print(f"{ch}: rtol 1e-7 against 1e-10: {rel:.2g} of its RMS; steps {a.steps} / {b.steps}")
        assert rel < 1e-4
    assert b.steps[0] > a.steps[0]     # the tighter tolerance took more steps: the control is active


def test_the_elements_are_the_library_physics_written_apart():
    rng = np.random.default_rng(1)
    z, zd = 0.006 * rng.standard_normal(5000), 0.1 * rng.standard_normal(5000)
    for e in EVERY:
        if e.kind in ("coulomb", "backlash"):
            continue          # a friction smoothed otherwise; a play with a state (below)
        params = {"knee": e.param} if e.kind == "velocity_deadzone" else {"gap": e.param} if e.kind in (
            "clearance", "bump_stop") else {}
        if e.kind == "bump_stop":
            params["side"] = "compression" if e.side < 0 else "rebound"
        if e.kind == "asymmetric_damping":
            params["side"] = "rebound" if e.side > 0 else "compression"
        np.testing.assert_allclose(e.force(z, zd), e.value * Term(e.kind, params).evaluate(z, zd), rtol=1e-12,
                                   atol=1e-12, err_msg=e.kind)
    friction = Element("coulomb", 30.0, 0.002).force(z, zd)
    assert np.all(np.abs(friction) < 30.0) and np.allclose(friction[np.abs(zd) > 0.05], 30.0 * np.sign(zd)[
        np.abs(zd) > 0.05], rtol=1e-3)


def test_the_body_equation_holds_on_the_truth_and_the_play_stays_within_its_window():
    cfg = IndependentConfig(corner=CORNER, elements=EVERY, road=HarmonicRoad(0.004), duration_s=20.0)
    run = simulate_independent(cfg, seed=6)
    a2 = -(CORNER.k2 * run.z + CORNER.c2 * run.zdot + run.strut_force_n) / CORNER.m2
    body = np.asarray(run.record.body_accel)
    cut = slice(600, -600)   # the decimation filter's edges
    rel = float(np.std(body[cut] - a2[cut]) / np.std(a2[cut]))
    print(f"\nbody acceleration recorded against -(K2·z + C2·ż + N)/M2 of the truth states: {rel:.2g} of its RMS")
    assert rel < 0.01    # what lies above the anti-aliasing filter's pass band (240 Hz): the stops' and play's kinks
    play = EVERY[-1]
    other = sum(e.force(run.z, run.zdot) for e in EVERY[:-1])
    slider = (run.strut_force_n - other) / play.value
    assert np.all(np.abs(slider - run.z) <= 0.5 * play.param * (1 + 1e-9))


def test_the_sensors_add_their_bias_and_noise():
    quiet = IndependentConfig(corner=CORNER, road=HarmonicRoad(0.002), duration_s=30.0)
    noisy = IndependentConfig(**{**quiet.__dict__, "sensors": Sensors(0.01, 0.02, 0.05, -0.03)})
    a, b = simulate_independent(quiet, seed=7).record, simulate_independent(noisy, seed=7).record
    for ch, rel, bias in (("spindle_accel", 0.01, 0.05), ("body_accel", 0.02, -0.03)):
        d = np.asarray(getattr(b, ch)) - np.asarray(getattr(a, ch))
        assert abs(float(np.mean(d)) - bias) < 0.1 * abs(bias)
        assert float(np.std(d)) == pytest.approx(rel * float(np.std(getattr(a, ch))), rel=0.05)


def test_bad_configurations_are_refused_with_what_to_change():
    with pytest.raises(ConfigError, match="unknown strut element"):
        Element("spring", 1.0)
    with pytest.raises(ConfigError, match="needs a positive parameter"):
        Element("velocity_deadzone", -700.0, 0.0)
    with pytest.raises(ConfigError, match="side"):
        Element("bump_stop", 1e5, 0.004)
    with pytest.raises(ConfigError, match="too low for a road"):
        IndependentConfig(road=HarmonicRoad(0.002, f_hi_hz=250.0))


def test_a_quarter_car_that_diverges_stops_the_simulator_with_its_words_not_a_stall():
    # an even spring whose total stiffness K2 + 2·k_q·z turns negative at z = -K2/(2·k_q) = -2.4 mm: at 6 mm of
    # road the strut collapses in finite time (before: the step control shrank the step for ever, case 57's stall)
    cfg = IndependentConfig(corner=CORNER, elements=(Element("quadratic_stiffness", 5e6),), road=HarmonicRoad(0.006),
                            duration_s=20.0, lift_off=True)
    with pytest.raises(SimulationStoppedError, match=r"diverged .*quadratic_stiffness 5e\+06"):
        simulate_independent(cfg, seed=3, source="collapse")
    # the same spring at 0.3 mm stays where K2 + 2·k_q·z > 0 and is carried to its end, one step per output instant
    run = simulate_independent(IndependentConfig(**{**cfg.__dict__, "road": HarmonicRoad(0.0003)}), seed=3)
    assert run.record.body_accel.size == 20 * 600 and np.all(np.isfinite(run.record.body_accel))
    assert run.steps[1] < 0.01 * run.steps[0]
