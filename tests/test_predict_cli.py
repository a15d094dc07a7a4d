"""``nifo predict``: a model.json or its directory (as ``nifo loop`` writes it), every record it can do, errors by name."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from nifo.cli import main
from nifo.io.results import read_model, write_json, write_model
from nifo_core.describing import make_term
from nifo_core.errors import DataFileError, IllConditionedError
from nifo_core.integrate import IntegrationBand
from nifo_core.model import BodyModel, IdentifiedModel
from nifo_core.spectral import SpectralSettings

SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "sample"
LOW, HIGH = SAMPLE / "road_1mm", SAMPLE / "road_2p5mm"
FS = 600.0


def _quietly(argv) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return main([str(a) for a in argv])


def _model(terms, gammas, k, c) -> IdentifiedModel:
    """A model as ``nifo loop`` builds it: a one-mass body and constant coefficients."""
    f = SpectralSettings().freq_hz(FS)
    body = BodyModel(k, c)
    t21 = body.t21(f)
    with np.errstate(divide="ignore", invalid="ignore"):
        b = np.array(gammas, float)[:, None] * ((1 - t21) / (2 * np.pi * f) ** 2)[None, :]
    return IdentifiedModel(freq_hz=f, t21=t21, b=b.reshape(len(terms), f.size), terms=tuple(terms),
                           c_over_m2=np.array(gammas, float), body=body, analysis_band_hz=(2.0, 30.0), fs_hz=FS,
                           settings=SpectralSettings(), band=IntegrationBand(0.5, 200.0),
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
        assert r["model"]["nmse_percent"] < 0.1 * r["linear"]["nmse_percent"]
    assert doc["linear_part"]["kind"] == "body"


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
    assert rc == IllConditionedError.exit_code
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
