"""characterize says what these data could not have shown (issue 28): the detection limit of a kind it did not
suggest is the size at which it would have been suggested — an effect added at 3× the limit is found, at 1/3 not."""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_characterize_sets import simulate_case  # noqa: E402

from nifo_core.characterize.automatic import characterize_restoring  # noqa: E402
from nifo_core.characterize.data import RegressionData  # noqa: E402
from nifo_core.characterize.restoring import restoring_force, suggest_band  # noqa: E402
from nifo_core.characterize.result import Thresholds  # noqa: E402
from nifo_core.characterize.score import detection_limit  # noqa: E402
from nifo_core.kinds.describing import Term  # noqa: E402


@pytest.fixture(scope="module")
def knee_data():
    recs, m2, _ = simulate_case("knee_only", 2, duration=60.0)
    band = suggest_band(recs[0]).band
    return [restoring_force(r, band=band) for r in recs], m2


def test_an_effect_at_three_times_the_detection_limit_is_found_and_at_a_third_is_not(knee_data):
    rfs, m2 = knee_data
    ch = characterize_restoring(rfs, m2_kg=m2)
    assert [c.kind for c in ch.suggested] == ["velocity_deadzone"]
    note = next(n for n in ch.notes if n.startswith("could not have been seen"))
    assert "cubic_stiffness with |coefficient| below" in note
    data = RegressionData(rfs, n_groups=4, body_stiffness=False)
    base = [data.regressor(ch.suggested[0].term)]
    cubic = Term("cubic_stiffness")
    th, peak = detection_limit(data, base, cubic, thresholds=Thresholds(), n_grid=1)
    assert np.isfinite(th) and th > 0 and peak > 0
    found = {}
    for factor in (3.0, 1.0 / 3.0):   # the truth plus θ·z³ per unit mass (y = -ẍ2: the force on the body)
        more = [replace(rf, force=rf.force + factor * th * cubic.evaluate(rf.z, rf.zdot)) for rf in rfs]
        found[factor] = "cubic_stiffness" in {c.kind for c in characterize_restoring(more, m2_kg=m2).suggested}
    print("cubic detection limit", th * m2, "N/m³; found at 3x / at 1/3:", found)
    assert found == {3.0: True, 1.0 / 3.0: False}


def test_a_ranking_on_a_grid_search_built_before_is_the_ranking_built_anew(knee_data):
    """The loop builds the candidates' grid once and ranks every round on it (rank_beyond(search=)): the same
    candidates, numbers to the bit; a grid built on other data, kinds or grid points is refused."""
    from nifo_core.characterize.automatic import grid_search, rank_beyond
    from nifo_core.errors import ConfigError

    rfs, m2 = knee_data
    kinds = ("velocity_deadzone", "coulomb", "cubic_stiffness")
    search = grid_search(rfs, kinds=kinds, grid_points=12)
    for declared in ((), (Term("velocity_deadzone", {"knee": 0.03}),)):   # two rounds on the one search
        anew = rank_beyond(rfs, declared, m2_kg=m2, kinds=kinds, grid_points=12)
        kept = rank_beyond(rfs, declared, m2_kg=m2, kinds=kinds, grid_points=12, search=search)
        assert [c.term for c in kept] == [c.term for c in anew]
        assert [(c.err, c.theta, c.p_value) for c in kept] == [(c.err, c.theta, c.p_value) for c in anew]
    for other in (dict(kinds=kinds[:2], grid_points=12), dict(kinds=kinds, grid_points=24)):
        with pytest.raises(ConfigError, match="other data, kinds"):
            rank_beyond(rfs, (), m2_kg=m2, search=search, **other)
    with pytest.raises(ConfigError, match="other data, kinds"):
        rank_beyond(list(reversed(rfs)), (), m2_kg=m2, kinds=kinds, grid_points=12, search=search)


def test_one_kinds_best_scored_on_its_columns_alone_is_its_best_among_all(knee_data):
    """A set search re-places one kind at a time on that kind's columns alone (GridSearch.best_given, each kind's
    columns stacked together): the same grid point as scoring every column, given nothing and given a term."""
    from nifo_core.characterize.automatic import grid_search

    rfs, _ = knee_data
    search = grid_search(rfs, kinds=("velocity_deadzone", "coulomb", "cubic_stiffness", "clearance"), grid_points=12)
    assert [t.kind for t in search.terms] == sorted((t.kind for t in search.terms), key=list(search.grids).index)
    none = np.empty((search.r0.size, 0))
    knee = search.best_given("velocity_deadzone", none, search.r0)
    for extra, r in ((none, search.r0), search.basis([search.data.regressor(search.terms[knee])])):
        e, sign = search.err(extra, r)
        for k in search.grids:
            assert search.best_given(k, extra, r) == search.best_of(k, e, sign)
            assert search.terms[search.best_given(k, extra, r)].kind == k
