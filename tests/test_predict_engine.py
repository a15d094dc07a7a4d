"""The prediction engine: the identified model simulated in time, against the simulator and against identification.

Every accuracy number is printed beside the linear model's in the same run.
"""

import json

import numpy as np
import pytest
from scipy import signal

from nifo_core.kinds.describing import Term
from nifo_core.signal.integrate import IntegrationBand
from nifo_core.predict.linear_part import BodyModel, LinearPart, fit_rational, select_linear_part
from nifo_core.predict.model import IdentifiedModel, predict_body
from nifo_core.nifo.identify import identify_nifo
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, preset, simulate
from nifo_core.signal.spectral import SpectralSettings

FS = 600.0


def _sf(kind, coef, **params):
    return StrutForce(Term(kind, params), coef)


#: the strong nonlinearities of issue 10 (and the paper's hysteretic strut, and every kind at once)
STRONG = {
    "cubic 2e8 N/m³ at 5 mm": ((_sf("cubic_stiffness", 2e8),), 0.005),
    "Coulomb 30 N at 0.5 mm": ((_sf("coulomb", 30.0, eps=0.005),), 0.0005),
    "bump stop 2e5 N/m beyond 8 mm at 5 mm": ((_sf("bump_stop", 2e5, gap=0.008, side="compression"),), 0.005),
    "paper backlash + deadzone at 1 mm": (preset("paper"), 0.001),
    "every kind at 2.5 mm": (preset("all"), 0.0025),
}


def _nmse(y, yhat) -> float:
    return float(100 * np.mean((y - yhat) ** 2) / np.var(y))


def _truth_model(sim, *, terms=True) -> IdentifiedModel:
    car = sim.truth.vehicle
    strut = sim.truth.strut if terms else ()
    return IdentifiedModel.from_body(BodyModel(car.k2 / car.m2, car.c2 / car.m2), [s.term for s in strut],
                                     [s.coefficient / car.m2 for s in strut], fs_hz=FS)


@pytest.mark.parametrize("case", list(STRONG))
def test_the_true_model_reproduces_the_simulator_where_the_old_solver_diverged(case):
    strut, rms = STRONG[case]
    sim = simulate(SimConfig(strut=strut, road=RandomRoad(rms), duration_s=40, fs_hz=FS), rng=21)
    a1, y = sim.record.spindle_accel, sim.record.body_accel
    pred = predict_body(_truth_model(sim), a1, FS, label=case)
    lin = predict_body(_truth_model(sim, terms=False), a1, FS)
    v = slice(int(6 * FS), a1.size - 600)     # past the start-up transient (12 time constants); decimation edge
    e_nl, e_lin = _nmse(y[v], pred.body_accel[v]), _nmse(y[v], lin.body_accel[v])
    print(f"\n{case}: true model NMSE {e_nl:.5f} %, true linear part alone {e_lin:.3f} % ({pred.method})")
    assert pred.engine == "time"
    assert e_nl < 0.01 and e_nl < 0.01 * e_lin
    z_err = np.std(pred.z[v] - sim.truth.z[v]) / np.std(sim.truth.z[v])
    assert z_err < 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("case,test_rms", [("Coulomb 30 N at 0.5 mm", 0.001),
                                           ("cubic 2e8 N/m³ at 5 mm", 0.0025)])
def test_identified_at_one_level_and_seed_predicts_another_within_one_percent(case, test_rms):
    strut, rms = STRONG[case]
    # the cubic is identified noise-free here: with 2 % sensor noise NIFO's coefficient is biased low (noise
    # integrated twice into z); the output-error refinement removes it (tests/test_refine.py)
    noise = SensorNoise(relative=0.0 if "cubic" in case else 0.02)
    fit = simulate(SimConfig(strut=strut, road=RandomRoad(rms), duration_s=300, fs_hz=FS, noise=noise), rng=1)
    res = identify_nifo(fit.record, [s.term for s in strut])
    model, linear = IdentifiedModel.from_nifo(res), IdentifiedModel.from_nifo(res, source="h1")
    test = simulate(SimConfig(strut=strut, road=RandomRoad(test_rms), duration_s=120, fs_hz=FS,
                              noise=SensorNoise(relative=0.02)), rng=7)
    a1, y = test.record.spindle_accel, test.record.body_accel
    p, pl = predict_body(model, a1, FS), predict_body(linear, a1, FS)
    v = p.valid
    e_nl, e_lin = _nmse(y[v], p.body_accel[v]), _nmse(y[v], pl.body_accel[v])
    print(f"\n{case}, identified at {rms * 1e3:g} mm seed 1, predicting {test_rms * 1e3:g} mm seed 7: NMSE "
          f"nonlinear {e_nl:.3f} % vs linear (H1 at the identification level) {e_lin:.3f} %; linear part: "
          f"{model.linear.reason}")
    assert e_nl < 1.0 and e_nl < 0.6 * e_lin


def _three_mode_t21(f):
    """T21 of a base-excited 3-DOF chain (masses 1, 0.5, 0.3 kg; springs 400, 300, 200 N/m; 1 % damping)."""
    m = np.diag([1.0, 0.5, 0.3])
    k = np.array([[700.0, -300, 0], [-300, 500, -200], [0, -200, 200]])
    c = 0.002 * k
    kb, cb = np.array([400.0, 0, 0]), np.array([0.8, 0, 0])
    s = 2j * np.pi * np.asarray(f)
    return np.array([np.linalg.solve(-(si.imag ** 2) * m + si * c + k, kb + si * cb)[2] for si in s])


def test_a_rational_linear_part_fits_a_three_mode_structure_and_simulates_like_its_transfer_function():
    f = np.linspace(0.2, 12, 600)
    t21 = _three_mode_t21(f)
    lp = fit_rational(f, t21, band_hz=(0.2, 12.0))
    print(f"\nrational fit: order {lp.order}, T21 error {lp.fit_rms:.2e}, |p|/2π "
          f"{np.sort(np.abs(lp.poles[lp.poles.imag > 0]) / (2 * np.pi)).round(4)} Hz")
    modes = np.sort(np.abs(lp.poles[lp.poles.imag > 0]) / (2 * np.pi))
    true = np.sort(np.sqrt(np.linalg.eigvals(np.linalg.solve(np.diag([1.0, 0.5, 0.3]), np.array(
        [[700.0, -300, 0], [-300, 500, -200], [0, -200, 200]]))).real) / (2 * np.pi))
    assert lp.stable and lp.fit_rms < 1e-6
    assert lp.order <= 8 and np.allclose(modes[:3], true, rtol=1e-3)      # 3 modes (+ the residual pair above)
    np.testing.assert_allclose(lp.t21(f), t21, rtol=1e-5)
    sel = select_linear_part(f, t21, band_hz=(0.2, 12.0))
    assert sel.kind == "rational" and "one-mass body" in sel.reason
    # time domain: the engine (no terms) against scipy's simulation of T21 = 1 - ω²·Hz from the same poles
    fs = 100.0
    a1 = signal.sosfiltfilt(signal.butter(4, 15, fs=fs, output="sos"),
                            np.random.default_rng(3).standard_normal(20_000))
    model = IdentifiedModel(freq_hz=f, t21=t21, b=np.zeros((0, f.size)), terms=(), c_over_m2=np.zeros(0), body=None,
                            linear=lp, analysis_band_hz=(0.2, 12.0), fs_hz=fs, settings=SpectralSettings(),
                            band=IntegrationBand(0.1, 30.0))
    pred = predict_body(model, a1, fs)
    a, b, c = lp.state_space()
    # body accel = a1 + z̈,  z̈ = c·A²·x + c·A·b·a1
    sysd = signal.StateSpace(a, b[:, None], (c @ a @ a)[None, :], np.array([[1 + c @ a @ b]]))
    _, a2, _ = signal.lsim(sysd, a1, np.arange(a1.size) / fs)
    v = pred.valid
    assert _nmse(a2[v], pred.body_accel[v]) < 1e-3


def test_models_round_trip_through_json_and_old_files_without_a_linear_part_still_load():
    f = np.linspace(0.2, 12, 300)
    t21 = _three_mode_t21(f)
    model = IdentifiedModel(freq_hz=f, t21=t21, b=np.zeros((1, f.size)), terms=(Term("coulomb"),),
                            c_over_m2=np.array([0.1]), body=None, linear=select_linear_part(f, t21, band_hz=(0.2, 12)),
                            analysis_band_hz=(0.2, 12.0), fs_hz=100.0, settings=SpectralSettings(),
                            band=IntegrationBand(0.1, 30.0), force_gain=1 / 300)
    back = IdentifiedModel.from_dict(json.loads(json.dumps(model.to_dict())))
    assert back.linear.kind == "rational" and back.force_gain == model.force_gain and back.body is None
    np.testing.assert_array_equal(back.linear.poles, model.linear.poles)
    assert back.linear.reason == model.linear.reason
    old = _truth_model(simulate(SimConfig(strut=preset("friction"), duration_s=20, fs_hz=FS), rng=1)).to_dict()
    del old["linear_part"], old["force_gain"]                    # what identify wrote before this round
    m = IdentifiedModel.from_dict(old)
    assert m.linear.kind == "body" and m.linear.body == m.body


def test_a_measured_force_drives_a_fixed_spindle_model():
    """Silverbox-like: m·ÿ + d·ẏ + k·y + c·y³ = F with the spindle fixed (U = -F/M2)."""
    m2, k2, c2, c3 = 2.0, 2 * (2 * np.pi * 20) ** 2, 2 * 2 * 0.05 * 2 * np.pi * 20, 1e9
    fs, n = 2000.0, 40_000
    force = signal.sosfiltfilt(signal.butter(4, 60, fs=fs, output="sos"),
                               np.random.default_rng(5).standard_normal(n)) * 30
    body = BodyModel(k2 / m2, c2 / m2)
    f = np.linspace(1, 100, 200)
    model = IdentifiedModel(freq_hz=f, t21=body.t21(f), b=np.zeros((1, f.size)), terms=(Term("cubic_stiffness"),),
                            c_over_m2=np.array([c3 / m2]), body=body, analysis_band_hz=(1.0, 100.0), fs_hz=fs,
                            settings=SpectralSettings(), band=IntegrationBand(0.5, 400.0), force_gain=1 / m2)
    pred = predict_body(model, None, fs, force=force)
    # reference: the same ODE by scipy's integrator at tight tolerance
    from scipy.integrate import solve_ivp
    t = np.arange(n) / fs
    samples = force.tolist()

    def rhs(tt, x):   # the force linear between samples
        i = min(int(tt * fs), n - 2)
        w = tt * fs - i
        fi = samples[i] + w * (samples[i + 1] - samples[i])
        return [x[1], (fi - c2 * x[1] - k2 * x[0] - c3 * x[0] ** 3) / m2]

    # 8th order at rtol 1e-8: 0.64 M right-hand sides in 4.3 s, against 2.1 M in 13 s for RK45 at 1e-9; the two
    # references differ by 1.4e-6 of y's RMS, far below the bound asserted here
    sol = solve_ivp(rhs, (0, t[-1]), [0, 0], t_eval=t, method="DOP853", rtol=1e-8, atol=1e-11, max_step=1 / fs)
    v = pred.valid
    err = np.std(pred.z[v] - sol.y[0][v]) / np.std(sol.y[0][v])
    print(f"\nforce-driven Duffing oscillator: relative error of y {err:.2e}")
    assert err < 2e-3


def test_the_paired_and_banded_steps_of_a_modal_linear_part_equal_the_full_product_to_the_last_bit():
    """A rational linear part is in real modal form: Φ is block diagonal, and the engine multiplies only inside
    the blocks (timesim._rows): two fixed products per row (2×2 blocks and a 1×1 one), or a loop over the band.
    Against the full product, every sample is the same bit for bit."""
    from nifo_core.kinds.strut_forces import strut_arrays
    from nifo_core.predict import timesim

    rng = np.random.default_rng(3)
    poles = [complex(-2.0 - k, 2 * np.pi * (3 + 7 * k)) for k in range(5)] + [-40.0]
    n = 2 * 5 + 1
    a, b, c = np.zeros((n, n)), np.zeros(n), np.zeros(n)
    for k, p in enumerate(poles[:5]):
        a[2 * k:2 * k + 2, 2 * k:2 * k + 2] = [[p.real, p.imag], [-p.imag, p.real]]
        b[2 * k], c[2 * k], c[2 * k + 1] = 1.0, rng.normal(), rng.normal()
    a[-1, -1], b[-1], c[-1] = -40.0, 1.0, -float(c[:-1] @ b[:-1])     # c·b = 0
    phi, g0, g1 = timesim.discretise(a, b, 1 / 4800)
    phi, lo, hi, c1, pa, pb, paired = timesim._rows(phi)
    cols = np.arange(n)[None, :]
    assert paired and (hi - lo).max() == 2 and (hi - lo)[-1] == 1
    assert np.all(phi[(cols < lo[:, None]) | (cols >= hi[:, None])] == 0)
    v = rng.normal(size=20_000)
    terms = [Term("velocity_deadzone", {"knee": 0.01}), Term("backlash", {"deadband": 1e-4})]
    codes, coef, p0, p1 = strut_arrays(terms, [-0.2, 3.0])
    full = (np.zeros(n, np.int64), np.full(n, n, np.int64))
    outs = []
    for rows in ((phi, lo, hi, c1, pa, pb, True), (phi, lo, hi, c1, pa, pb, False), (phi, *full, c1, pa, pb, False)):
        got = [np.zeros(v.size) for _ in range(4)]
        fail = timesim._run(*rows, g0, g1, c, c @ a, c @ a @ a, float(c @ a @ b), v, codes, coef, p0, p1, 0.0, 0.0,
                            np.inf, 0.0, 1, *got)    # q = 1: every output at every step
        assert fail == -1
        outs.append(got)
    for pair, band, whole in zip(*outs):
        assert np.array_equal(pair, whole) and np.array_equal(band, whole)
    assert not timesim._rows(np.triu(np.ones((3, 3))))[-1]    # a row of three: the band's loop


def test_the_linear_peak_is_computed_once_per_record_and_linear_part_and_never_stale():
    """The divergence bound's scale (the linear part's peak response to the record) is kept per record and
    realised response: the same linear part built again is looked up, a changed one is computed anew."""
    from dataclasses import replace

    from nifo_core.predict import time_prediction as pm

    fs = 400.0
    v = np.random.default_rng(5).normal(size=8000)
    lin = LinearPart("body", body=BodyModel(k=(2 * np.pi * 1.5) ** 2, c=2.0))
    direct = pm._peak(v, pm._Realised(lin), fs)
    pm._PEAK.clear()
    assert pm._linear_peak(lin, v, fs) == direct
    again = LinearPart("body", body=BodyModel(k=(2 * np.pi * 1.5) ** 2, c=2.0), absorbed=(0.0, 0.0))
    assert pm._linear_peak(again, v.copy(), fs) == direct and len(pm._PEAK._kept) == 1   # looked up
    stiffer = replace(lin, body=BodyModel(k=(2 * np.pi * 3.0) ** 2, c=2.0))
    assert pm._linear_peak(stiffer, v, fs) == pm._peak(v, pm._Realised(stiffer), fs) != direct
    assert pm._linear_peak(lin, v * 2, fs) == pytest.approx(2 * direct, rel=1e-12)
    assert len(pm._PEAK._kept) == 3
