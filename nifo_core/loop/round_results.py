"""What one round of the loop tried and added (:mod:`nifo_core.loop.closing`).

:class:`Errors` holds how well one model does on held-out data (the held-out
*prediction* NMSE and the held-out *equation error*, always labelled, never one
standing in for the other); :class:`Trial`, :class:`Evidence` and :class:`Round`
hold what each round tried and added. Beside them, the words of an added effect, which a round's text carries
(:meth:`Round.with_added` re-words it); the rest of the report's words are :mod:`nifo_core.loop.words`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from ..characterize.automatic import Candidate
from ..kinds.describing import Term

__all__ = ["Errors", "Trial", "Evidence", "Round"]


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
