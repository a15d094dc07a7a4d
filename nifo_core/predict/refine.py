"""Output-error refinement: the identified coefficients that make the model *predict* the data best.

NIFO (paper Eq. 8) is an equation-error estimator: it regresses the body
equation on z, ż integrated from noisy accelerations. That is fast, needs no
iteration and gives good starting values, but it is biased where the
regressors are noisy or the model class misses something (sensor noise
integrated twice into z pulls a cubic coefficient towards zero; on a real
multi-mode structure the static fit splits stiffness between the linear part
and the terms). The model's job is to predict, so the final step minimises
the prediction error itself — the output-error / simulation-error criterion
of system identification (Ljung 1999, §7; the refinement step of FNSI and of
nonlinear state-space models, Noël & Kerschen 2017; Paduart et al. 2010):

    θ* = argmin_θ Σ_r NMSE_r(θ)/100,   NMSE_r = band-limited prediction error of record r
                                        (:mod:`nifo_core.predict.prediction_error`)

with every record simulated in time by the identified model
(:func:`nifo_core.predict.model.predict_body`) from its measured spindle acceleration
(or force). Each record counts by its *relative* error, so a low level weighs
as much as a high one. θ holds

- the coefficients γ_i = c_i/M2 of the terms (scaled by their NIFO values),
- the key parameter of each term that has one (gap, deadband, knee…; log
  scale, within ¼-4× of its start) unless ``shape=False``,
- for a one-mass body, its realised stiffness and damping per unit mass (log
  scale; reported as the nominal body's, the terms' absorbed linear part taken
  out); a rational linear part is kept as fitted, or (``linear_residues``)
  its residues are refined too, its poles kept: the linear part identified
  jointly with the terms.

Two starting points: the NIFO model itself, and — when a linear model
identified on the same data is given — that linear model with the terms added
at zero coefficient, its linear part kept as the *realised* one so that a term
adds only its bounded remainder (a play's or a clearance's force minus its
slope, :func:`~nifo_core.predict.linear_part.absorbed_rates`): no coefficient can
destabilise it. A trust-region step is accepted only when it lowers the cost,
so from the linear start the result predicts the identification data at least
as well as the linear model — the nonlinear model *nests* the linear one on
this metric. The linear start is refined when the refined NIFO model does not
already beat the linear model (``both_starts=True``: always); the better
result is kept. A step whose simulation diverges counts as a very poor fit
and is refused.

The linear part identified jointly with the terms (:func:`refine_jointly`,
``nifo identify --refine-linear``): the linear model's residues are refined
alone first — the linear baseline of the procedure — and the terms are then
added to *that* linear part as their bounded remainder, refined with its
residues from two starts, NIFO's coefficients and zero (the refined linear
model itself), the better on the identification records kept: the result
never predicts them worse than the equally refined linear model.

Driven by the *measured* spindle signal, the fit is biased by that sensor's noise (errors in
variables); :func:`nifo_core.predict.refine_bias.correct_refinement` removes the bias by simulating the
refinement with the estimated noise (the loop does so; ``refine_model`` itself does not).

Minimised by :func:`scipy.optimize.least_squares` (trust-region reflective, the trust region scaled by the
Jacobian's columns — with unit scales it ran out of its 30 evaluations on the F-16's identification and on
``benchmarks/bench_loop.py``'s final model, 16 and 28 Jacobians; scaled, both converge, in 7 and 23 (issue 58);
finite-difference Jacobian: one simulation per parameter and record per
iteration; a record's simulations for all the parameters marched together, :mod:`nifo_core.predict.timesim_lanes`,
the same bits as one by one, and the parameters split over threads, :mod:`nifo_core.signal.parallel`). The
refinement never makes the model worse on the records it is
given; whether it predicts *other* levels better is measured, not assumed
(``tools/f16_predict.py``, ``tests/test_refine.py``).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Sequence

import numpy as np
import scipy.optimize

from ..errors import ConfigError, IllConditionedError, InputError
from .linear_part import absorbed_rates
from .model import IdentifiedModel, PredictionDivergedError, predict_body, record_inputs
from .refine_space import Space, half_widths, reported_values, space_for, stored_covariance, terms_on
from .sensitivity import Parameters, residual_jacobian
from .time_prediction import predict_bodies, predict_records
from .prediction_error import band_spectra
from ..signal.parallel import batch_map, thread_map
from ..signal.record import Record

__all__ = ["Refinement", "refine_model", "refine_jointly", "model_nmse", "start_up_samples", "prediction_residual",
           "prediction_residuals", "record_residuals", "march_jacobians"]

#: relative error a diverged simulation counts as (per record; 1 = predicting zero)
_DIVERGED = 10.0
#: the refinement stops when an accepted step lowers the cost by less than this fraction of it (least squares' ``ftol``;
#: scipy's default is 1e-8). Measured (issue 58): past 1e-6 of the cost the steps only polish digits no held-out
#: figure shows — the F-16's refinement from the linear start 37 → 23 evaluations (held-out 0.29412 → 0.29411 %), the
#: loop benchmark's 25 → 18 (its final held-out 0.41598 → 0.41618 %), the sample's 7 → 6 (0.061104 → 0.061104 %);
#: at 1e-5 the loop benchmark's stopped 0.18 of a half-width short in the knee's coefficient, predicted its held-out
#: parts at 0.438 % and was not kept (0.431 % without it): 1e-6 is the largest power of ten that kept every figure
COST_RTOL = 1e-6


@dataclass(frozen=True)
class Refinement:
    """The refined model and what the refinement did.

    Attributes
    ----------
    model : IdentifiedModel
        The refined model (``provenance['refined']`` says how it was made).
    start : {'nifo', 'linear'}
        The starting point the kept result came from.
    nmse_before : mapping
        Per starting point, the band NMSE [%] of every record before refinement.
    nmse : list of float
        Band NMSE [%] of every record with the refined model.
    parameters : list of dict
        name, unit, before (of the kept start), after.
    evaluations : int
        Simulations of the whole record set (all starts).
    message : str
    """

    model: IdentifiedModel
    start: str
    nmse_before: Mapping[str, list]
    nmse: list
    parameters: list
    evaluations: int
    message: str
    labels: list = field(default_factory=list)
    #: what a bias correction did, or why there is none (:mod:`nifo_core.predict.refine_bias`; empty: not tried)
    bias_note: str = ""

    def to_dict(self) -> dict:
        return {"start": self.start, "nmse_before_pct": {k: list(v) for k, v in self.nmse_before.items()},
                "nmse_pct": list(self.nmse), "records": list(self.labels), "parameters": list(self.parameters),
                "evaluations": self.evaluations, "message": self.message, "bias_note": self.bias_note}


def model_nmse(model: IdentifiedModel, records: Sequence[Record], *, band_hz: tuple[float, float],
               period_samples: int | None = None, skip_samples: int | Sequence[int] = 0,
               oversample: int | None = None) -> list[float]:
    """Band NMSE [%] of the model's prediction of every record (:mod:`nifo_core.predict.prediction_error`).

    A record whose prediction diverges gives ``inf``.
    """
    got = record_residuals(model, records, band_hz=band_hz, period_samples=period_samples,
                           skip_samples=_skips(skip_samples, len(records)), oversample=oversample)
    return [float("inf") if r is None else float(100 * np.sum(np.abs(r) ** 2)) for r in got]


def start_up_samples(model: IdentifiedModel, record: Record, period_samples: int | None = None) -> int:
    """Samples left out of the score after a simulation from rest (the default ``skip_samples``): one period
    of periodic data, else five time constants of the linear part's slowest pole (at most a quarter of the
    record)."""
    if period_samples:
        return int(period_samples)
    return int(min(len(record.body_accel) // 4, np.ceil(5 * model.linear.slowest_decay_s() * record.fs_hz)))


def _skips(skip_samples, n: int) -> list[int]:
    if np.ndim(skip_samples) == 0:
        return [int(skip_samples)] * n
    s = [int(v) for v in skip_samples]
    if len(s) != n:
        raise ConfigError(f"{len(s)} skips for {n} records")
    return s


def _residual(model, rec, band_hz, period_samples, skip, oversample) -> np.ndarray:
    """(Ŷ - Y)/‖Y‖ on the band's lines (complex)."""
    a1, force = record_inputs(rec, model)
    p = predict_body(model, a1, rec.fs_hz, force=force, oversample=oversample, label=rec.source)
    return _scored(p.body_accel, rec, band_hz, period_samples, skip)


def record_residuals(model: IdentifiedModel, records: Sequence[Record], *, band_hz: tuple[float, float],
                     period_samples: int | None = None, skip_samples: Sequence[int] | None = None,
                     oversample: int | None = None) -> list[np.ndarray | None]:
    """:func:`prediction_residual` of ``model`` on each record (``skip_samples[i]`` for record i), None where its
    simulation diverges: the same values, the records of one length marched together
    (:func:`~nifo_core.predict.time_prediction.predict_records`: a refinement's evaluation, a synthetic refit's)."""
    skips = [0] * len(records) if skip_samples is None else list(skip_samples)
    drives = [record_inputs(r, model) for r in records]
    preds = predict_records(model, [a1 for a1, _ in drives], [r.fs_hz for r in records],
                            forces=[f for _, f in drives], oversample=oversample, labels=[r.source for r in records])
    return [None if isinstance(p, PredictionDivergedError) else _scored(p.body_accel, r, band_hz, period_samples, s)
            for p, r, s in zip(preds, records, skips, strict=True)]


def _scored(body_accel: np.ndarray, rec, band_hz, period_samples, skip) -> np.ndarray:
    y, yh = band_spectra(rec.body_accel, body_accel, rec.fs_hz, band_hz=band_hz, period_samples=period_samples,
                         skip_samples=skip)
    return (yh - y) / np.sqrt(np.sum(np.abs(y) ** 2))


# Long (over 100 lines): the parameter space, the two starts and the least squares with its covariance
# share the residual closure. Left whole here while the noise branch (issue 28) edits its body; to split after
# the merge.
def refine_model(model: IdentifiedModel, records: Sequence[Record], *, band_hz: tuple[float, float] | None = None,
                 period_samples: int | None = None, skip_samples: int | Sequence[int] | None = None,
                 linear: IdentifiedModel | None = None, shape: bool = True, linear_params: bool = True,
                 max_iterations: int = 30, oversample: int | None = None, both_starts: bool = False,
                 linear_residues: bool = False,
                 progress: Callable[[str, int, float], None] | None = None) -> Refinement:
    """Refine ``model`` on ``records`` by minimising the band-limited prediction error (module docstring).

    Parameters
    ----------
    model : IdentifiedModel
        The NIFO model (its terms, coefficients, linear part).
    records : sequence of Record
        The identification records, each predicted whole from rest.
    band_hz : (float, float), optional
        Band of the metric [Hz]; default: the model's analysis band.
    period_samples : int, optional
        Periodic data: score the period-averaged steady state.
    skip_samples : int or sequence of int, optional
        Start-up samples left out of the score; default one period for
        periodic data, else five time constants of the slowest pole of the
        linear part (at most a quarter of the record).
    linear : IdentifiedModel, optional
        The linear model identified on the same data: a second start (terms at
        zero coefficient, its linear part), which makes the result at least as
        good as the linear model on these records.
    shape, linear_params : bool
        Also refine the terms' key parameters / a one-mass body's k and c.
    both_starts : bool
        Refine the linear start even when the refined NIFO model already beats the linear model.
    linear_residues : bool
        Also refine a rational linear part's residues (its poles kept, Σ r = 0
        kept): the linear part is then identified jointly with the terms by
        output error instead of fixed before them (2 parameters per pole pair:
        one simulation each per iteration). Only on a start whose feedback is
        bounded — the linear start (the terms adding their bounded remainder),
        or a model whose linear part absorbed the terms' slopes or whose terms
        are bounded forces — so that no θ can destabilise it at another level;
        the linear start is then always refined. A model without terms may be
        refined too (its residues alone: the linear baseline of the same
        procedure).
    max_iterations : int
        Trust-region iterations per start (each costs 1 + len(θ) simulations of every record).
    oversample : int, optional
        Fine steps per sample of the simulation (default: the predictor's).
    progress : callable(start, evaluations, cost), optional

    Returns
    -------
    Refinement

    Raises
    ------
    ConfigError
        For a model without terms (nothing to refine), a model with feedback paths, or bad options.
    IllConditionedError
        When no start can be simulated on these records.
    """
    if not model.terms and not (linear_residues and model.linear.kind == "rational"):
        raise ConfigError("the model has no nonlinear term to refine",
                          hint="a linear model's rational linear part can be refined with linear_residues=True")
    if model.linear.paths is not None:
        raise ConfigError("the model's terms act through feedback paths (nifo_core.predict.feedback_paths): their residues "
                          "are fitted there, not by this refinement", hint="refine the constant-coefficient model")
    if not records:
        raise InputError("refinement needs at least one record")
    band = tuple(band_hz) if band_hz is not None else model.analysis_band_hz
    if skip_samples is None:
        skip_samples = [start_up_samples(model, r, period_samples) for r in records]
    skips = _skips(skip_samples, len(records))
    # the NIFO model keeps its convention: the terms' linear part absorbed into the linear part (bounded
    # feedback) when from_nifo chose so, else not
    tracked = any(model.linear.absorbed) and np.allclose(model.linear.absorbed,
                                                         absorbed_rates(model.terms, model.c_over_m2))
    # residues move only where the terms' feedback is bounded (their slope absorbed into the realised linear part,
    # or a bounded force): the realised part keeps its poles, so no θ can destabilise the model at any level
    bounded = tracked or all(t.spec.bounded for t in model.terms)
    starts = {"nifo": space_for(model, model, shape=shape, linear_params=linear_params, track_absorbed=tracked,
                             residues=linear_residues and bounded)}
    if linear is not None and model.terms:
        if linear.terms:
            raise ConfigError("linear= must be a model without terms (source 'h1')")
        # the linear model's linear part is the realised one: the terms add only their bounded remainder
        # (a play's or a clearance's force minus its slope), so no γ can destabilise it
        base = terms_on(linear, model, np.zeros(len(model.terms)))
        starts["linear"] = space_for(base, model, shape=shape, linear_params=linear_params, track_absorbed=True,
                                  residues=linear_residues)
    n_eval = 0
    # a record whose simulation diverges counts as relative error _DIVERGED, spread over its lines
    penalty = [np.full(band_spectra(r.body_accel, r.body_accel, r.fs_hz, band_hz=band, period_samples=period_samples,
                                    skip_samples=s)[0].size, 1.0) for r, s in zip(records, skips)]
    penalty = [np.sqrt(_DIVERGED / p.size) * p for p in penalty]
    sizes = np.cumsum([p.size for p in penalty])[:-1]
    diverged: dict[bytes, set] = {}     # per evaluated θ: the records whose simulation diverged
    lock = threading.Lock()             # evaluations run side by side for the Jacobian's columns

    def evaluate(name: str, sp: Space, x: np.ndarray) -> np.ndarray:
        """Residual vector (real, imaginary) of every record at θ = x; a diverged record gets its penalty.
        Safe on several threads at once. A θ the Jacobian's columns computed together (:func:`columns`) is
        taken from there."""
        nonlocal n_eval
        key = np.asarray(x, float).tobytes()
        if key in ready:
            out, bad = ready.pop(key)
        else:
            m = sp.model(x)

            def some(ks: list[int]) -> list[np.ndarray | None]:
                return record_residuals(m, [records[k] for k in ks], band_hz=band, period_samples=period_samples,
                                        skip_samples=[skips[k] for k in ks], oversample=oversample)

            # the records side by side: a batch on each thread, those of one length marched together
            out, bad = assembled(batch_map(some, range(len(records))))
        with lock:
            n_eval += 1
            diverged[key] = bad
            if progress is not None:
                progress(name, n_eval, float(np.sum(out ** 2)))
        return out

    def assembled(parts: list) -> tuple[np.ndarray, set]:
        """The residual vector from each record's residual (None: diverged, its penalty), and the diverged."""
        bad = {k for k, r in enumerate(parts) if r is None}
        r = np.concatenate([penalty[k].astype(complex) if p is None else p for k, p in enumerate(parts)])
        return np.concatenate([r.real, r.imag]), bad

    ready: dict[bytes, tuple[np.ndarray, set]] = {}   # residual vectors computed together, until evaluate takes them

    def columns(sp: Space):
        """least_squares' ``workers`` for the forward-difference Jacobian: its θs' simulations of each record
        marched together (:mod:`nifo_core.predict.timesim_lanes`, the same bits as one by one), the θs split over
        the threads; then ``fun`` of each θ in order, which finds its residual computed."""
        def work(fun, xs):
            xs = [np.asarray(x, float) for x in xs]

            def batch(part: list[np.ndarray]) -> list[tuple[np.ndarray, set]]:
                models = [sp.model(x) for x in part]
                per_record = [prediction_residuals(models, rec, band_hz=band, period_samples=period_samples,
                                                   skip_samples=s, oversample=oversample)
                              for rec, s in zip(records, skips)]
                return [assembled([per_record[k][lane] for k in range(len(records))]) for lane in range(len(part))]

            for x, res in zip(xs, batch_map(batch, xs)):
                ready[x.tobytes()] = res
            try:
                return [fun(x) for x in xs]
            finally:
                ready.clear()
        return work

    def sensitivities(sp: Space, x: np.ndarray) -> np.ndarray:
        """The residual vector's Jacobian (real parts, then imaginary); a diverged record's constant penalty: zero
        rows."""
        m = sp.model(x)
        parts = march_jacobians(m, sp.march_parameters(m), records, band_hz=band, period_samples=period_samples,
                                skips=skips, oversample=oversample)
        jc = np.concatenate([np.zeros((pen.size, x.size), complex) if p is None else p
                             for p, pen in zip(parts, penalty)])
        return np.vstack([jc.real, jc.imag])

    def per_record(x: np.ndarray, out: np.ndarray) -> list[float]:
        """Band NMSE [%] per record from the residual vector at θ = x (inf where the simulation diverged)."""
        bad = diverged.get(np.asarray(x, float).tobytes(), set())
        r = out[:out.size // 2] + 1j * out[out.size // 2:]
        return [float("inf") if k in bad else float(100 * np.sum(np.abs(part) ** 2))
                for k, part in enumerate(np.split(r, sizes))]

    def run(name: str, sp: Space, x0: np.ndarray, r0: np.ndarray):
        """Refine from θ = x0 (residual r0 there): (θ, space, solution, NMSE per record), None if x0 diverges."""
        before[name] = per_record(x0, r0)
        if not np.all(np.isfinite(before[name])):
            return None
        lo, hi = sp.bounds()
        # the Jacobian from one march of every record (forward sensitivities, :mod:`.sensitivity`); where the
        # march cannot give it (the residues move), forward differences: one simulation of every record per
        # parameter, the columns marched together, on threads
        how = dict(jac=lambda x: sensitivities(sp, x)) if sp.march_parameters(sp.base) is not None else \
            dict(diff_step=1e-3, workers=columns(sp))
        sol = scipy.optimize.least_squares(lambda x: evaluate(name, sp, x), x0, bounds=(lo, hi), method="trf",
                                           x_scale="jac", max_nfev=max_iterations, f_scale=1.0, ftol=COST_RTOL,
                                           **how)
        if sol.cost <= 0.5 * float(np.sum(r0 ** 2)):
            return sol.x, sp, sol, per_record(sol.x, sol.fun)
        return x0, sp, sol, before[name]

    results, before = {}, {}
    nifo = starts["nifo"]
    x_nifo = nifo.x0(np.asarray(model.c_over_m2, float))
    results["nifo"] = run("nifo", nifo, x_nifo, evaluate("nifo", nifo, x_nifo))
    if "linear" in starts:
        # the linear start (terms at zero) guarantees "no worse than the linear model on these records";
        # it is only needed when the refined NIFO model is not already better than the linear one
        lin0 = starts["linear"]
        x_lin = lin0.x0(np.zeros(len(model.terms)))
        r_lin = evaluate("linear", lin0, x_lin)
        nifo_sum = float(np.sum(results["nifo"][3])) if results["nifo"] is not None else np.inf
        if both_starts or (linear_residues and not nifo.residues) or \
                nifo_sum > float(np.sum(per_record(x_lin, r_lin))):
            results["linear"] = run("linear", lin0, x_lin, r_lin)
        else:
            before["linear"] = per_record(x_lin, r_lin)
    ok = {k: v for k, v in results.items() if v is not None}
    if not ok:
        raise IllConditionedError("the model cannot be simulated on these records from any start "
                                  f"({', '.join(r.source for r in records)})",
                                  hint="identify on data that covers these levels, or leave the term out")
    finals = {k: v[3] for k, v in ok.items()}
    best = min(finals, key=lambda k: float(np.sum(finals[k])))
    x, sp, sol, _ = ok[best]
    refined = sp.model(x)
    cov = _covariance(sol) if x is sol.x else None
    hw = half_widths(sp, x, cov)
    params = [{"name": n, "unit": u, "before": float(v0), "after": float(v1), "half_width_95": h}
              for (n, u), v0, v1, h in zip(sp.names(), reported_values(sp, sp.x0(np.asarray(sp.base.c_over_m2, float))),
                                              reported_values(sp, x), hw)]
    jointly = f" with the linear part's {sp.n_residues // 2} residue pairs" if sp.residues else ""
    msg = (f"output-error refinement{jointly} from the {best} start: mean band NMSE "
           f"{np.mean(before[best]):.4g} % → {np.mean(finals[best]):.4g} % on {len(records)} record(s) "
           f"({band[0]:g}-{band[1]:g} Hz{', period-averaged' if period_samples else ''}); {sol.message}")
    prov = {**dict(refined.provenance), "refined": {
        "method": "output-error (simulation-error) least squares, nifo_core.predict.refine", "start": best,
        "band_hz": list(band), "period_samples": period_samples, "skip_samples": skips,
        "nmse_before_pct": {k: v for k, v in before.items()}, "nmse_pct": finals[best],
        "records": [r.source for r in records], "parameters": params,
        "covariance": stored_covariance(sp, x, cov)}}
    refined = replace(refined, provenance=prov)
    return Refinement(model=refined, start=best, nmse_before=before, nmse=finals[best], parameters=params,
                      evaluations=n_eval, message=msg, labels=[r.source for r in records])


def march_jacobians(model: IdentifiedModel, params: Parameters, records: Sequence[Record], *,
                    band_hz: tuple[float, float], period_samples: int | None, skips: Sequence[int],
                    oversample: int | None) -> list[np.ndarray | None]:
    """Each record's block of the refinement's Jacobian (the derivative of its (Ŷ - Y)/‖Y‖ on its lines, complex)
    at ``model`` from one sensitivity march (:mod:`.sensitivity`), the records side by side; None for a record whose
    simulation diverges (each caller has its own penalty there)."""
    return thread_map(lambda k: residual_jacobian(model, records[k], params, band_hz=band_hz,
                                                  period_samples=period_samples, skip_samples=skips[k],
                                                  oversample=oversample), range(len(records)))


def refine_jointly(model: IdentifiedModel, linear: Refinement, records: Sequence[Record], *,
                   max_iterations: int = 40, **kw) -> Refinement:
    """The terms of ``model`` refined jointly with the residues of ``linear``'s linear part (module docstring).

    Parameters
    ----------
    model : IdentifiedModel
        The NIFO model: its terms and their coefficients (its own linear part is not used).
    linear : Refinement
        The linear model of the same data with its residues refined alone on the same ``records``
        (``refine_model(linear_model, records, linear_residues=True)``): the linear baseline of the
        procedure, refined once and shared by every model form compared on it.
    records, max_iterations, **kw
        As :func:`refine_model` (``linear_residues`` is implied).

    Returns
    -------
    Refinement
        From the better of two starts on ``linear``'s linear part: NIFO's coefficients (start
        ``'nifo'``) and zero coefficients (start ``'linear'``), both adding only the terms' bounded
        remainder (their slope absorbed), so that no θ moves a pole.

    Raises
    ------
    ConfigError
        When ``linear`` is not a refined linear model with a rational linear part, or ``model`` has no term.
    """
    lin = linear.model
    if lin.terms or lin.linear.kind != "rational":
        raise ConfigError("the joint refinement needs a linear model with a rational linear part",
                          hint="use --refine (the coefficients alone) for a one-mass body")
    if not model.terms:
        raise ConfigError("the model has no nonlinear term to refine")
    start = terms_on(lin, model, np.asarray(model.c_over_m2, float))
    return refine_model(start, records, linear=lin, both_starts=True, linear_residues=True,
                        max_iterations=max_iterations, **kw)


def _covariance(sol) -> np.ndarray | None:
    """cov(θ) = s²·(JᵀJ)⁻¹, s² = Σr²/(m - p) at the solution (asymptotic output-error covariance,
    Ljung 1999 §9.3). Random error only, under the assumption that the residual lines are independent:
    model error is not in it. None when there are no more residual lines than parameters."""
    jac, r = np.asarray(sol.jac, float), np.asarray(sol.fun, float)
    m, p = jac.shape
    if m <= p:
        return None
    return float(r @ r) / (m - p) * np.linalg.pinv(jac.T @ jac)


def prediction_residual(model: IdentifiedModel, record: Record, *, band_hz: tuple[float, float],
                        period_samples: int | None = None, skip_samples: int = 0,
                        oversample: int | None = None) -> np.ndarray:
    """(Ŷ - Y)/‖Y‖ on the band's lines of ``record`` (complex): what the refinement minimises.

    Raises :class:`~nifo_core.predict.model.PredictionDivergedError` where the simulation diverges."""
    return _residual(model, record, band_hz, period_samples, skip_samples, oversample)


def prediction_residuals(models: Sequence[IdentifiedModel], record: Record, *, band_hz: tuple[float, float],
                         period_samples: int | None = None, skip_samples: int = 0,
                         oversample: int | None = None) -> list[np.ndarray | None]:
    """:func:`prediction_residual` of each model on ``record``, None where its simulation diverges: the same
    values, the models' simulations marched together (:func:`~nifo_core.predict.time_prediction.predict_bodies`;
    models of one parameter space, e.g. a Jacobian's columns)."""
    if not models:
        return []
    a1, force = record_inputs(record, models[0])
    preds = predict_bodies(models, a1, record.fs_hz, force=force, oversample=oversample, label=record.source)
    return [None if isinstance(p, PredictionDivergedError)
            else _scored(p.body_accel, record, band_hz, period_samples, skip_samples) for p in preds]
