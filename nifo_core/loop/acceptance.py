"""Whether a candidate is added (:mod:`nifo_core.loop.closing`, step 3): every gate of one candidate
(:func:`_judge`), a round's candidates judged in rank order or side by side (:func:`_try_candidates`), and, when a
rational linear part accepts nothing, the round again on the one-mass body (:func:`_body_round`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Callable, Sequence

import numpy as np

from ..kinds.describing import Term
from ..signal.parallel import thread_map
from ..characterize.result import Candidate
from .residual import _Evaluator, _g, _static_candidate, _tire_check
from .rivals import rivals_of
from ..predict.model_fit import RATIONAL_MARGIN
from .round_results import Errors, Trial
from .settings import LoopSettings
from .ambiguity import Ambiguity, compare_errors
from .gates import (Alternative, heldout_failures, judge_alternatives, one_of_kind_alternatives, prediction_failures,
                    unseen_failures, whole_signal_failures)
from .predictor import _errors, _Predictor
from .state import _Setup

__all__ = ["acts_linearly"]


@dataclass(frozen=True)
class _Tried:
    """A round's trials, the one added (None: none) and the model's errors they were judged against."""

    trials: tuple[Trial, ...]
    added: Trial | None
    current: Errors
    ambiguity: Ambiguity | None = None
    why: str = ""          # why ``added`` was taken over another that passed, when the round's text must say so


#: a term whose describing function the linear columns z, ż explain to this R² on the fit parts acts linearly there
#: (a play wider than the motion is stuck: its force a constant; a slipping play of 0.4 mm in 5 mm of motion: 0.998)
LINEAR_R2 = 0.9999


def acts_linearly(ev: _Evaluator, term: Term) -> float:
    """R² of the term's band-passed describing function on the fit parts regressed on z and ż (1: it never leaves
    one regime — a play wider than the motion, a clearance never reached — and only adds a linear term)."""
    g = np.concatenate([_g(p, term, ev.static) for p in ev.fit_parts])
    x = np.column_stack([np.concatenate([p.z for p in ev.fit_parts]), np.concatenate([p.zdot for p in ev.fit_parts])])
    tss = float(g @ g)
    if not tss > 0:
        return 1.0
    r = g - x @ np.linalg.lstsq(x, g, rcond=None)[0]
    return float(1 - (r @ r) / tss)


def _try_candidates(u: _Setup, i: int, terms: Sequence[Term], ranked: Sequence[Candidate],
                    cands: Sequence[Candidate], current: Errors, judge_in: Callable[..., Trial],
                    say: Callable[[float, str], None]) -> _Tried:
    """A round's candidates judged: on a flexible body side by side (the best that passes), on a one-mass body in
    rank order (the first that passes, with a rival that does as well named); on a flexible body that accepts
    nothing, the round again on the one-mass body."""
    s, pred = u.s, u.pred
    total = s.max_rounds + 1
    base = (i - 1) / total
    judge = partial(judge_in, pred, current)
    trials: list[Trial] = []
    added = amb = None
    why = ""
    if pred.flexible:      # every candidate judged on the one metric, side by side: the best that passes
        say(base + 0.5 / total, f"round {i}: checking {len(cands)} candidates side by side")
        trials = thread_map(judge, cands)
        added, why = _best_onward(pred, terms, [t for t in trials if t.accepted])
    else:                  # in rank order, the first that passes
        for j, c in enumerate(cands):
            say(base + (0.5 + 0.45 * j / max(len(cands), 1)) / total, f"round {i}: checking {c.term.label}")
            trials.append(judge(c))
            if trials[-1].accepted:
                added = trials[-1]
                break
        if added is not None:   # another kind that explains as much and predicts as well: named beside it
            got = rivals_of(i, u.held, u.ev.fit_rfs, added, cands[len(trials):], judge, trials, u.explanation,
                            s.min_prediction_gain)
            added, amb, why = got.kept, got.ambiguity, got.words
    if added is None and pred.flexible:   # the one-mass body again, with a term in (:meth:`_Predictor.reconsider`)
        got = _body_round(u.ev, pred, terms, ranked, s, u.m2_kg, judge_in, say, base + 0.9 / total, i)
        if got is not None:
            body_trials, added, current = got
            trials += body_trials
    return _Tried(tuple(trials), added, current, amb, why)


def _best_onward(pred: _Predictor, terms: Sequence[Term], ok: Sequence[Trial]) -> tuple[Trial | None, str]:
    """Of the trials that passed on the rational part, the one predicting best in the form the loop goes on with
    once it is in (:meth:`_Predictor.onward_score`), and the round's words when that is not the best on the rational
    part itself."""
    if not ok:
        return None, ""
    onward = [pred.onward_score([*terms, t.candidate.term]) for t in ok]
    j = min(range(len(ok)), key=lambda k: onward[k])
    here = min(range(len(ok)), key=lambda k: ok[k].after.prediction_nmse_pct)
    if j == here:
        return ok[j], ""
    a, b = ok[j], ok[here]
    return a, (f" Taken instead of {b.candidate.term.label}, which predicts the held-out parts better on the rational "
               f"part ({b.after.prediction_nmse_pct:.3g} % against {a.after.prediction_nmse_pct:.3g} %): once in, "
               f"the loop goes on with the {onward[j][1]}, where {a.candidate.term.label} predicts them at "
               f"{onward[j][0]:.3g} %, and {b.candidate.term.label} with the {onward[here][1]} at "
               f"{onward[here][0]:.3g} %.")


def _judge(u: _Setup, terms: Sequence[Term], ranked: Sequence[Candidate], twin: Errors | None, pred: _Predictor,
           current: Errors, c: Candidate) -> Trial:
    """The acceptance of a candidate with ``pred``'s linear form, against the model ``current`` (every gate)."""
    ev, s, held = u.ev, u.s, u.held
    c = _static_candidate(ev, terms, c, s, u.m2_kg)  # a bump stop: its gap from the static position
    u.frame.candidate(ev, c.term)                     # a form of z: from the static position of the model's frame
    failed = []
    r2 = acts_linearly(ev, c.term)
    if r2 >= LINEAR_R2:
        failed.append(f"it acts linearly on these data (z and ż explain {100 * r2:.2f} % of it: it never "
                      f"leaves one regime)")
    shift, frac = _tire_check(ev, terms, c.term, s)
    if not shift <= s.max_tire_shift and not pred.flexible:   # impacts: a vehicle's tire, a one-mass body
        failed.append(f"impact check: the coefficient moves {100 * shift:.0f} % without the samples near "
                      f"the input side's impacts (> {100 * s.max_tire_shift:.0f} %): an artefact of impacts "
                      f"(tire events on a vehicle), not an effect of the nonlinear element")
    after = _errors(ev, pred, [*terms, c.term])
    gain = 1 - after.equation_nmse_pct / current.equation_nmse_pct if current.equation_nmse_pct > 0 else 0.0
    if pred.flexible:
        eq_failed = unseen_failures(c.p_value, c.err, s)
        pred_failed = prediction_failures(current, after, s, twin, u.floor)
    else:
        eq_failed, pred_failed = heldout_failures(current, after, s, compare_errors(held, after, current))
    failed += eq_failed + pred_failed + whole_signal_failures(current, after, s)
    ties = instead = ()
    passed = not failed
    # failing the prediction alone makes a candidate "unconfirmed" (maybe missing), unless a term of a kind
    # already present, re-placed, does as well: then it only stands in for that one (measured: a declared
    # friction at eps 0.005 m/s, the truth, and a second friction at 0.01 m/s "unconfirmed")
    only_pred = bool(pred_failed) and len(failed) == len(pred_failed) and not pred.flexible
    more: list[str] = []
    if (passed or only_pred) and not pred.flexible:  # one term of a kind already present must not do as well
        alts = []
        for k, a in one_of_kind_alternatives(terms, c.term, [r.term for r in ranked], ev.static):
            u.frame.candidate(ev, a)
            e = _errors(ev, pred, [*terms[:k], a, *terms[k + 1:]])
            alts.append(Alternative(k, a, e, compare_errors(held, after, e), *u.keeps(e),
                                    against_model=compare_errors(held, e, current)))
        judged = judge_alternatives(terms, c.term, alts, s, candidate_keeps=u.keeps(after)[0])
        more, ties, instead = list(judged.failed), list(judged.ties), list(judged.instead)
        failed += more
    return Trial(candidate=c, tire_shift=shift, tire_excluded_fraction=frac, heldout_gain=gain, after=after,
                 accepted=not failed, failed=tuple(failed), unconfirmed=only_pred and not more,
                 ties=tuple(ties), instead=tuple(instead), gates_passed=passed)


def _body_round(ev: _Evaluator, pred: _Predictor, terms: Sequence[Term], ranked: Sequence[Candidate],
                s: LoopSettings, m2_kg: float | None, judge_in: Callable, say: Callable[[float, str], None],
                at: float, i: int) -> tuple[list[Trial], Trial, Errors] | None:
    """When the rational linear part adds nothing: the round again on the one-mass body, whose form is taken
    (with the term it accepts) unless the rational model with that term predicts clearly better
    (:data:`~nifo_core.predict.model_fit.RATIONAL_MARGIN`, as :meth:`_Predictor.reconsider`).

    The form was chosen on the linear model alone, and a strong nonlinearity the body lacks makes its linear model
    predict worse than a black box's extra poles do: measured, a bump stop 3.5e5 N/m beyond 5.6 mm beside a declared
    knee (3 levels up to 5.5 mm road): the linear body 41 % against the rational 16 %; on the rational part every
    candidate made the held-out prediction worse (the stop through no path of its own), so nothing was added.
    None when the body is not physical with ``terms`` or accepts nothing."""
    body = pred.body_twin()
    current = _errors(ev, body, terms)
    if current.prediction_nmse_pct is None or body._equation(terms) is None:
        return None
    trials = []
    for c in [c for c in ranked if c.present][: s.top_tried]:
        say(at, f"round {i}: checking {c.term.label} on the one-mass body")
        t = judge_in(body, current, c)
        trials.append(t)
        if not t.accepted:
            continue
        flex = pred.fit([*terms, t.candidate.term])
        if flex.score <= RATIONAL_MARGIN * t.after.prediction_nmse_pct:
            return None      # the rational model with it predicts clearly better: its form stays
        pred.switch_to_body(f"one-mass body from round {i} on: with {t.candidate.term.label} its equation-error fit "
                            f"is physical and predicts the held-out parts at {t.after.prediction_nmse_pct:.4g} % "
                            f"against {flex.score:.4g} % for the rational model with it (the rational form was "
                            f"chosen on the linear model alone)")
        return trials, t, current
    return None
