"""Speed of prediction: the time-domain engine against the frequency-domain fixed point, same run.

Run: ``.venv/bin/python benchmarks/bench_predict.py [--duration S] [--fs HZ] [--oversample Q]``.
Also a structure like the F-16's (rational order 30) with three plays, with constant coefficients and through
feedback paths (:mod:`nifo_core.predict.feedback_paths`), the ratio printed, and the path kernel with its
number of terms compiled in against counted at run time (the baseline, same run), bit for bit; and, for these
and the quarter car with every kind, the step as it runs (each row of the block-diagonal Φ two fixed products)
against the same step looping over each row's band (the baseline, same run), bit for bit the same output; and
for each quarter car, three models of one record (a forward-difference Jacobian's columns) marched together
(:mod:`nifo_core.predict.timesim_lanes`) against one by one (the baseline, same run), bit for bit the same, and
one model on four records of one length (the record's quarters, :func:`~nifo_core.predict.model.predict_records`)
marched together against one by one (the baseline, same run), bit for bit the same.
Target: 300 s at 600 Hz predicted in less than 2 s after compilation (CPU
time of the process; the wall time is printed beside it, with the load). Each
model is the true one of a simulated record (so the accuracy printed beside
the time is the engine's own error, and the linear part alone is the
baseline). The frequency-domain path (Picard iteration on the zero-padded
record, :mod:`nifo_core.predict.fixed_point`) runs only where its contraction bound
holds: the paper's velocity dead zone; for the others it is refused, which is
printed. The first call (numba compile or cache load) is a warm-up and not timed.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
from dataclasses import replace

import numpy as np

from nifo_core.kinds.describing import Term
from nifo_core.errors import ConfigError
from nifo_core.predict.model import BodyModel, IdentifiedModel, predict_bodies, predict_body, predict_records
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, StrutForce, preset, simulate

TARGET_S = 2.0


def _model(sim, fs: float, *, terms: bool = True) -> IdentifiedModel:
    car = sim.truth.vehicle
    strut = sim.truth.strut if terms else ()
    return IdentifiedModel.from_body(BodyModel(car.k2 / car.m2, car.c2 / car.m2), [s.term for s in strut],
                                     [s.coefficient / car.m2 for s in strut], fs_hz=fs)


def _timed(fn, repeats: int):
    """(best wall time [s], best CPU time of this process [s], result) of ``repeats`` runs."""
    best, cpu, out = float("inf"), float("inf"), None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        best, cpu = min(best, time.perf_counter() - t0), min(cpu, time.process_time() - c0)
    return best, cpu, out


@contextlib.contextmanager
def _band_loop():
    """Inside, the step kernels loop over each row's band of Φ instead of its two fixed products (the baseline)."""
    from nifo_core.predict import timesim

    rows = timesim._rows
    timesim._rows = lambda phi: (*rows(phi)[:-1], False)
    try:
        yield
    finally:
        timesim._rows = rows


@contextlib.contextmanager
def _terms_at_run_time():
    """Inside, the feedback-path kernel reads its number of terms at run time instead of having it compiled in
    (:func:`nifo_core.predict.timesim._path_kernel`; the baseline)."""
    from nifo_core.predict import timesim

    unrolled = timesim.MAX_UNROLLED_TERMS
    timesim.MAX_UNROLLED_TERMS = 0
    try:
        yield
    finally:
        timesim.MAX_UNROLLED_TERMS = unrolled


def _against_baseline(name: str, fn, repeats: int, baseline, what: str, forms: tuple[str, str]) -> None:
    """CPU of ``fn`` (a prediction) as it runs and inside the context ``baseline`` (the other form of ``what``), and
    whether the outputs are identical: ``forms`` names the two."""
    with baseline():
        fn()                                   # compile or load the baseline's kernel: not timed
        _, slow, ref = _timed(fn, repeats)
    _, fast, out = _timed(fn, repeats)
    same = all(np.array_equal(getattr(out, k), getattr(ref, k)) for k in ("z", "zdot", "body_accel"))
    print(f"{name:<38} {what}: {forms[0]} {fast:6.3f} s CPU, {forms[1]} {slow:6.3f} s "
          f"-> {slow / fast:.2f}x, output {'identical' if same else 'DIFFERENT'}")
    if not same:
        raise SystemExit(f"{name}: the two forms of the {what} differ")


def _against_terms_at_run_time(name: str, fn, repeats: int) -> None:
    """A prediction through feedback paths with the path kernel's terms compiled in and counted at run time."""
    _against_baseline(name, fn, repeats, _terms_at_run_time, "path kernel",
                      ("terms compiled in", "counted at run time"))


def _against_band_loop(name: str, fn, repeats: int) -> None:
    """A prediction with Φ's rows as two fixed products and as their band's loop."""
    _against_baseline(name, fn, repeats, _band_loop, "step kernel", ("two products per row", "band loop"))


def _columns(model: IdentifiedModel, lanes: int) -> list[IdentifiedModel]:
    """The model and ``lanes - 1`` copies, each with one coefficient 0.1 % larger: a forward-difference
    Jacobian's columns, as the output-error refinement simulates them."""
    out = [model]
    for j in range(lanes - 1):
        g = np.array(model.c_over_m2, float)
        if g.size:
            g[j % g.size] *= 1.001
        out.append(replace(model, c_over_m2=g))
    return out


def _against_one_by_one(name: str, model: IdentifiedModel, a1, fs: float, q, repeats: int, lanes: int = 3) -> None:
    """CPU of ``lanes`` predictions of one record marched together (:func:`predict_bodies`) against one by one
    (the baseline, same run), and whether every output is identical."""
    models = _columns(model, lanes)
    _, alone, ref = _timed(lambda: [predict_body(m, a1, fs, oversample=q) for m in models], repeats)
    _, together, out = _timed(lambda: predict_bodies(models, a1, fs, oversample=q), repeats)
    same = all(np.array_equal(getattr(o, k), getattr(r, k)) for o, r in zip(out, ref) for k in ("z", "zdot", "body_accel"))
    print(f"{name:<38} {lanes} models of one record: marched together {together:6.3f} s CPU, one by one "
          f"{alone:6.3f} s -> {together / alone:.2f}, output {'identical' if same else 'DIFFERENT'}")
    if not same:
        raise SystemExit(f"{name}: the models marched together differ from one by one")


def _records_against_one_by_one(name: str, model: IdentifiedModel, a1, fs: float, q, repeats: int,
                                records: int = 4) -> None:
    """CPU of one model's predictions of ``records`` records of one length (the quarters of ``a1``) marched together
    (:func:`predict_records`: the bias corrections' synthetic records, the held-out parts) against one by one (the
    baseline, same run), and whether every output is identical."""
    n = a1.size // records
    drives = [a1[k * n:(k + 1) * n] for k in range(records)]
    _, alone, ref = _timed(lambda: [predict_body(model, a, fs, oversample=q) for a in drives], repeats)
    _, together, out = _timed(lambda: predict_records(model, drives, fs, oversample=q), repeats)
    same = all(np.array_equal(getattr(o, k), getattr(r, k))
               for o, r in zip(out, ref) for k in ("z", "zdot", "body_accel"))
    print(f"{name:<38} {records} records of one model: marched together {together:6.3f} s CPU, one by one "
          f"{alone:6.3f} s -> {together / alone:.2f}, output {'identical' if same else 'DIFFERENT'}")
    if not same:
        raise SystemExit(f"{name}: the records marched together differ from one by one")


def _nmse(y, yhat, v) -> float:
    return float(100 * np.mean((y[v] - yhat[v]) ** 2) / np.var(y[v]))


def _rational_cases(duration: float, fs: float, q, repeats: int):
    """A structure like the F-16's (15 modes in 2-15 Hz, rational order 30) with three plays, predicted with
    constant coefficients (one input) and through feedback paths (:mod:`nifo_core.predict.feedback_paths`, two inputs):
    (wall, CPU) of each."""
    from dataclasses import replace

    from nifo_core.kinds.describing import make_term
    from nifo_core.signal.integrate import IntegrationBand
    from nifo_core.predict.linear_part import LinearPart
    from nifo_core.signal.spectral import SpectralSettings

    rng = np.random.default_rng(0)
    wn = 2 * np.pi * np.linspace(2.5, 14.5, 15)
    p = -0.02 * wn + 1j * wn * np.sqrt(1 - 0.02**2)
    r = 1e-3 * (rng.standard_normal(15) + 1j * rng.standard_normal(15)) / wn
    r -= r.real.sum() / 15
    poles, res = np.concatenate([p, p.conj()]), np.concatenate([r, r.conj()])
    terms = [make_term({"kind": "backlash", "params": {"deadband": d}}) for d in (5e-5, 1.4e-4, 4e-4)]
    gam = np.array([2e3, -1e3, -3e3])
    lin = LinearPart("rational", poles=poles, residues=res, band_hz=(2.0, 15.0), absorbed=(float(gam.sum()), 0.0))
    a1 = 2.0 * np.random.default_rng(1).standard_normal(int(duration * fs))
    const = IdentifiedModel(freq_hz=np.zeros(1), t21=np.ones(1, complex), b=np.zeros((3, 1), complex), terms=terms,
                            c_over_m2=gam, body=None, analysis_band_hz=(2.0, 15.0), fs_hz=fs,
                            settings=SpectralSettings(), band=IntegrationBand(0.5, 40.0), linear=lin)
    paths = replace(const, linear=replace(lin, absorbed=(0.0, 0.0), paths=gam[:, None] * res[None, :]))
    predict_body(paths, a1[: int(5 * fs)], fs, oversample=q)                 # compile or load the kernel
    wc, cc, _ = _timed(lambda: predict_body(const, a1, fs, oversample=q), repeats)
    wp, cp, _ = _timed(lambda: predict_body(paths, a1, fs, oversample=q), repeats)
    _against_band_loop("rational order 30, constant γ", lambda: predict_body(const, a1, fs, oversample=q), repeats)
    _against_band_loop("rational order 30, feedback paths", lambda: predict_body(paths, a1, fs, oversample=q), repeats)
    _against_terms_at_run_time("rational order 30, feedback paths", lambda: predict_body(paths, a1, fs, oversample=q),
                               repeats)
    return wc, cc, wp, cp


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=300.0, help="predicted seconds (default 300)")
    p.add_argument("--fs", type=float, default=600.0, help="sample rate [Hz] (default 600)")
    p.add_argument("--oversample", type=int, default=None, help="fine steps per sample (default: the engine's, 4 at 600 Hz)")
    p.add_argument("--repeats", type=int, default=2, help="timed runs, best kept (default 2)")
    args = p.parse_args()
    fs, q = args.fs, args.oversample

    cases = {"paper velocity dead zone, 2.5 mm": (preset("paper_deadzone"), 0.0025),
             "cubic 2e8 N/m³, 5 mm": ((StrutForce(Term("cubic_stiffness"), 2e8),), 0.005),
             "every kind (incl. backlash), 2.5 mm": (preset("all"), 0.0025)}
    t0 = time.perf_counter()
    warm = simulate(SimConfig(strut=preset("all"), duration_s=5.0, fs_hz=fs), rng=0)
    predict_body(_model(warm, fs), warm.record.spindle_accel, fs, oversample=q)
    print(f"warm-up (compile or cache load): {time.perf_counter() - t0:.2f} s")
    worst = 0.0
    for name, (strut, rms) in cases.items():
        sim = simulate(SimConfig(strut=strut, road=RandomRoad(rms), duration_s=args.duration, fs_hz=fs), rng=1)
        a1, y = sim.record.spindle_accel, sim.record.body_accel
        model = _model(sim, fs)
        wall, cpu, pred = _timed(lambda: predict_body(model, a1, fs, oversample=q), args.repeats)
        worst = max(worst, cpu)
        v = slice(int(10 * fs), a1.size - int(fs))
        lin = predict_body(_model(sim, fs, terms=False), a1, fs)
        line = (f"{name:<38} time domain: wall {wall:6.3f} s, CPU {cpu:6.3f} s = 1/{args.duration / cpu:.0f} of real "
                f"time, "
                f"NMSE {_nmse(y, pred.body_accel, v):.5f} % (linear part alone {_nmse(y, lin.body_accel, v):.3f} %)")
        try:
            wf, cf, pf = _timed(lambda: predict_body(model, a1, fs, engine="frequency", tol=1e-8), args.repeats)
            line += (f"; frequency domain: wall {wf:6.3f} s, CPU {cf:6.3f} s ({pf.iterations} iterations, NMSE "
                     f"{_nmse(y, pf.body_accel, v):.5f} %) -> time/frequency CPU = {cpu / cf:.2f}")
        except ConfigError as err:
            line += f"; frequency domain refused ({err.message})"
        print(line)
        _against_one_by_one(name, model, a1, fs, q, args.repeats)
        _records_against_one_by_one(name, model, a1, fs, q, args.repeats)
        if strut is cases["every kind (incl. backlash), 2.5 mm"][0]:
            _against_band_loop(name, lambda: predict_body(model, a1, fs, oversample=q), args.repeats)
    wall_c, cpu_c, wall_p, cpu_p = _rational_cases(args.duration, fs, q, args.repeats)
    worst = max(worst, cpu_c, cpu_p)
    print(f"{'rational order 30, three plays, constant γ':<38} time domain: wall {wall_c:6.3f} s, CPU {cpu_c:6.3f} s")
    print(f"{'the same through feedback paths':<38} time domain: wall {wall_p:6.3f} s, CPU {cpu_p:6.3f} s "
          f"-> paths/constant CPU = {cpu_p / cpu_c:.2f}")
    ok = worst < TARGET_S
    print(f"target: {args.duration:g} s at {fs:g} Hz in < {TARGET_S:g} s of CPU: {'met' if ok else 'MISSED'} "
          f"(slowest {worst:.3f} s; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores, "
          "so wall time on a shared machine is longer)")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
