"""nifo_core.fleet: tree reduction and strut health (pure, no Dask)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nifo_core.errors import ConfigError
from nifo_core.fleet import (Estimate, HealthSettings, assess_health, reduction_plan, robust_z, standard_error,
                             tree_reduce)


# --------------------------------------------------------------------------------------------- reduction
def test_reduction_plan_of_five_items_is_three_levels_of_pairs():
    assert reduction_plan(5) == [[(0, 1), (2, 3), (4,)], [(0, 1), (2,)], [(0, 1)]]
    assert reduction_plan(1) == []
    assert reduction_plan(9, fanout=3) == [[(0, 1, 2), (3, 4, 5), (6, 7, 8)], [(0, 1, 2)]]


@given(n=st.integers(1, 300), fanout=st.integers(2, 9))
def test_reduction_plan_uses_every_item_once_per_level_and_has_log_depth(n, fanout):
    levels = reduction_plan(n, fanout=fanout)
    width = n
    for level in levels:
        assert sorted(i for ix in level for i in ix) == list(range(width))
        assert all(1 <= len(ix) <= fanout for ix in level)
        width = len(level)
    assert width == 1
    assert len(levels) == (0 if n == 1 else int(np.ceil(np.log(n) / np.log(fanout) - 1e-12)))


@settings(max_examples=50)
@given(st.lists(st.integers(-10**6, 10**6), min_size=1, max_size=60), st.integers(2, 5))
def test_tree_reduce_equals_the_sequential_fold_for_an_associative_merge(xs, fanout):
    assert tree_reduce(xs, lambda a, b: a + b, fanout=fanout) == sum(xs)
    # order is kept: string concatenation is associative but not commutative
    assert tree_reduce([str(x) for x in xs], lambda a, b: a + b, fanout=fanout) == "".join(map(str, xs))


def test_reduction_rejects_bad_arguments_with_the_value():
    with pytest.raises(ConfigError, match="n=0"):
        reduction_plan(0)
    with pytest.raises(ConfigError, match="fanout=1"):
        reduction_plan(4, fanout=1)
    with pytest.raises(ConfigError, match="no items"):
        tree_reduce([], lambda a, b: a)


# --------------------------------------------------------------------------------------------- statistics
def test_standard_error_is_std_over_root_n_and_nan_from_one_value():
    assert standard_error([1.0, 2.0, 3.0, 4.0]) == pytest.approx(np.std([1, 2, 3, 4], ddof=1) / 2)
    assert np.isnan(standard_error([5.0]))
    assert np.isnan(standard_error([5.0, np.nan]))


def test_robust_z_of_normal_data_has_unit_scale_and_finds_a_planted_outlier():
    rng = np.random.default_rng(0)
    x = rng.normal(10.0, 2.0, 4000)
    med, scale, z = robust_z(x)
    assert med == pytest.approx(10.0, abs=0.1)
    assert scale == pytest.approx(2.0, rel=0.05)
    x[7] = 10.0 + 8 * 2.0
    _, _, z = robust_z(x)
    assert z[7] == pytest.approx(8.0, rel=0.08)


def test_robust_z_scale_is_not_inflated_by_a_minority_of_outliers():
    base = np.linspace(0.9, 1.1, 8)
    healthy_sd = np.std(base, ddof=1)
    _, scale, z = robust_z(np.r_[base, 0.7, 1.5])
    assert scale == pytest.approx(healthy_sd / 0.9546, rel=0.02)
    assert z[-2] < -3.5 and z[-1] > 3.5
    assert np.all(np.abs(z[:-2]) < 2)


def test_robust_z_ignores_nan_and_inputs_are_not_modified():
    x = np.array([1.0, np.nan, 1.1, 0.9, 1.05, 0.95])
    before = x.copy()
    _, _, z = robust_z(x)
    assert np.isnan(z[1]) and np.all(np.isfinite(np.delete(z, 1)))
    np.testing.assert_array_equal(x, before)


# --------------------------------------------------------------------------------------------- health
def _fleet(values, *, n=5, dur=300.0, se=0.005):
    return {f"v{i}": {"c": Estimate(v, se, n, dur)} for i, v in enumerate(values)}


def test_a_worn_damper_is_flagged_with_evidence_and_healthy_ones_are_not():
    vals = list(np.linspace(0.92, 1.08, 11)) + [0.70]
    h = assess_health(_fleet(vals), units={"c": "N·s/m"})
    flagged = [g for g, r in h.items() if r.flagged]
    assert flagged == ["v11"]
    (ev,) = h["v11"].evidence
    assert "c = 0.7 N·s/m is 0.70× the fleet median" in ev and "robust z -" in ev


def test_never_flag_from_too_little_data():
    vals = list(np.linspace(0.92, 1.08, 11)) + [0.70]
    few_bags = _fleet(vals)
    few_bags["v11"] = {"c": Estimate(0.70, float("nan"), 1, 300.0)}
    h = assess_health(few_bags)
    assert not h["v11"].flagged and not h["v11"].assessed
    assert "1 record(s)" in h["v11"].reason
    short = _fleet(vals)
    short["v11"] = {"c": Estimate(0.70, 0.005, 3, 20.0)}
    h = assess_health(short)
    assert not h["v11"].flagged and "20 s of data" in h["v11"].reason


def test_a_deviation_the_group_cannot_resolve_is_not_flagged():
    vals = list(np.linspace(0.92, 1.08, 11)) + [0.70]
    est = _fleet(vals)
    est["v11"] = {"c": Estimate(0.70, 0.2, 5, 300.0)}   # ±2 SE = ±0.4 covers the 0.3 deviation
    h = assess_health(est)
    assert not h["v11"].flagged
    assert "uncertainty covers the deviation" in h["v11"].coefficients[0].note


def test_a_fleet_too_small_to_compare_flags_nobody():
    h = assess_health(_fleet([1.0, 1.01, 0.99, 0.5]), settings=HealthSettings(min_groups=5))
    assert not any(r.flagged for r in h.values())
    assert all("at least 5 make a fleet" in r.coefficients[0].note for r in h.values())


def test_health_settings_reject_meaningless_limits():
    with pytest.raises(ConfigError, match="min_records=1"):
        HealthSettings(min_records=1)
    with pytest.raises(ConfigError, match="z_limit"):
        HealthSettings(z_limit=0)


def test_interval_uses_student_t_so_two_records_give_a_wide_interval():
    from nifo_core.fleet import interval_halfwidth

    assert interval_halfwidth(1.0, 2) == pytest.approx(12.706, rel=1e-3)
    assert interval_halfwidth(1.0, 1000) == pytest.approx(1.962, rel=1e-3)
    assert np.isnan(interval_halfwidth(1.0, 1))
