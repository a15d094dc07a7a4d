"""The loop's result (:mod:`nifo_core.loop.closing`).

:class:`LoopResult` holds what the loop found: the rounds, the final model, errors before and after, the verdict, the
report and ``loop.json``; :class:`LoopRefinement` the output-error refinement of its final model and
:class:`DeclaredTerm` what became of each declared term. Its settings are :mod:`nifo_core.loop.settings`, what each
round tried and added :mod:`nifo_core.loop.round_results`, the report's words :mod:`nifo_core.loop.words`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from ..characterize.automatic import Candidate
from ..kinds.describing import Term
from ..signal.uncertainty import CoefficientBounds
from .detection import Confounding, DetectionLimit, Undetermined
from ..signal.integrate import IntegrationBand
from ..predict.model import IdentifiedModel
from .round_results import Errors, Round, _effect_dict, _fin
from .settings import RETUNE_FACTOR, LoopSettings
from .words import NOTHING_MISSING, _errors_line

__all__ = ["LoopRefinement", "DeclaredTerm", "LoopResult"]


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
