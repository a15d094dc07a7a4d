"""The best set of effects (:mod:`nifo_core.loop.closing`, on a one-mass body after the rounds): the subset search's
best set of one effect fewer than the rounds added one at a time, and of as many, taken when it predicts the
held-out parts as well (fewer) or better (as many); then an added effect the final fit does not determine dropped.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import Callable, Sequence

from ..characterize.subsets import best_subsets, subset_rss
from ..kinds.describing import Term
from ..characterize.score import score_candidate
from .residual import _Evaluator, _static_candidate
from .round_results import Errors
from .settings import LoopSettings
from .ambiguity import Ambiguity, Comparison, compare_errors, separating_record
from .prune import drop_undetermined
from .frame import Frame
from .predictor import _errors, _Predictor
from .rounds import _Found
from .state import _placed, _Setup


def _best_set_pass(u: _Setup, found: _Found, say: Callable[[float, str], None]) -> _Found:
    """The best set of effects, fewer or as many than the rounds added one at a time (a one-mass body)."""
    say(0.95, "the best set of effects")
    terms, current, ambiguities, n_decl = list(found.terms), found.current, list(found.ambiguities), u.n_decl
    swapped = []
    for _ in range(len(terms) - n_decl + 1):
        changed = False
        for fewer, new, e, comp in _best_sets(u.ev, u.pred, found.search, terms, n_decl, current, u.s, u.m2_kg,
                                              u.frame):
            if (fewer and not comp.better("b", u.s.min_prediction_gain)) or (not fewer and comp.better("a")):
                how = ("one effect fewer predicts the held-out parts as well" if fewer else
                       "that set predicts the held-out parts better; one effect added at a time had stopped "
                       "short of it")
                swapped.append(f"{', '.join(t.label for t in terms[n_decl:])} re-chosen as "
                               f"{', '.join(t.label for t in new[n_decl:]) or 'nothing'}: {how} "
                               f"({comp.nmse_a:.3g} % against {comp.nmse_b:.3g} %, paired t {comp.t:+.2g})")
                terms, current, changed = new, e, True
                labels = {t.label for t in terms}    # what the rounds could not tell apart, if still held
                ambiguities = [a for a in ambiguities if {t.label for t in a.options[0].terms} <= labels]
                break
            if not fewer and not comp.apart():
                options = (u.explanation("as found, one effect at a time", current),
                           u.explanation("the best set of as many effects", e))
                ambiguities.append(Ambiguity(len(found.rounds), options, (compare_errors(u.held, current, e),),
                                             "found first", separating_record(u.ev.fit_rfs, terms[-1], new[-1])))
        if not changed or len(terms) == n_decl:
            break
    pruned = drop_undetermined(   # an added effect the final fit does not determine
        u.ev, u.held, terms, current, ambiguities, n_decl, u.s, partial(_errors, u.ev, u.pred), partial(_placed, u))
    terms, current, ambiguities = pruned.terms, pruned.current, pruned.ambiguities
    verdict = "".join(f"{d.text(u.s.min_prediction_gain)}. " for d in pruned.dropped) + found.verdict
    if swapped:
        verdict = "Effects re-chosen: " + "; then ".join(swapped) + ". " + verdict
    return replace(found, terms=tuple(terms), current=current, ambiguities=tuple(ambiguities), verdict=verdict)


#: a set of as many effects from the subset search is tried when it leaves this much less of the subsample's residual
SUBSET_GAIN = 0.01


def _best_sets(ev: _Evaluator, pred: _Predictor, search, terms: Sequence[Term], n_decl: int, current: Errors,
               s: LoopSettings, m2_kg: float | None, frame: Frame) -> list[tuple[bool, list[Term], Errors, Comparison]]:
    """The best set of one effect fewer than the rounds added, and of as many, beside the declared terms
    (:func:`~nifo_core.characterize.subsets.best_subsets` on the ranking's grid): (fewer?, its model's terms, their
    errors, their comparison with ``current`` — A: that set, B: as found). The set of as many is tried when its kinds
    differ and it leaves :data:`SUBSET_GAIN` less of the residual. Adding one effect at a time can stop short of the
    best set, and can take one effect more than it needs: measured on the fleet of issue 54, a cubic and an even
    spring beside a knee were taken for a one-sided stop, then a second stop and a clearance."""
    data = search.data
    fixed = [data.regressor(t, offsets=ev.static.get(t.label)) for t in terms[:n_decl]]
    added = list(terms[n_decl:])
    now = subset_rss(search, fixed + [data.regressor(t, offsets=ev.static.get(t.label)) for t in added], [])
    kinds = list(search.grids)
    out = []
    for size in ([len(added) - 1] if len(added) > 1 else []) + [len(added)]:
        fewer = size < len(added)
        for rss, js in best_subsets(search, fixed, kinds, size):
            new = [search.terms[j] for j in js]
            if not fewer and sorted(t.kind for t in new) == sorted(t.kind for t in added):
                continue          # the same kinds: their parameters are the rounds' own
            if not fewer and not rss < (1 - SUBSET_GAIN) * now:
                break
            model = list(terms[:n_decl])
            for t in new:         # each at full length, a stop or an even spring re-measured from the static position
                base = [data.regressor(u, offsets=ev.static.get(u.label)) for u in model]
                c = score_candidate(data, base, t, thresholds=s.thresholds, n_grid=s.grid_points, m2=m2_kg,
                                    names=tuple(u.label for u in model))
                model.append(_static_candidate(ev, model, c, s, m2_kg).term)
                frame.candidate(ev, model[-1])
            e = _errors(ev, pred, model)
            if e.prediction_nmse_pct is not None and current.prediction_nmse_pct is not None:
                out.append((fewer, model, e, compare_errors(ev.held, e, current)))
            break
    return out
