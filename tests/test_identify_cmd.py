"""``nifo identify`` and ``nifo predict`` end to end on the bundled sample bags."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from nifo_core.signal.integrate import IntegrationBand
from nifo_core.signal.spectral import SpectralSettings

from nifo.cli import main
from nifo.io.loader import load_record, save_record
from nifo.io.ownership import write_marker
from nifo.io.results import read_identify, read_model
from nifo_core.kinds.describing import make_term
from nifo_core.errors import ConfigError, DataFileError, IllConditionedError, RecordTooShortError
from nifo_core.nifo.identify import identify_nifo
from nifo_core.signal.record import Record

SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "sample"
LOW, HIGH = SAMPLE / "road_1mm", SAMPLE / "road_2p5mm"

KNEE = {"kind": "velocity_deadzone", "params": {"knee": 0.03}}


def _model_file(path: Path, *terms) -> Path:
    lines = ["nifo_model: 1", "nonlinearities:"] + [f"  - {json.dumps(t)}" for t in terms]
    path.write_text("\n".join(lines) + "\n")
    return path


def _quietly(argv) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return main([str(a) for a in argv])


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """Velocity deadzone identified on the 2.5 mm sample, streamed in small chunks."""
    d = tmp_path_factory.mktemp("identify")
    model = _model_file(d / "model.yaml", KNEE)
    out = d / "out"
    rc = _quietly(["identify", HIGH, "--model", model, "--out", out, "--chunk-samples", 10000])
    assert rc == 0
    return out


def test_identify_writes_parseable_results_model_and_figures(identified):
    for name in ("identify.json", "model.json", "transmissibility.png", "coefficients.png", "conditioning.png",
                 "tire.png"):
        assert (identified / name).stat().st_size > 0, name
    res, doc = read_identify(identified)
    assert doc["data"][0]["name"] == "road_2p5mm" and doc["data"][0]["size_bytes"] > 0
    assert doc["data"][0]["meta"]["topics"]["spindle"] == "/nifo/spindle/imu"
    term = doc["summary"]["terms"][0]
    assert term["unit"] == "(N·s/m)/kg" and term["c_over_m2"] == pytest.approx(res.static.c_over_m2[0])
    assert doc["settings"]["integration_band_hz"] == [res.band.f_lo_hz, res.band.f_hi_hz]
    lower, upper = (np.asarray(doc["bounds"]["t21_static"][k], float) for k in ("lower", "upper"))
    m = res.in_band
    assert np.all(lower[m] <= np.abs(res.static.t21[m])) and np.all(np.abs(res.static.t21[m]) <= upper[m])
    model, linear = read_model(identified / "model.json")
    assert model.source == "static" and linear.source == "h1" and len(linear.terms) == 0
    assert model.provenance["data"][0]["name"] == "road_2p5mm"


def _settings(doc) -> dict:
    """identify_nifo's keyword arguments for the settings identify.json says were used (chosen from the data)."""
    st = doc["settings"]
    return {"settings": SpectralSettings(**{k: st["spectral"][k] for k in ("block", "overlap", "window")}),
            "band": IntegrationBand(*st["integration_band_hz"]), "analysis_band_hz": tuple(st["analysis_band_hz"])}


def test_identify_streamed_in_chunks_equals_identify_nifo_on_the_whole_record(identified):
    res, doc = read_identify(identified)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = identify_nifo(load_record(HIGH), [make_term(KNEE)], **_settings(doc))
    assert res.n_avg == ref.n_avg and res.band == ref.band
    for a, b in ((res.static.t21, ref.static.t21), (res.t21, ref.t21), (res.t21_h1, ref.t21_h1),
                 (res.mu_over_k2, ref.mu_over_k2)):
        m = np.isfinite(b)
        np.testing.assert_allclose(a[m], b[m], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(res.static.c_over_m2, ref.static.c_over_m2, rtol=1e-9)


def test_identify_averages_several_files_as_merged_accumulators(tmp_path):
    model = _model_file(tmp_path / "m.yaml", KNEE)
    assert _quietly(["identify", LOW, HIGH, "--model", model, "--out", tmp_path / "o", "--no-plots",
                     "--freq-range", 2, 25]) == 0
    res, doc = read_identify(tmp_path / "o")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = identify_nifo([load_record(LOW), load_record(HIGH)], [make_term(KNEE)], **_settings(doc))
    assert doc["settings"]["analysis_band_hz"] == [2, 25]
    assert [d["name"] for d in doc["data"]] == ["road_1mm", "road_2p5mm"] and res.n_avg == ref.n_avg
    np.testing.assert_allclose(res.static.t21[res.in_band], ref.static.t21[ref.in_band], rtol=1e-9)
    assert not (tmp_path / "o" / "transmissibility.png").exists()


def test_identify_two_step_model_runs_each_step_on_its_data(tmp_path):
    spec = tmp_path / "two.yaml"
    spec.write_text("nifo_model: 1\nsteps:\n"
                    "  - {name: play, nonlinearities: [{kind: backlash, params: {deadband: 0.00043}}], "
                    f"data: [{LOW}]}}\n"
                    f"  - {{name: knee, nonlinearities: [{json.dumps(KNEE)}]}}\n")
    # the second step's data from the command line
    assert _quietly(["identify", "--model", spec, "--out", tmp_path / "o", "--no-plots",
                     "--step-data", LOW, "--step-data", HIGH]) == 0
    res, doc = read_identify(tmp_path / "o")
    assert res.fixed == (True, False) and [t.kind for t in res.terms] == ["backlash", "velocity_deadzone"]
    assert [s["data"][0]["name"] for s in doc["data"]["steps"]] == ["road_1mm", "road_2p5mm"]
    assert "two_step" in res.provenance


@pytest.mark.parametrize("content, code", [
    ("nifo_model: 1\nnonlinearities: [{kind: warp_drive}]\n", ConfigError.exit_code),
    ("nifo_model: 1\nnonlinearities: [{kind: clearance}]\n", ConfigError.exit_code),   # gap missing
    ("nifo_model: 1\nnonlinearities: [ {kind: coulomb\n", ConfigError.exit_code),       # broken YAML
])
def test_identify_bad_model_file_exits_with_config_error_and_writes_nothing(tmp_path, capsys, content, code):
    model = tmp_path / "bad.yaml"
    model.write_text(content)
    out = tmp_path / "out"
    assert _quietly(["identify", HIGH, "--model", model, "--out", out]) == code
    assert "error" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml"]


def test_identify_missing_data_or_model_exits_with_data_file_error(tmp_path):
    model = _model_file(tmp_path / "m.yaml", KNEE)
    assert _quietly(["identify", tmp_path / "nope.mcap", "--model", model, "--out", tmp_path / "o"]) \
        == DataFileError.exit_code
    assert _quietly(["identify", HIGH, "--model", tmp_path / "nope.yaml", "--out", tmp_path / "o"]) \
        == DataFileError.exit_code
    assert not (tmp_path / "o").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["m.yaml"]


def test_identify_keeps_an_existing_output_when_it_fails(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "identify.json").write_text("{}")
    write_marker(out)   # an earlier result nifo wrote
    model = _model_file(tmp_path / "m.yaml", KNEE)
    assert _quietly(["identify", tmp_path / "missing.csv", "--model", model, "--out", out]) \
        == DataFileError.exit_code
    assert sorted(p.name for p in out.iterdir()) == [".nifo-output", "identify.json"]
    assert (out / "identify.json").read_text() == "{}"


def test_identify_refuses_when_the_terms_cannot_be_told_apart(tmp_path, capsys):
    model = _model_file(tmp_path / "dup.yaml", KNEE, KNEE)
    assert _quietly(["identify", LOW, "--model", model, "--out", tmp_path / "o"]) == IllConditionedError.exit_code
    err = capsys.readouterr().err
    assert "ill-conditioned on every line" in err and f"error: {LOW}: " in err and "Fix: " in err   # names the data
    assert not (tmp_path / "o").exists()


def test_identify_on_an_axis_that_recorded_nothing_says_so_as_info_does(tmp_path, capsys):
    """Issue 26: --axis x on z-only data ended in exit 10 (ill-conditioned); info said the axis recorded nothing."""
    model = _model_file(tmp_path / "m.yaml", KNEE)
    assert main(["info", str(LOW), "--axis", "x"]) == DataFileError.exit_code
    said = capsys.readouterr().err.strip()
    assert _quietly(["identify", LOW, "--model", model, "--axis", "x", "--out", tmp_path / "o"]) \
        == DataFileError.exit_code
    err = capsys.readouterr().err.strip()
    assert "the sensor recorded nothing" in err and err.split("error: ", 1)[1] == said.split("error: ", 1)[1]
    assert not (tmp_path / "o").exists()


def test_identify_warns_plainly_about_conditioning(tmp_path, capsys):
    model = _model_file(tmp_path / "m.yaml", KNEE, {"kind": "backlash", "params": {"deadband": 0.00043}})
    # knee + play on the 2.5 mm record: 5 % of lines above the default limit 1e4 on the 1/f-road sample;
    # a stricter limit puts more than 10 % over it, where the plain warning must appear
    assert _quietly(["identify", HIGH, "--model", model, "--out", tmp_path / "o", "--no-plots",
                     "--cond-limit", "1000"]) == 0
    text = capsys.readouterr().out
    _, doc = read_identify(tmp_path / "o")
    assert doc["summary"]["ill_conditioned_fraction"] > 0.1
    assert any("ill-conditioned" in w for w in doc["warnings"]) and "WARNING: The per-line" in text


def test_identify_too_short_record_exits_with_record_too_short(tmp_path):
    rng = np.random.default_rng(0)
    rec = Record(600.0, rng.normal(size=3000), rng.normal(size=3000))
    save_record(tmp_path / "short.csv", rec)
    model = _model_file(tmp_path / "m.yaml", KNEE)
    assert _quietly(["identify", tmp_path / "short.csv", "--model", model, "--out", tmp_path / "o"]) \
        == RecordTooShortError.exit_code
    assert not (tmp_path / "o").exists()


def test_predict_with_the_identified_model_beats_the_linear_model(identified, tmp_path, capsys):
    out = tmp_path / "pred"
    assert _quietly(["predict", LOW, "--model", identified / "model.json", "--out", out]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((out / "predict.json").read_text())
    r = doc["records"][0]
    print(printed)
    assert r["model"]["whole_signal"]["nmse_percent"] < r["linear"]["whole_signal"]["nmse_percent"]
    assert r["model"]["transmissibility_error"]["median"] < 0.5 * r["linear"]["transmissibility_error"]["median"]
    # truth beside the bag: the NIFO nominal T21 is much nearer the true linear T21 than the measured H1
    tr = r["truth"]
    assert tr["model_nominal_t21_vs_true"]["median"] < 0.5 * tr["measured_h1_vs_true"]["median"]
    for name in r["figures"]:
        assert (out / name).stat().st_size > 0


def test_predict_missing_model_exits_with_data_file_error_and_writes_nothing(tmp_path):
    assert _quietly(["predict", LOW, "--model", tmp_path / "none.json", "--out", tmp_path / "p"]) \
        == DataFileError.exit_code
    assert not (tmp_path / "p").exists()
    (tmp_path / "bad.json").write_text('{"nifo_identified_model": 1, "terms": []}')
    assert _quietly(["predict", LOW, "--model", tmp_path / "bad.json", "--out", tmp_path / "p"]) \
        == ConfigError.exit_code
    assert not (tmp_path / "p").exists()


def test_feedback_paths_on_a_one_mass_body_say_why_and_keep_the_constant_coefficients(tmp_path, capsys):
    """--feedback-paths needs a rational linear part; on the quarter-car sample (a physical one-mass body, where a
    constant coefficient is exact) it warns, writes the constant-coefficient model, and says so in identify.json;
    with --refine it is refused before any work."""
    model = _model_file(tmp_path / "m.yaml", {"kind": "backlash", "params": {"deadband": 4.3e-4}})
    out = tmp_path / "o"
    assert _quietly(["identify", HIGH, "--model", model, "--out", out, "--feedback-paths", "--no-plots"]) == 0
    printed = capsys.readouterr().out
    assert "--feedback-paths: feedback paths need a rational linear part" in printed
    assert "model.json holds the constant-coefficient model" in printed
    doc = json.loads((out / "identify.json").read_text())
    assert "rational" in doc["summary"]["feedback_paths"]["error"]
    m, _ = read_model(out)
    assert m.linear.kind == "body" and m.linear.paths is None and m.source == "static"
    assert _quietly(["identify", HIGH, "--model", model, "--out", tmp_path / "o2", "--feedback-paths",
                     "--refine"]) == ConfigError.exit_code
    assert not (tmp_path / "o2").exists()


def test_a_ridge_whose_held_out_prediction_could_not_be_scored_is_said_so_not_a_traceback(capsys):
    """--feedback-paths prints each ridge weight's held-out NMSE; a stable one whose model could not be scored on the
    held-out parts (its mean is None in the grid) printed a TypeError traceback before."""
    from types import SimpleNamespace

    from nifo.pipeline.identify import _print_fits

    grid = ({"ridge": 0.001, "regimes_stable": True, "held_out_nmse_percent": None},
            {"ridge": 0.01, "regimes_stable": False},
            {"ridge": 0.1, "regimes_stable": True, "held_out_nmse_percent": 0.25})
    _print_fits(SimpleNamespace(message="paths", grid=grid), None, {}, None)
    out = capsys.readouterr().out
    assert "ridge 0.001: its held-out prediction could not be scored" in out
    assert "ridge 0.01: not eligible" in out and "ridge 0.1: held-out prediction NMSE 0.25 %" in out
