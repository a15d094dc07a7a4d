"""Closing the loop: residual → the effect the model lacks → add it → error before and after (METHOD.md §5).

Given records and a *declared* model (describing functions, :mod:`nifo_core.describing`),
:func:`close_loop` repeats, for at most ``max_rounds`` rounds:

1. **Residual that can show what is missing.** Each record is split in time:
   the first ``fit_fraction`` fits, the rest is held out. Two residuals:

   - equation error in force-balance form (paper Eq. 2 per unit sprung mass)::

         e = -ẍ2 - k·z - c·ż - Σ_declared θ_i·g_i           θ_i = c_i/M2

     every column band-passed with the one integrator-matched filter
     (:func:`nifo_core.restoring.bandpass`, g *after* the nonlinear map), the
     coefficients fitted on the fit part and the error scored on the held-out part;
   - prediction error on the held-out part: the declared model is identified by
     NIFO (:func:`nifo_core.nifo.identify_nifo`, static fit) on the fit part and
     the body acceleration predicted from the measured spindle acceleration of
     the held-out part (:func:`nifo_core.model.predict_transmissibility`).

   The displacement-form NIFO residual / multiple coherence is *not* used: a
   describing function of z = x2 - x1 carries the output into the regressors,
   and the fit absorbs whatever is missing (METHOD.md §3).

2. **Tracing.** Every kind of the library, over parameter grids scaled to the
   motion, is scored by the fraction of the linear + declared equation error it
   explains (:func:`nifo_core.characterize.rank_beyond`: band-limited after the
   map, orthogonalised against z, ż and the declared terms, error reduction
   ratio, refined and refitted at full length).

3. **Acceptance.** The best candidates are tried in rank order; one is added
   only if all hold:

   - *significant*: F-test with an effective number of degrees of freedom,
     N_eff = N·mean(S)²/mean(S²) from the residual spectrum S, Bonferroni over
     the grid, p < ``thresholds.alpha``. An F-test rather than a per-line
     partial coherence because the residual is coloured (band-passed, a
     body-mode peak): N counts samples, not independent information, and the
     effect is static, so its evidence pools over the whole band; per-line
     partial coherence against its 95 % level 1 - 0.05^(1/(n_d - q - 1)) is
     reported as evidence, not used as the gate (it splits the same evidence
     over ~300 lines of 60 averages each);
   - it explains ≥ ``thresholds.min_err`` of the remaining residual, and does
     so on alternate held-in/held-out blocks too (cross-validated ERR);
   - its coefficient is *stable*: across the records (amplitude levels) when
     several are given, else across quarters of the record (weighted relative
     spread ≤ ``thresholds.max_spread``);
   - the *held-out* equation error falls by at least ``min_heldout_gain``
     (relative) with the coefficients fitted on the fit part only, and the
     held-out prediction error does not rise;
   - *tire check*: the body equation holds no tire force (paper Eq. 2: tire
     nonlinearities such as lift-off act on M1 only and cannot appear in the
     spindle→body path), so a tire effect can reach the body-equation residual
     only through processing (the spindle's impacts smeared by integration and
     band-passing). The candidate's coefficient is refitted without the
     samples around the spindle's impacts (|ẍ1| above its ``tire_quantile``
     quantile, ± ``tire_guard_s``); a strut effect acts along the whole
     strut motion and keeps its coefficient (shift ≤ ``max_tire_shift``),
     an artefact of tire events does not.

4. **Add and refit**: the accepted term joins the model, everything is refitted
   (equation error and NIFO), and the next round traces what is left. The loop
   stops when no candidate passes ("Nothing significant is missing.") or after
   ``max_rounds``.

5. **Report** before and after each addition: NMSE (%) on held-out data
   (Worden & Tomlinson: 100·Σ(y - ŷ)²/(N·σ_y²); < 5 % good, < 1 % excellent),
   per-band residual 10·log10(G_ee/G_yy) in 2-5, 5-10, 10-20, 20-30 Hz (one
   spectral engine, :mod:`nifo_core.spectral`), the transmissibility
   prediction error at each level, and the added effect with its evidence.

References: Billings (error reduction ratio, forward orthogonal regression);
Bendat & Piersol (conditioned/partial coherence); Worden & Tomlinson (NMSE);
Haroon & Adams (paper Eq. 2, 7-9).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import Callable, Literal, Mapping, Sequence

import numpy as np

from .characterize import DEFAULT_KINDS, Candidate, Thresholds, candidate_grid, rank_beyond
from .describing import Term, make_term
from .errors import ConfigError, InputError, NifoError
from .integrate import IntegrationBand
from .model import BodyModel, IdentifiedModel, predict_transmissibility
from .nifo import identify_nifo
from .record import Record
from .restoring import RestoringForce, bandpass, bandpass_settle_samples, restoring_force, suggest_band
from .spectral import SpectralSettings, auto_spectrum, cross_spectra, h1, partial_coherence

__all__ = ["LoopSettings", "Errors", "Trial", "Evidence", "Round", "LoopResult", "close_loop",
           "RESIDUAL_BANDS_HZ", "NOTHING_MISSING"]

#: bands of the per-band residual [Hz]
RESIDUAL_BANDS_HZ = ((2.0, 5.0), (5.0, 10.0), (10.0, 20.0), (20.0, 30.0))
#: the verdict when the last round found nothing
NOTHING_MISSING = "Nothing significant is missing."

Prediction = Literal["equation", "nifo", "none"]


@dataclass(frozen=True)
class LoopSettings:
    """How the loop traces, accepts and reports (module docstring).

    Parameters
    ----------
    max_rounds : int
        Most effects added (each round adds at most one).
    fit_fraction : float
        Leading fraction of every record used for fitting; the rest is held out.
    kinds : tuple of str
        Library kinds searched.
    thresholds : Thresholds
        Significance, ERR, cross-validation and stability thresholds (shared with characterize).
    grid_points : int
        Grid points per parameter.
    min_heldout_gain : float
        Relative fall of the held-out equation-error NMSE a candidate must bring.
    tire_quantile, tire_guard_s, max_tire_shift : float
        Tire check: samples with |ẍ1| above this quantile, ± guard [s], are left
        out in a refit; the coefficient may move by at most ``max_tire_shift`` (relative).
    top_tried : int
        Candidates tried per round, in rank order, before "nothing significant".
    spectral : SpectralSettings
        For the per-band residual and the transmissibilities (paper Table 2 by default).
    analysis_band_hz : (float, float)
        Band of the transmissibility error and of NIFO.
    prediction : {'equation', 'nifo', 'none'}
        Which model predicts the held-out body acceleration from the measured spindle
        acceleration (:func:`nifo_core.model.predict_body`, parametric): ``'equation'`` the
        equation-error fit (k, c, θ_i: the model the loop traced and refitted, simulated in time,
        METHOD.md §4), ``'nifo'`` output-only NIFO's static fit on the fit part, ``'none'``:
        equation error only.
    retune : bool
        Before each round, re-tune the parameter (gap, knee, eps...) of every term of the model
        over its grid (a key parameter within a factor 2 of its value) (declared terms state the form; the data set the parameter). Without it a
        declared term whose parameter does not match the band-limited motion leaves a residual
        that a second term of the same kind "explains".
    """

    max_rounds: int = 4
    fit_fraction: float = 2.0 / 3.0
    kinds: tuple[str, ...] = DEFAULT_KINDS
    thresholds: Thresholds = field(default_factory=Thresholds)
    grid_points: int = 24
    min_heldout_gain: float = 0.01
    tire_quantile: float = 0.995
    tire_guard_s: float = 0.1
    max_tire_shift: float = 0.5
    top_tried: int = 3
    spectral: SpectralSettings = field(default_factory=SpectralSettings)
    analysis_band_hz: tuple[float, float] = (2.0, 30.0)
    prediction: Prediction = "equation"
    retune: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.max_rounds, bool) or not isinstance(self.max_rounds, (int, np.integer)) \
                or not 1 <= self.max_rounds <= 10:
            raise ConfigError(f"max_rounds={self.max_rounds!r} must be a whole number in 1..10")
        if not 0.3 <= float(self.fit_fraction) <= 0.9:
            raise ConfigError(f"fit_fraction={self.fit_fraction!r} must be in [0.3, 0.9]",
                              hint="e.g. 2/3: fit on the first two thirds, test on the last third")
        if not 0.5 < float(self.tire_quantile) < 1:
            raise ConfigError(f"tire_quantile={self.tire_quantile!r} must be in (0.5, 1)")
        for name in ("min_heldout_gain", "tire_guard_s", "max_tire_shift"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"{name}={v!r} must be finite and non-negative")
        if self.top_tried < 1:
            raise ConfigError(f"top_tried={self.top_tried!r} must be at least 1")
        lo, hi = (float(v) for v in self.analysis_band_hz)
        if not 0 < lo < hi:
            raise ConfigError(f"analysis_band_hz={self.analysis_band_hz!r} must satisfy 0 < lo < hi")
        if self.prediction not in ("equation", "nifo", "none"):
            raise ConfigError(f"prediction={self.prediction!r} must be 'equation', 'nifo' or 'none'")
        object.__setattr__(self, "kinds", tuple(self.kinds))
        object.__setattr__(self, "analysis_band_hz", (lo, hi))

    def to_dict(self) -> dict:
        return {"max_rounds": int(self.max_rounds), "fit_fraction": float(self.fit_fraction),
                "kinds": list(self.kinds), "thresholds": self.thresholds.to_dict(),
                "grid_points": self.grid_points, "min_heldout_gain": self.min_heldout_gain,
                "tire_quantile": self.tire_quantile, "tire_guard_s": self.tire_guard_s,
                "max_tire_shift": self.max_tire_shift, "top_tried": self.top_tried,
                "spectral": self.spectral.to_dict(), "analysis_band_hz": list(self.analysis_band_hz),
                "prediction": self.prediction, "retune": self.retune}


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Errors:
    """How well a model does, on held-out data unless said otherwise.

    Attributes
    ----------
    terms : tuple of Term
        The model's describing functions (besides the linear strut).
    theta_per_kg : tuple of float
        Their coefficients c_i/M2 from the equation-error fit on the fit part.
    k_per_kg, c_per_kg : float
        K2/M2 [1/s²] and C2/M2 [1/s] of that fit.
    equation_nmse_pct : float
        Held-out NMSE of the force-balance equation error (band-passed -ẍ2) [%].
    equation_nmse_fit_pct : float
        The same on the fit part [%].
    prediction_nmse_pct : float or None
        Held-out NMSE of the body acceleration predicted from the measured spindle
        acceleration by the NIFO-identified model, all records pooled [%].
    prediction_nmse_per_record_pct : tuple of float
        The same per record (level).
    band_residual_db : mapping
        ``"2-5"`` → 10·log10(G_ee/G_yy) in that band [dB], e the held-out
        prediction error (the equation error when no prediction), records pooled.
    residual_of : str
        ``"prediction"`` or ``"equation"``: which error ``band_residual_db`` is of.
    transmissibility_error_pct : tuple of (str, float)
        Per record (level): median over the analysis band of |T_pred - T_meas|/|T_meas| [%]
        on the held-out part.
    notes : tuple of str
    """

    terms: tuple[Term, ...]
    theta_per_kg: tuple[float, ...]
    k_per_kg: float
    c_per_kg: float
    equation_nmse_pct: float
    equation_nmse_fit_pct: float
    prediction_nmse_pct: float | None
    prediction_nmse_per_record_pct: tuple[float, ...]
    band_residual_db: Mapping[str, float]
    residual_of: str
    transmissibility_error_pct: tuple[tuple[str, float], ...]
    notes: tuple[str, ...] = ()

    @property
    def headline_nmse_pct(self) -> float:
        """The held-out NMSE reported first: prediction when available, else equation error."""
        return self.prediction_nmse_pct if self.prediction_nmse_pct is not None else self.equation_nmse_pct

    def to_dict(self) -> dict:
        return {"terms": [t.to_dict() for t in self.terms], "theta_per_kg": list(self.theta_per_kg),
                "k_per_kg": self.k_per_kg, "c_per_kg": self.c_per_kg,
                "heldout_nmse_pct": self.headline_nmse_pct,
                "equation_nmse_pct": self.equation_nmse_pct, "equation_nmse_fit_pct": self.equation_nmse_fit_pct,
                "prediction_nmse_pct": self.prediction_nmse_pct,
                "prediction_nmse_per_record_pct": list(self.prediction_nmse_per_record_pct),
                "band_residual_db": dict(self.band_residual_db), "residual_of": self.residual_of,
                "transmissibility_error_pct": [{"record": s, "error_pct": e}
                                               for s, e in self.transmissibility_error_pct],
                "notes": list(self.notes)}


@dataclass(frozen=True)
class Trial:
    """One candidate tried in a round: its tracing statistics and the acceptance checks."""

    candidate: Candidate
    tire_shift: float
    tire_excluded_fraction: float
    heldout_gain: float | None
    after: Errors | None
    accepted: bool
    failed: tuple[str, ...]

    def to_dict(self) -> dict:
        return {"candidate": self.candidate.to_dict(), "tire_shift": _fin(self.tire_shift),
                "tire_excluded_fraction": self.tire_excluded_fraction,
                "heldout_equation_gain": _fin(self.heldout_gain), "accepted": self.accepted,
                "failed": list(self.failed), "after": None if self.after is None else self.after.to_dict()}


@dataclass(frozen=True)
class Evidence:
    """What backs an added effect: partial coherence and the residual against the effect's variable.

    ``bins``: centres of bins of the effect's variable (z [m] or ż [m/s], band-passed as the
    regression sees it); ``before``/``after``: mean equation residual per bin without/with the effect
    [m/s², per unit sprung mass]; ``effect``: mean per bin of what adding the term explains
    (before - after: θ·g less the share of it the refitted linear terms take over).
    """

    variable: str
    bins: tuple[float, ...]
    before: tuple[float, ...]
    after: tuple[float, ...]
    effect: tuple[float, ...]
    partial_coherence_mean: float
    partial_coherence_level: float
    fraction_lines_above_level: float

    def to_dict(self) -> dict:
        return {"variable": self.variable, "bins": list(self.bins), "residual_before": list(self.before),
                "residual_after": list(self.after), "effect": list(self.effect),
                "partial_coherence_mean": self.partial_coherence_mean,
                "partial_coherence_95pct_level": self.partial_coherence_level,
                "fraction_lines_above_level": self.fraction_lines_above_level}


@dataclass(frozen=True)
class Round:
    """One round: the ranked candidates given the model so far, what was tried and added."""

    index: int
    model_before: tuple[Term, ...]
    ranked: tuple[Candidate, ...]
    trials: tuple[Trial, ...]
    before: Errors
    added: Trial | None
    evidence: Evidence | None
    text: str

    @property
    def after(self) -> Errors | None:
        return None if self.added is None else self.added.after

    def to_dict(self) -> dict:
        return {"round": self.index, "model_before": [t.to_dict() for t in self.model_before],
                "ranked": [c.to_dict() for c in self.ranked], "trials": [t.to_dict() for t in self.trials],
                "before": self.before.to_dict(),
                "added": None if self.added is None else _effect_dict(self.added),
                "after": None if self.after is None else self.after.to_dict(),
                "evidence": None if self.evidence is None else self.evidence.to_dict(), "text": self.text}


@dataclass(frozen=True)
class LoopResult:
    """What :func:`close_loop` found: rounds, the refined model, errors before and after, the verdict."""

    declared: tuple[Term, ...]
    terms: tuple[Term, ...]
    rounds: tuple[Round, ...]
    initial: Errors
    final: Errors
    verdict: str
    band: IntegrationBand
    m2_kg: float | None
    settings: LoopSettings
    sources: tuple[str, ...]
    fit_seconds: tuple[float, ...]
    test_seconds: tuple[float, ...]
    notes: tuple[str, ...] = ()

    @property
    def added(self) -> tuple[Candidate, ...]:
        """The effects added, in order."""
        return tuple(r.added.candidate for r in self.rounds if r.added is not None)

    @property
    def nothing_missing(self) -> bool:
        """True when the last round found nothing significant."""
        return self.verdict.endswith(NOTHING_MISSING)

    def report(self) -> str:
        """The report a test engineer reads: one paragraph per round, then the verdict."""
        lines = [f"Declared model: linear element{''.join(' + ' + t.label for t in self.declared)}.",
                 f"Data: {len(self.sources)} record(s); fitted on the first "
                 f"{100 * self.settings.fit_fraction:.0f} % of each, errors on the last "
                 f"{100 * (1 - self.settings.fit_fraction):.0f} % (held out); integration band "
                 f"{self.band.f_lo_hz:g}-{self.band.f_hi_hz:g} Hz.",
                 "Before: " + _errors_line(self.initial)]
        for r in self.rounds:
            lines.append(r.text)
        if self.rounds and any(r.added for r in self.rounds):
            lines.append("After: " + _errors_line(self.final))
        lines.append(self.verdict)
        lines.extend(f"Note: {n}" for n in self.notes)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"declared_model": [t.to_dict() for t in self.declared],
                "refined_model": [t.to_dict() for t in self.terms],
                "effects_added": [_effect_dict(r.added) | {"round": r.index} for r in self.rounds if r.added],
                "errors_before": self.initial.to_dict(), "errors_after": self.final.to_dict(),
                "rounds": [r.to_dict() for r in self.rounds], "verdict": self.verdict,
                "nothing_missing": self.nothing_missing, "report": self.report(),
                "band": self.band.to_dict(), "m2_kg": self.m2_kg, "settings": self.settings.to_dict(),
                "records": [{"source": s, "fit_s": a, "test_s": b}
                            for s, a, b in zip(self.sources, self.fit_seconds, self.test_seconds)],
                "notes": list(self.notes)}


def _fin(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _effect_dict(t: Trial) -> dict:
    c = t.candidate
    kp = c.key_param
    return {"kind": c.kind, "params": dict(c.term.params), "label": c.term.label,
            "key_param": None if kp is None else {"name": kp[0], "value": kp[1]},
            "theta_per_kg": c.theta, "coefficient": c.coefficient, "coefficient_unit": c.term.spec.coef_unit,
            "meaning": c.describe(), "err": c.err, "err_cv": c.err_cv, "p_value": c.p_value, "spread": _fin(c.spread),
            "group_theta": list(c.group_theta), "tire_shift": _fin(t.tire_shift),
            "heldout_equation_gain": _fin(t.heldout_gain)}


# --------------------------------------------------------------------------------------------
# residuals
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Part:
    """Regression columns of one record part: every column band-passed once more (as characterize does)."""

    y: np.ndarray           # band-passed -ẍ2 [m/s²]
    z: np.ndarray           # band-passed z [m]
    zdot: np.ndarray        # band-passed ż [m/s]
    rf: RestoringForce
    keep: np.ndarray        # indices into rf of the rows


def _part(rf: RestoringForce) -> _Part:
    s = bandpass_settle_samples(rf.fs_hz, rf.band)
    if rf.n - 2 * s < max(64, int(4 * rf.fs_hz / rf.band.f_lo_hz)):
        raise InputError(f"{rf.n / rf.fs_hz:.1f} s of data is too short for the loop (the band-pass settles over "
                         f"{s / rf.fs_hz:.1f} s at each end)", source=rf.source or "record",
                         hint="record longer, or raise the band's lower edge")
    keep = np.arange(s, rf.n - s)
    b = bandpass(np.vstack([rf.force, rf.z, rf.zdot]), rf.fs_hz, rf.band)[:, keep]
    return _Part(b[0], b[1], b[2], rf, keep)


def _g(part: _Part, term: Term) -> np.ndarray:
    """g(z, ż) on the part's motion, band-passed AFTER the map (METHOD.md §5 step 3)."""
    rf = part.rf
    return bandpass(term.evaluate(rf.z, rf.zdot), rf.fs_hz, rf.band)[part.keep]


def _design(parts: Sequence[_Part], terms: Sequence[Term]) -> tuple[np.ndarray, np.ndarray]:
    ys, xs = [], []
    for p in parts:
        ys.append(p.y)
        xs.append(np.column_stack([p.z, p.zdot, *[_g(p, t) for t in terms]]))
    return np.concatenate(ys), np.vstack(xs)


def _nmse_pct(y: np.ndarray, e: np.ndarray) -> float:
    """Worden & Tomlinson: 100·Σe²/(N·σ_y²)."""
    v = float(np.var(y))
    return 100.0 * float(np.mean(e ** 2)) / v if v > 0 else float("nan")


def _band_db(spec_pairs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> dict[str, float]:
    """10·log10(ΣG_ee/ΣG_yy) per band, PSDs summed over records: [(freq, G_yy, G_ee), ...]."""
    out = {}
    for lo, hi in RESIDUAL_BANDS_HZ:
        num = den = 0.0
        for f, gyy, gee in spec_pairs:
            m = (f >= lo) & (f < hi)
            num += float(gee[m].sum())
            den += float(gyy[m].sum())
        out[f"{lo:g}-{hi:g}"] = float(10 * np.log10(num / den)) if num > 0 and den > 0 else float("nan")
    return out


class _Evaluator:
    """Fits a term set on the fit parts and scores it on the held-out parts (both residuals)."""

    def __init__(self, fit_recs: Sequence[Record], test_recs: Sequence[Record], band: IntegrationBand,
                 settings: LoopSettings) -> None:
        self.fit_recs, self.test_recs = list(fit_recs), list(test_recs)
        self.band, self.settings = band, settings
        self.fit_rfs = [restoring_force(r, band=band) for r in self.fit_recs]
        self.test_rfs = [restoring_force(r, band=band) for r in self.test_recs]
        self.fit_parts = [_part(rf) for rf in self.fit_rfs]
        self.test_parts = [_part(rf) for rf in self.test_rfs]
        spec = settings.spectral
        self.spec = spec if all(r.n >= 2 * spec.block for r in self.test_recs) else replace(
            spec, block=int(2 ** np.floor(np.log2(max(min(r.n for r in self.test_recs) // 8, 256)))))
        self._measured = [cross_spectra(np.stack([r.spindle_accel, r.body_accel]), r.fs_hz, self.spec)
                          for r in self.test_recs]
        self._cache: dict = {}

    def joint(self, terms: Sequence[Term]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(θ = [k, c, θ_i...], fit rows y, X) of the equation-error fit on the fit part."""
        y, x = _design(self.fit_parts, terms)
        return np.linalg.lstsq(x, y, rcond=None)[0], y, x

    def errors(self, terms: Sequence[Term]) -> Errors:
        key = tuple(t.label for t in terms)
        if key in self._cache:
            return self._cache[key]
        terms = tuple(terms)
        theta, y, x = self.joint(terms)
        fit_nmse = _nmse_pct(y, y - x @ theta)
        yt, xt = _design(self.test_parts, terms)
        eq_nmse = _nmse_pct(yt, yt - xt @ theta)
        notes: list[str] = []
        pred_nmse, per_rec, trans, pairs = None, (), (), []
        residual_of = "equation"
        if self.settings.prediction != "none":
            try:
                pred_nmse, per_rec, trans, pairs = self._predict(terms)
                residual_of = "prediction"
            except (NifoError, np.linalg.LinAlgError) as err:
                notes.append(f"no held-out prediction for this model ({err}); equation error only")
        if not pairs:  # per-band residual of the equation error
            for p in self.test_parts:
                e = p.y - np.column_stack([p.z, p.zdot, *[_g(p, t) for t in terms]]) @ theta
                if e.size >= self.spec.block:
                    s = cross_spectra(np.stack([p.y, e]), p.rf.fs_hz, self.spec)
                    pairs.append((s.freq_hz, auto_spectrum(s, 0), auto_spectrum(s, 1)))
        out = Errors(terms=terms, theta_per_kg=tuple(float(v) for v in theta[2:]), k_per_kg=float(theta[0]),
                     c_per_kg=float(theta[1]), equation_nmse_pct=eq_nmse, equation_nmse_fit_pct=fit_nmse,
                     prediction_nmse_pct=pred_nmse, prediction_nmse_per_record_pct=tuple(per_rec),
                     band_residual_db=_band_db(pairs), residual_of=residual_of,
                     transmissibility_error_pct=tuple(trans), notes=tuple(notes))
        self._cache[key] = out
        return out

    def model(self, terms: Sequence[Term]) -> IdentifiedModel:
        """The model that predicts: the equation-error fit (default) or NIFO's static fit, on the fit part."""
        s = self.settings
        terms = tuple(terms)
        if s.prediction == "nifo":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = identify_nifo(self.fit_recs, list(terms), settings=s.spectral, band=self.band,
                                    analysis_band_hz=s.analysis_band_hz, input_measured=False)
            return IdentifiedModel.from_nifo(res, source="static")
        theta = self.joint(terms)[0]
        if not (theta[0] > 0 and theta[1] > 0):
            raise ConfigError(f"the equation-error fit is not physical (k={theta[0]:.4g} 1/s², c={theta[1]:.4g} 1/s)")
        body = BodyModel(float(theta[0]), float(theta[1]))
        f = s.spectral.freq_hz(self.fit_recs[0].fs_hz)
        t21 = body.t21(f)
        w2 = (2 * np.pi * f) ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            b = np.zeros((len(terms), f.size), complex)
            for i, th in enumerate(theta[2:]):
                b[i] = th * (1 - t21) / np.where(w2 > 0, w2, np.inf)
        return IdentifiedModel(freq_hz=f, t21=t21, b=b, terms=terms, c_over_m2=np.asarray(theta[2:], float),
                               body=body, analysis_band_hz=s.analysis_band_hz, fs_hz=self.fit_recs[0].fs_hz,
                               settings=s.spectral, band=self.band, source="static",
                               provenance={"from": "nifo loop equation-error fit"})

    def _predict(self, terms: tuple[Term, ...]):
        s = self.settings
        model = self.model(terms)
        lo, hi = s.analysis_band_hz
        num = den = 0.0
        per, trans, pairs = [], [], []
        for rec, meas in zip(self.test_recs, self._measured):
            pt = predict_transmissibility(model, rec.spindle_accel, rec.fs_hz, settings=self.spec,
                                          method="parametric")
            v = pt.prediction.valid
            y = np.asarray(rec.body_accel)[v]
            e = y - pt.prediction.body_accel[v]
            num += float(np.sum(e ** 2))
            den += y.size * float(np.var(y))
            per.append(_nmse_pct(y, e))
            if y.size >= self.spec.block:
                sp = cross_spectra(np.stack([y, e]), rec.fs_hz, self.spec)
                pairs.append((sp.freq_hz, auto_spectrum(sp, 0), auto_spectrum(sp, 1)))
            sv = cross_spectra(np.stack([np.asarray(rec.spindle_accel)[v], y]), rec.fs_hz, self.spec)
            t_meas = h1(sv, 0, 1)
            m = (sv.freq_hz >= lo) & (sv.freq_hz <= hi)
            rel = np.abs(pt.t21[m] - t_meas[m]) / np.abs(t_meas[m])
            trans.append((rec.source, 100.0 * float(np.nanmedian(rel))))
        return 100.0 * num / den, per, trans, pairs


# --------------------------------------------------------------------------------------------
# checks and evidence
# --------------------------------------------------------------------------------------------
def _tire_events(part: _Part, quantile: float, guard_s: float) -> np.ndarray:
    """Rows near the spindle's impacts: |ẍ1| above its quantile, dilated by ± guard."""
    a = np.abs(np.asarray(part.rf.spindle_accel)[part.keep])
    hit = a > np.quantile(a, quantile)
    g = max(1, int(round(guard_s * part.rf.fs_hz)))
    k = np.convolve(hit.astype(float), np.ones(2 * g + 1), mode="same") > 0
    return k


def _tire_check(ev: _Evaluator, terms: Sequence[Term], cand: Term, s: LoopSettings) -> tuple[float, float]:
    """(relative coefficient shift when the rows near spindle impacts are left out, fraction left out)."""
    theta, y, x = ev.joint([*terms, cand])
    events = np.concatenate([_tire_events(p, s.tire_quantile, s.tire_guard_s) for p in ev.fit_parts])
    keep = ~events
    th2 = np.linalg.lstsq(x[keep], y[keep], rcond=None)[0]
    shift = abs(th2[-1] - theta[-1]) / abs(theta[-1]) if theta[-1] != 0 else float("inf")
    return float(shift), float(events.mean())


def _evidence(ev: _Evaluator, terms: Sequence[Term], cand: Term, s: LoopSettings, n_bins: int = 30) -> Evidence:
    th0, y, x0 = ev.joint(terms)
    th1, _, x1 = ev.joint([*terms, cand])
    e0, e1 = y - x0 @ th0, y - x1 @ th1
    effect = e0 - e1  # what adding the term explains (its linear part re-absorbed by the refit)
    var = np.concatenate([p.zdot if cand.variable == "zdot" else p.z for p in ev.fit_parts])
    lo, hi = np.quantile(var, [0.005, 0.995])
    edges = np.linspace(lo, hi, n_bins + 1)
    idx = np.clip(np.digitize(var, edges) - 1, 0, n_bins - 1)
    inside = (var >= lo) & (var <= hi)
    cnt = np.bincount(idx[inside], minlength=n_bins).astype(float)

    def mean(a):
        return tuple(float(v) for v in np.where(cnt > 0, np.bincount(idx[inside], a[inside], n_bins) /
                                                np.maximum(cnt, 1), np.nan))

    # partial coherence of the residual with the candidate, given z, ż and the declared terms (one engine)
    pcs, n_avg = [], 0
    for p in ev.fit_parts:
        if p.y.size < ev.spec.block:
            continue
        chans = np.vstack([p.y, p.z, p.zdot, *[_g(p, t) for t in [*terms, cand]]])
        sp = cross_spectra(chans, p.rf.fs_hz, ev.spec)
        m = (sp.freq_hz >= s.analysis_band_hz[0]) & (sp.freq_hz <= s.analysis_band_hz[1])
        pc = partial_coherence(sp, 0, list(range(1, chans.shape[0])))[-1][m]
        pcs.append(pc)
        n_avg = max(n_avg, sp.n_avg)
    q = 2 + len(terms) + 1
    level = 1 - 0.05 ** (1 / max(n_avg - q - 1, 1)) if n_avg else float("nan")
    pc_all = np.concatenate(pcs) if pcs else np.array([np.nan])
    centres = 0.5 * (edges[1:] + edges[:-1])
    return Evidence(variable=cand.variable, bins=tuple(float(c) for c in centres), before=mean(e0), after=mean(e1),
                    effect=mean(effect), partial_coherence_mean=float(np.nanmean(pc_all)),
                    partial_coherence_level=float(level),
                    fraction_lines_above_level=float(np.nanmean(pc_all > level)) if pcs else float("nan"))


def _retune(ev: "_Evaluator", terms: Sequence[Term], s: LoopSettings) -> tuple[list[Term], list[str]]:
    """Each term's varying parameter re-tuned over its grid (then refined), the others held: best ERR."""
    z = np.concatenate([p.z for p in ev.fit_parts])
    v = np.concatenate([p.zdot for p in ev.fit_parts])
    rng = dict(z_range=float(np.quantile(np.abs(z), 0.995)), zdot_range=float(np.quantile(np.abs(v), 0.995)),
               z_neg=float(np.quantile(-z, 0.998)), z_pos=float(np.quantile(z, 0.998)))
    out, notes = list(terms), []
    for i, t in enumerate(terms):
        grid = [g for g in candidate_grid(t.kind, points=s.grid_points, **rng)
                if g.params.get("side") == t.params.get("side")]
        vary = [k for k in t.params if k not in ("side", "offset") and len({g.params[k] for g in grid}) > 1]
        if not vary:
            continue
        key = vary[0]
        y, x0 = _design(ev.fit_parts, out[:i] + out[i + 1:])
        q, _ = np.linalg.qr(x0)
        r = y - q @ (q.T @ y)

        def err(term: Term) -> float:
            g = np.concatenate([_g(p, term) for p in ev.fit_parts])
            g = g - q @ (q.T @ g)
            d = float(g @ g)
            return float(g @ r) ** 2 / d if d > 0 else 0.0

        vals = sorted({float(g.params[key]) for g in grid})
        if key == t.spec.key_param:  # a declared gap/knee/deadband is the engineer's statement: within 2×
            v0 = float(t.params[key])
            vals = [x for x in vals if 0.5 * v0 <= x <= 2.0 * v0] or [v0]
        scores = [err(Term(t.kind, {**t.params, key: x})) for x in vals]
        j = int(np.argmax(scores))
        lo, hi = vals[max(j - 1, 0)], vals[min(j + 1, len(vals) - 1)]
        fine = [x for x in np.linspace(lo, hi, 9)[1:-1] if x > 0 or t.kind == "bump_stop"]
        cands = [(scores[j], vals[j])] + [(err(Term(t.kind, {**t.params, key: x})), x) for x in fine]
        cands.append((err(t), float(t.params[key])))
        best_score, best = max(cands)
        old = float(t.params[key])
        if best != old and best_score > 1.001 * cands[-1][0]:
            out[i] = Term(t.kind, {**t.params, key: best})
            notes.append(f"{t.label} re-tuned to {key}={best:.4g} on these data")
    return out, notes


# --------------------------------------------------------------------------------------------
# words
# --------------------------------------------------------------------------------------------
def _errors_line(e: Errors) -> str:
    parts = []
    if e.prediction_nmse_pct is not None:
        parts.append(f"held-out NMSE {e.prediction_nmse_pct:.2f} % (body acceleration predicted from the spindle)")
    parts.append(f"equation error {e.equation_nmse_pct:.2f} % (held-out, force balance)")
    parts.append("residual " + ", ".join(f"{k} Hz {v:+.1f} dB" for k, v in e.band_residual_db.items()))
    if e.transmissibility_error_pct:
        parts.append("transmissibility error " + ", ".join(f"{s or 'record'} {v:.1f} %"
                                                           for s, v in e.transmissibility_error_pct))
    return "; ".join(parts) + "."


def _p_text(p: float) -> str:
    if p < 1e-6:
        return "p < 1e-6"
    return f"p = {p:.1g}"


def _effect_words(c: Candidate, m2: float | None) -> str:
    unit = c.term.spec.coef_unit
    kp = c.key_param
    where = ""
    if kp is not None:
        v = kp[1]
        if c.term.variable == "z":
            where = f" ({kp[0]} {1e3 * v:.3g} mm)"
        else:
            where = f" ({kp[0]} {v:.3g} m/s)"
    if c.coefficient is not None:
        size = f"{c.coefficient:.3g} {unit} (θ = {c.theta:.3g} {unit}/kg × M2 = {m2:g} kg)"
    else:
        size = f"{c.theta:.3g} {unit} per kg of the output-side mass M2 (give --m2 for newtons)"
    if c.kind == "coulomb":
        return f"Coulomb friction of {size}"
    return f"{c.describe()}{where}: {c.term.label}, coefficient {size}"


def _stability_words(c: Candidate, n_records: int) -> str:
    if not np.isfinite(c.spread):
        return "stability unknown"
    what = f"the {n_records} records (levels)" if n_records > 1 else "the four quarters of the record"
    return f"stable across {what} (±{100 * c.spread:.0f} %)"


def _round_text(i: int, trial: Trial, before: Errors, ev: Evidence | None, m2: float | None,
                n_records: int, ranked: Sequence[Candidate] = ()) -> str:
    c, after = trial.candidate, trial.after
    alts = [a for a in ranked if a.kind != c.kind and a.err >= 0.98 * c.err]
    alt = ""
    if alts:
        alt = (" Nearly as good: " + ", ".join(f"{a.term.label} (explains {100 * a.err:.2f} %)" for a in alts)
               + f" — the data barely tell them apart; {c.kind} explains most ({100 * c.err:.2f} %).")
    assert after is not None
    nm0, nm1 = before.headline_nmse_pct, after.headline_nmse_pct
    pc = ""
    if ev is not None and np.isfinite(ev.partial_coherence_mean):
        pc = (f", partial coherence {ev.partial_coherence_mean:.2f} (95 % level {ev.partial_coherence_level:.2f}) "
              f"in the analysis band, {100 * ev.fraction_lines_above_level:.0f} % of lines above it")
    return (f"Round {i}: added {_effect_words(c, m2)}. It explains {100 * c.err:.0f} % of the remaining "
            f"body-acceleration residual ({100 * c.err_cv:.0f} % on alternate held-out blocks), "
            f"{_p_text(c.p_value)}{pc}, {_stability_words(c, n_records)}, and is not an artefact of impacts "
            f"on the input side (coefficient moves {100 * trial.tire_shift:.0f} % without the samples around "
            f"them); "
            f"held-out NMSE {nm0:.2f} % → {nm1:.2f} %, equation error {before.equation_nmse_pct:.2f} % → "
            f"{after.equation_nmse_pct:.2f} %.{alt}")


def _nothing_text(i: int, ranked: Sequence[Candidate], trials: Sequence[Trial]) -> str:
    if trials:
        t = trials[0]
        why = "; ".join(t.failed)
        return (f"Round {i}: the best remaining candidate, {t.candidate.term.label}, passes the significance "
                f"tests but fails the acceptance: {why}. {NOTHING_MISSING}")
    if ranked:
        c = ranked[0]
        return (f"Round {i}: the best remaining candidate, {c.term.label}, explains "
                f"{100 * c.err:.1f} % of what is left and fails: {'; '.join(c.failed)}. {NOTHING_MISSING}")
    return f"Round {i}: no candidate to try. {NOTHING_MISSING}"


# --------------------------------------------------------------------------------------------
# the loop
# --------------------------------------------------------------------------------------------
def _split(rec: Record, frac: float) -> tuple[Record, Record]:
    k = int(round(frac * rec.n))
    a, b = rec.slice(0, k), rec.slice(k, rec.n)
    return a, b


def close_loop(records: Record | Sequence[Record], declared: Sequence[Term | Mapping | str] = (), *,
               m2_kg: float | None = None, band: IntegrationBand | None = None,
               settings: LoopSettings = LoopSettings(),
               progress: Callable[[float, str], None] | None = None) -> LoopResult:
    """Find what the declared model lacks, add it, refit, repeat; report errors before and after.

    Parameters
    ----------
    records : Record or sequence of Record
        One record, or several at different excitation levels (same vehicle, same rate).
    declared : sequence of Term (or model-file entries)
        The declared strut nonlinearities besides the linear strut (empty: linear).
    m2_kg : float, optional
        Sprung mass [kg]: coefficients also in N, N/m, N·s/m...
    band : IntegrationBand, optional
        Integration band; default :func:`~nifo_core.restoring.suggest_band` of the first record.
    settings : LoopSettings
    progress : callable, optional
        ``progress(fraction, what)`` as the work advances.

    Returns
    -------
    LoopResult
    """
    recs = [records] if isinstance(records, Record) else list(records)
    if not recs:
        raise InputError("no records to run the loop on")
    if m2_kg is not None and not (np.isfinite(m2_kg) and m2_kg > 0):
        raise ConfigError(f"m2_kg={m2_kg!r} must be a positive mass [kg]")
    rates = sorted({r.fs_hz for r in recs})
    if len(rates) > 1:
        raise InputError(f"records have different sample rates {rates} Hz", hint="resample to one rate first")
    terms = [make_term(t) for t in declared]
    s = settings
    band = band or suggest_band(recs[0]).band
    say = progress or (lambda f, w: None)
    split = [_split(r, s.fit_fraction) for r in recs]
    say(0.0, "restoring force and the declared model")
    ev = _Evaluator([a for a, _ in split], [b for _, b in split], band, s)
    retuned: list[str] = []
    if s.retune and terms:
        terms, retuned = _retune(ev, terms, s)
    current = ev.errors(terms)
    initial = current
    rounds: list[Round] = []
    verdict = ""
    total = s.max_rounds + 1
    for i in range(1, s.max_rounds + 1):
        base = (i - 1) / total
        tuned: list[str] = []
        if s.retune and i > 1:
            say(base, f"round {i}: re-tuning the model's parameters")
            terms, tuned = _retune(ev, terms, s)
            current = ev.errors(terms)
        say(base, f"round {i}: tracing the residual")
        ranked = rank_beyond(ev.fit_rfs, terms, m2_kg=m2_kg, kinds=s.kinds, thresholds=s.thresholds,
                             grid_points=s.grid_points,
                             progress=lambda f, b=base: say(b + 0.8 * f / total, f"round {i}: tracing"))
        trials: list[Trial] = []
        added = None
        for c in [c for c in ranked if c.present][: s.top_tried]:
            say(base + 0.85 / total, f"round {i}: checking {c.term.label}")
            failed = []
            shift, frac = _tire_check(ev, terms, c.term, s)
            if not shift <= s.max_tire_shift:
                failed.append(f"impact check: the coefficient moves {100 * shift:.0f} % without the samples near "
                              f"the input side's impacts (> {100 * s.max_tire_shift:.0f} %): an artefact of impacts "
                              f"(tire events on a vehicle), not an effect of the nonlinear element")
            after = ev.errors([*terms, c.term])
            gain = 1 - after.equation_nmse_pct / current.equation_nmse_pct if current.equation_nmse_pct > 0 else 0.0
            if not gain >= s.min_heldout_gain:
                failed.append(f"held-out equation error {current.equation_nmse_pct:.3g} % → "
                              f"{after.equation_nmse_pct:.3g} % does not fall by {100 * s.min_heldout_gain:g} %")
            if (after.prediction_nmse_pct is not None and current.prediction_nmse_pct is not None
                    and after.prediction_nmse_pct > current.prediction_nmse_pct):
                failed.append(f"held-out prediction NMSE rises {current.prediction_nmse_pct:.3g} % → "
                              f"{after.prediction_nmse_pct:.3g} %")
            t = Trial(candidate=c, tire_shift=shift, tire_excluded_fraction=frac, heldout_gain=gain, after=after,
                      accepted=not failed, failed=tuple(failed))
            trials.append(t)
            if t.accepted:
                added = t
                break
        pre = "".join(f"(Re-tuned first: {n}.) " for n in tuned)
        if added is None:
            text = pre + _nothing_text(i, ranked, trials)
            rounds.append(Round(i, tuple(terms), ranked, tuple(trials), current, None, None, text))
            verdict = NOTHING_MISSING if i > 1 else f"The declared model lacks nothing the library can name. " \
                                                     f"{NOTHING_MISSING}"
            break
        evid = _evidence(ev, terms, added.candidate.term, s)
        text = pre + _round_text(i, added, current, evid, m2_kg, len(recs), ranked)
        rounds.append(Round(i, tuple(terms), ranked, tuple(trials), current, added, evid, text))
        terms = [*terms, added.candidate.term]
        current = added.after
    else:
        verdict = (f"Stopped after the limit of {s.max_rounds} round(s); more may be missing: run again with more "
                   f"rounds.")
    say(1.0, "done")
    n_added = sum(1 for r in rounds if r.added)
    if n_added:
        verdict = (f"Added {n_added} effect(s): " + ", ".join(r.added.candidate.term.label for r in rounds if r.added)
                   + f"; held-out NMSE {initial.headline_nmse_pct:.2f} % → {current.headline_nmse_pct:.2f} %. "
                   + verdict)
    notes = [f"declared {n} (the declared form is kept; the data set its parameter)" for n in retuned]
    if band.f_lo_hz > 1.0:
        notes.append(f"the integration band starts at {band.f_lo_hz:g} Hz: motion below it is only partly in z, ż")
    return LoopResult(declared=tuple(make_term(t) for t in declared), terms=tuple(terms), rounds=tuple(rounds),
                      initial=initial, final=current, verdict=verdict, band=band, m2_kg=m2_kg, settings=s,
                      sources=tuple(r.source for r in recs),
                      fit_seconds=tuple(a.duration_s for a, _ in split),
                      test_seconds=tuple(b.duration_s for _, b in split), notes=tuple(notes))
