"""F-16 ground vibration test (Noël & Schoukens 2017, nonlinearbenchmark.org): prediction of every level.

What holds and is asserted (the study with every option is ``tools/f16_predict.py``,
docs/f16_predict.md): identified on levels 3/5/7, the model — linear or with
a clearance term — is written as model.json, read back, and predicts every
level (1, 3, 5, 7) from rest without diverging (the NMSE of the
period-averaged 2-15 Hz steady state stays bounded), the linear model within
2 %. That the nonlinear model beats the linear one at every level is asserted where it holds
(identified on levels spanning 1-7: backlash on 1/5/7, two plays on 1/5/7 and 1/3/7), not on 3/5/7 (see the doc);
on 3/5/7 the plays through feedback paths do, asserted in test_feedback_paths.py.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

import f16_predict  # noqa: E402

from nifo.io.results import read_model  # noqa: E402


def test_score_is_zero_for_a_perfect_prediction_and_one_hundred_for_none():
    rng = np.random.default_rng(0)
    y = np.tile(rng.standard_normal(f16_predict.PERIOD), 3)
    assert f16_predict.score(y, y, 400.0) == 0.0
    assert f16_predict.score(y, np.zeros_like(y), 400.0) == pytest.approx(100.0)


def test_the_choice_uses_the_identification_levels_alone_and_keeps_linear_when_nothing_beats_it_there():
    def row(form, source, nmse, ids=(3, 5, 7)):
        return {"set": "s", "identified_on": list(ids), "linear_part": "auto", "form": form, "source": source,
                "nmse": dict(zip(f16_predict.LEVELS, nmse))}
    lib, joint_lin = row("linear", "static", [1, 1, 1, 1]), row("linear", "joint", [0.5, 0.5, 0.5, 0.5])
    rows = [lib, joint_lin,
            row("a", "static", [0.1, 0.9, 0.9, 0.9]),          # margin 1.11 against the library's linear
            row("b", "static", [5.0, 0.6, 0.7, 0.8]),          # margin 1.25; loses the held-out level 1
            row("c", "joint", [0.3, 0.45, 0.45, 0.45]),        # margin 1.11 against the linear model of its procedure
            row("d", "static", [0.1, 0.1, 0.1, 1.2])]          # loses level 7: does not qualify
    (sel,) = f16_predict.select(rows)
    assert (sel["form"], sel["margin"]) == ("b", pytest.approx(1.25))
    assert sel["held_out_better"] == {1: False} and not sel["every_level_better"]
    (sel,) = f16_predict.select(rows, strict=True)     # against the better linear model at each level: c alone
    assert sel["form"] == "c" and sel["baseline"] == {lv: 0.5 for lv in f16_predict.LEVELS}
    (sel,) = f16_predict.select([lib, joint_lin, rows[4], rows[5]])
    assert sel["form"] == "c" and sel["baseline"] == joint_lin["nmse"] and sel["every_level_better"]
    (sel,) = f16_predict.select([lib, joint_lin, rows[5]])
    assert (sel["form"], sel["source"]) == ("linear", "joint") and sel["held_out_better"] == {1: False}
    assert sel["sweep_better_at_every_level"] is None            # no sweep scored: no verdict, not "no"


def test_the_sine_sweep_verdict_compares_each_level_with_the_baseline_and_plays_no_part_in_the_choice():
    def row(form, source, nmse, sweep):
        return {"set": "s", "identified_on": [3, 5, 7], "linear_part": "auto", "form": form, "source": source,
                "nmse": dict(zip(f16_predict.LEVELS, nmse)), "sweep": dict(zip(f16_predict.LEVELS, sweep))}
    lin = row("linear", "static", [1, 1, 1, 1], [1, 1, 1, 1])
    wide = row("wide", "static", [0.9, 0.5, 0.5, 0.5], [2.0, 0.9, 0.9, 0.9])     # multisine margin 2, sweep L1 lost
    narrow = row("narrow", "static", [0.9, 0.8, 0.8, 0.8], [0.9, 0.9, 0.9, 0.9])
    (sel,) = f16_predict.select([lin, wide, narrow])
    assert sel["form"] == "wide" and sel["sweep_better_at_every_level"] is False
    assert sel["sweep"] == wide["sweep"]
    v = {r["form"]: r for r in f16_predict.verdicts([lin, wide, narrow])}
    assert v["narrow"]["sweep_better_at_every_level"] and not v["wide"]["sweep_better_at_every_level"]
    assert v["wide"]["sweep_ratio"][1] == pytest.approx(0.5)
    lin_old = {**lin, "sweep": {}}                                  # a linear row from a run without sweeps
    (sel,) = f16_predict.select([lin_old, wide, narrow], strict=True)
    assert sel["sweep_better_at_every_level"] is None                 # no floor: no verdict, not "yes"


@pytest.mark.slow
def test_identified_on_3_5_7_predicts_every_level_without_divergence(shared_data, tmp_path):
    rows = f16_predict.study(shared_data / "f16", tmp_path, sets={"3/5/7": (3, 5, 7)},
                             forms={"clearance 0.02 mm": f16_predict.FORMS["clearance 0.02 mm"]},
                             linear_parts={"auto": None}, log=print)
    assert [r["form"] for r in rows] == ["linear", "clearance 0.02 mm"]
    for r in rows:
        assert not r["errors"], r["errors"]
        model, _ = read_model(r["model_json"])                       # model.json written every time
        assert model.linear.stable
        assert sorted(r["nmse"]) == [1, 3, 5, 7]
        assert all(np.isfinite(v) and v < 100.0 for v in r["nmse"].values()), r["nmse"]   # bounded: no divergence
        assert sorted(r["sweep"]) == [1, 3, 5, 7]                    # the sine sweeps: a second excitation
        assert all(np.isfinite(v) and v < 100.0 for v in r["sweep"].values()), r["sweep"]
    linear = rows[0]["nmse"]
    assert all(v < 2.0 for v in linear.values()), linear
    assert all(v < 2.0 for v in rows[0]["sweep"].values()), rows[0]["sweep"]    # 0.48-0.89 % measured


@pytest.mark.slow
def test_backlash_identified_on_1_5_7_beats_linear_at_every_level(shared_data):
    """The one configuration of the study where the nonlinear model wins everywhere (held-out level 3 included).

    Margins are 3-23 % of the linear NMSE and depend on the rational linear part
    the library selects (docs/f16_predict.md): a change there shows up here.
    """
    rows = f16_predict.study(shared_data / "f16", None, sets={"1/5/7": (1, 5, 7)},
                             forms={"backlash 0.14 mm": f16_predict.FORMS["backlash 0.14 mm"]},
                             linear_parts={"auto": None}, log=print)
    linear, play = rows[0]["nmse"], rows[1]["nmse"]
    assert all(play[lv] < linear[lv] for lv in (1, 3, 5, 7)), (play, linear)


@pytest.mark.slow
def test_two_plays_beat_linear_at_every_level_identified_on_a_set_spanning_the_levels(shared_data):
    """Two plays (0.07 and 0.28 mm, half and twice the characterized play: a discrete Iwan model).

    Identified on 1/5/7 (NIFO) and on 1/3/7 (refined), below the linear model of the same
    set at every level, the held-out one included (docs/f16_predict.md, "Several plays":
    1.03-2.16× and 1.35-1.50×), and the refined one also on the sine sweeps, a second
    excitation ("A second excitation"). Not on 3/5/7 or 1/3/5 (measured there, not asserted).
    """
    plays = {"plays 0.07/0.28 mm": f16_predict.PLAYS["plays 0.07/0.28 mm"]}
    rows = f16_predict.study(shared_data / "f16", None, sets={"1/5/7": (1, 5, 7)}, forms=plays,
                             linear_parts={"auto": None}, log=print)
    linear, nl = rows[0]["nmse"], rows[1]["nmse"]
    assert all(nl[lv] < linear[lv] for lv in (1, 3, 5, 7)), (nl, linear)
    rows = f16_predict.study(shared_data / "f16", None, sets={"1/3/7": (1, 3, 7)}, forms=plays,
                             linear_parts={"auto": None}, refine_periods=4, log=print)
    linear, refined = rows[0]["nmse"], rows[2]["nmse"]
    assert rows[2]["source"] == "static refined"
    assert all(refined[lv] < 0.9 * linear[lv] for lv in (1, 3, 5, 7)), (refined, linear)
    # the second excitation, used for nothing else: the sine sweeps at every level, 1.40-1.67x measured
    linear, refined = rows[0]["sweep"], rows[2]["sweep"]
    assert all(refined[lv] < 0.9 * linear[lv] for lv in (1, 3, 5, 7)), (refined, linear)
