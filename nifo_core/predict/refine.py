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

import functools
import threading
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Sequence

import numpy as np
import scipy.optimize

from ..kinds.describing import KINDS, Term
from ..errors import ConfigError, IllConditionedError, InputError
from .linear_part import BodyModel, absorbed_rates
from .model import IdentifiedModel, PredictionDivergedError, predict_body, record_inputs
from .sensitivity import BODY_C, BODY_K, FORCE_GAIN, GAMMA, SHAPE, Parameters, residual_jacobian
from .time_prediction import predict_bodies
from .prediction_error import band_spectra
from ..signal.parallel import batch_map, thread_map
from ..signal.record import Record

__all__ = ["Refinement", "refine_model", "refine_jointly", "model_nmse", "parameter_space", "ParameterSpace",
           "start_up_samples", "prediction_residual", "prediction_residuals", "moved_refinement",
           "march_jacobians"]

#: relative error a diverged simulation counts as (per record; 1 = predicting zero)
_DIVERGED = 10.0
#: range of a key parameter around its start (factor)
_SHAPE_RANGE = 4.0


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


@dataclass(frozen=True)
class _Space:
    """θ ↔ model for one starting model."""

    base: IdentifiedModel
    gamma_scale: np.ndarray
    shape_idx: tuple[int, ...]        # terms whose key parameter is refined
    body: bool                        # refine k, c of a one-mass body
    track_absorbed: bool = False      # absorbed = absorbed_rates(terms, γ) as γ moves (bounded feedback)
    residues: bool = False            # refine a rational linear part's residues (poles kept)
    force: bool = False               # refine a measured force's gain 1/M2 (log scale)

    @functools.cached_property
    def _pairs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(upper members of the conjugate pairs, their partners, real poles, |r| of the upper ones: the scale)."""
        if not self.residues:
            return (np.zeros(0, int),) * 3 + (np.zeros(0),)
        p, r = self.base.linear.poles, self.base.linear.residues
        up = np.flatnonzero(p.imag > 0)
        lo = np.array([int(np.argmin(np.abs(p - np.conj(p[k])))) for k in up], int)
        real = np.flatnonzero(p.imag == 0)
        scale = np.abs(r[up])
        return up, lo, real, np.where(scale > 0, scale, max(float(scale.max(initial=0.0)), 1e-12))

    @property
    def n_residues(self) -> int:
        return 2 * self._pairs[0].size

    @functools.cached_property
    def hz(self) -> np.ndarray:
        """(1 - T21)/ω² on the model's lines: B_i = γ_i·hz (paper Eq. 8 with constant coefficients)."""
        w = 2 * np.pi * self.base.freq_hz
        with np.errstate(divide="ignore", invalid="ignore"):
            return (1 - self.base.t21) / np.where(w > 0, w, np.nan) ** 2

    @property
    def n_linear(self) -> int:
        """Log factors of the linear part's physical parameters: a one-mass body's k and c, a force's 1/M2."""
        return (2 if self.body else 0) + (1 if self.force else 0)

    @property
    def size(self) -> int:
        return self.gamma_scale.size + len(self.shape_idx) + self.n_linear + self.n_residues

    def x0(self, gammas: np.ndarray) -> np.ndarray:
        return np.concatenate([gammas / self.gamma_scale,
                               np.zeros(len(self.shape_idx) + self.n_linear + self.n_residues)])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        nt, ns, nr = self.gamma_scale.size, len(self.shape_idx), self.n_residues
        lo = np.concatenate([np.full(nt, -np.inf), np.full(ns, -np.log(_SHAPE_RANGE)),
                             np.full(self.n_linear, -2.0), np.full(nr, -np.inf)])
        hi = np.concatenate([np.full(nt, np.inf), np.full(ns, np.log(_SHAPE_RANGE)),
                             np.full(self.n_linear, 2.0), np.full(nr, np.inf)])
        return lo, hi

    def _linear(self, lin, dx: np.ndarray):
        """The rational linear part with residues r + Δr (Δr = dx·|r| per pair, re then im), Σ r kept at 0
        (relative degree 2: z and ż stay states) by one shift of the pairs' real parts; the poles kept."""
        up, lo, real, scale = self._pairs
        k = up.size
        r = np.array(self.base.linear.residues, complex)
        r[up] = r[up] + (dx[:k] + 1j * dx[k:]) * scale
        total = 2 * float(np.sum(r[up]).real) + float(np.sum(r[real]).real)
        r[up] -= total / (2 * k)
        r[lo] = np.conj(r[up])
        return replace(lin, residues=r)

    def march_parameters(self, model: IdentifiedModel) -> Parameters | None:
        """θ as the sensitivity march takes it (:mod:`nifo_core.predict.sensitivity`) for ``model`` = self.model(θ),
        or None where the march cannot give its Jacobian (the linear part's residues move, feedback paths)."""
        if self.residues or model.linear.paths is not None or not _blocks(model.linear.state_space()[0]):
            return None
        nt, sh = self.gamma_scale.size, list(self.shape_idx)
        kind = [GAMMA] * nt + [SHAPE] * len(sh)
        term = list(range(nt)) + sh
        scale = list(self.gamma_scale) + [0.0] * len(sh)
        if self.body:
            kind += [BODY_K, BODY_C]
            term += [-1, -1]
            scale += [model.linear.body.k, model.linear.body.c]
        if self.force:
            kind.append(FORCE_GAIN)
            term.append(-1)
            scale.append(0.0)
        ab = np.array([KINDS[t.kind].absorb if self.track_absorbed else (0.0, 0.0) for t in model.terms], float)
        ab = ab.reshape(len(model.terms), 2)
        return Parameters(np.array(kind, np.int64), np.array(term, np.int64), np.array(scale, float),
                          np.ascontiguousarray(ab[:, 0]), np.ascontiguousarray(ab[:, 1]))

    def names(self) -> list[tuple[str, str]]:
        """(name, unit) of every reported value (:func:`_values`)."""
        out = [(f"c/M2 of {t.kind}", f"{KINDS[t.kind].coef_unit}/kg") for t in self.base.terms]
        for i in self.shape_idx:
            t = self.base.terms[i]
            key = KINDS[t.kind].shape_param
            out.append((f"{t.kind}.{key}", KINDS[t.kind].params[key][1]))
        if self.body:
            out += [("k = K2/M2 (nominal body)", "1/s²"), ("c = C2/M2 (nominal body)", "1/s")]
        if self.force:
            out.append(("1/M2 (gain of the measured force)", "1/kg"))
        return out

    def model(self, x: np.ndarray) -> IdentifiedModel:
        m = self.base
        nt = self.gamma_scale.size
        gam = x[:nt] * self.gamma_scale
        terms = list(m.terms)
        for j, i in enumerate(self.shape_idx):
            t = terms[i]
            key = KINDS[t.kind].shape_param
            terms[i] = Term(t.kind, {**dict(t.params), key: float(t.params[key]) * float(np.exp(x[nt + j]))})
        lin, body = m.linear, m.body
        if self.residues:
            lin = self._linear(lin, x[self.size - self.n_residues:])
        k0 = nt + len(self.shape_idx)
        if self.body:
            kb, cb = x[k0:k0 + 2]
            bm = lin.body
            lin = replace(lin, body=BodyModel(bm.k * float(np.exp(kb)), bm.c * float(np.exp(cb)), bm.k3, bm.fit_rms))
        force_gain = m.force_gain * float(np.exp(x[k0 + (2 if self.body else 0)])) if self.force else m.force_gain
        if self.track_absorbed:       # the realised linear part stays; the terms' linear part moves with γ
            lin = replace(lin, absorbed=absorbed_rates(terms, gam))
        if lin.kind == "body":        # the nominal body: the realised one without the absorbed strut part
            bm, (ka, ca) = lin.body, lin.absorbed
            body = BodyModel(bm.k - ka, bm.c - ca, bm.k3, bm.fit_rms)
        b = gam[:, None] * self.hz[None, :]
        return replace(m, terms=tuple(terms), c_over_m2=gam, b=b, linear=lin, body=body, force_gain=force_gain)


def model_nmse(model: IdentifiedModel, records: Sequence[Record], *, band_hz: tuple[float, float],
               period_samples: int | None = None, skip_samples: int | Sequence[int] = 0,
               oversample: int | None = None) -> list[float]:
    """Band NMSE [%] of the model's prediction of every record (:mod:`nifo_core.predict.prediction_error`).

    A record whose prediction diverges gives ``inf``.
    """
    skips = _skips(skip_samples, len(records))
    out = []
    for rec, skip in zip(records, skips):
        try:
            r = _residual(model, rec, band_hz, period_samples, skip, oversample)
            out.append(float(100 * np.sum(np.abs(r) ** 2)))
        except PredictionDivergedError:
            out.append(float("inf"))
    return out


def _terms_on(linear: IdentifiedModel, model: IdentifiedModel, gammas: np.ndarray) -> IdentifiedModel:
    """``model``'s terms at coefficients ``gammas`` on ``linear``'s linear part, taken as the realised one: the
    terms' slope absorbed into it, so that each adds only its bounded remainder."""
    return replace(linear, terms=model.terms, c_over_m2=gammas, source=model.source,
                   provenance=dict(model.provenance), b=np.zeros((len(model.terms), linear.freq_hz.size), complex),
                   linear=replace(linear.linear, absorbed=absorbed_rates(model.terms, gammas)))


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


def _scored(body_accel: np.ndarray, rec, band_hz, period_samples, skip) -> np.ndarray:
    y, yh = band_spectra(rec.body_accel, body_accel, rec.fs_hz, band_hz=band_hz, period_samples=period_samples,
                         skip_samples=skip)
    return (yh - y) / np.sqrt(np.sum(np.abs(y) ** 2))


def _space(start: IdentifiedModel, scale_from: IdentifiedModel, *, shape: bool, linear_params: bool,
           track_absorbed: bool, residues: bool = False) -> _Space:
    g = np.abs(np.asarray(scale_from.c_over_m2, float))
    scale = np.where((g > 0) & np.isfinite(g), g, 1.0)
    shaped = [(i, t.params.get(KINDS[t.kind].shape_param)) for i, t in enumerate(start.terms)]
    idx = tuple(i for i, v in shaped if shape and isinstance(v, float) and v > 0)
    body = bool(linear_params and start.linear.kind == "body" and start.linear.body.k > 0 and start.linear.body.c > 0)
    res = bool(residues and start.linear.kind == "rational" and np.any(start.linear.poles.imag > 0))
    # a measured force's gain 1/M2 comes from NIFO's force path; refined with the body, it is what sets the static
    # gain of the output: the Silverbox at 150 mV refined with it predicts 50 and 100 mV at 0.77 and 0.78 mV
    # against 0.92 and 0.97 mV with NIFO's gain held (1/M2 +0.34 %)
    force = bool(linear_params and start.force_gain > 0)
    return _Space(start, scale, idx, body, track_absorbed, res, force)


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
    starts = {"nifo": _space(model, model, shape=shape, linear_params=linear_params, track_absorbed=tracked,
                             residues=linear_residues and bounded)}
    if linear is not None and model.terms:
        if linear.terms:
            raise ConfigError("linear= must be a model without terms (source 'h1')")
        # the linear model's linear part is the realised one: the terms add only their bounded remainder
        # (a play's or a clearance's force minus its slope), so no γ can destabilise it
        base = _terms_on(linear, model, np.zeros(len(model.terms)))
        starts["linear"] = _space(base, model, shape=shape, linear_params=linear_params, track_absorbed=True,
                                  residues=linear_residues)
    n_eval = 0
    # a record whose simulation diverges counts as relative error _DIVERGED, spread over its lines
    penalty = [np.full(band_spectra(r.body_accel, r.body_accel, r.fs_hz, band_hz=band, period_samples=period_samples,
                                    skip_samples=s)[0].size, 1.0) for r, s in zip(records, skips)]
    penalty = [np.sqrt(_DIVERGED / p.size) * p for p in penalty]
    sizes = np.cumsum([p.size for p in penalty])[:-1]
    diverged: dict[bytes, set] = {}     # per evaluated θ: the records whose simulation diverged
    lock = threading.Lock()             # evaluations run side by side for the Jacobian's columns

    def evaluate(name: str, sp: _Space, x: np.ndarray) -> np.ndarray:
        """Residual vector (real, imaginary) of every record at θ = x; a diverged record gets its penalty.
        Safe on several threads at once. A θ the Jacobian's columns computed together (:func:`columns`) is
        taken from there."""
        nonlocal n_eval
        key = np.asarray(x, float).tobytes()
        if key in ready:
            out, bad = ready.pop(key)
        else:
            m = sp.model(x)

            def one(k: int) -> np.ndarray | None:
                try:
                    return _residual(m, records[k], band, period_samples, skips[k], oversample)
                except PredictionDivergedError:
                    return None

            # the records side by side
            out, bad = assembled(thread_map(one, range(len(records))))
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

    def columns(sp: _Space):
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

    def sensitivities(sp: _Space, x: np.ndarray) -> np.ndarray:
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

    def run(name: str, sp: _Space, x0: np.ndarray, r0: np.ndarray):
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
                                           x_scale="jac", max_nfev=max_iterations, f_scale=1.0, **how)
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
    hw = _half_widths(sp, x, cov)
    params = [{"name": n, "unit": u, "before": float(v0), "after": float(v1), "half_width_95": h}
              for (n, u), v0, v1, h in zip(sp.names(), _values(sp, sp.x0(np.asarray(sp.base.c_over_m2, float))),
                                              _values(sp, x), hw)]
    jointly = f" with the linear part's {sp.n_residues // 2} residue pairs" if sp.residues else ""
    msg = (f"output-error refinement{jointly} from the {best} start: mean band NMSE "
           f"{np.mean(before[best]):.4g} % → {np.mean(finals[best]):.4g} % on {len(records)} record(s) "
           f"({band[0]:g}-{band[1]:g} Hz{', period-averaged' if period_samples else ''}); {sol.message}")
    prov = {**dict(refined.provenance), "refined": {
        "method": "output-error (simulation-error) least squares, nifo_core.predict.refine", "start": best,
        "band_hz": list(band), "period_samples": period_samples, "skip_samples": skips,
        "nmse_before_pct": {k: v for k, v in before.items()}, "nmse_pct": finals[best],
        "records": [r.source for r in records], "parameters": params,
        "covariance": _stored_covariance(sp, x, cov)}}
    refined = replace(refined, provenance=prov)
    return Refinement(model=refined, start=best, nmse_before=before, nmse=finals[best], parameters=params,
                      evaluations=n_eval, message=msg, labels=[r.source for r in records])


def _blocks(a: np.ndarray) -> bool:
    """A is block diagonal in 2×2 and 1×1 blocks (so is e^{A·h}): what the sensitivity march takes."""
    nz = a != 0
    cols = np.arange(a.shape[1])
    return all(not row.any() or np.ptp(cols[row]) <= 1 for row in nz)


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
    start = _terms_on(lin, model, np.asarray(model.c_over_m2, float))
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


def _half_widths(sp: _Space, x: np.ndarray, cov: np.ndarray | None) -> list[float | None]:
    """95 % half-widths of the reported values (:func:`_values`), cov(θ) carried by their derivatives in θ."""
    if cov is None:
        return [None] * len(sp.names())
    p = x.size
    v0 = np.asarray(_values(sp, x))
    d = np.zeros((v0.size, p))
    for j in range(p):
        step = 1e-6 * max(1.0, abs(x[j]))
        xx = np.array(x, float)
        xx[j] += step
        d[:, j] = (np.asarray(_values(sp, xx)) - v0) / step
    var = np.einsum("ij,jk,ik->i", d, cov, d)
    return [float(1.96 * np.sqrt(v)) if np.isfinite(v) and v >= 0 else None for v in var]


def _stored_covariance(sp: _Space, x: np.ndarray, cov: np.ndarray | None) -> dict | None:
    """cov(θ) in coordinates of the refined model itself (what :func:`parameter_space` rebuilds).

    θ' = (γ_i/γ_i*, log of each refined key parameter's factor, log k, log c of a one-mass body): the
    coefficients relative to their refined values (1 where a value is 0), the rest log offsets, which
    carry over unchanged.
    """
    if cov is None:
        return None
    nt = sp.gamma_scale.size
    gam = x[:nt] * sp.gamma_scale
    scale = np.where(gam != 0, gam, 1.0)
    d = np.concatenate([sp.gamma_scale / scale, np.ones(x.size - nt - sp.n_residues)])
    if sp.residues:              # residue changes in units of the refined |r| (what parameter_space rebuilds)
        start_scale = sp._pairs[3]
        ref = _Space(sp.model(x), np.ones(nt), (), False, residues=True)._pairs[3]
        d = np.concatenate([d, np.tile(start_scale / ref, 2)])
    return {"coordinates": "coefficients relative to the refined ones, then log factors of the key parameters, "
                           "of a one-mass body's k and c and of a force's 1/M2, then the rational linear part's residue changes "
                           "(re, im per pole pair, in units of |r|)",
            "shape_terms": list(sp.shape_idx), "body": bool(sp.body), "track_absorbed": bool(sp.track_absorbed),
            "residues": bool(sp.residues), "force": bool(sp.force), "matrix": (d[:, None] * cov * d[None, :]).tolist()}


def _stored_space(model: IdentifiedModel) -> tuple[_Space, np.ndarray] | None:
    """The refined model's own space θ' and cov(θ') from its stored covariance, or None."""
    c = (model.provenance.get("refined") or {}).get("covariance")
    if not c:
        return None
    gam = np.asarray(model.c_over_m2, float)
    scale = np.where(gam != 0, gam, 1.0)
    sp = _Space(model, scale, tuple(int(i) for i in c["shape_terms"]), bool(c["body"]), bool(c["track_absorbed"]),
                bool(c.get("residues", False)), bool(c.get("force", False)))
    cov = np.asarray(c["matrix"], float)
    if cov.shape != (sp.size, sp.size) or not np.all(np.isfinite(cov)):
        return None
    return sp, cov


@dataclass(frozen=True)
class ParameterSpace:
    """A refined model's parameters θ' (relative coefficients and log factors, the covariance's own coordinates).

    Parameters
    ----------
    to_model : callable θ' → IdentifiedModel
        The model at θ'; ``to_model(theta)`` is the refined model itself.
    theta : ndarray, shape (p,)
        θ'* of the refined model.
    cov : ndarray, shape (p, p)
        cov(θ') stored with the refinement.
    """

    to_model: Callable[[np.ndarray], IdentifiedModel]
    theta: np.ndarray
    cov: np.ndarray
    #: the model's θ' as the sensitivity march takes them (:meth:`_Space.march_parameters`; None: it cannot)
    march: Callable[[IdentifiedModel], Parameters | None] = lambda m: None


def parameter_space(model: IdentifiedModel) -> ParameterSpace | None:
    """The :class:`ParameterSpace` of a refined model's stored covariance, or None.

    For propagating the refinement's parameter uncertainty to predictions
    (:mod:`nifo_core.predict.prediction_bounds`): ``space.to_model(space.theta)`` is ``model``.
    """
    got = _stored_space(model)
    if got is None:
        return None
    sp, cov = got
    return ParameterSpace(to_model=sp.model, theta=sp.x0(np.asarray(model.c_over_m2, float)), cov=cov,
                          march=sp.march_parameters)


def moved_refinement(model: IdentifiedModel, x: np.ndarray, cov: np.ndarray,
                     note: Mapping) -> tuple[IdentifiedModel, list[dict]]:
    """A refined ``model`` moved to θ' = ``x`` of its :func:`parameter_space` with covariance ``cov`` (there):
    the moved model (its stored covariance re-expressed around it, ``note`` stored as the refinement's
    ``bias_correction``) and its reported parameters (before as in ``model``, after, 95 % half-widths)."""
    sp, _ = _stored_space(model)
    moved = sp.model(x)
    old = model.provenance["refined"]
    params = [{**p, "after": float(v), "half_width_95": h}
              for p, v, h in zip(old["parameters"], _values(sp, x), _half_widths(sp, x, cov))]
    prov = {**dict(model.provenance), "refined": {**old, "parameters": params, "bias_correction": dict(note),
                                                  "covariance": _stored_covariance(sp, x, cov)}}
    return replace(moved, provenance=prov), params


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


def _values(sp: _Space, x: np.ndarray) -> list[float]:
    m = sp.model(x)
    vals = [float(g) for g in m.c_over_m2]
    for i in sp.shape_idx:
        t = m.terms[i]
        vals.append(float(t.params[KINDS[t.kind].shape_param]))
    if sp.body:      # the nominal body: the realised one without the terms' absorbed linear part
        vals += [m.body.k, m.body.c]
    if sp.force:
        vals.append(m.force_gain)
    return vals
