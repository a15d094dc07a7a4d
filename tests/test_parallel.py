"""Threads for independent simulations (nifo_core.signal.parallel): results in order, errors as the serial loop
raises them, and the refinement's threaded Jacobian the same to the last digit as least_squares' own '2-point'."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import scipy.optimize

from nifo_core.signal.parallel import forward_jacobian, thread_map


def test_thread_map_keeps_order_and_runs_on_threads(monkeypatch):
    monkeypatch.setenv("NIFO_THREADS", "2")
    seen = set()

    def f(x):
        seen.add(threading.get_ident())
        return x * x
    assert thread_map(f, range(50)) == [x * x for x in range(50)]
    assert threading.get_ident() not in seen


def test_thread_map_raises_the_first_error_in_item_order(monkeypatch):
    monkeypatch.setenv("NIFO_THREADS", "2")

    def f(x):
        if x in (3, 7):
            raise ValueError(f"item {x}")
        return x
    with pytest.raises(ValueError, match="item 3"):
        thread_map(f, range(10))


def test_a_map_inside_a_map_runs_serially(monkeypatch):
    monkeypatch.setenv("NIFO_THREADS", "2")
    outer = threading.get_ident()

    def inner_threads(_):
        here = threading.get_ident()
        return {threading.get_ident() for _ in thread_map(lambda y: y, range(4))} | {here}
    for ids in thread_map(inner_threads, range(2)):
        assert len(ids) == 1 and outer not in ids


def test_one_thread_runs_in_the_caller(monkeypatch):
    monkeypatch.setenv("NIFO_THREADS", "1")
    assert set(thread_map(lambda _: threading.get_ident(), range(4))) == {threading.get_ident()}


def _problem():
    t = np.linspace(0, 3, 400)
    y = 1.3 * np.exp(-0.7 * t) * np.cos(4.1 * t + 0.2) + 0.05 * np.sin(11 * t)

    def res(x):
        return x[0] * np.exp(-x[1] * t) * np.cos(x[2] * t + x[3]) - y
    return res


@pytest.mark.parametrize("bounds", [(-np.inf, np.inf),
                                    (np.array([0.0, 0.0, 3.0, -1.0]), np.array([2.0, 0.5000001, 5.0, 1.0]))])
def test_least_squares_with_threads_gives_its_serial_result_bit_for_bit(monkeypatch, bounds):
    """What the refinement does (nifo_core.predict.refine): least_squares' Jacobian columns on thread_map."""
    monkeypatch.setenv("NIFO_THREADS", "2")
    res = _problem()
    threads = set()

    def fun(x):
        threads.add(threading.get_ident())
        return res(x)
    x0 = np.array([1.0, 0.5, 4.0, 0.0])      # a zero coordinate (the √ε step) and one near its upper bound
    ref = scipy.optimize.least_squares(res, x0, bounds=bounds, method="trf", diff_step=1e-3, max_nfev=30)
    got = scipy.optimize.least_squares(fun, x0, bounds=bounds, method="trf", diff_step=1e-3, max_nfev=30,
                                       workers=thread_map)
    assert np.array_equal(got.x, ref.x) and np.array_equal(got.jac, ref.jac) and got.nfev == ref.nfev
    assert len(threads - {threading.get_ident()}) >= 1


def test_forward_jacobian_is_the_serial_forward_difference(monkeypatch):
    monkeypatch.setenv("NIFO_THREADS", "2")
    res = _problem()
    x0 = np.array([1.2, 0.6, 4.2, -0.3])
    h = 1e-3 * np.where(x0 >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x0))
    f0 = res(x0)
    serial = np.empty((f0.size, x0.size))
    for j in range(x0.size):
        x = x0.copy()
        x[j] += h[j]
        serial[:, j] = (res(x) - f0) / (x[j] - x0[j])
    assert np.array_equal(forward_jacobian(res, x0, f0, h), serial)


def test_refinement_of_several_records_on_threads_is_its_serial_result_bit_for_bit(monkeypatch):
    """The refinement's evaluations simulate the records side by side (and each Jacobian column's records one
    after the other): the refined model, its cost and its evaluations are those of one thread, to the last bit."""
    from nifo_core.kinds.describing import Term
    from nifo_core.nifo.identify import identify_nifo
    from nifo_core.predict.model import IdentifiedModel
    from nifo_core.predict.refine import refine_model
    from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

    strut = (StrutForce(Term("coulomb", {"eps": 0.005}), 30.0),)
    recs = [simulate(SimConfig(strut=strut, road=RandomRoad(rms), duration_s=40.0, fs_hz=400.0,
                               noise=SensorNoise(relative=0.02)), rng=seed).record
            for rms, seed in ((0.5e-3, 1), (1e-3, 2), (2e-3, 3))]
    model = IdentifiedModel.from_nifo(identify_nifo(recs, [s.term for s in strut]))
    got = {}
    for n in ("1", "2"):
        monkeypatch.setenv("NIFO_THREADS", n)
        got[n] = refine_model(model, recs, max_iterations=8)
    one, two = got["1"], got["2"]
    assert np.array_equal(one.model.c_over_m2, two.model.c_over_m2)
    assert one.nmse == two.nmse and one.evaluations == two.evaluations and one.parameters == two.parameters


def test_rational_fits_of_every_order_side_by_side_are_the_serial_fit(monkeypatch):
    """fit_rational tries its orders a few at a time on threads: the chosen order, poles and residues, and the table
    of every order tried, are those of one thread to the last bit."""
    from nifo_core.predict.linear_part import LinearPart, fit_rational

    poles = np.array([-1.5 + 2 * np.pi * 4j, -1.5 - 2 * np.pi * 4j, -3 + 2 * np.pi * 11j, -3 - 2 * np.pi * 11j])
    res = np.array([-0.004j, 0.004j, 0.0012j, -0.0012j])
    res[2:] -= res.sum().real / 2
    f = np.linspace(1.0, 25.0, 400)
    rng = np.random.default_rng(5)
    t21 = LinearPart("rational", poles=poles, residues=res, band_hz=(2.0, 20.0)).t21(f)
    t21 = t21 * (1 + 0.01 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)))
    got = {}
    for n in ("1", "2"):
        monkeypatch.setenv("NIFO_THREADS", n)
        got[n] = fit_rational(f, t21, band_hz=(2.0, 20.0), max_order=16)
    one, two = got["1"], got["2"]
    assert len(one.candidates["orders_tried"]) == 8
    assert np.array_equal(one.poles, two.poles) and np.array_equal(one.residues, two.residues)
    assert one.candidates == two.candidates and one.fit_rms == two.fit_rms


def test_the_loop_judges_a_flexible_bodys_candidates_side_by_side_as_one_thread_does(monkeypatch):
    """On a flexible body (rational linear part) the loop judges every candidate on its held-out prediction; they
    run side by side on threads: the result (trials, added terms, errors, model) is that of one thread."""
    from test_feedback_paths import PERIOD, _linear, _paths_true, _record

    from nifo_core.loop.closing import close_loop
    from nifo_core.loop.settings import LoopSettings
    from nifo_core.settings import AnalysisSettings
    from nifo_core.signal.integrate import IntegrationBand
    from nifo_core.signal.spectral import SpectralSettings

    truth = _linear(paths=_paths_true())
    recs = [_record(lv, truth, periods=6) for lv in (1.0, 6.0)]
    data = AnalysisSettings(spectral=SpectralSettings(block=PERIOD, overlap=0.0, window="boxcar"),
                            band=IntegrationBand(1.0, 60.0), analysis_band_hz=(2.0, 20.0), period_samples=PERIOD,
                            skip_periods=1)
    got = {}
    for n in ("1", "2"):
        monkeypatch.setenv("NIFO_THREADS", n)
        got[n] = close_loop(recs, (), data=data, settings=LoopSettings(max_rounds=1, refine=False))
    one, two = got["1"], got["2"]
    trials = one.rounds[0].trials
    assert one.model.linear.kind == "rational" and len(trials) >= 2, one.report()   # judged side by side
    assert one.to_dict() == two.to_dict()


def test_the_bias_correction_side_by_side_is_its_serial_result_bit_for_bit(monkeypatch):
    """simulated_correction runs a step's records, its noisy refits and its noise-free refit side by side on threads
    (side_by_side=True): the corrected θ, the bias and every spread are those of the serial loop to the last bit."""
    from nifo_core.signal.bias_correction import simulated_correction

    from conftest import static_cubic_problem

    simulate, fit, recs, noise = static_cubic_problem(3, 4000)
    theta0 = fit(recs)
    got = {}
    for n, side in (("1", False), ("2", True)):
        monkeypatch.setenv("NIFO_THREADS", n)
        got[n] = simulated_correction(fit, simulate, recs, noise, theta0, pairs=2, side_by_side=side,
                                      drive_noise=True)
    one, two = got["1"], got["2"]
    assert one is not None and not np.array_equal(one.theta, theta0)     # a correction was made
    for name in ("theta", "noise_bias", "draw_sd", "tail", "drive_sd", "fit_sd"):
        assert np.array_equal(getattr(one, name), getattr(two, name)), name
    assert one.gain == two.gain


def test_the_bias_correction_with_its_records_simulated_together_is_the_record_by_record_one():
    """Given ``simulate_records`` (the records of one length marched together), simulated_correction simulates each
    step's records and each record's drive-noise versions in it, side by side or not: the correction is the one of
    ``simulate`` record by record, to the last bit."""
    from nifo_core.signal.bias_correction import DRIVE_PAIRS, simulated_correction

    from conftest import static_cubic_problem

    simulate, fit, recs, noise = static_cubic_problem(3, 4000)
    theta0 = fit(recs)
    kw = dict(pairs=2, drive_noise=True, iterations=3)
    alone = simulated_correction(fit, simulate, recs, noise, theta0, **kw)
    for side in (False, True):
        calls = []

        def together(theta, some):
            calls.append(len(some))
            return [simulate(theta, r) for r in some]

        got = simulated_correction(fit, simulate, recs, noise, theta0, side_by_side=side, simulate_records=together,
                                   **kw)
        for name in ("theta", "noise_bias", "draw_sd", "tail", "drive_sd", "fit_sd"):
            assert np.array_equal(getattr(alone, name), getattr(got, name)), name
        # three steps of three records, then each record's 2·DRIVE_PAIRS drive-noise versions in one call (or batches)
        assert sum(calls) == 3 * len(recs) + len(recs) * 2 * DRIVE_PAIRS
        assert side or calls == [len(recs)] * 3 + [2 * DRIVE_PAIRS] * len(recs)


def test_the_kinds_tried_by_output_error_side_by_side_are_what_one_thread_gives(monkeypatch):
    """Beyond the equation error's reach the loop refines every kind the last round ranked by output error
    (:func:`nifo_core.loop.beyond.search_beyond`), the kinds side by side on threads: every trial (its refined term,
    coefficient, held-out figures, verdict) and the model are those of one thread, bit for bit."""
    from test_loop_beyond import BAND, D, _record

    from nifo_core.loop import LoopSettings, close_loop

    rec, _ = _record(0.04 * D, seconds=30.0)
    got = {}
    for n in ("1", "2"):
        monkeypatch.setenv("NIFO_THREADS", n)
        got[n] = close_loop([rec], ["cubic_stiffness"], band=BAND, settings=LoopSettings(max_rounds=1))
    one, two = got["1"], got["2"]
    assert len(one.beyond) >= 2, one.report()      # tried side by side
    assert one.to_dict() == two.to_dict()
