"""The loop on real data: F-16 ground vibration test (Noël & Schoukens 2017), skipped without the data.

Asserts what docs/f16_loop.md claims, with margin: from a linear model, across
levels 1, 3, 5, 7 (full multisines, periods 2-9, first 2/3 fit / last 1/3 held
out), a play (backlash) of ≈ 0.13 mm is found, stable across the levels that
exercise it; level 1 alone adds nothing; levels 5 and 7 alone still find the play.
"""

from __future__ import annotations

import importlib.util

import pytest

from tests.conftest import REPO


@pytest.fixture(scope="module")
def f16(shared_data):
    d = shared_data / "f16"
    if not all((d / f"F16Data_FullMSine_Level{lv}.mat").is_file() for lv in (1, 3, 5, 7)):
        pytest.skip(f"F-16 full multisine files not found in {d}")
    spec = importlib.util.spec_from_file_location("f16_loop", REPO / "tools" / "f16_loop.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.run_loop(mod.load_levels(d))


def _found(res):
    """Effects found: added, then those found but not confirmed by the held-out prediction."""
    return [*res.added, *res.unconfirmed]


def test_f16_loop_finds_a_play_of_about_a_tenth_of_a_millimetre(f16):
    found = [c for c in _found(f16) if c.kind == "backlash"]
    assert found, f16.report()
    assert 0.08e-3 < found[0].term.params["deadband"] < 0.2e-3
    assert found[0].p_value < 1e-6 and found[0].spread < 0.3
    assert len(f16.added) <= 2


def test_f16_loop_reports_the_prediction_on_both_sides_and_the_equation_error_beside_it(f16):
    # the one-mass body is not physical here: the held-out prediction comes from NIFO's static fit with a
    # rational linear part, the same predictor before and after; the equation error is reported beside it
    assert f16.initial.prediction_nmse_pct is not None and f16.final.prediction_nmse_pct is not None
    assert f16.final.prediction_nmse_pct <= f16.initial.prediction_nmse_pct
    assert f16.final.equation_nmse_pct <= f16.initial.equation_nmse_pct
    assert 25 < f16.initial.equation_nmse_pct < 55  # the one-mass body equation leaves a lot
    assert f16.model is not None and f16.model.linear.kind == "rational"
    assert "not physical" in f16.model.provenance["why"]


# --------------------------------------------------------------------------------------------
# one level at a time: the practically linear level adds nothing, the high levels still show the play
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def f16_tool(shared_data):
    d = shared_data / "f16"
    if not all((d / f"F16Data_FullMSine_Level{lv}.mat").is_file() for lv in (1, 5, 7)):
        pytest.skip(f"F-16 full multisine files not found in {d}")
    spec = importlib.util.spec_from_file_location("f16_loop", REPO / "tools" / "f16_loop.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod, d


@pytest.mark.slow
def test_f16_level1_alone_adds_nothing_though_a_play_is_significant(f16_tool):
    # the one-mass body equation is mis-specified on this multi-mode structure: a tiny play passes the
    # F-test but makes the 20-30 Hz held-out residual much worse; the held-out gate must refuse it
    mod, d = f16_tool
    res = mod.run_loop(mod.load_levels(d, levels=(1,)), analysis_band_hz=(2.0, 15.0))  # as in issue 13
    assert res.added == (), res.report()
    assert res.nothing_missing
    trial = res.rounds[0].trials[0] if res.rounds[0].trials else None
    assert trial is not None and any("equation error grows by more than" in f for f in trial.failed), res.report()
    assert res.unconfirmed == ()


@pytest.mark.slow
@pytest.mark.parametrize("level", [5, 7])
def test_f16_high_levels_alone_still_show_the_play(f16_tool, level):
    mod, d = f16_tool
    res = mod.run_loop(mod.load_levels(d, levels=(level,)))
    found = _found(res)
    assert found and found[0].kind == "backlash", res.report()
    assert 0.08e-3 < found[0].term.params["deadband"] < 0.2e-3
    assert not res.nothing_missing  # found: never "nothing is missing", even when prediction does not confirm it
