"""A kind that passes every check and predicts the held-out parts better than the first in rank is taken (issue 54).

On the one-mass body a round's candidates are judged in rank order; the first that passes used to be added even when
a rival judged after it passed too and predicted the held-out parts better beyond their scatter (only a tie was
named). The loop's one metric decides now (:mod:`nifo_core.loop.rivals`).
"""

from __future__ import annotations

import numpy as np

from nifo_core.characterize.result import Candidate
from nifo_core.kinds.describing import Term
from nifo_core.loop.ambiguity import Explanation
from nifo_core.loop.round_results import Errors, Trial
from nifo_core.loop.rivals import rivals_of
from nifo_core.predict.heldout import split_records
from nifo_core.signal.record import Record

CLEARANCE = Term("clearance", {"gap": 0.005})
CUBIC = Term("cubic_stiffness")


def _trial(term: Term, err: float, pct: float) -> Trial:
    """A trial that passed every check: its candidate explains ``err`` of the residual, its model predicts the
    held-out parts at ``pct`` % (no per-block predictions: compared by the relative difference alone)."""
    cand = Candidate(term=term, theta=1.0, coefficient=None, err=err, delta_r2=err, err_cv=err, p_value=1e-9,
                     n_eff=1e3, spread=0.05, group_theta=(1.0, 1.0), present=True)
    after = Errors(terms=(term,), theta_per_kg=(1.0,), k_per_kg=75.0, c_per_kg=4.5, equation_nmse_pct=1.0,
                   equation_nmse_fit_pct=1.0, prediction_nmse_pct=pct, prediction_nmse_per_record_pct=(pct,),
                   band_residual_db={}, residual_of="prediction", transmissibility_error_pct=())
    return Trial(candidate=cand, tire_shift=0.0, tire_excluded_fraction=0.0, heldout_gain=0.1, after=after,
                 accepted=True, failed=(), gates_passed=True)


def _rivals(first: Trial, rival_pct: float, min_gain: float = 0.02):
    rng = np.random.default_rng(5)
    y = rng.standard_normal(20000)
    held = split_records([Record(200.0, 0.1 * rng.standard_normal(y.size), y, source="synthetic")],
                         band_hz=(1.0, 30.0))
    name = lambda what, e: Explanation(what, e.terms, e.theta_per_kg, e.prediction_nmse_pct)  # noqa: E731
    trials: list[Trial] = []
    got = rivals_of(1, held, [], first, [_trial(CUBIC, 0.07, rival_pct).candidate],
                    lambda c: _trial(CUBIC, c.err, rival_pct), trials, name, min_gain)
    return got.kept, got.ambiguity, got.words, trials


def test_a_rival_predicting_better_beyond_the_scatter_is_taken_instead_of_the_first_in_rank():
    # a clearance explains a little more of the residual (8 % against 7 %) than a cubic, which predicts the
    # held-out parts 8 % better: the cubic is taken, and the round says so
    first = _trial(CLEARANCE, 0.08, 0.0063)
    got, amb, took, trials = _rivals(first, 0.0058)
    assert got.candidate.term == CUBIC and amb is None and len(trials) == 1
    assert "Taken instead of clearance(gap=0.005)" in took and "0.0063 % against 0.0058 %" in took
    # better, but by less than the margin a term must clear to be added at all: the first in rank kept
    got, amb, took, _ = _rivals(first, 0.0058, min_gain=0.1)
    assert got is first and took == "" and amb is None


def test_a_rival_the_data_cannot_tell_apart_is_named_and_the_first_in_rank_kept():
    first = _trial(CLEARANCE, 0.08, 0.0063)
    got, amb, took, _ = _rivals(first, 0.0062)      # within 2 % and no blocks: not apart
    assert got is first and took == "" and set(amb.kinds) == {"clearance", "cubic_stiffness"}
    got, amb, took, _ = _rivals(first, 0.0070)      # worse: the first kept, nothing named
    assert got is first and took == "" and amb is None
