"""What a user takes away: ``nifo export`` (the strut's force law as tables, its linear part, a figure) and the
Python API (``nifo.Model``), on the bundled sample's ``nifo run`` (its final model, loop/model.json, against the
simulator's truth files bags/sample/*.truth.json)."""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from nifo.cli import main
from nifo.io.signals import read_signals
from test_run_cmd import sample_run_once

REPO = Path(__file__).resolve().parents[1]
TRUTH = REPO / "bags" / "sample" / "road_1mm.truth.json"


@pytest.fixture(scope="module")
def run_out(tmp_path_factory) -> Path:
    return sample_run_once(tmp_path_factory)[0]


@pytest.fixture(scope="module")
def exported(run_out, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export") / "strut"
    assert main(["-q", "export", str(run_out), "--out", str(out)]) == 0
    return out


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    with open(path, newline="", encoding="utf-8") as f:   # as a spreadsheet reads it: one header row, then numbers
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def _truth_force(variable: str, x: np.ndarray, branch: str) -> np.ndarray:
    """The simulator's strut force per kg of its M2, written out from the truth file (not from nifo's code)."""
    doc = json.loads(TRUTH.read_text())
    v, strut = doc["vehicle"], {s["kind"]: s for s in doc["strut"]}
    if variable == "zdot":
        knee, c = strut["velocity_deadzone"]["params"]["knee"], strut["velocity_deadzone"]["coefficient"]
        return (v["c2"] * x + c * np.sign(x) * np.maximum(np.abs(x) - knee, 0.0)) / v["m2"]
    h, c = strut["backlash"]["params"]["deadband"] / 2, strut["backlash"]["coefficient"]
    play = x - h if branch == "z increasing" else x + h        # a steady cycle's branches, away from the turns
    return (v["k2"] * x + c * play) / v["m2"]


@pytest.mark.parametrize("name, variable", [("force_deflection.csv", "z"), ("force_velocity.csv", "zdot")])
def test_export_of_the_sample_total_force_is_within_5_percent_of_the_truth_and_opens_as_a_table(
        exported, name, variable):
    header, rows = _read_csv(exported / name)
    assert header[0] == ("deflection z [m]" if variable == "z" else "velocity ż [m/s]")
    assert all(re.search(r"\[[^\]]+\]$", h) for i, h in enumerate(header) if i not in (1, 2)), header
    assert "total [N per kg of M2]" in header and any("[N per kg of M2]" in h for h in header[3:])
    col = {h: i for i, h in enumerate(header)}
    x = np.array([float(r[0]) for r in rows])
    total = np.array([float(r[col["total [N per kg of M2]"]]) for r in rows])
    inside = np.array([r[1] == "yes" for r in rows])
    assert inside.any() and (~inside).any(), "the grid reaches beyond the measured range, marked"
    branches = sorted({r[2] for r in rows})
    assert branches == (["z decreasing", "z increasing"] if variable == "z" else ["either"])
    worst = 0.0
    for b in branches:
        m = inside & np.array([r[2] == b for r in rows])
        if variable == "z":   # the play's turning points lie at the grid's ends, outside the measured range
            m &= np.abs(x) > 1e-3
        truth = _truth_force(variable, x[m], b)
        worst = max(worst, float(np.max(np.abs(total[m] - truth)) / np.max(np.abs(truth))))
    print(f"\n{name}: total strut force within {100 * worst:.2f} % of the simulator's truth over the measured range")
    assert worst < 0.05
    doc = json.loads((exported / "export.json").read_text())
    assert doc["mass_kg"] is None and "per kg of the body mass M2" in doc["forces"]
    assert doc["truth"][{"z": "deflection", "zdot": "velocity"}[variable]] < 0.05


def test_export_linear_part_is_the_models_transmissibility(run_out, exported):
    from nifo.api import Model

    doc = json.loads((exported / "linear_part.json").read_text())
    tf = doc["transfer_functions"]["T21(s) = X2/X1, the nominal linear spindle→body transmissibility"]
    f = np.array([1.0, 2.0, 13.0, 40.0])
    s = 2j * np.pi * f
    t21 = np.polyval(tf["numerator"], s) / np.polyval(tf["denominator"], s)
    np.testing.assert_allclose(t21, Model.load(run_out).transmissibility(f), rtol=1e-9)
    a, b, c, d = (np.array(doc[k]) for k in "ABCD")
    assert [u["unit"] for u in doc["inputs"]] == ["m/s²", "N/kg"] and doc["outputs"][0]["unit"] == "m"
    # the state-space form gives the same T21: ẍ2 from ẍ1 alone
    h = np.array([c[2] @ np.linalg.solve(si * np.eye(a.shape[0]) - a, b[:, 0]) + d[2, 0] for si in s])
    np.testing.assert_allclose(h, t21, rtol=1e-9)
    assert (exported / "force_law.png").stat().st_size > 20_000 and (exported / ".nifo-output").is_file()


def test_export_in_newtons_with_the_mass_given(run_out, tmp_path):
    out = tmp_path / "n"
    assert main(["-q", "export", str(run_out / "loop"), "--out", str(out), "--m2", "300", "--points", "41"]) == 0
    header, rows = _read_csv(out / "force_velocity.csv")
    assert "total [N]" in header and len(rows) == 41
    assert json.loads((out / "export.json").read_text())["mass_kg"] == 300.0


def test_export_refuses_a_model_without_its_measured_range_in_one_line(run_out, tmp_path, capsys):
    doc = json.loads((run_out / "loop" / "model.json").read_text())
    doc.pop("validity")
    old = tmp_path / "model.json"
    old.write_text(json.dumps(doc))
    code = main(["export", str(old), "--out", str(tmp_path / "e")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 9 and len(err) == 1 and "measured range" in err[0] and "Fix:" in err[0], err
    assert not (tmp_path / "e").exists()


def _readme_example() -> str:
    text = (REPO / "README.md").read_text()
    part = text.split("## The model in your own tools", 1)[1]
    return re.search(r"```python\n(.*?)```", part, re.S).group(1)


def test_readme_python_example_runs_as_written_and_reproduces_nifo_predict(run_out, tmp_path, monkeypatch,
                                                                           capsys):
    """The README's example in a folder where ./nifo.sh wrote results/ (and the checkout's bags/): it runs as
    written, and its simulation is nifo predict's predicted signal of the same record to numerical precision."""
    (tmp_path / "results").symlink_to(run_out)
    (tmp_path / "bags").symlink_to(REPO / "bags")
    monkeypatch.chdir(tmp_path)
    scope: dict = {"__name__": "__main__"}
    exec(compile(_readme_example(), "README.md", "exec"), scope)
    printed = capsys.readouterr().out
    assert "damper knee" in printed and "deflection_m" in printed
    sim = scope["sim"]
    pred = read_signals(run_out / "predict" / "road_1mm_signals.parquet")
    np.testing.assert_allclose(sim.output, pred["body_accel_model"], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(scope["rec"].body_accel, pred["body_accel_measured"])


def test_the_model_simulates_at_another_sample_rate(run_out):
    """The model is continuous-time: the same input at half the rate (every second sample of a signal well inside
    the band) gives the same response at the common instants, to the discretisation's error."""
    import nifo

    model = nifo.Model.load(run_out)
    fs = 600.0
    t = np.arange(int(20 * fs)) / fs
    a1 = np.sin(2 * np.pi * 3.0 * t) + 0.5 * np.sin(2 * np.pi * 7.0 * t)
    full = model.simulate(a1, fs_hz=fs)
    half = model.simulate(a1[::2], fs_hz=fs / 2)
    v = slice(half.valid.start, half.valid.stop)
    diff = np.abs(full.body_accel[::2][v] - half.body_accel[v])
    assert diff.max() < 1e-3 * np.abs(full.body_accel).max()
