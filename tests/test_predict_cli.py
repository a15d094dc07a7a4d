"""``nifo predict``: a model.json or its directory (as ``nifo loop`` writes it), every record it can do, errors by name."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from nifo.cli import main
from nifo.io.results import read_model, write_json, write_model
from nifo_core.kinds.describing import make_term
from nifo_core.errors import DataFileError
from nifo_core.predict.model import BodyModel, IdentifiedModel, PredictionDivergedError

SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "sample"
LOW, HIGH = SAMPLE / "road_1mm", SAMPLE / "road_2p5mm"
FS = 600.0


def _quietly(argv) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return main([str(a) for a in argv])


def _model(terms, gammas, k, c) -> IdentifiedModel:
    """A model as ``nifo loop`` builds it: a one-mass body and constant coefficients."""
    return IdentifiedModel.from_body(BodyModel(k, c), terms, gammas, fs_hz=FS,
                                     provenance={"from": "nifo loop equation-error fit"})


@pytest.fixture(scope="module")
def truth_dir(tmp_path_factory) -> Path:
    """The sample's true strut written with write_model into a directory, as the loop does."""
    doc = json.loads((SAMPLE / "road_1mm.truth.json").read_text())
    m2 = doc["vehicle"]["m2"]
    terms = [make_term({"kind": s["kind"], "params": s["params"]}) for s in doc["strut"]]
    model = _model(terms, [s["coefficient"] / m2 for s in doc["strut"]], doc["vehicle"]["k2"] / m2,
                   doc["vehicle"]["c2"] / m2)
    d = tmp_path_factory.mktemp("loop_out")
    write_model(d / "model.json", model, linear=_model([], [], model.body.k, model.body.c))
    return d


def test_predict_takes_the_directory_a_loop_wrote_and_predicts_every_sample_record(truth_dir, tmp_path, capsys):
    assert _quietly(["predict", LOW, HIGH, "--model", truth_dir, "--out", tmp_path / "p", "--no-plots"]) == 0
    print(capsys.readouterr().out)
    doc = json.loads((tmp_path / "p" / "predict.json").read_text())
    assert [r["name"] for r in doc["records"]] == ["road_1mm", "road_2p5mm"] and doc["failed"] == []
    for r in doc["records"]:     # the true backlash + dead zone: far better than the linear part alone
        assert r["model"]["whole_signal"]["nmse_percent"] < 0.1 * r["linear"]["whole_signal"]["nmse_percent"]
        band = r["model"]["band_nmse"]          # the band-limited metric beside it, on the same footing
        assert band["band_hz"] == [2.0, 30.0] and "start-up edge" in band["how"]
        assert band["percent"] < 0.1 * r["linear"]["band_nmse"]["percent"]
    assert doc["linear_part"]["kind"] == "body"


def test_predict_scores_periodic_data_on_the_period_average_after_the_transient_period(shared_data, tmp_path, capsys):
    """F-16 convention (issue 10): --period-samples scores the steady state's period average on the band."""
    data = shared_data / "f16" / "F16Data_FullMSine_Level1.mat"
    f16 = ["--columns", "spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"]
    model = tmp_path / "m.yaml"
    model.write_text("nifo_model: 1\nnonlinearities: []\n")
    ident = tmp_path / "id"
    assert _quietly(["identify", data, *f16, "--model", model, "--out", ident, "--no-plots", "--block", "8192",
                     "--overlap", "0", "--window", "boxcar", "--band", "1.5", "40", "--freq-range", "2", "15",
                     "--skip-periods", "1", "--period-samples", "8192"]) == 0
    assert _quietly(["predict", data, *f16, "--model", ident, "--out", tmp_path / "p", "--no-plots",
                     "--freq-range", "2", "15", "--period-samples", "8192"]) == 0
    out = capsys.readouterr().out
    rec = json.loads((tmp_path / "p" / "predict.json").read_text())["records"][0]
    band = rec["model"]["band_nmse"]
    print(out, band)
    assert "period average" in band["how"] and 0 < band["percent"] < 2.0


def test_a_multi_file_predict_writes_what_it_can_and_exits_naming_the_rest(truth_dir, tmp_path, capsys):
    missing = tmp_path / "nope.mcap"
    rc = _quietly(["predict", LOW, missing, "--model", truth_dir / "model.json", "--out", tmp_path / "p",
                   "--no-plots"])
    err = capsys.readouterr().err
    assert rc == DataFileError.exit_code
    assert "1 of 2 records could not be predicted" in err and "nope.mcap" in err and "Traceback" not in err
    doc = json.loads((tmp_path / "p" / "predict.json").read_text())
    assert [r["name"] for r in doc["records"]] == ["road_1mm"] and doc["failed"][0]["path"] == str(missing)


def test_a_model_unstable_at_one_level_names_that_record_and_level(tmp_path, capsys):
    # a strut that goes negative-stiff beyond |z| = 9 mm: the 1 mm record stays inside (linear peak 7.4 mm),
    # 2.5 mm of road (linear peak 11.6 mm) throws the body over it
    d = tmp_path / "m"
    d.mkdir()
    write_model(d / "model.json", _model([make_term({"clearance": {"gap": 0.009}})], [-7330.0], 73.3, 4.67))
    rc = _quietly(["predict", LOW, HIGH, "--model", d, "--out", tmp_path / "p", "--no-plots"])
    err = capsys.readouterr().err
    assert rc == PredictionDivergedError.exit_code
    assert "road_2p5mm" in err and "grows without bound" in err and "spindle RMS" in err
    assert "relax" not in err and "max_iter" not in err          # no setting the CLI does not have
    doc = json.loads((tmp_path / "p" / "predict.json").read_text())
    assert [r["name"] for r in doc["records"]] == ["road_1mm"]


def test_a_directory_without_model_json_is_named(tmp_path):
    write_json(tmp_path / "identify.json", {"nifo_identify": 1})
    with pytest.raises(DataFileError, match=r"has no model\.json.*nifo identify or nifo loop"):
        read_model(tmp_path)
    with pytest.raises(DataFileError, match=r"model\.json does not exist"):
        read_model(tmp_path / "model.json")



@pytest.mark.slow
def test_identify_refine_linear_on_f16_level_5_refines_the_residues_and_the_model_stays_stable_at_level_7(
        shared_data, tmp_path, capsys):
    """--refine-linear: the linear model's residues refined alone (the baseline written beside the model), then a
    rational linear part's residues refined with the play on that linear part (bounded feedback, poles kept) from
    NIFO's coefficient and from zero, so the model cannot run away at a level it was not fitted on (on its own
    linear part from the NIFO start it did: |z| grew without bound at level 7)."""
    f16 = ["--columns", "spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"]
    opts = ["--no-plots", "--freq-range", "2", "15", "--period-samples", "8192"]
    model = tmp_path / "m.yaml"
    model.write_text("nifo_model: 1\nnonlinearities: [{kind: backlash, params: {deadband: 1.4e-4}}]\n")
    ident = tmp_path / "id"
    assert _quietly(["identify", shared_data / "f16" / "F16Data_FullMSine_Level5.mat", *f16, "--model", model,
                     "--out", ident, *opts, "--block", "8192", "--overlap", "0", "--window", "boxcar", "--band",
                     "1.5", "40", "--skip-periods", "1", "--refine-linear", "--refine-seconds", "41"]) == 0
    ref = json.loads((ident / "identify.json").read_text())["summary"]["refinement"]
    assert "residue pairs" in ref["message"] and set(ref["nmse_before_pct"]) == {"nifo", "linear"}, ref["message"]
    assert "residue pairs" in ref["linear"]["message"] and sum(ref["nmse_pct"]) <= sum(ref["linear"]["nmse_pct"])
    m, _ = read_model(ident)
    assert m.linear.kind == "rational" and m.linear.stable and m.provenance["refined"]["covariance"]["residues"]
    assert _quietly(["predict", shared_data / "f16" / "F16Data_FullMSine_Level7.mat", *f16, "--model", ident,
                     "--out", tmp_path / "p", *opts]) == 0
    rec = json.loads((tmp_path / "p" / "predict.json").read_text())["records"][0]
    print(capsys.readouterr().out[-400:], rec["model"]["band_nmse"]["percent"])
    assert rec["model"]["band_nmse"]["percent"] < rec["linear"]["band_nmse"]["percent"]


def test_a_record_beyond_the_identified_amplitudes_is_named_and_never_called_validated(tmp_path, capsys):
    """nifo identify on the 1 mm record alone, nifo predict of it and of the 2.5 mm record: the model.json records
    the band and the input amplitudes it was identified on; the 2.5 mm record's input RMS is 2.9× the highest, so
    predict.json marks it outside with one line saying why, the summary says NOT VALIDATED, and the 1 mm record is
    inside."""
    spec = tmp_path / "knee.yaml"
    spec.write_text("nifo_model: 1\nnonlinearities:\n  - kind: velocity_deadzone\n    params: {knee: 0.03}\n")
    assert _quietly(["identify", LOW, "--model", spec, "--out", tmp_path / "id", "--no-plots", "-q"]) == 0
    model, _ = read_model(tmp_path / "id")
    v = model.validity
    assert v.input_name == "spindle_accel" and v.n_records == 1 and v.rms[0] == v.rms[1] > 0
    assert v.band_hz == model.analysis_band_hz and model.offsets.output_name == "body_accel"
    assert model.prediction_band.policy in ("whole", "band") and model.prediction_band.reason
    capsys.readouterr()
    assert _quietly(["predict", LOW, HIGH, "--model", tmp_path / "id", "--out", tmp_path / "p", "--no-plots"]) == 0
    printed = capsys.readouterr().out
    recs = {r["name"]: r for r in json.loads((tmp_path / "p" / "predict.json").read_text())["records"]}
    assert not recs["road_1mm"]["validity"]["outside"]
    high = recs["road_2p5mm"]["validity"]
    assert high["outside"] and high["rms_ratio"] > 2 and "the highest identified" in high["message"]
    assert printed.count("NOT VALIDATED") == 1 and high["message"] in printed
