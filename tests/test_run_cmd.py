"""``nifo run``: the whole job on a short simulated pair of levels produces the report and the recording.

The bundled sample (2 x 120 s) is what ``./nifo.sh`` runs; CI uses a 60 s pair
of the same simulated car (same preset, noise, two road levels) to keep time.
:func:`pipeline` runs it once per session and is shared with test_viz.py and
test_report_browser.py.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pytest

from nifo.cli import main

DURATION_S = 60


@functools.lru_cache(maxsize=None)
def pipeline(base: Path) -> tuple[Path, int, str]:
    """Simulate two levels and ``nifo --json run`` them into ``base/out``: (out, exit code, the human text).

    The human text goes to stderr under --json; the JSON summary (stdout) is kept in ``base/run.json``."""
    import contextlib
    import io

    base.mkdir(parents=True, exist_ok=True)
    data = []
    for name, rms, seed in (("road_lo", "1.0", 11), ("road_hi", "2.5", 12)):
        p = base / name
        assert main(["simulate", "--out", str(p), "--preset", "paper", "--road-rms", rms, "--duration",
                     str(DURATION_S), "--noise", "0.02", "--seed", str(seed)]) == 0
        data.append(str(p))
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["--json", "run", *data, "--out", str(base / "out")])
    (base / "run.json").write_text(out.getvalue())   # --json: the summary document alone on stdout
    return base / "out", code, err.getvalue()


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    return pipeline(tmp_path_factory.getbasetemp() / "nifo_run")


def test_run_writes_each_step_in_its_own_directory_with_report_and_recording(ran):
    out, code, _ = ran
    assert code == 0
    for sub, doc in (("characterize", "characterize.json"), ("identify", "identify.json"),
                     ("predict", "predict.json")):
        assert (out / sub / doc).is_file(), sub
    assert (out / "report" / "report.html").stat().st_size > 50_000
    assert (out / "recording" / "nifo.rrd").stat().st_size > 10_000


def test_run_identifies_on_the_highest_level_and_predicts_the_other(ran):
    out, _, _ = ran
    ident = json.loads((out / "identify" / "identify.json").read_text())
    assert [d["name"] for d in ident["data"]] == ["road_hi"]
    pred = json.loads((out / "predict" / "predict.json").read_text())
    assert [r["name"] for r in pred["records"]] == ["road_lo"]


def test_run_runs_the_loop_when_it_is_part_of_the_build(ran):
    from nifo.commands.run import loop_available

    out, _, stdout = ran
    if loop_available():
        assert (out / "loop" / "loop.json").is_file()
        assert "loop" in stdout


def test_run_prints_where_the_results_are(ran):
    out, _, stdout = ran
    assert str(out / "report" / "report.html") in stdout
    assert str(out / "recording" / "nifo.rrd") in stdout
    assert "nifo run finished in" in stdout


def test_run_without_data_and_without_a_bundled_sample_says_what_to_do(tmp_path, monkeypatch, capsys):
    import nifo.commands.run as run_cmd

    monkeypatch.setattr(run_cmd, "SAMPLE_DIR", tmp_path / "nothing")
    assert main(["run", "--out", str(tmp_path / "o")]) != 0
    assert "nifo run DATA" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_run_defaults_to_the_bundled_sample():
    from nifo.commands.run import sample_data

    assert [p.name for p in sample_data()] == ["road_1mm", "road_2p5mm"]


def test_run_json_is_one_document_naming_every_result(ran):
    out, code, _ = ran
    doc = json.loads((out.parent / "run.json").read_text())
    assert doc["command"] == "run" and doc["ok"] is True and doc["exit_code"] == code == 0
    assert doc["report"] == str(out / "report" / "report.html")
    assert set(doc["results"]) >= {"characterize", "identify", "predict"}
    assert set(doc["timings_s"]) >= {"characterize", "identify", "report"}
