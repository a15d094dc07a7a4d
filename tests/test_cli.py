"""Command-line conventions: ``--json`` on every command, ``--quiet``/``--verbose``, exit codes, progress.

The result directories come from :func:`test_run_cmd.pipeline` (one ``nifo run`` per session), so
each command's ``--json`` is checked on real results in seconds.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import os
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nifo.cli import COMMANDS, _jsonable, main
from nifo_core.errors import EXIT_CODES, USAGE_EXIT_CODE, InputError, NifoError
from test_run_cmd import pipeline

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "bags" / "sample" / "road_1mm"


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    out, code, _ = pipeline(tmp_path_factory)
    assert code == 0
    return out


def _json(argv: list[str]) -> tuple[int, dict, str]:
    """Run ``nifo`` in-process: (exit code, the one JSON document on stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    text = out.getvalue()
    assert text.count("\n") == 1, f"stdout must be exactly one JSON document: {text[:500]!r}"
    return code, json.loads(text), err.getvalue()


def _all_errors() -> list[type]:
    for mod in ("nifo_core.predict.model", "nifo_core.nifo.identify", "nifo_core.loop.closing", "nifo.io.loader", "nifo.io.bag",
                "nifo.fleet.cluster"):
        importlib.import_module(mod)
    found, todo = [], [NifoError]
    while todo:
        c = todo.pop()
        found.append(c)
        todo += c.__subclasses__()
    return found


def test_exit_codes_are_unique_per_class_listed_in_help_and_two_is_only_usage():
    classes = _all_errors()
    codes = {c.__name__: c.exit_code for c in classes}
    assert len(set(codes.values())) == len(classes), codes
    assert USAGE_EXIT_CODE == 2 and 2 not in codes.values() and InputError.exit_code != 2
    for name, code in codes.items():
        assert EXIT_CODES[name][0] == code, name
    helptext = subprocess.run([sys.executable, "-m", "nifo", "--help"], capture_output=True, text=True,
                              cwd=REPO, check=True).stdout
    for name, (code, _) in EXIT_CODES.items():
        assert f" {code}  {name}" in helptext, name
    assert "  2  usage" in helptext


def test_usage_error_exits_2_and_input_error_its_own_code(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["info", "--no-such-option", str(SAMPLE)])
    assert e.value.code == 2
    capsys.readouterr()
    code, doc, err = _json(["--json", "info", str(tmp_path / "missing.mcap")])
    assert code == doc["exit_code"] == 3 and doc["ok"] is False
    assert doc["files"][0]["exit_code"] == 3 and "missing.mcap" in doc["files"][0]["error"]
    code, doc, err = _json(["identify", str(tmp_path / "missing.mcap"), "--model", str(tmp_path / "m.yaml"),
                            "--out", str(tmp_path / "o"), "--json"])
    assert code == 3 and doc["error"]["type"] == "DataFileError" and doc["error"]["hint"]
    assert err.count("\n") == 1 and "Traceback" not in err


def test_every_command_prints_one_json_document(ran, tmp_path):
    sim = tmp_path / "sim.mcap"
    checks = {
        "simulate": (["simulate", "--out", str(sim), "--duration", "4", "--seed", "1"], ("out", "seed")),
        "info": (["info", str(SAMPLE)], ("files",)),
        "characterize": (["characterize", str(sim), "--out", str(tmp_path / "c"), "--grid", "6",
                          "--kinds", "coulomb"], ("suggested", "band_hz")),
        "identify": (["identify", str(SAMPLE), "--model", str(ran / "characterize" / "suggested_model.yaml"),
                      "--out", str(tmp_path / "i"), "--no-plots"], ("summary", "warnings")),
        "predict": (["predict", str(SAMPLE), "--model", str(ran / "identify"), "--out", str(tmp_path / "p"),
                     "--no-plots"], ("records",)),
        "loop": (["loop", str(SAMPLE), "--out", str(tmp_path / "l"), "--max-rounds", "1", "--grid", "6",
                  "--kinds", "coulomb"], ("added", "errors_before")),
        "report": (["report", str(ran / "identify"), "--out", str(tmp_path / "r.html"), "--no-levels"],
                   ("out", "size_bytes")),
        "view": (["view", str(ran / "identify"), "--save", str(tmp_path / "v.rrd"), "--no-data"], ("out",)),
        "export": (["export", str(ran / "identify"), "--out", str(tmp_path / "e"), "--points", "21"],
                   ("files", "measured_range", "forces")),
    }
    seen = set()
    for name, (argv, keys) in checks.items():
        code, doc, err = _json([*argv, "--json"])
        assert code == 0 and doc["ok"] and doc["command"] == name, (name, err[-2000:])
        assert all(k in doc for k in keys), (name, doc.keys())
        seen.add(name)
    # run: tests/test_run_cmd.py (its pipeline runs with --json); replay: test_replay_json below;
    # fleet: tests/test_fleet_cluster.py (on a real LocalCluster)
    assert seen | {"run", "replay", "fleet"} == set(COMMANDS)


def test_replay_json_in_a_subprocess_on_its_own_ros_domain():
    pytest.importorskip("rclpy")
    env = {**os.environ, "ROS_DOMAIN_ID": str(random.randint(60, 100)), "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-m", "nifo", "replay", str(SAMPLE), "--rate", "0", "--start", "118",
                           "--json"], capture_output=True, text=True, cwd=REPO, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    doc = json.loads(proc.stdout)
    assert doc["command"] == "replay" and doc["messages"] > 0


def test_replay_waits_only_for_the_topics_named_and_says_which_had_no_subscriber():
    """--wait-for: the start waits for those topics alone (run_pipeline.py names the Imu topics; waiting for a
    bag's tire-patch topic, which no node takes, held every replay the whole --wait). Nobody listens here: after
    the wait the replay says so on stderr and publishes everything (stdout stays one JSON document); a topic the
    bag does not hold is one line and the configuration exit code."""
    pytest.importorskip("rclpy")
    env = {**os.environ, "ROS_DOMAIN_ID": str(random.randint(60, 100)), "PYTHONPATH": str(REPO)}
    base = [sys.executable, "-m", "nifo", "replay", str(SAMPLE), "--rate", "0", "--start", "118", "--json"]
    proc = subprocess.run([*base, "--wait", "1", "--wait-for", "/nifo/spindle/imu", "/nifo/body/imu"],
                          capture_output=True, text=True, cwd=REPO, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "nifo replay: no subscriber on /nifo/spindle/imu, /nifo/body/imu after 1 s; replaying anyway" in proc.stderr
    assert json.loads(proc.stdout)["by_topic"].get("/nifo/tire_patch/displacement", 0) > 0   # still published
    bad = subprocess.run([*base, "--wait", "1", "--wait-for", "/nifo/spindle/imu", "/nope"], capture_output=True,
                         text=True, cwd=REPO, env=env, timeout=120)
    assert bad.returncode == EXIT_CODES["ConfigError"][0], bad.stderr
    assert "--wait-for /nope: not a topic this replay publishes" in bad.stderr and "Traceback" not in bad.stderr


def test_quiet_prints_nothing_on_stdout_and_verbose_shows_progress(tmp_path, capsys):
    assert main(["-q", "simulate", "--out", str(tmp_path / "a.csv"), "--duration", "3", "--seed", "2"]) == 0
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err == ""
    assert main(["simulate", "--out", str(tmp_path / "b.csv"), "--duration", "3", "--seed", "2", "--verbose"]) == 0
    cap = capsys.readouterr()
    assert "wrote" in cap.out and "simulate" in cap.err      # progress even for 3 s of data
    main(["simulate", "--out", str(tmp_path / "c.csv"), "--duration", "3", "--seed", "2"])   # back to normal


def test_progress_off_a_terminal_writes_plain_lines_and_nests():
    from nifo.progress import Progress, configure

    configure()
    buf = io.StringIO()
    with Progress(4, "outer", stream=buf, min_interval_s=0.0) as outer:
        for _ in range(2):
            with Progress(2, "inner", stream=buf, min_interval_s=0.0) as inner:
                inner.advance(2)
            outer.advance(2)
    text = buf.getvalue()
    assert "outer:  50.0 %" in text and "inner: 100.0 %" in text
    assert "\r" not in text and "\x1b[" not in text            # no terminal control codes in a log file
    configure(quiet=True)
    quiet = io.StringIO()
    with Progress(1, "hidden", stream=quiet, min_interval_s=0.0) as p:
        p.advance(1)
    assert quiet.getvalue() == ""
    configure()


def test_nifo_info_is_a_quick_look_that_loads_no_signal_processing():
    # nifo info reads and summarises a file: the core's front doors are lazy (nifo_core.signal), so it loads neither
    # scipy.signal nor numba nor the integrator (measured: 1.3-1.7 s -> 0.37-0.41 s, imports 1.2 s -> 0.3 s)
    from nifo.commands.run import SAMPLE_DIR

    heavy = ("scipy.signal", "numba", "nifo_core.signal.integrate", "nifo_core.signal.spectral")
    code = ("import sys\nfrom nifo.cli import main\n"
            f"rc = main(['info', {str(SAMPLE_DIR / 'road_1mm')!r}])\n"
            f"print(rc, [m for m in {heavy!r} if m in sys.modules])\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip().splitlines()[-1] == "0 []", p.stdout


def test_nifo_help_lists_every_command_without_importing_one(capsys):
    """``nifo --help``, ``nifo --version`` and a mistyped command need the commands' names and lines only: none of
    their modules (each imports its step and the libraries) is imported (measured: ``nifo --help`` 1.97 -> 0.09 s),
    and the help is the full parser's, line for line; asked before a command (``nifo -h run``) it lists every
    command too (it listed that one alone)."""
    from nifo.cli import COMMANDS, build_parser, main

    assert build_parser(summary=True).format_help() == build_parser().format_help()
    with pytest.raises(SystemExit) as done:
        main(["-h", "run"])
    listed = capsys.readouterr().out
    assert done.value.code == 0 and all(f"\n    {name}" in listed for name in COMMANDS), listed
    code = ("import sys\nfrom nifo.cli import main\n"
            "for argv in (['--help'], ['--version'], ['rnu']):\n"
            "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
            "print([m for m in sys.modules if m.startswith('nifo.commands.') or m in ('numpy', 'scipy')])\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert p.stdout.strip().splitlines()[-1] == "[]", p.stdout
    assert "run          the whole job" in p.stdout and "invalid choice: 'rnu'" in p.stderr


def test_every_name_of_a_lazy_front_door_is_its_modules_own():
    import nifo_core.signal as front

    assert "Record" in dir(front) and len(front.__all__) == len(set(front.__all__))
    for name in front.__all__:
        value = getattr(front, name)
        owner = getattr(value, "__module__", None)
        assert owner in (None, "typing") or owner.startswith("nifo_core.signal."), (name, owner)   # Literal aliases
    with pytest.raises(AttributeError):
        front.no_such_name
    import nifo_core.signal.integrate   # noqa: F401  (the submodule of the same name as a function: not shadowing it)
    from nifo_core.signal import integrate
    assert callable(integrate) and integrate.__module__ == "nifo_core.signal.integrate"


@pytest.mark.parametrize("command", ["loop", "characterize"])
@pytest.mark.parametrize("mass", ["-3", "0", "nan", "inf", "300kg"])
def test_a_sprung_mass_that_is_not_one_is_a_usage_error_before_any_data_is_read(command, mass, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main([command, str(SAMPLE), "--m2", mass, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "argument --m2:" in err and "e.g. --m2 300" in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("flag, value, says", [
    ("--max-rounds", "0", "0 must be a whole number in 1..10"),
    ("--max-rounds", "11", "11 must be a whole number in 1..10"),
    ("--max-rounds", "two", "'two' is not a whole number"),
    ("--fit-fraction", "0.95", "0.95 must be in [0.3, 0.9]"),
    ("--refine-seconds", "2", "2 must be at least 5 s"),
    ("--refine-seconds", "x", "'x' is not a number"),
])
def test_a_loop_setting_the_loop_refuses_is_a_usage_error_before_any_data_is_read(flag, value, says, tmp_path, capsys):
    """The loop's own rule (LoopSettings) checks the flag as it is parsed: before, --max-rounds 0 was refused after
    the data were read and the settings printed."""
    with pytest.raises(SystemExit) as e:
        main(["loop", str(SAMPLE), flag, value, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and f"argument {flag}: {says}" in err, err
    assert not (tmp_path / "out").exists()


def test_a_loop_setting_it_accepts_reaches_the_loop():
    from nifo.cli import build_parser

    args = build_parser().parse_args(["loop", str(SAMPLE), "--out", "x", "--max-rounds", "10", "--fit-fraction",
                                      "0.3", "--refine-seconds", "5"])
    assert (args.max_rounds, args.fit_fraction, args.refine_seconds) == (10, 0.3, 5.0)


def test_json_summary_writes_a_nan_or_infinite_number_as_null():
    # `nifo loop --json` on a control case: a per-band residual of NaN made the summary's json.dumps raise
    # (exit 1, traceback) after the loop had written its results
    doc = {"a": float("nan"), "b": [np.float64("inf"), 1.5], "c": {"d": np.float32(-np.inf)}, "e": 2}
    assert json.loads(json.dumps(_jsonable(doc), allow_nan=False)) == {"a": None, "b": [None, 1.5],
                                                                       "c": {"d": None}, "e": 2}
