"""The loop's acceptance gates: what a candidate must do on held-out data to be added (:mod:`nifo_core.loop` step 3).

Each gate returns the reasons a candidate fails (empty: it passes), in words a report can print.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from ..kinds.describing import Term
from .ambiguity import T_DISTINCT, Comparison
from .round_results import Errors
from .settings import RETUNE_FACTOR, LoopSettings

__all__ = ["heldout_failures", "prediction_failures", "unseen_failures", "one_of_kind_alternatives", "Alternative",
           "Judgement", "judge_alternatives", "RETUNE_FACTOR", "whole_signal_failures", "WHOLE_RISE"]

#: a term may not raise the held-out whole-signal NMSE by more than this fraction (relative); a smaller rise is
#: said in the round's before/after (:func:`~nifo_core.loop.words.before_after_text`). Measured on the bundled
#: sample's 1 + 2.5 mm records with the knee declared: the true play lowers the held-out band NMSE 0.099 → 0.068 %
#: and raises the whole-signal NMSE 0.298 → 0.305 % (+2.3 %, the part outside the analysis band): a 2 % limit
#: refused it
WHOLE_RISE = 0.10


def heldout_failures(current: Errors, after: Errors, s: LoopSettings,
                     comparison: Comparison | None = None) -> tuple[list[str], list[str]]:
    """Why a candidate does not improve the model on held-out data: (equation side, prediction side).

    Equation side: it must lower the held-out equation error by ``min_heldout_gain`` (relative) and
    raise no band of it by more than ``max_band_rise_db``. Prediction side: it must lower the held-out
    prediction NMSE whenever the current model has one (a model that cannot be predicted any more
    fails), by more than the scatter of its held-out blocks (``comparison``: the model with the candidate against
    the current one, :func:`nifo_core.loop.ambiguity.compare`; measured on the fleet of issue 54, a play was
    added for a 1 % fall, paired t 1.8, where no play was), and raise no band of the prediction error by more
    than ``max_band_rise_db``. A significance
    test alone trusts a mis-specified model (F-16 level 1: a multi-mode structure read as one mass
    takes a play that lowers the error at 2-15 Hz while the 20-30 Hz residual grows by 22 dB).
    """
    eq, pred = [], []
    e0, e1 = current.equation_nmse_pct, after.equation_nmse_pct
    gain = 1 - e1 / e0 if e0 > 0 else 0.0
    if not gain >= s.min_heldout_gain:
        eq.append(f"held-out equation error {e0:.3g} % → {e1:.3g} % does not fall by {100 * s.min_heldout_gain:g} %")
    eq += _worse_bands("equation error", current.equation_band_residual_db, after.equation_band_residual_db, s)
    p0, p1 = current.prediction_nmse_pct, after.prediction_nmse_pct
    if p0 is not None and p1 is None:
        pred.append(f"the model with it cannot be predicted ({after.prediction_unavailable})")
    elif p0 is not None:
        if not p1 < p0:
            pred.append(f"held-out prediction NMSE does not fall ({p0:.3g} % → {p1:.3g} %)")
        elif comparison is not None and not comparison.better("a"):
            pred.append(f"held-out prediction NMSE {p0:.3g} % → {p1:.3g} % falls less than the scatter of the "
                        f"held-out blocks (paired t {comparison.t:+.2g} over the pooled blocks, "
                        f"{comparison.z if comparison.z is not None else comparison.t:+.2g} over the records; "
                        f"{T_DISTINCT:g} needed)")
        pred += _worse_bands("prediction error", current.band_residual_db, after.band_residual_db, s)
    return eq, pred


def whole_signal_failures(current: Errors, after: Errors, s: LoopSettings) -> list[str]:
    """Why a candidate is refused on the whole signal: it raises the held-out whole-signal NMSE (the raw predicted
    output over all frequencies, offset included: what the field scores) by more than :data:`WHOLE_RISE`
    (relative) — whatever it does inside the band. Empty when either side has no whole-signal score."""
    w0, w1 = current.whole_nmse_pct, after.whole_nmse_pct
    if w0 is None or w1 is None or not w1 > w0 * (1 + WHOLE_RISE):
        return []
    p0, p1 = current.prediction_nmse_pct, after.prediction_nmse_pct
    band = (f"it lowers the held-out band NMSE ({p0:.3g} % → {p1:.3g} %) but " if p0 is not None and p1 is not None
            and p1 < p0 else "")
    return [f"{band}it raises the held-out whole-signal NMSE (all frequencies, offset included) {w0:.3g} % → "
            f"{w1:.3g} %: the predicted signal gets worse"]


def _worse_bands(what: str, b0, b1, s: LoopSettings) -> list[str]:
    worse = [f"{k} Hz {b0[k]:+.1f} → {b1[k]:+.1f} dB" for k in b0
             if k in b1 and np.isfinite(b0[k]) and np.isfinite(b1[k]) and b1[k] > b0[k] + s.max_band_rise_db]
    return [f"the held-out {what} grows by more than {s.max_band_rise_db:g} dB in " + ", ".join(worse)] if worse else []


def prediction_failures(current: Errors, after: Errors, s: LoopSettings, twin: Errors | None = None,
                         floor: Sequence[float] = ()) -> list[str]:
    """Why a candidate does not improve the held-out prediction enough (a rational linear part: the only gate).

    It must lower the held-out prediction NMSE by ``min_prediction_gain`` (relative) and by more than the noise
    floor (``floor``: per record, what a perfect model would still show, :meth:`HeldOut.noise_floor`), beat its
    linear twin (the same model with one more *linear* path: else what it adds is flexibility) by as much, and make
    no record's held-out prediction worse by more than ``max_record_rise`` (relative), the record's noise floor or a
    quarter of the mean gain (a term that trades one level for another is not an effect of the structure).
    """
    p0, p1 = current.prediction_nmse_pct, after.prediction_nmse_pct
    if p1 is None:
        return [f"the model with it cannot be predicted ({after.prediction_unavailable})"]
    if p0 is None:
        return []
    nf = float(np.mean(floor)) if len(floor) else 0.0
    out = []
    need = max(s.min_prediction_gain * p0, nf)
    if not p1 <= p0 - need:
        why = (f"does not fall by {100 * s.min_prediction_gain:g} %" if need > nf else
               f"does not fall by more than the noise floor of the held-out parts ({nf:.2g} %)")
        out.append(f"held-out prediction NMSE {p0:.3g} % → {p1:.3g} % {why}")
    elif twin is not None and twin.prediction_nmse_pct is not None and \
            not p1 <= twin.prediction_nmse_pct - max(s.min_prediction_gain * twin.prediction_nmse_pct, nf):
        out.append(f"it predicts the held-out parts no better than the same model with one more linear path "
                   f"({p1:.3g} % against {twin.prediction_nmse_pct:.3g} %): what it adds is flexibility, not a "
                   f"nonlinearity")
    gain = max(p0 - p1, 0.0)
    floors = list(floor) + [0.0] * (len(current.prediction_nmse_per_record_pct) - len(floor))
    worse = [(src, a, b) for src, a, b, f in zip(_names(current), current.prediction_nmse_per_record_pct,
                                                 after.prediction_nmse_per_record_pct, floors)
             if b - a > max(s.max_record_rise * a, f, 0.25 * gain)]
    if worse:
        out.append("it makes the held-out prediction of " + ", ".join(f"{n} worse ({a:.3g} % → {b:.3g} %)"
                                                                      for n, a, b in worse))
    return out


def unseen_failures(p_value: float, err: float, s: LoopSettings) -> list[str]:
    """Why a candidate judged on a rational linear part is not added although it may predict better: the force
    balance shows nothing of it (its equation-error F-test, with the term's grid, does not pass ``alpha``: the term
    does not lower the residual beyond its scatter). On a rational part the one-mass equation error is
    mis-specified and only the held-out prediction judges (:func:`prediction_failures`), but a term it calls
    nothing adds only flexibility to the black box's fit. Measured (a fresh control of issue 54's fleet, #109,
    a declared rebound damper and nothing else): a backlash with a 17 mm deadband explaining 0.1 % of the residual,
    p = 1, lowered the held-out prediction 0.032 → 0.0286 % and was added. Every true effect the fleet's rounds added
    on a rational part had p < 1e-80 (ERR 0.24-0.97), the F-16's play p < 1e-50 (ERR 0.08-0.11)."""
    if p_value < s.thresholds.alpha:
        return []
    return [f"the force balance shows nothing of it (equation-error p {p_value:.2g} ≥ {s.thresholds.alpha:g}; it "
            f"explains {100 * err:.2g} % of the residual): a held-out prediction gain alone does not add a term"]


def _names(e: Errors) -> list[str]:
    names = [n for n, _ in e.transmissibility_error_pct]
    return names + [f"record {i + 1}" for i in range(len(names), len(e.prediction_nmse_per_record_pct))]


def one_of_kind_alternatives(terms: Sequence[Term], candidate: Term, ranked: Sequence[Term],
                             static: Mapping) -> list[tuple[int, Term]]:
    """The one-term alternatives to adding ``candidate`` beside ``terms``: (index of a term of the model, the
    term of its kind that would replace it).

    A second term of a kind already present (the candidate in place of the present one — a bump stop measured
    from the static position too: measured, a second stop was added beside the first, which fell to −4.7e3 N/m),
    and the present kinds' own best candidates in the ranking (``ranked``: a term re-placed — a knee at another
    velocity — that the candidate may only stand in for: a friction absorbing a mis-placed knee's sign(ż) part).
    A bump stop measured from the static position (``static``) has its gap fitted with its offsets: the ranking's
    stops (from the mean position) are no alternative to it.
    """
    kinds = {t.kind: k for k, t in enumerate(terms)}
    present = {t.kind: k for k, t in enumerate(terms) if t.label not in static}
    out = []
    if candidate.kind in kinds:
        out.append((kinds[candidate.kind], candidate))
    for r in ranked:
        k = present.get(r.kind)
        if k is not None and r.kind != candidate.kind and r.label != terms[k].label:
            out.append((k, r))
    return out


@dataclass(frozen=True)
class Alternative:
    """One term of a kind already in the model, re-placed, in place of adding a candidate
    (:func:`one_of_kind_alternatives`), and how it compares with the candidate added.

    ``comparison``: the model with the candidate added (A) against this one (B), on the held-out parts
    (:func:`nifo_core.loop.ambiguity.compare`). ``keeps_declared``: it re-places a term the loop added, or a
    declared term within :data:`RETUNE_FACTOR` of its declared key parameter, and every declared term keeps the
    sign of its coefficient in the declared model's fit (the declared physics kept); else ``changes`` says how it
    changes a declared term. ``against_model``: this one (A) against the model without either (B), when compared: an
    alternative that does not predict better than that model beyond the scatter explains nothing of what the
    candidate explains, and is no rival to it (:func:`judge_alternatives`).
    """

    index: int
    term: Term
    errors: Errors
    comparison: Comparison
    keeps_declared: bool
    changes: str = ""
    against_model: Comparison | None = None

    @property
    def explains(self) -> bool:
        """Whether it predicts the held-out parts better than the model without either (True when not compared)."""
        return self.against_model is None or self.against_model.better("a")


def _same_feature(present: Term, candidate: Term) -> bool:
    """Whether ``candidate`` is the feature ``present`` models, re-placed: the same kind (and side), its key parameter
    within :data:`RETUNE_FACTOR` of the present one's (a second stop 0.2 mm from the first, a second knee at
    0.035 m/s beside one at 0.03). Two knees a factor 3 apart (a damper's two valve stages), or a rebound stop beside
    a compression one, are two features."""
    if present.kind != candidate.kind or present.params.get("side") != candidate.params.get("side"):
        return False
    key = present.spec.key_param
    if key is None:
        return True
    a, b = float(present.params[key]), float(candidate.params[key])
    return a > 0 and b > 0 and 1 / RETUNE_FACTOR <= b / a <= RETUNE_FACTOR


@dataclass(frozen=True)
class Judgement:
    """:func:`judge_alternatives`' answer: why the candidate is not added (``failed``: empty when it is), the
    alternatives the data cannot tell from it (``ties``), and the alternatives taken instead of it (``instead``)."""

    failed: tuple[str, ...]
    ties: tuple[Alternative, ...]
    instead: tuple[Alternative, ...]


def judge_alternatives(terms: Sequence[Term], candidate: Term, alternatives: Sequence[Alternative],
                       s: LoopSettings, *, candidate_keeps: bool = True
                       ) -> Judgement:
    """Whether one term of a kind already present does as well as adding ``candidate`` (:class:`Judgement`: why
    the candidate is not added, the alternatives the data cannot tell from it, the alternatives taken instead of
    it). An alternative that predicts the held-out parts better
    (:meth:`~nifo_core.loop.ambiguity.Comparison.better`, beyond the scatter) is taken instead. The candidate must
    predict better than each alternative, beyond the scatter and by ``min_prediction_gain`` (one term more);
    otherwise the data cannot tell them apart: an ambiguity, resolved towards the declared physics. The
    alternative is taken when it keeps the declared physics (a re-tune within the stated factor: the declaration
    kept, no term added), when the candidate's model does not keep it either (``candidate_keeps``: fewer terms), or
    when it is the candidate itself in place of the term of its kind (no second term of a kind without held-out
    evidence for two: a second knee beside a declared one that it shrinks to nothing keeps the declared term in
    name only); the candidate when only its model keeps the declared physics. The other explanation is named
    either way. A second term of a kind that is the present one's feature re-placed (:func:`_same_feature`) is
    never added: the candidate is taken in its place instead. An alternative that predicts no better than the model
    without either (:attr:`Alternative.explains`) is no rival: measured on ``benchmarks/bench_loop.py``'s records, a
    re-placed knee predicting 2.67 % against the model's 1.08 % and the friction's 0.431 % tied with the friction
    (paired t +1.2 over blocks whose errors are heavy-tailed), refused it, and then was not taken either (it predicts
    worse than the model): the friction was silently dropped and the loop said nothing was missing.
    """
    failed: list[str] = []
    ties: list[Alternative] = []
    instead: list[Alternative] = []
    for alt in alternatives:
        c = alt.comparison
        present = terms[alt.index]
        second = alt.term.kind == candidate.kind and alt.term.label == candidate.label
        what = (f"a second {alt.term.kind} without held-out evidence for two" if second
                else f"it only stands in for {present.label} re-placed")
        fig = (f"one {alt.term.kind}, {alt.term.label} in place of {present.label}, predicts the held-out parts at "
               f"{c.nmse_b:.3g} % against {c.nmse_a:.3g} % with {candidate.label} added (paired t {c.t:+.2g})")
        changes = "" if alt.keeps_declared else f" — it changes the declared term ({alt.changes})"
        if second and _same_feature(present, candidate):
            instead.append(alt)
            key = present.spec.key_param
            near = f"within a factor {RETUNE_FACTOR:g} of its {key}" if key else "a kind with no position of its own"
            failed.append(f"a second {candidate.kind} where the model has {present.label}: {near}, the same "
                          f"feature re-placed ({fig})")
        elif not alt.explains:
            continue
        elif c.better("b"):
            instead.append(alt)
            failed.append(f"{what}: {fig}, better{changes}")
        elif not c.better("a", s.min_prediction_gain):
            ties.append(alt)
            if alt.keeps_declared or not candidate_keeps or second:
                instead.append(alt)
                failed.append(f"{what}: {fig}, as well (these data cannot tell them apart: it must be "
                              f"{100 * s.min_prediction_gain:g} % better beyond the scatter){changes} — "
                              f"{present.label} re-placed rather than a term added")
    return Judgement(failed=tuple(failed), ties=tuple(ties), instead=tuple(instead))
