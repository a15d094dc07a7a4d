"""The loop's settings, its results and the words of its report (:mod:`nifo_core.loop.closing`).

:class:`LoopSettings` says how the loop traces, accepts and reports;
:class:`Errors` holds how well one model does on held-out data (the held-out
*prediction* NMSE and the held-out *equation error*, always labelled, never one
standing in for the other); :class:`Trial`, :class:`Evidence`, :class:`Round`
and :class:`LoopResult` hold what each round tried and added.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal, Mapping, Sequence

import numpy as np

from ..characterize.automatic import DEFAULT_KINDS, Candidate, Thresholds
from ..kinds.describing import Term
from ..signal.uncertainty import CoefficientBounds
from .detection import Confounding, DetectionLimit, Undetermined
from ..defaults import DEFAULT_ANALYSIS_BAND_HZ
from ..errors import ConfigError
from ..signal.integrate import IntegrationBand
from ..predict.model import IdentifiedModel
from ..signal.spectral import SpectralSettings

__all__ = ["LoopSettings", "Errors", "Trial", "Evidence", "Round", "LoopRefinement", "LoopResult",
           "RESIDUAL_BANDS_HZ", "NOTHING_MISSING", "RETUNE_FACTOR", "DeclaredTerm"]

#: bands of the per-band residual [Hz]
RESIDUAL_BANDS_HZ = ((2.0, 5.0), (5.0, 10.0), (10.0, 20.0), (20.0, 30.0))
#: the verdict when the last round found nothing
NOTHING_MISSING = "Nothing significant is missing."
#: a declared term's key parameter (knee, gap, deadband...) may be re-tuned within this factor of its declared
#: value; beyond it, or with its coefficient's sign flipped against the declared model's fit, it is another
#: physics than the one declared, and the loop says so
RETUNE_FACTOR = 2.0

Prediction = Literal["model", "none"]
Structure = Literal["auto", "constant", "paths"]


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
    max_band_rise_db : float
        Most a candidate may raise any band of the held-out residual (prediction error and
        equation error) [dB]; besides, it must lower the held-out prediction NMSE when there is one.
    tire_quantile, tire_guard_s, max_tire_shift : float
        Tire check: samples with |ẍ1| above this quantile, ± guard [s], are left
        out in a refit; the coefficient may move by at most ``max_tire_shift`` (relative).
    top_tried : int
        Candidates tried per round, in rank order, before "nothing significant".
    spectral : SpectralSettings
        For the per-band residual and the transmissibilities (paper Table 2 by default).
    analysis_band_hz : (float, float)
        Band of the transmissibility error and of NIFO.
    prediction : {'model', 'none'}
        ``'model'``: every term set is fitted as ``nifo identify`` fits it (:mod:`nifo_core.predict.model_fit`:
        NIFO on the fit parts, the linear part's form chosen by held-out prediction, constant
        coefficients or feedback paths) and its held-out body acceleration predicted from the
        measured input (spindle acceleration and/or force), simulated from rest
        (:mod:`nifo_core.predict.heldout`): the one metric. ``'none'``: equation error only.
    structure : {'auto', 'constant', 'paths'}
        Feedback structure of the predicting model (:func:`nifo_core.predict.model_fit.fit_model`).
    min_prediction_gain : float
        Relative fall of the held-out prediction NMSE a term must bring (on a rational linear part,
        where it is the only gate).
    max_record_rise : float
        A term may not make any record's held-out prediction worse by more than this (relative).
    path_widths : int
        On a rational linear part (a flexible body): widths tried per kind that can act through a
        feedback path (backlash, clearance, saturation), geometric over the relative motion.
    noise_correction : bool
        Remove the bias that noise on both sensors gives the equation-error fit and the final
        output-error refinement (errors in variables: :mod:`nifo_core.signal.bias_correction`,
        :mod:`nifo_core.predict.refine_bias`, with each record's noise estimated from its spectra,
        :mod:`nifo_core.signal.noise`); its uncertainty joins the coefficients' bounds.
    retune : bool
        Before each round, re-tune the parameter (gap, knee, eps...) of every term of the model
        over its grid (a key parameter within a factor 2 of its value) (declared terms state the form; the data set the parameter). Without it a
        declared term whose parameter does not match the band-limited motion leaves a residual
        that a second term of the same kind "explains".
    refine : bool
        After the rounds, refine the final model by output error (:func:`nifo_core.predict.refine.refine_model`:
        the coefficients, gaps/knees and a one-mass body's k, c that make it predict the fit parts
        best) and keep the refined model when its held-out prediction NMSE is not worse. A final
        step: the acceptance of terms does not use it.
    refine_seconds : float
        Leading seconds of each fit part the refinement simulates [s] (each iteration simulates
        every record once per parameter).
    """

    max_rounds: int = 4
    fit_fraction: float = 2.0 / 3.0
    kinds: tuple[str, ...] = DEFAULT_KINDS
    thresholds: Thresholds = field(default_factory=Thresholds)
    grid_points: int = 24
    min_heldout_gain: float = 0.01
    max_band_rise_db: float = 1.0
    tire_quantile: float = 0.995
    tire_guard_s: float = 0.1
    max_tire_shift: float = 0.5
    top_tried: int = 3
    spectral: SpectralSettings = field(default_factory=SpectralSettings)
    analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ
    prediction: Prediction = "model"
    retune: bool = True
    refine: bool = True
    refine_seconds: float = 60.0
    structure: Structure = "auto"
    min_prediction_gain: float = 0.02
    max_record_rise: float = 0.05
    path_widths: int = 8
    noise_correction: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.max_rounds, bool) or not isinstance(self.max_rounds, (int, np.integer)) \
                or not 1 <= self.max_rounds <= 10:
            raise ConfigError(f"max_rounds={self.max_rounds!r} must be a whole number in 1..10")
        if not 0.3 <= float(self.fit_fraction) <= 0.9:
            raise ConfigError(f"fit_fraction={self.fit_fraction!r} must be in [0.3, 0.9]",
                              hint="e.g. 2/3: fit on the first two thirds, test on the last third")
        if not 0.5 < float(self.tire_quantile) < 1:
            raise ConfigError(f"tire_quantile={self.tire_quantile!r} must be in (0.5, 1)")
        for name in ("min_heldout_gain", "max_band_rise_db", "tire_guard_s", "max_tire_shift"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"{name}={v!r} must be finite and non-negative")
        if self.top_tried < 1:
            raise ConfigError(f"top_tried={self.top_tried!r} must be at least 1")
        lo, hi = (float(v) for v in self.analysis_band_hz)
        if not 0 < lo < hi:
            raise ConfigError(f"analysis_band_hz={self.analysis_band_hz!r} must satisfy 0 < lo < hi")
        if not (np.isfinite(float(self.refine_seconds)) and float(self.refine_seconds) >= 5):
            raise ConfigError(f"refine_seconds={self.refine_seconds!r} must be at least 5 s")
        if self.prediction not in ("model", "none"):
            raise ConfigError(f"prediction={self.prediction!r} must be 'model' or 'none'")
        if self.structure not in ("auto", "constant", "paths"):
            raise ConfigError(f"structure={self.structure!r} must be 'auto', 'constant' or 'paths'")
        for name in ("min_prediction_gain", "max_record_rise"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and 0 <= v < 1):
                raise ConfigError(f"{name}={v!r} must be in [0, 1)")
        if isinstance(self.path_widths, bool) or not 2 <= int(self.path_widths) <= 32:
            raise ConfigError(f"path_widths={self.path_widths!r} must be a whole number in 2..32")
        object.__setattr__(self, "kinds", tuple(self.kinds))
        object.__setattr__(self, "analysis_band_hz", (lo, hi))

    def to_dict(self) -> dict:
        return {"max_rounds": int(self.max_rounds), "fit_fraction": float(self.fit_fraction),
                "kinds": list(self.kinds), "thresholds": self.thresholds.to_dict(),
                "grid_points": self.grid_points, "min_heldout_gain": self.min_heldout_gain,
                "max_band_rise_db": self.max_band_rise_db,
                "tire_quantile": self.tire_quantile, "tire_guard_s": self.tire_guard_s,
                "max_tire_shift": self.max_tire_shift, "top_tried": self.top_tried,
                "spectral": self.spectral.to_dict(), "analysis_band_hz": list(self.analysis_band_hz),
                "prediction": self.prediction, "retune": self.retune, "refine": self.refine,
                "refine_seconds": self.refine_seconds, "structure": self.structure,
                "min_prediction_gain": self.min_prediction_gain, "max_record_rise": self.max_record_rise,
                "path_widths": int(self.path_widths)}


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
        acceleration (``settings.prediction`` says by which fit), all records pooled [%];
        None when it could not be computed (``prediction_unavailable`` says why).
    prediction_nmse_per_record_pct : tuple of float
        The same per record (level).
    band_residual_db : mapping
        ``"2-5"`` → 10·log10(G_ee/G_yy) in that band [dB], e the held-out
        prediction error (the equation error when no prediction), records pooled.
    residual_of : str
        ``"prediction"`` or ``"equation"``: which error ``band_residual_db`` is of.
    equation_band_residual_db : mapping
        The same bands of the held-out equation error, always.
    transmissibility_error_pct : tuple of (str, float)
        Per record (level): median over the analysis band of |T_pred - T_meas|/|T_meas| [%]
        on the held-out part.
    prediction_unavailable : str or None
        Why there is no held-out prediction (None when there is one).
    notes : tuple of str
    whole_nmse_pct : float or None
        Held-out NMSE of the raw predicted output over all frequencies, offset included (the field's score,
        :mod:`nifo_core.predict.whole_signal`), mean over records [%]; None without a prediction.
    whole_nmse_per_record_pct : tuple of float
    whole_policy : str
        'whole' or 'band': whether that prediction is limited to the analysis band (whichever scores lower).
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
    prediction_unavailable: str | None = None
    equation_band_residual_db: Mapping[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    structure: str = ""
    model_note: str = ""
    fitted: object = field(default=None, compare=False, repr=False)   # the Fitted model scored (model_fit)
    whole_nmse_pct: float | None = None
    whole_nmse_per_record_pct: tuple[float, ...] = ()
    whole_policy: str = ""

    def to_dict(self) -> dict:
        return {"terms": [t.to_dict() for t in self.terms], "theta_per_kg": list(self.theta_per_kg),
                "whole_signal_nmse_pct": self.whole_nmse_pct,
                "whole_signal_nmse_per_record_pct": list(self.whole_nmse_per_record_pct),
                "whole_signal_prediction": self.whole_policy or None,
                "structure": self.structure, "model_note": self.model_note,
                "k_per_kg": self.k_per_kg, "c_per_kg": self.c_per_kg,
                "prediction_nmse_pct": self.prediction_nmse_pct,
                "prediction_unavailable": self.prediction_unavailable,
                "equation_nmse_pct": self.equation_nmse_pct, "equation_nmse_fit_pct": self.equation_nmse_fit_pct,
                "prediction_nmse_per_record_pct": list(self.prediction_nmse_per_record_pct),
                "band_residual_db": dict(self.band_residual_db), "residual_of": self.residual_of,
                "equation_band_residual_db": dict(self.equation_band_residual_db),
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
    unconfirmed: bool = False  # passes everything but the held-out prediction
    #: the one-of-kind alternatives (:class:`~nifo_core.loop.gates.Alternative`) the data cannot tell from it, and
    #: those taken instead of it; ``gates_passed``: it passes every check but those alternatives
    ties: tuple = ()
    instead: tuple = ()
    gates_passed: bool = False
    #: the added term's coefficient is bias-corrected (:mod:`nifo_core.signal.bias_correction`), not the plain fit
    coefficient_corrected: bool = False

    def to_dict(self) -> dict:
        def alt(a) -> dict:
            return {"replaces": a.index, "term": a.term.to_dict(), "comparison": a.comparison.to_dict(),
                    "keeps_declared": a.keeps_declared, "changes": a.changes}
        return {"candidate": self.candidate.to_dict(), "tire_shift": _fin(self.tire_shift),
                "tire_excluded_fraction": self.tire_excluded_fraction,
                "heldout_equation_gain": _fin(self.heldout_gain), "accepted": self.accepted,
                "unconfirmed": self.unconfirmed, "as_good_alternatives": [alt(a) for a in self.ties],
                "alternatives_taken_instead": [alt(a) for a in self.instead],
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

    def with_added(self, trial: Trial, m2: float | None) -> "Round":
        """This round with ``trial`` (the same term, another coefficient) as its addition, its words with it."""
        assert self.added is not None and trial.candidate.term.label == self.added.candidate.term.label
        return replace(self, added=trial, text=self.text.replace(_effect_words(self.added.candidate, m2),
                                                                 _effect_words(trial.candidate, m2)))

    def to_dict(self) -> dict:
        return {"round": self.index, "model_before": [t.to_dict() for t in self.model_before],
                "ranked": [c.to_dict() for c in self.ranked], "trials": [t.to_dict() for t in self.trials],
                "before": self.before.to_dict(),
                "added": None if self.added is None else _effect_dict(self.added),
                "after": None if self.after is None else self.after.to_dict(),
                "evidence": None if self.evidence is None else self.evidence.to_dict(), "text": self.text}


@dataclass(frozen=True)
class LoopRefinement:
    """The loop's final output-error refinement and both models' held-out prediction (one metric).

    Attributes
    ----------
    kept : bool
        True when the refined model is the loop's model (its held-out prediction NMSE is not worse).
    heldout_before_pct, heldout_after_pct : float or None
        Held-out prediction NMSE [%] of the equation-error model and of the refined one, records
        pooled, scored alike (``_Evaluator.predict_model`` of :mod:`nifo_core.loop.residual`);
        None: could not be predicted.
    heldout_before_per_record_pct, heldout_after_per_record_pct : tuple of float
    parameters : tuple of dict
        name, unit, ``equation_error`` (the loop's fit), ``refined`` and, with M2, both × M2
        (``*_times_m2``, ``unit_times_m2``).
    seconds : tuple of float
        Seconds of each fit part simulated [s].
    refinement : mapping or None
        :meth:`nifo_core.predict.refine.Refinement.to_dict` (band NMSE on the fit parts before and after).
    unavailable : str or None
        Why there is no refinement (None when there is one).
    whole_before_pct, whole_after_pct : float or None
        Beside the band figures, the held-out whole-signal NMSE [%] (the raw predicted output over all frequencies,
        offset included: the field's score) of the equation-error model and of the refined one, records pooled;
        None: not computed.
    whole_before_per_record_pct, whole_after_per_record_pct : tuple of float
    whole_before_policy, whole_after_policy : str
        'whole' or 'band': whether each prediction is limited to the analysis band (as :class:`Errors`).
    """

    kept: bool
    heldout_before_pct: float | None
    heldout_after_pct: float | None
    heldout_before_per_record_pct: tuple[float, ...] = ()
    heldout_after_per_record_pct: tuple[float, ...] = ()
    parameters: tuple[Mapping, ...] = ()
    seconds: tuple[float, ...] = ()
    refinement: Mapping | None = None
    unavailable: str | None = None
    refused: str | None = None       # why a refinement that predicts better is not kept (it changes a declared term)
    whole_before_pct: float | None = None
    whole_after_pct: float | None = None
    whole_before_per_record_pct: tuple[float, ...] = ()
    whole_after_per_record_pct: tuple[float, ...] = ()
    whole_before_policy: str = ""
    whole_after_policy: str = ""

    def parameter(self, name: str) -> Mapping:
        """The entry of ``parameters`` called ``name``."""
        return next(p for p in self.parameters if p["name"] == name)

    def text(self) -> str:
        if self.unavailable:
            return f"Output-error refinement: not done ({self.unavailable}); model.json holds the equation-error fit."
        what = "; ".join(f"{p['name']} {_value_text(p, 'equation_error')} → {_value_text(p, 'refined')}"
                         for p in self.parameters)
        score = (f"held-out prediction NMSE {_pct(self.heldout_before_pct)} (equation-error fit) → "
                 f"{_pct(self.heldout_after_pct)} (refined); whole signal (all frequencies, offset included) "
                 f"{_pct(self.whole_before_pct)} → {_pct(self.whole_after_pct)}")
        which = ("model.json holds the refined model" if self.kept else
                 f"not kept, {self.refused}: model.json holds the equation-error fit" if self.refused else
                 "not better on held-out data: model.json holds the equation-error fit")
        secs = ", ".join(f"{v:.0f}" for v in self.seconds)
        note = (self.refinement or {}).get("bias_note", "")
        return (f"Output-error refinement (every record simulated from its measured input, the prediction error "
                f"minimised over the coefficients, gaps/knees and the body's k, c; on the first {secs} s of the "
                f"fit parts), equation-error fit → refined: {what}; {score}: {which}."
                + (f" Bias correction of the refined values: {note}." if note else ""))

    def to_dict(self) -> dict:
        return {"kept": self.kept, "heldout_prediction_nmse_before_pct": self.heldout_before_pct,
                "heldout_prediction_nmse_after_pct": self.heldout_after_pct,
                "heldout_prediction_nmse_before_per_record_pct": list(self.heldout_before_per_record_pct),
                "heldout_prediction_nmse_after_per_record_pct": list(self.heldout_after_per_record_pct),
                "heldout_whole_signal_nmse_before_pct": self.whole_before_pct,
                "heldout_whole_signal_nmse_after_pct": self.whole_after_pct,
                "heldout_whole_signal_nmse_before_per_record_pct": list(self.whole_before_per_record_pct),
                "heldout_whole_signal_nmse_after_per_record_pct": list(self.whole_after_per_record_pct),
                "heldout_whole_signal_before_prediction": self.whole_before_policy or None,
                "heldout_whole_signal_after_prediction": self.whole_after_policy or None,
                "parameters": [dict(p) for p in self.parameters], "seconds": list(self.seconds),
                "refinement": None if self.refinement is None else dict(self.refinement),
                "unavailable": self.unavailable, "refused": self.refused, "text": self.text()}


def _pct(v: float | None) -> str:
    return "not computed" if v is None else f"{v:.3g} %"


def _value_text(p: Mapping, which: str) -> str:
    """``which`` ('equation_error' or 'refined') of a parameter in its unit (× M2 when given), ± its 95 % bound."""
    m2 = p.get(which + "_times_m2") is not None
    v, hw = (p[which + "_times_m2"], p.get(which + "_half_width_95_times_m2")) if m2 else \
        (p[which], p.get(which + "_half_width_95"))
    unit = p["unit_times_m2"] if m2 else p["unit"]
    scale, unit = (1e3, "mm") if unit == "m" else (1.0, unit)
    return f"{scale * v:.4g}" + (f" ± {scale * hw:.2g}" if hw is not None else "") + f" {unit}"


@dataclass(frozen=True)
class DeclaredTerm:
    """What became of one declared term: fitted as declared, and in the loop's final model.

    ``theta_declared``: its coefficient per unit sprung mass when the declared model is fitted as declared (the
    sign the declaration means: a falling knee, a hardening spring...); ``final``/``theta_final``: the term and
    coefficient in the final model (re-tuned within :data:`RETUNE_FACTOR`, refined). It *changed its meaning*
    when the coefficient's sign flipped or the key parameter moved beyond the factor: the loop says so, never
    silently.
    """

    declared: Term
    theta_declared: float
    final: Term
    theta_final: float
    m2_kg: float | None = None

    @property
    def factor(self) -> float:
        """Final key parameter over the declared one (1 without one)."""
        k = self.declared.spec.key_param
        if k is None or k not in self.final.params or not float(self.declared.params[k]):
            return 1.0
        return float(self.final.params[k]) / float(self.declared.params[k])

    @property
    def sign_flipped(self) -> bool:
        return bool(self.theta_declared * self.theta_final < 0)

    @property
    def changed_meaning(self) -> bool:
        return self.sign_flipped or not (1 / RETUNE_FACTOR <= self.factor <= RETUNE_FACTOR)

    def _coef(self, th: float) -> str:
        unit = self.declared.spec.coef_unit
        return f"{th * self.m2_kg:.4g} {unit}" if self.m2_kg else f"{th:.4g} {unit}/kg"

    def text(self) -> str:
        k = self.declared.spec.key_param
        moved = (f", its {k} {self.declared.params[k]:.4g} → {self.final.params[k]:.4g} (× {self.factor:.3g})"
                 if k is not None and self.factor != 1.0 else "")
        if self.changed_meaning:
            # the facts, not a judgement: the declared model fitted alone may be the biased one (a missing effect
            # pulls it: measured, a hidden quadratic damping turned the paper's falling knee to +329 N·s/m, the final
            # model restored -701 for the true -700), or the final one (issue 54: a knee re-tuned to 0.227 m/s rising)
            why = []
            if self.sign_flipped:
                why.append(f"its coefficient changed sign, {self._coef(self.theta_declared)} when the declared model "
                           f"is fitted alone, {self._coef(self.theta_final)} in the final model")
            if not 1 / RETUNE_FACTOR <= self.factor <= RETUNE_FACTOR:
                why.append(f"its {k} moved beyond the stated factor {RETUNE_FACTOR:g}: {self.declared.params[k]:.4g} → "
                           f"{self.final.params[k]:.4g} (× {self.factor:.3g})")
            return (f"The declared {self.declared.label} changed its meaning between the declared model's fit and the "
                    f"final model: " + "; ".join(why) + " (model.json holds the final model).")
        return (f"declared {self.declared.label}: coefficient {self._coef(self.theta_declared)} as declared → "
                f"{self._coef(self.theta_final)} in the final model{moved} (within the stated factor "
                f"{RETUNE_FACTOR:g}, same sign)")

    def to_dict(self) -> dict:
        return {"declared": self.declared.to_dict(), "theta_declared_per_kg": self.theta_declared,
                "final": self.final.to_dict(), "theta_final_per_kg": self.theta_final,
                "coefficient_declared": None if self.m2_kg is None else self.theta_declared * self.m2_kg,
                "coefficient_final": None if self.m2_kg is None else self.theta_final * self.m2_kg,
                "key_param_factor": self.factor, "sign_flipped": self.sign_flipped,
                "changed_meaning": self.changed_meaning, "retune_factor": RETUNE_FACTOR, "text": self.text()}


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
    model: IdentifiedModel | None = None
    linear_model: IdentifiedModel | None = None
    model_unavailable: str | None = None
    detection_limits: tuple[DetectionLimit, ...] = ()
    confounded: tuple[Confounding, ...] = ()
    bounds: CoefficientBounds | None = None
    undetermined: tuple[Undetermined, ...] = ()
    refinement: LoopRefinement | None = None
    linear_heldout_pct: float | None = None
    final_heldout_pct: float | None = None
    noise: tuple = ()                 # NoiseEstimate per record (nifo_core.signal.noise)
    bias_corrected: bool = False      # coefficients and bounds with the fit's bias removed (nifo_core.signal.bias_correction)
    ambiguities: tuple = ()           # Ambiguity (nifo_core.loop.ambiguity): explanations the data cannot tell apart
    declared_terms: tuple[DeclaredTerm, ...] = ()   # what became of each declared term
    beyond: tuple = ()   # BeyondTrial (nifo_core.loop.beyond): the kinds tried by output error after the refinement

    def coefficients(self) -> list[dict]:
        """The final model's equation-error coefficients with 95 % random-error bounds (per kg, and × M2).

        With ``bias_corrected``, θ has the fit's bias removed (noise on both sensors and the band-limited z, ż;
        :mod:`nifo_core.signal.bias_correction`) and the bound holds its uncertainty; otherwise random error only
        (:mod:`nifo_core.signal.uncertainty`), and noise reaching the regressors biases some kinds beyond it
        (measured: Coulomb −4.5 % against a ±0.6 % bound).
        """
        if self.bounds is None:
            return []
        # a measured force is one more column of the fit, after k and c: its coefficient is -1/M2
        force = len(self.bounds.theta) == 3 + len(self.terms)
        units = ["1/s²", "1/s", *(["1/kg"] if force else []), *[t.spec.coef_unit + "/kg" for t in self.terms]]
        names = ["k = K2/M2", "c = C2/M2", *(["-1/M2 (force column)"] if force else []),
                 *[t.label for t in self.terms]]
        out = []
        for n, u, d in zip(names, units, self.bounds.to_list(names)):
            m = None if n.startswith("-1/M2") else self.m2_kg
            out.append({**d, "unit": u, "value_times_m2": None if m is None else d["value"] * m,
                        "half_width_times_m2": None if m is None else d["half_width"] * m})
        return out

    @property
    def added(self) -> tuple[Candidate, ...]:
        """The effects added, in order."""
        return tuple(r.added.candidate for r in self.rounds if r.added is not None)

    @property
    def unconfirmed(self) -> tuple[Candidate, ...]:
        """Effects found in the last round that pass everything but the held-out prediction (not added)."""
        if not self.rounds or self.rounds[-1].added is not None:
            return ()
        return tuple(t.candidate for t in self.rounds[-1].trials if t.unconfirmed)

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
        lines.extend(f"Declared term: {d.text()}." for d in self.declared_terms if not d.changed_meaning)
        if self.bounds is not None:
            m = self.m2_kg
            what = ("bias-corrected, bounds: random error and the correction's uncertainty" if self.bias_corrected else
                    "random error only; may be biased low by noise on z, ż")
            lines.append(f"Final model, equation-error fit on the fit parts (95 % bounds, {what}): " + "; ".join(
                f"{d['name']} {d['value']:.4g} ± {d['half_width']:.2g} {d['unit']}"
                + (f" (× M2: {d['value_times_m2']:.4g} ± {d['half_width_times_m2']:.2g})" if m else "")
                for d in self.coefficients()) + ".")
        if self.refinement is not None:
            lines.append(self.refinement.text())
        if self.beyond:
            lines.append("Tried by output error after the refinement (the kinds the last round ranked and did not add; "
                         "added when it predicts the held-out parts better beyond the scatter of their blocks): "
                         + "; ".join(b.text() for b in self.beyond) + ".")
        if self.detection_limits:
            lines.append("Could not have been seen in these data (detection limits given the noise, levels, length "
                         "and the model's terms): " + "; ".join(d.text() for d in self.detection_limits) + ".")
        lines.extend(f"Note: {n}" for n in self.notes)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"declared_model": [t.to_dict() for t in self.declared],
                "refined_model": [t.to_dict() for t in self.terms],
                "effects_added": [_effect_dict(r.added) | {"round": r.index} for r in self.rounds if r.added],
                "effects_in_final_model": [t.to_dict() for t in self.terms[len(self.declared):]]
                + [b.term.to_dict() for b in self.beyond if b.accepted],
                "effects_added_by_output_error": [b.to_dict() for b in self.beyond if b.accepted],
                "tried_by_output_error": [b.to_dict() for b in self.beyond],
                "effects_unconfirmed": [_effect_dict(t) | {"round": self.rounds[-1].index}
                                        for t in (self.rounds[-1].trials if self.unconfirmed else ()) if t.unconfirmed],
                "errors_before": self.initial.to_dict(), "errors_after": self.final.to_dict(),
                "rounds": [r.to_dict() for r in self.rounds], "verdict": self.verdict,
                "nothing_missing": self.nothing_missing, "report": self.report(),
                "model_unavailable": self.model_unavailable,
                "refinement": None if self.refinement is None else self.refinement.to_dict(),
                "detection_limits": [d.to_dict() for d in self.detection_limits],
                "coefficients": self.coefficients(),
                "confounded": [c.to_dict() for c in self.confounded],
                "undetermined": [u.to_dict() for u in self.undetermined],
                "linear_heldout_prediction_nmse_pct": _fin(self.linear_heldout_pct),
                "final_heldout_prediction_nmse_pct": _fin(self.final_heldout_pct),
                "band": self.band.to_dict(), "m2_kg": self.m2_kg, "settings": self.settings.to_dict(),
                "records": [{"source": s, "fit_s": a, "test_s": b}
                            for s, a, b in zip(self.sources, self.fit_seconds, self.test_seconds)],
                "noise": [e.to_dict() for e in self.noise], "bias_corrected": self.bias_corrected,
                "ambiguities": [a.to_dict() for a in self.ambiguities],
                "declared_terms": [d.to_dict() for d in self.declared_terms], "notes": list(self.notes)}


def _fin(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _effect_dict(t: Trial) -> dict:
    c = t.candidate
    kp = c.key_param
    return {"kind": c.kind, "params": dict(c.term.params), "label": c.term.label,
            "key_param": None if kp is None else {"name": kp[0], "value": kp[1]},
            "theta_per_kg": c.theta, "coefficient": c.coefficient, "coefficient_unit": c.term.spec.coef_unit,
            "meaning": c.describe(), "err": c.err, "err_cv": c.err_cv, "p_value": c.p_value, "spread": _fin(c.spread),
            "group_theta": list(c.group_theta), "offset_per_record_m": list(c.offsets),
            "tire_shift": _fin(t.tire_shift),
            "heldout_equation_gain": _fin(t.heldout_gain), "coefficient_bias_corrected": t.coefficient_corrected}



# --------------------------------------------------------------------------------------------
# words
# --------------------------------------------------------------------------------------------
def _errors_line(e: Errors) -> str:
    parts = []
    if e.prediction_nmse_pct is not None:
        parts.append(f"held-out prediction NMSE {e.prediction_nmse_pct:.2f} % (output acceleration simulated from the "
                     f"measured input)")
    else:
        parts.append(f"held-out prediction NMSE not computed ({e.prediction_unavailable or 'prediction off'})")
    parts.append(f"held-out equation error {e.equation_nmse_pct:.2f} % (force balance, band-limited)")
    parts.append(f"residual of the {e.residual_of} " + ", ".join(f"{k} Hz {v:+.1f} dB"
                                                              for k, v in e.band_residual_db.items()))
    if e.transmissibility_error_pct:
        parts.append("transmissibility error " + ", ".join(f"{s or 'record'} {v:.1f} %"
                                                           for s, v in e.transmissibility_error_pct))
    return "; ".join(parts) + "."


def before_after_text(before: Errors, after: Errors) -> str:
    """Before → after on each metric, each labelled; a side without a prediction says so (never another metric)."""
    p0, p1 = before.prediction_nmse_pct, after.prediction_nmse_pct
    if p0 is not None and p1 is not None:
        pred = f"held-out prediction NMSE {p0:.2f} % → {p1:.2f} %"
    elif p0 is None and p1 is None:
        pred = f"held-out prediction NMSE not computed ({before.prediction_unavailable or 'prediction off'})"
    else:
        pred = ("held-out prediction NMSE " + (f"{p0:.2f} %" if p0 is not None else "not computed")
                + " → " + (f"{p1:.2f} %" if p1 is not None else "not computed")
                + f" ({(after if p1 is None else before).prediction_unavailable})")
    w0, w1 = before.whole_nmse_pct, after.whole_nmse_pct
    whole = ""
    if w0 is not None and w1 is not None:
        whole = f"; held-out whole-signal NMSE (all frequencies, offset included) {w0:.3g} % → {w1:.3g} %"
        if w1 > w0 and p0 is not None and p1 is not None and p1 < p0:
            whole += " (worse over all frequencies while better in the band: not confirmed outside the band)"
    return (f"{pred}{whole}; held-out equation error {before.equation_nmse_pct:.2f} % → "
            f"{after.equation_nmse_pct:.2f} %")


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
    if c.term.spec.sentence:
        return f"{c.term.spec.sentence} of {size}"
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
    pc = ""
    if ev is not None and np.isfinite(ev.partial_coherence_mean):
        pc = (f", partial coherence {ev.partial_coherence_mean:.2f} (95 % level {ev.partial_coherence_level:.2f}) "
              f"in the analysis band, {100 * ev.fraction_lines_above_level:.0f} % of lines above it")
    return (f"Round {i}: added {_effect_words(c, m2)}. It explains {100 * c.err:.0f} % of the remaining "
            f"body-acceleration residual ({100 * c.err_cv:.0f} % on alternate held-out blocks), "
            f"{_p_text(c.p_value)}{pc}, {_stability_words(c, n_records)}, and is not an artefact of impacts "
            f"on the input side (coefficient moves {100 * trial.tire_shift:.0f} % without the samples around "
            f"them); "
            f"{before_after_text(before, after)}.{alt}")


def unconfirmed_text(trials: Sequence[Trial], current: Errors) -> str:
    """The verdict when candidates pass everything on the equation error but the held-out prediction refuses them."""
    names = "; ".join(f"{t.candidate.term.label} ({t.candidate.describe()}, explains {100 * t.candidate.err:.0f} % "
                      f"of the equation residual)" for t in trials)
    why = "; ".join(dict.fromkeys(f for t in trials for f in t.failed))
    return (f"Found but not added: {names}. Significant, stable and lowering the held-out equation error with no "
            f"band worse, but the held-out prediction does not confirm it ({why}). Either the effect is not "
            f"there, or the predicting model (held-out prediction NMSE "
            + (f"{current.prediction_nmse_pct:.2f} %" if current.prediction_nmse_pct is not None else "not computed")
            + ") cannot use it at these levels: not proven missing, not proven absent.")


def _nothing_text(i: int, ranked: Sequence[Candidate], trials: Sequence[Trial]) -> str:
    if trials:
        t = trials[0]
        why = "; ".join(t.failed)
        end = ("Not added: the held-out prediction does not confirm it." if any(x.unconfirmed for x in trials)
               else NOTHING_MISSING)
        # a candidate below the significance tests is tried too where the held-out prediction judges (a rational part)
        tests = ("passes the significance tests but" if t.candidate.present else
                 "is tried for its held-out prediction and")
        return (f"Round {i}: the best remaining candidate, {t.candidate.term.label}, {tests} fails the acceptance: "
                f"{why}. {end}")
    if ranked:
        c = ranked[0]
        return (f"Round {i}: the best remaining candidate, {c.term.label}, explains "
                f"{100 * c.err:.1f} % of what is left and fails: {'; '.join(c.failed)}. {NOTHING_MISSING}")
    return f"Round {i}: no candidate to try. {NOTHING_MISSING}"
