"""The rounds of the loop (:mod:`nifo_core.loop.closing`, steps 1-4): round after round, the model's added terms
re-tuned, the residual traced and ranked, the candidates judged and the best that passes added (:func:`_run_rounds`),
or a term re-placed instead, or the verdict when nothing is added; the model the rounds arrive at (:class:`_Found`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import Callable, Sequence

import numpy as np

from ..characterize.automatic import rank_beyond
from ..kinds.describing import Term, linear_twin
from ..characterize.result import Candidate
from ..predict.feedback_paths import PATH_KINDS
from .residual import _Evaluator, _evidence, _retune
from .stops import retune_stops
from .round_results import Errors, Round, Trial
from .settings import RETUNE_FACTOR
from .words import NOTHING_MISSING, _nothing_text, _round_text, unconfirmed_text
from .ambiguity import Ambiguity, compare_errors, separating_record
from .gates import Alternative
from .acceptance import _judge, _try_candidates
from .candidates import _round_candidates
from .predictor import _errors
from .state import _placed, _Setup


@dataclass(frozen=True)
class _Found:
    """The model the rounds arrived at: its terms and errors, the rounds, what the data could not tell apart, the
    verdict so far and the candidates' grid (None: no round traced the residual)."""

    terms: tuple[Term, ...]
    current: Errors
    rounds: tuple[Round, ...]
    ambiguities: tuple[Ambiguity, ...]
    verdict: str
    search: object = None


def _run_rounds(u: _Setup, say: Callable[[float, str], None]) -> _Found:
    """Round after round, the best candidate that passes every gate added, until none does or the rounds run out."""
    terms, current = list(u.declared_terms), u.initial
    rounds: list[Round] = []
    ambiguities: tuple[Ambiguity, ...] = ()
    search = None
    for i in range(1, u.s.max_rounds + 1):
        step = _round(u, i, terms, current, search, ambiguities, say)
        rounds += step.rounds
        terms, current, ambiguities, search = list(step.terms), step.current, step.ambiguities, step.search
        if step.verdict:
            verdict = step.verdict
            break
    else:
        verdict = (f"Stopped after the limit of {u.s.max_rounds} round(s); more may be missing: run again with more "
                   f"rounds.")
    return _Found(tuple(terms), current, tuple(rounds), ambiguities, verdict, search)


def _round(u: _Setup, i: int, terms: list[Term], current: Errors, search, ambiguities: tuple[Ambiguity, ...],
           say: Callable[[float, str], None]) -> _Found:
    """Round ``i``: re-tune what the loop added, trace and rank the residual, judge the candidates, add the best
    that passes. Its ``verdict`` is set when the loop stops here."""
    s, ev, pred = u.s, u.ev, u.pred
    total = s.max_rounds + 1
    base = (i - 1) / total
    tuned: list[str] = []
    if u.retune_ok and i > 1 and len(terms) > u.n_decl:   # the terms the loop added (a declared one: at the end)
        say(base, f"round {i}: re-tuning the model's parameters")
        terms, tuned = _retune(ev, terms, s, which=range(u.n_decl, len(terms)))   # not a term with offsets: those
        terms, in_frame = u.frame.retune(ev, terms, which=range(u.n_decl, len(terms)))   # in the frame (frame.py)
        placed = _placed(u, terms)    # then a stop's static gap given the model in its frame (stops.py; a new label)
        terms, moved = retune_stops(ev.regression(), ev.static, terms, which=range(u.n_decl, len(terms)))
        tuned += in_frame + moved
        if _placed(u, terms) or placed or tuned:
            current = _errors(ev, pred, terms)
    say(base, f"round {i}: tracing the residual")
    # the candidates' grid on the fit parts: the data's in the model's frame, built again only when that moved
    search = u.frame.search(ev, s.kinds, s.grid_points, search,
                            lambda f, b=base: say(b + 0.5 * f / total, f"round {i}: tracing"))
    ranked = rank_beyond(ev.fit_rfs, terms, m2_kg=u.m2_kg, kinds=s.kinds, thresholds=s.thresholds,
                         grid_points=s.grid_points, offsets=[ev.static.get(t.label) for t in terms], search=search)
    cands = _round_candidates(ev, pred, terms, ranked, s, u.m2_kg)
    twin = None
    if pred.flexible and cands and all(t.kind in PATH_KINDS for t in terms):
        say(base + 0.5 / total, f"round {i}: the linear twin (one more linear path)")
        twin = _errors(ev, pred, [*terms, linear_twin(_reach(ev))])
    tried = _try_candidates(u, i, terms, ranked, cands, current, partial(_judge, u, terms, ranked, twin), say)
    trials, added, current = list(tried.trials), tried.added, tried.current
    ambiguities += () if tried.ambiguity is None else (tried.ambiguity,)
    pre = "".join(f"(Re-tuned first: {n}.) " for n in tuned)
    if added is None:
        return replace(_nothing_added(u, i, terms, current, ranked, trials, ambiguities, pre), search=search)
    if added.ties:   # a declared term changed in meaning would do as well: the declared physics kept, both named
        ambiguities += (Ambiguity(
            i, (u.explanation(f"{added.candidate.term.label} added", added.after),
                *[u.explanation(f"{terms[a.index].label} re-placed by {a.term.label} ({a.changes})", a.errors)
                  for a in added.ties]),
            tuple(a.comparison for a in added.ties), "it keeps the declared physics",
            separating_record(ev.fit_rfs, added.candidate.term, added.ties[0].term)),)
    added = _with_joint_coefficient(ev, terms, added, u.m2_kg)
    evid = _evidence(ev, terms, added.candidate.term, s)
    text = pre + _round_text(i, added, current, evid, u.m2_kg, len(u.recs), ranked) + tried.why
    text += "".join(f" Ambiguity: {a.text()}." for a in ambiguities if a.round == i)
    done = Round(i, tuple(terms), ranked, tuple(trials), current, added, evid, text)
    terms = [*terms, added.candidate.term]
    current = added.after
    placed = _placed(u, terms)      # the frame the model with the new term implies
    if pred.reconsider(terms) or placed:
        current = _errors(ev, pred, terms)
    return _Found(tuple(terms), current, (done,), ambiguities, "", search)


def _reach(ev: _Evaluator) -> float:
    """The peak |z| of the fitted records [m]."""
    return max(float(np.max(np.abs(p.z))) for p in ev.fit_parts)


def _nothing_added(u: _Setup, i: int, terms: list[Term], current: Errors, ranked: Sequence[Candidate],
                   trials: Sequence[Trial], ambiguities: tuple[Ambiguity, ...], pre: str) -> _Found:
    """A round that adds nothing: a term re-placed instead when one does as well or better (the loop goes on when it
    does better and re-tuning is on), else the verdict."""
    s = u.s
    text = pre + _nothing_text(i, ranked, trials)
    retune = _retune_instead(trials, current)
    if retune is not None:      # a term re-placed does as well as (or better than) a term added
        t, a, is_better = retune
        old, model_before, before = terms[a.index], tuple(terms), current
        text = text.replace(f" {NOTHING_MISSING}", "")     # the round found something: said below
        if s.retune:
            terms = [*terms[:a.index], a.term, *terms[a.index + 1:]]
            current = a.errors
        if not is_better:
            why = ("re-tuning is off: the model is kept as it was" if not s.retune else
                   f"it keeps the declared physics within the stated factor {RETUNE_FACTOR:g} and adds no term"
                   if a.keeps_declared else "it adds no term (neither keeps the declared physics)")
            ambiguities += (Ambiguity(i, (u.explanation(f"{old.label} re-placed by {a.term.label}", a.errors),
                                          u.explanation(f"{t.candidate.term.label} added", t.after)),
                                      (compare_errors(u.held, a.errors, t.after),), why,
                                      separating_record(u.ev.fit_rfs, t.candidate.term, a.term)),)
            text += (f" {old.label} re-placed by {a.term.label} instead: these data cannot tell it from "
                     f"{t.candidate.term.label} added." if s.retune else
                     f" These data cannot tell {t.candidate.term.label} added from {old.label} re-placed by "
                     f"{a.term.label}; re-tuning is off.")
            done = Round(i, model_before, ranked, tuple(trials), before, None, None, text)
            return _Found(tuple(terms), current, (done,), ambiguities, NOTHING_ELSE)
        if s.retune:
            text += (f" {old.label} re-placed by {a.term.label} instead: it predicts the held-out parts "
                     f"better than {t.candidate.term.label} added ({a.comparison.nmse_b:.3g} % against "
                     f"{a.comparison.nmse_a:.3g} %, paired t {a.comparison.t:+.2g}).")
            done = Round(i, model_before, ranked, tuple(trials), before, None, None, text)
            return _Found(tuple(terms), current, (done,), ambiguities, "")
    done = Round(i, tuple(terms), ranked, tuple(trials), current, None, None, text)
    unconfirmed = [t for t in trials if t.unconfirmed]
    if unconfirmed:
        verdict = unconfirmed_text(unconfirmed, current)
    elif ambiguities:
        verdict = NOTHING_ELSE
    else:
        verdict = NOTHING_MISSING if i > 1 else f"The declared model lacks nothing the library can name. " \
                                                 f"{NOTHING_MISSING}"
    return _Found(tuple(terms), current, (done,), ambiguities, verdict)


#: the verdict when nothing is missing beyond what an ambiguity or a conflict names
NOTHING_ELSE = "Nothing else the library can name is missing."


def _retune_instead(trials: Sequence[Trial], current: Errors) -> tuple[Trial, Alternative, bool] | None:
    """The term re-placed instead of a term added, and whether it predicts better than the term (else the data
    cannot tell them apart): of the candidates refused only by one-of-kind alternatives taken instead of them
    (:func:`~nifo_core.loop.gates.judge_alternatives`), one that predicts better first, then the one predicting
    the held-out parts best; never one that predicts worse than the model ``current``."""
    now = current.prediction_nmse_pct
    options = [(t, a, a not in t.ties) for t in trials if t.gates_passed and not t.accepted
               for a in t.instead if a.errors.prediction_nmse_pct is not None
               and (now is None or a.errors.prediction_nmse_pct <= now)]
    if not options:
        return None
    return min(options, key=lambda o: (not o[2], o[1].errors.prediction_nmse_pct))


def _with_joint_coefficient(ev: _Evaluator, terms: Sequence[Term], trial: Trial, m2_kg: float | None, *,
                            corrected: bool = False) -> Trial:
    """The added term's coefficient from the loop's joint fit beside the model's terms (each re-estimated), with its
    bound: the ranking's coefficient is conditional on the others held. ``corrected``: with the fit's bias removed
    (:meth:`_Evaluator.bounds`), else the plain fit and its random error. A round adds the plain fit; the
    corrected one is given it at the end (:func:`_rounds_corrected`)."""
    b = ev.bounds([*terms, trial.candidate.term], corrected=corrected)
    th, hw = float(b.theta[-1]), float(b.half_width[-1])
    c = trial.candidate
    done = corrected and ev.corrected([*terms, trial.candidate.term]) is not None
    return replace(trial, candidate=replace(c, theta=th, theta_half_width=hw,
                                            coefficient=None if m2_kg is None else th * m2_kg),
                   coefficient_corrected=done)
