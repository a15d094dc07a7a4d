"""The main job, hands off, on real data: F-16 ground vibration test (Noël & Schoukens 2017; skipped without the data).

Only the columns are given: the period, the transient, the bands and the blocks are read off the data
(nifo.settings), the linear part and the terms are chosen by held-out prediction (nifo_core.loop.closing). Asserts the
acceptance of the issue "Real data, hands off": from a linear model on levels 3/5/7 ``nifo loop`` adds a play and
its held-out prediction improves; on level 1 alone (practically linear) it adds nothing; and ``nifo run`` on 3/5/7
gives a final model that predicts the held-out level 1 better than the linear model of the same levels, on the
multisine and on the sine sweep (a second excitation, used for nothing else). The three other leave-one-out sets:
``benchmarks/bench_hands_off.py``.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest

from nifo.cli import main

from conftest import built_once

COLUMNS = ["--columns", "spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"]


@pytest.fixture(scope="module")
def f16(shared_data):
    d = shared_data / "f16"
    if not all((d / f"F16Data_{e}_Level{lv}.mat").is_file() for lv in (1, 3, 5, 7) for e in ("FullMSine", "SineSw")):
        pytest.skip(f"F-16 files not found in {d}")
    return d


def _quietly(argv) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return main(["-q", *map(str, argv)])


@pytest.mark.slow
def test_nifo_loop_from_linear_on_levels_3_5_7_adds_a_play_and_the_held_out_prediction_improves(f16, tmp_path_factory):
    """The loop step of ``nifo run`` on 3/5/7 (:func:`f16_run_once`, built once per test run): it is ``nifo loop``
    from the linear model, with the settings the run read off the data. Measured (2026-11-27): ``nifo loop`` on
    the same three files alone writes the same loop.json, every number, apart from the settings' provenance
    ("command line" there, "data" here). ``nifo loop`` reading its own settings off the F-16 data is tested by
    :func:`test_nifo_loop_on_level_1_alone_adds_nothing`."""
    doc = json.loads((f16_run_once(tmp_path_factory, f16) / "loop" / "loop.json").read_text())
    chosen = doc["settings_chosen"]["choices"]
    assert chosen["period_samples"]["value"] == 8192 and chosen["skip_periods"]["value"] == 1
    lo, hi = chosen["analysis_band_hz"]["value"]
    assert 1.9 < lo < 2.2 and 14.8 < hi < 15.2         # the multisine's 2-15 Hz, read off the data
    kinds = [e["kind"] for e in doc["effects_added"]]
    assert "backlash" in kinds, doc["report"]
    before, after = doc["errors_before"]["prediction_nmse_pct"], doc["errors_after"]["prediction_nmse_pct"]
    print(f"\nF-16 3/5/7 hands off: added {[e['label'] for e in doc['effects_added']]}; held-out prediction NMSE "
          f"{before:.4f} % → {after:.4f} %")
    assert after < 0.95 * before
    assert doc["final_heldout_prediction_nmse_pct"] < doc["linear_heldout_prediction_nmse_pct"]


@pytest.mark.slow
def test_nifo_loop_on_level_1_alone_adds_nothing(f16, tmp_path):
    out = tmp_path / "loop1"
    assert _quietly(["loop", f16 / "F16Data_FullMSine_Level1.mat", *COLUMNS, "--out", out]) == 0
    doc = json.loads((out / "loop.json").read_text())
    assert doc["effects_added"] == [], doc["report"]


#: what the F-16 data are in the report (passed as --system)
SYSTEM = "F-16 wing-payload interface (ground vibration test) [m/s²]"


def f16_run_once(tmp_path_factory, f16) -> Path:
    """``nifo run`` on the multisine levels 3/5/7 (hands off: only the columns and what the system is), built once
    per test run and shared with test_report_browser.py; its output directory."""
    def build(base: Path) -> None:
        assert _quietly(["run", *[f16 / f"F16Data_FullMSine_Level{k}.mat" for k in (3, 5, 7)], *COLUMNS,
                         "--system", SYSTEM, "--out", base / "out", "--no-recording"]) == 0

    return built_once(tmp_path_factory, "f16_run_357", build) / "out"


@pytest.mark.slow
def test_nifo_run_on_levels_3_5_7_predicts_the_held_out_level_1_better_than_linear_on_both_excitations(
        f16, tmp_path, tmp_path_factory):
    out = f16_run_once(tmp_path_factory, f16)
    got, whole = {}, {}
    for exc in ("FullMSine", "SineSw"):
        pred = tmp_path / exc
        assert _quietly(["predict", f16 / f"F16Data_{exc}_Level1.mat", *COLUMNS, "--model", out / "loop",
                         "--out", pred]) == 0
        r = json.loads((pred / "predict.json").read_text())["records"][0]
        got[exc] = (r["model"]["band_nmse"]["percent"], r["linear"]["band_nmse"]["percent"])
        whole[exc] = (r["model"]["whole_signal"]["rms_error"], r["linear"]["whole_signal"]["rms_error"])
        assert (pred / r["signals"][0]).is_file() and r["output"]["name"] == "body_accel"
        assert not r["validity"]["outside"], r["validity"]
        if exc == "FullMSine":      # the model's response at this level wanders from period to period: said
            assert "not periodic" in r["model"]["not_periodic"], r["model"]
            d = r["model"]["distortion"]          # the prediction, its periodic response, wanders no more than linear
            assert d["simulated_period_variation_rms"] > 4 * d["period_variation_rms"], d
    print(f"\nF-16 nifo run 3/5/7, held-out level 1 (band NMSE model | linear of 3/5/7): {got}; whole-signal RMS "
          f"error [m/s²] model | linear: {whole}")
    for exc, (model, linear) in got.items():
        assert model < linear, exc
    # the field's score: the raw predicted signal over all frequencies, offset included (issue 53: before, the final
    # model was worse than its linear twin there on every held-out record: its gain outside 2-15 Hz is not fitted).
    # Both below the linear twin. The multisine through the model's periodic response (method.md M18): the play
    # model's simulation wanders from period to period at this level (0.009 m/s², the structure 0.003), its
    # prediction is its period average plus the linear twin's non-periodic part: 0.01566 against 0.01803 m/s²
    # (as simulated it was 0.01813): docs/f16_loop.md "The whole signal"
    for exc, (model, linear) in whole.items():
        assert model < 0.95 * linear, exc
    fitted = json.loads((out / "predict" / "predict.json").read_text())["records"]
    for r in fitted:          # the identification levels, whole signal
        assert r["model"]["whole_signal"]["rms_error"] < r["linear"]["whole_signal"]["rms_error"], r["name"]
    model_doc = json.loads((out / "loop" / "model.json").read_text())
    assert model_doc["prediction_band"]["policy"] == "band"     # limited to 2-15 Hz, chosen by held-out error
    assert model_doc["periodic_response"]["policy"] == "periodic", model_doc["periodic_response"]
    report = (out / "report" / "report.html").read_text()
    assert "band NMSE" in report and "Nothing significant is missing" not in report.split("<h2")[0]
