"""``nifo characterize``: files written, what it prints, errors; the paper's chirp protocol end to end;
the F-16 ground vibration test (skipped without ../shared/data)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nifo.cli import main
from nifo.io.loader import save_record
from nifo.io.modelfile import load_model_spec
from nifo_core.kinds.describing import Term
from nifo_core.simulate.quarter_car import ChirpRoad, RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

PNG = b"\x89PNG\r\n\x1a\n"
DEADZONE = (StrutForce(Term("velocity_deadzone", {"knee": 0.03}), -700.0),)
F16_COLUMNS = "spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"
#: kinds that describe a clearance or friction (the F-16 interface: clearance + friction in its back connection)
CLEARANCE_OR_FRICTION = {"clearance", "saturation", "bump_stop", "backlash", "coulomb"}


def _png(path) -> bool:
    return path.is_file() and path.read_bytes()[:8] == PNG and path.stat().st_size > 10_000


@pytest.fixture(scope="module")
def chirp_file(tmp_path_factory):
    """The paper's characterization protocol (Table 1): 0-15 Hz at 0.025 Hz/s, fs 300 Hz, 180 000 points."""
    cfg = SimConfig(strut=DEADZONE, road=ChirpRoad(amplitude_m=0.0005, f0_hz=0.0, f1_hz=15.0, rate_hz_per_s=0.025),
                    fs_hz=300.0, noise=SensorNoise(relative=0.02))
    sim = simulate(cfg, rng=7)
    assert sim.record.n == 180_000
    return save_record(tmp_path_factory.mktemp("chirp") / "chirp_0.5mm.mat", sim.record)


def test_paper_chirp_protocol_runs_end_to_end_with_frequency_slices(chirp_file, tmp_path, capsys):
    out = tmp_path / "char"
    code = main(["characterize", str(chirp_file), "--out", str(out), "--m2", "300",
                 "--slices-hz", "3.8", "5", "8.4", "14.2"])
    assert code == 0
    for name in ("restoring_frequency.png", "characteristic.png", "ranking.png"):
        assert _png(out / name), name
    doc = json.loads((out / "characterize.json").read_text())
    assert doc["records"][0]["sweep"]["detected"]
    lo, hi = doc["records"][0]["sweep"]["range_hz"]
    assert lo < 2 and 14 < hi < 15.5
    top = doc["candidates"][0]
    assert top["kind"] == "velocity_deadzone" and top["status"] == "suggested"
    assert top["key_param"]["value"] == pytest.approx(0.03, rel=0.2)
    assert top["coefficient"] == pytest.approx(-700, rel=0.2)
    assert doc["band"]["f_lo_hz"] > 0 and doc["band_choice"]["chosen_by"] == "data"
    spec = load_model_spec(out / "suggested_model.yaml")
    assert [t.kind for t in spec.terms] == ["velocity_deadzone"]
    assert spec.settings["integration_band_hz"] == [doc["band"]["f_lo_hz"], doc["band"]["f_hi_hz"]]
    text = capsys.readouterr().out
    assert "velocity_deadzone" in text and "suggested model" in text
    assert not list(tmp_path.glob(".char.partial-*"))


def test_several_files_are_amplitude_slices_and_a_linear_strut_says_nothing_found(tmp_path, capsys):
    paths = []
    for i, rms in enumerate((0.001, 0.003)):
        sim = simulate(SimConfig(road=RandomRoad(rms_m=rms), duration_s=90.0, fs_hz=600.0,
                                 noise=SensorNoise(relative=0.02)), rng=50 + i)
        paths.append(str(save_record(tmp_path / f"linear_{rms * 1e3:g}mm.mat", sim.record)))
    out = tmp_path / "lin"
    assert main(["characterize", *paths, "--out", str(out), "--band", "1.5", "200", "--top", "3"]) == 0
    text = capsys.readouterr().out
    assert "nothing nonlinear found" in text
    assert _png(out / "restoring_amplitude.png")
    doc = json.loads((out / "characterize.json").read_text())
    assert doc["nothing_found"] and doc["suggested"] == []
    assert [r["path"] for r in doc["records"]] == paths
    assert doc["band_choice"]["chosen_by"] == "command line"
    assert load_model_spec(out / "suggested_model.yaml").terms == ()


def test_errors_exit_with_their_code_and_write_nothing(chirp_file, tmp_path, capsys):
    out = tmp_path / "never"
    assert main(["characterize", str(tmp_path / "missing.mat"), "--out", str(out)]) == 3
    assert main(["characterize", str(chirp_file), "--out", str(out), "--band", "5", "1"]) == 9
    assert main(["characterize", str(chirp_file), "--out", str(out), "--freq-window", "9", "2"]) == 9
    assert main(["characterize", str(chirp_file), "--out", str(out), "--kinds", "warp_drive"]) == 9
    err = capsys.readouterr().err
    assert "missing.mat" in err and "Fix:" in err
    assert not out.exists() and not list(tmp_path.glob(".never*"))


# --------------------------------------------------------------------------------------------
# real data: the F-16 ground vibration test (Noël & Schoukens 2017, nonlinearbenchmark.org)
# --------------------------------------------------------------------------------------------
def _f16(shared_data, level: int, tmp_path, capsys) -> dict:
    path = shared_data / "f16" / f"F16Data_SineSw_Level{level}.mat"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    out = tmp_path / f"l{level}"
    code = main(["characterize", str(path), "--out", str(out), "--columns", F16_COLUMNS,
                 "--band", "5", "160", "--freq-window", "6.8", "7.8", "--slices-hz", "7.3"])
    capsys.readouterr()
    assert code == 0
    assert _png(out / "restoring_frequency.png")
    return json.loads((out / "characterize.json").read_text())


@pytest.mark.realdata
def test_f16_level7_names_a_clearance_or_friction_type_nonlinearity(shared_data, tmp_path, capsys):
    doc = _f16(shared_data, 7, tmp_path, capsys)
    assert not doc["nothing_found"]
    first = doc["suggested"][0]
    assert first["kind"] in CLEARANCE_OR_FRICTION
    assert first["err"] > 0.2 and first["present"]
    assert doc["model"]["r2"] > doc["linear"]["r2"] + 0.1


@pytest.mark.realdata
def test_f16_level1_reports_nothing_strong(shared_data, tmp_path, capsys):
    doc = _f16(shared_data, 1, tmp_path, capsys)
    assert doc["nothing_found"]
    assert all(not c["present"] for c in doc["candidates"])
    assert np.isfinite(doc["linear"]["r2"])
