"""Ambiguity is a verdict, and a declared term is never silently re-tuned into another physics (issue 54).

The pieces, on synthetic inputs whose answer is known: the paired comparison of two models' held-out predictions,
the decision between adding a candidate and re-placing a term of its kind, and what became of a declared term.
"""

from __future__ import annotations

import numpy as np

from nifo_core.kinds.describing import Term
from nifo_core.loop.ambiguity import T_DISTINCT, Comparison, compare
from nifo_core.loop.gates import Alternative, Judgement, judge_alternatives
from nifo_core.loop.results import DeclaredTerm
from nifo_core.loop.round_results import Errors
from nifo_core.loop.settings import RETUNE_FACTOR, LoopSettings
from nifo_core.predict.heldout import split_records
from nifo_core.signal.record import Record

KNEE = Term("velocity_deadzone", {"knee": 0.03})
QUAD = Term("quadratic_damping")
S = LoopSettings()


def _held(seconds: float = 300.0, fs: float = 200.0):
    rng = np.random.default_rng(3)
    y = np.convolve(rng.standard_normal(int(seconds * fs)), np.ones(8) / 8, mode="same")
    rec = Record(fs, 0.1 * rng.standard_normal(y.size), y, source="synthetic")
    return split_records([rec], band_hz=(1.0, 30.0)), y, rng


def test_the_paired_comparison_tells_a_better_model_from_an_equal_one():
    held, y, rng = _held()
    k = held.split[0]
    same_a = y + 0.05 * rng.standard_normal(y.size)
    same_b = y + 0.05 * rng.standard_normal(y.size)
    worse = y + 0.08 * rng.standard_normal(y.size)
    equal = compare(held, [same_a], [same_b])
    apart = compare(held, [same_a], [worse])
    print(f"\nequal noise: NMSE {equal.nmse_a:.3f} / {equal.nmse_b:.3f} %, t {equal.t:+.2f} over {equal.blocks} blocks; "
          f"1.6× the noise: {apart.nmse_a:.3f} / {apart.nmse_b:.3f} %, t {apart.t:+.2f}")
    assert equal.blocks == (y.size - k) // int(4.0 * 200.0)
    assert abs(equal.t) < T_DISTINCT and not equal.apart()
    assert apart.t > T_DISTINCT and apart.better("a") and not apart.better("b")
    assert apart.nmse_b > 2 * apart.nmse_a      # the metric's own numbers: band NMSE of the held-out part


_N = 24000


def _three_levels(seed: int, errors):
    """Three 120 s records at 200 Hz (band-limited noise) split into fit and held-out parts, and two models'
    predictions of each: ``errors(j, y, e, e2)`` → (A's, B's) from the output ``y`` and two noises."""
    rng = np.random.default_rng(seed)
    smooth = lambda: np.convolve(rng.standard_normal(_N), np.ones(8) / 8, mode="same")  # noqa: E731
    recs, a, b = [], [], []
    for j in range(3):
        y = smooth()
        recs.append(Record(200.0, 0.1 * rng.standard_normal(_N), y, source=f"level {j}"))
        pa, pb = errors(j, y, smooth(), smooth())
        a.append(pa)
        b.append(pb)
    return split_records(recs, band_hz=(1.0, 30.0)), a, b


def test_a_gain_every_block_of_two_records_shows_is_not_lost_in_a_third_records_heavy_tail():
    """Own draw of issue 54's fleet (seed 5411, #41: a compression stop and a cubic hidden beside a declared knee):
    with the stop in, the cubic takes the held-out prediction 4.57 % → 0.277 %, a hundredfold in every block of the
    two lower records, but the highest record's blocks (12.6 % → 0.79 %, a few impacts carrying most of it) made
    the pooled paired t +1.3 and the cubic was refused. Each record's blocks are also judged on their own scatter
    and the records' scores combined (z): the same shape here, where the pooled t alone refuses."""
    burst = np.zeros(_N)
    burst[-2000:-1400] = 3.0 * np.hanning(600)

    def errors(j, y, e, e2):
        if j < 2:                                   # a hundredfold in every block
            return y + 0.01 * e, y + 0.1 * e
        return y + 0.3 * e + 0.2 * burst * e2, y + 0.3 * e + burst * e2   # B misses a burst, A nearly not

    held, a, b = _three_levels(11, errors)
    c = compare(held, a, b)
    print(f"\nNMSE {c.nmse_a:.3g} / {c.nmse_b:.3g} %: pooled paired t {c.t:+.2f}, the records' combined score "
          f"{c.z:+.2f} over {c.blocks} blocks")
    assert c.t < T_DISTINCT < c.z and c.better("a")
    # the burst alone (the two lower records equal) does not decide
    calm = compare(held, [b[0], b[1], a[2]], [b[0], b[1], b[2]])
    assert calm.nmse_a < calm.nmse_b and not calm.better("a"), calm


def test_a_gain_one_record_carries_is_kept_though_the_others_lose_a_little():
    """The other way round (held-out case #112 of issue 54's fleet: a true knee lowered the held-out prediction
    0.0204 → 0.016 %, the records' combined score −4.9): one record gains much in every block, two lose a little in
    every block. The metric falls beyond its pooled scatter, and that is enough."""
    held, a, b = _three_levels(12, lambda j, y, e, _: (y + (0.05 if j == 2 else 0.105) * e,
                                                       y + (0.2 if j == 2 else 0.1) * e))
    c = compare(held, a, b)
    print(f"\nNMSE {c.nmse_a:.3g} / {c.nmse_b:.3g} %: pooled paired t {c.t:+.2f}, records' z {c.z:+.2f}")
    assert c.z < -T_DISTINCT < T_DISTINCT < c.t and c.better("a") and not c.better("b")


def _errors(terms, theta, pct) -> Errors:
    return Errors(terms=tuple(terms), theta_per_kg=tuple(theta), k_per_kg=75.0, c_per_kg=4.5, equation_nmse_pct=1.0,
                  equation_nmse_fit_pct=1.0, prediction_nmse_pct=pct, prediction_nmse_per_record_pct=(pct,),
                  band_residual_db={}, residual_of="prediction", transmissibility_error_pct=())


def _alt(comp: Comparison, keeps: bool, term: Term = Term("velocity_deadzone", {"knee": 0.227})) -> Alternative:
    return Alternative(0, term, _errors([term], [3.5], comp.nmse_b), comp, keeps, "" if keeps else "sign flipped")


def _judged(*args, **kw):
    j = judge_alternatives(*args, **kw)
    return j.failed, j.ties, j.instead


def test_adding_a_term_or_re_placing_a_declared_one_is_decided_by_the_held_out_data_and_the_declaration():
    better = Comparison(0.30, 0.40, 6.0, 60)          # the candidate's model predicts clearly better
    worse = Comparison(0.40, 0.30, -6.0, 60)          # the re-placed term predicts clearly better
    tie = Comparison(0.30, 0.31, 0.4, 60)             # these data cannot tell them apart
    # the candidate wins: added, nothing named
    assert judge_alternatives([KNEE], QUAD, [_alt(better, keeps=False)], S) == Judgement((), (), ())
    # the re-placed knee predicts better: taken instead (and said to change the declared term when it does)
    failed, ties, instead = _judged([KNEE], QUAD, [_alt(worse, keeps=False)], S)
    assert len(instead) == 1 and "better" in failed[0] and "changes the declared term" in failed[0]
    # cannot tell apart, the re-placed knee changes the declared physics: the candidate is added, the tie named
    failed, ties, instead = _judged([KNEE], QUAD, [_alt(tie, keeps=False)], S)
    assert not failed and len(ties) == 1 and not instead
    # ... a re-tune within the stated factor keeps it: the re-tune is taken (no term added), the tie named
    failed, ties, instead = _judged([KNEE], QUAD, [_alt(tie, keeps=True, term=Term(
        "velocity_deadzone", {"knee": 0.045}))], S)
    assert len(failed) == 1 and len(ties) == 1 and len(instead) == 1
    # ... neither keeps it: fewer terms
    failed, ties, instead = _judged([KNEE], QUAD, [_alt(tie, keeps=False)], S, candidate_keeps=False)
    assert len(failed) == 1 and len(instead) == 1
    # a second knee a few per cent from the first is the same feature re-placed, however it predicts
    second = Term("velocity_deadzone", {"knee": 0.035})
    failed, ties, instead = _judged([KNEE], second, [_alt(better, keeps=True, term=second)], S)
    assert "the same feature re-placed" in failed[0] and len(instead) == 1
    # ... two knees a factor 3 apart are two valve stages
    stage = Term("velocity_deadzone", {"knee": 0.1})
    assert judge_alternatives([KNEE], stage, [_alt(better, keeps=True, term=stage)], S) == Judgement((), (), ())


def test_a_re_placed_term_that_predicts_no_better_than_the_model_is_no_rival():
    """benchmarks/bench_loop.py's records (a hidden friction beside a declared knee): the knee re-placed predicted
    2.67 % against the model's 1.08 % and the friction's 0.431 %, a tie by the paired t (+1.2, heavy-tailed
    blocks); the friction was refused for it, the re-placed knee not taken either (worse than the model), and the
    loop said nothing was missing. A rival must itself predict better than the model without either."""
    tie = Comparison(0.431, 2.67, 1.2, 100)                  # the candidate against the re-placed knee
    retuned = Term("velocity_deadzone", {"knee": 0.0257})
    worse_than_model = Comparison(2.67, 1.08, -3.0, 100)    # the re-placed knee against the model without either
    alt = Alternative(0, retuned, _errors([retuned], [-2.0], 2.67), tie, True, against_model=worse_than_model)
    assert not alt.explains
    assert judge_alternatives([KNEE], Term("coulomb", {"eps": 0.0073}), [alt], S) == Judgement((), (), ())
    # the same re-placed knee, had it predicted better than the model, is a rival: the tie keeps the declared term
    helps = Comparison(0.9, 1.08, 3.0, 100)
    alt = Alternative(0, retuned, _errors([retuned], [-2.0], 0.9), tie, True, against_model=helps)
    failed, ties, instead = _judged([KNEE], Term("coulomb", {"eps": 0.0073}), [alt], S)
    assert alt.explains and len(failed) == 1 and len(ties) == 1 and len(instead) == 1


def test_a_declared_term_that_changed_its_meaning_says_so():
    same = DeclaredTerm(KNEE, -2.19, Term("velocity_deadzone", {"knee": 0.036}), -2.0, 320.0)
    flipped = DeclaredTerm(KNEE, -2.19, Term("velocity_deadzone", {"knee": 0.227}), 3.5, 320.0)
    moved = DeclaredTerm(KNEE, -2.19, Term("velocity_deadzone", {"knee": 0.03 * 1.01 * RETUNE_FACTOR}), -2.0, 320.0)
    assert not same.changed_meaning and "within the stated factor" in same.text()
    assert flipped.sign_flipped and flipped.changed_meaning
    assert "changed its meaning" in flipped.text() and "changed sign, -700.8 N·s/m when the declared model is " \
        "fitted alone, 1120 N·s/m in the final model" in flipped.text()
    assert "its knee moved beyond the stated factor 2: 0.03 → 0.227 (× 7.57)" in flipped.text()
    assert moved.changed_meaning and not moved.sign_flipped and "beyond the stated factor" in moved.text()
    assert flipped.to_dict()["changed_meaning"] and flipped.to_dict()["key_param_factor"] > 7
