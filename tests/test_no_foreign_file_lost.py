"""No command ever deletes or overwrites a file it did not write (issue 26).

Every command that takes an output path (identify, loop, characterize,
predict, run, fleet, export: ``--out DIR``; report, simulate: ``--out FILE``;
simulate: a bag folder; view: ``--save FILE``) is pointed at a folder or file
holding a user's own files. It must exit 13 with one line naming the path and
the fix, and leave every byte as it was. Beside each refusal a positive
control: the same command writing to a new path and then replacing its own
output succeeds, so the refusals are not a command that never writes.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest

from nifo.io.loader import save_record
from nifo.io.ownership import MARKER
from nifo_core.errors import OutputError
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate

from fuzz_engine import cli

#: the issue's cases: a user's folder of common files, one lone file, a data folder that is not a bag nifo wrote
FOLDERS = {
    "papers": {"model.yaml": b"nifo_model: 1\nnonlinearities: [coulomb]\n", "notes.txt": b"do not lose me\n",
               "photo.png": b"\x89PNG\r\n\x1a\n" + bytes(range(64)), "paper.tex": b"\\documentclass{article}\n"},
    "setup": {"vehicle_setup.yaml": b"m2: 400\n"},
    "thesis": {"data.mcap": b"\x89MCAP0\r\n" + bytes(100), "thesis.docx": b"PK\x03\x04 thesis"},
    "results_plus_notes": None,   # a result folder nifo wrote, to which the user added notes.txt
}
#: a quick characterization (one kind, a coarse grid): these tests are about the output folder
FAST_CHAR = ["--kinds", "coulomb", "--grid", "4"]


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, Path]:
    """A 60 s record, a model file and an identify result: the inputs every command needs."""
    root = tmp_path_factory.mktemp("inputs")
    sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=60.0, road=RandomRoad(2.5e-3)), rng=3)
    rec = save_record(root / "rec.mcap", sim.record)
    model = root / "m.yaml"
    model.write_text("nifo_model: 1\nnonlinearities: [{kind: velocity_deadzone, params: {knee: 0.03}}]\n")
    ident = root / "ident"
    code, _, err = cli(["identify", str(rec), "--model", str(model), "--out", str(ident), "--no-plots", "-q"])
    assert code == 0, err
    manifest = root / "fleet.csv"
    manifest.write_text(f"vehicle,corner,path\nv1,fl,{rec}\n")
    return {"rec": rec, "model": model, "ident": ident, "manifest": manifest}


def _snapshot(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


def _folder(root: Path, kind: str, data: dict[str, Path]) -> Path:
    d = root / f"out_{kind}"
    if kind == "results_plus_notes":
        code, _, err = cli(["characterize", str(data["rec"]), "--out", str(d), "-q", *FAST_CHAR])
        assert code == 0 and (d / MARKER).is_file(), err
        (d / "notes.txt").write_text("my notes on this result\n")
        return d
    d.mkdir()
    for name, content in FOLDERS[kind].items():
        (d / name).write_bytes(content)
    return d


def _commands(data: dict[str, Path], out: Path) -> dict[str, list[str]]:
    rec, model, ident = str(data["rec"]), str(data["model"]), str(data["ident"])
    return {
        "identify": ["identify", rec, "--model", model, "--out", str(out)],
        "loop": ["loop", rec, "--model", model, "--out", str(out)],
        "characterize": ["characterize", rec, "--out", str(out)],
        "predict": ["predict", rec, "--model", ident, "--out", str(out)],
        "run": ["run", rec, "--out", str(out)],
        "fleet": ["fleet", str(data["manifest"]), "--model", model, "--out", str(out)],
        "simulate": ["simulate", "--out", str(out), "--duration", "5"],   # a bag folder
        "export": ["export", ident, "--out", str(out)],
    }


def _refused(argv: list[str], path: Path, before: dict, root: Path) -> None:
    code, out, err = cli(argv)
    lines = err.strip().splitlines()
    assert code == OutputError.exit_code, (argv, code, err)
    assert len(lines) == 1 and str(path) in lines[0] and ". Fix: " in lines[0], lines
    assert "Traceback" not in err and _snapshot(root) == before, f"{argv[0]} changed what was there"


@pytest.mark.parametrize("kind", list(FOLDERS))
def test_no_command_with_out_dir_deletes_a_folder_of_the_users_files(data, tmp_path, kind):
    out = _folder(tmp_path, kind, data)
    before = _snapshot(tmp_path)
    for name, argv in _commands(data, out).items():
        _refused(argv, out, before, tmp_path)


@pytest.mark.parametrize("cmd", ["identify", "loop"])
def test_the_model_files_own_folder_as_out_is_refused(data, tmp_path, cmd):
    """``--model cfg/model.yaml --out cfg``: the issue's first case."""
    cfg = tmp_path / "cfg"
    cfg.mkdir()
    (cfg / "model.yaml").write_bytes(data["model"].read_bytes())
    before = _snapshot(tmp_path)
    _refused([cmd, str(data["rec"]), "--model", str(cfg / "model.yaml"), "--out", str(cfg)], cfg, before, tmp_path)


FOREIGN_FILES = {"precious.txt": b"my thesis\n", "foreign.html": b"<!doctype html><title>mine</title>\n",
                 "data.csv": b"time,spindle_accel,body_accel\n0,1,2\n", "foreign.mcap": b"\x89MCAP0\r\n" + bytes(64),
                 "foreign.rrd": b"RRF2\x00\x00\x00\x00 someone else's recording", "foreign.mat": b"MATLAB 5.0" + bytes(118),
                 "foreign.json": b'{"mine": true}\n'}


@pytest.mark.parametrize("name", list(FOREIGN_FILES))
def test_no_command_with_an_out_file_overwrites_a_file_nifo_did_not_write(data, tmp_path, name):
    f = tmp_path / name
    f.write_bytes(FOREIGN_FILES[name])
    before = _snapshot(tmp_path)
    _refused(["report", str(data["ident"]), "--out", str(f)], f, before, tmp_path)
    _refused(["view", str(data["ident"]), "--save", str(f)], f, before, tmp_path)
    if Path(name).suffix in (".txt", ".csv", ".mcap", ".mat"):
        _refused(["simulate", "--out", str(f), "--duration", "5"], f, before, tmp_path)
    for argv in _commands(data, f).values():   # a file where a folder is to go
        if argv[0] != "simulate":
            _refused(argv, f, before, tmp_path)


def test_a_fifo_or_dev_null_as_out_is_named_for_what_it_is(data, tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for target, what in ((fifo, "a FIFO (named pipe)"), (Path("/dev/null"), "a character device")):
        for argv in (["identify", str(data["rec"]), "--model", str(data["model"]), "--out", str(target)],
                     ["report", str(data["ident"]), "--out", str(target)]):
            code, _, err = cli(argv)
            assert code == OutputError.exit_code and what in err and "regular file," not in err, err


def test_a_300_character_name_in_out_is_one_line_for_every_command(data, tmp_path):
    long = "x" * 300
    for out in (tmp_path / long, tmp_path / long / "res"):
        before = _snapshot(tmp_path)
        argvs = [*_commands(data, out).values(), ["report", str(data["ident"]), "--out", str(out) + ".html"],
                 ["view", str(data["ident"]), "--save", str(out) + ".rrd"]]
        for argv in argvs:
            code, _, err = cli(argv)
            lines = err.strip().splitlines()
            assert code == OutputError.exit_code, (argv[0], err)
            assert len(lines) == 1 and re.search(r"is 30\d bytes long", lines[0]) and "Fix: give an --out path" in lines[0]
            assert _snapshot(tmp_path) == before


def test_each_command_replaces_its_own_output_and_refuses_once_a_user_file_is_added(data, tmp_path):
    """The positive control: what nifo wrote it may replace; one foreign file added and it may not."""
    rec, ident = str(data["rec"]), str(data["ident"])
    runs = {"characterize": ["characterize", rec, "--out", str(tmp_path / "c"), "-q", *FAST_CHAR],
            "predict": ["predict", rec, "--model", ident, "--out", str(tmp_path / "p"), "--no-plots", "-q"],
            "report": ["report", ident, "--out", str(tmp_path / "r.html"), "--no-levels", "-q"],
            "export": ["export", ident, "--out", str(tmp_path / "e"), "--points", "11", "-q"],
            "view": ["view", ident, "--save", str(tmp_path / "v.rrd"), "--no-data", "-q"],
            "simulate_bag": ["simulate", "--out", str(tmp_path / "bag"), "--duration", "5", "-q"],
            "simulate_mcap": ["simulate", "--out", str(tmp_path / "s.mcap"), "--duration", "5", "-q"],
            "simulate_mat": ["simulate", "--out", str(tmp_path / "s.mat"), "--duration", "5", "-q"]}
    for name, argv in runs.items():
        for _ in range(2):     # writes, then replaces its own output
            code, _, err = cli(argv)
            assert code == 0, (name, err)
    marker = json.loads((tmp_path / "c" / MARKER).read_text())
    assert marker["nifo_output"] == 2 and marker["command"].startswith("nifo characterize") and \
        "characterize.json" in marker["entries"] and marker["nifo_version"]
    (tmp_path / "c" / "notes.txt").write_text("mine")
    (tmp_path / "bag" / "thesis.docx").write_text("mine")
    before = _snapshot(tmp_path)
    _refused(runs["characterize"], tmp_path / "c", before, tmp_path)
    _refused(runs["simulate_bag"], tmp_path / "bag", before, tmp_path)
    code, _, err = cli(["simulate", "--out", str(tmp_path / "s.csv"), "--duration", "5", "-q"])
    assert code == 0, err   # a new CSV is written; an existing one is never replaced (no writer's mark)
    before = _snapshot(tmp_path)
    _refused(["simulate", "--out", str(tmp_path / "s.csv"), "--duration", "5"], tmp_path / "s.csv", before, tmp_path)
    assert isinstance(json.loads((tmp_path / "s.csv.truth.json").read_text())["seed"], int)
