"""One writer per output folder (issue 56): two commands on one ``--out`` never leave neither result.

Before: two ``nifo run --out SAME`` started together ended with one traceback (``FileNotFoundError ... INCOMPLETE``
in ``staged_run``), one exit 0, and no ``SAME`` at all. Now the output is locked for the whole command
(:mod:`nifo.io.lock`): the second command is refused at once (exit 15) with one line naming the first one's process,
and a command killed while it writes leaves its previous result beside the folder, put back by the next writer.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nifo.io import lock
from nifo.io.atomic import INCOMPLETE, MARKER, staged_dir
from nifo.io.lock import lock_path, output_lock
from nifo.io.ownership import read_marker, unowned
from nifo_core.errors import OutputBusyError

from conftest import REPO
from fuzz_engine import cli

#: the acceptance: two writers at once on one folder, 20 times
TRIALS = 20

#: a cheap writer that goes the way ``nifo run`` does (the output locked for the whole command, staged_run, each
#: file claimed as it is written), started as its own process: ``WRITER OUT TAG N [SLEEP]``
WRITER = """
import sys, time
from nifo.io.atomic import claim, staged_run
from nifo.io.lock import output_lock
from nifo_core.errors import NifoError

out, tag, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
pause = float(sys.argv[4]) if len(sys.argv) > 4 else 0.01
try:
    with output_lock(out), staged_run(out) as d:
        print("writing", flush=True)
        (d / "step").mkdir()
        for i in range(n):
            p = d / "step" / f"{i}.txt"
            claim(p)
            p.write_text(tag * 1000)
            time.sleep(pause)
except NifoError as err:
    print(f"error: {err}", file=sys.stderr)
    sys.exit(err.exit_code)
"""

#: holds the lock of OUT until killed, after saying so: ``HOLDER OUT``
HOLDER = """
import sys, time
from nifo.io.lock import output_lock
from nifo.io.ownership import set_invocation

set_invocation(["run", "--out", sys.argv[1]])
with output_lock(sys.argv[1]):
    print("held", flush=True)
    time.sleep(600)
"""


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO), "PYTHONUNBUFFERED": "1"}


def _start(script: str, *argv: str, cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", script, *argv], cwd=cwd, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _holding(out: Path, cwd: Path) -> subprocess.Popen:
    p = _start(HOLDER, str(out), cwd=cwd)
    assert p.stdout.readline().strip() == "held", p.stderr.read()
    return p


def _complete(out: Path) -> str | None:
    """The writer's tag when ``out`` holds one writer's complete result (marker complete, every file of one tag),
    else None."""
    doc = read_marker(out)
    files = sorted((out / "step").glob("*.txt")) if (out / "step").is_dir() else []
    tags = {f.read_text()[:1] for f in files}
    if doc is None or not doc.get("complete") or (out / INCOMPLETE).exists() or len(tags) != 1 or unowned(out):
        return None
    return tags.pop()


def test_two_writers_at_once_on_one_folder_leave_exactly_one_complete_result_every_time(tmp_path):
    """20 trials of two writers started together on a folder holding a complete earlier result; in one trial in
    three one of them is killed (SIGKILL) at a random moment. After each: one complete result in the folder (the
    earlier one, or a writer's), or — only after a kill — the killed writer's INCOMPLETE folder with the earlier
    result kept beside it, which the next writer puts back. Never neither, never a traceback; a refusal is exit 15
    naming the other process."""
    rng = random.Random(56)
    out = tmp_path / "SAME"
    first = _start(WRITER, str(out), "o", "5", cwd=tmp_path)
    assert first.wait(60) == 0, first.stderr.read()
    outcomes = {"one wrote, one refused": 0, "both wrote in turn": 0, "killed": 0}
    for k in range(TRIALS):
        before = _complete(out)
        assert before is not None, f"trial {k}: no complete result to start from"
        tags = ("ab"[k % 2], "cd"[k % 2])
        procs = [_start(WRITER, str(out), t, str(rng.randint(3, 12)), cwd=tmp_path) for t in tags]
        victim = rng.randrange(2) if k % 3 == 2 else None
        if victim is not None:
            time.sleep(rng.uniform(0.2, 1.2))
            procs[victim].kill()
        results = [(p.wait(60), p.stdout.read(), p.stderr.read()) for p in procs]
        for i, (code, _, err) in enumerate(results):
            assert "Traceback" not in err, err
            if i == victim and code == -signal.SIGKILL:
                continue
            assert code in (0, OutputBusyError.exit_code), (k, code, err)
            if code == OutputBusyError.exit_code:
                assert len(err.strip().splitlines()) == 1 and "is being written by another nifo command (process " \
                    in err and "Fix: wait until that command has ended" in err, err
        now = _complete(out)
        wrote = [tags[i] for i, (code, _, _) in enumerate(results) if code == 0]
        if now is None:      # only a kill may leave the folder incomplete; the earlier result waits beside it
            assert victim is not None and (out / INCOMPLETE).is_file(), (k, results)
            olds = [p for p in tmp_path.glob(".SAME.old-*")]
            assert len(olds) == 1 and _complete(olds[0]) is not None, (k, olds)
            repair = _start(WRITER, str(out), "o", "2", cwd=tmp_path)
            assert repair.wait(60) == 0, repair.stderr.read()
            outcomes["killed"] += 1
        else:
            # a writer that exited 0 wrote it; or the earlier result stayed (the other was refused, or killed); or
            # the killed one had finished writing before the kill came
            done = wrote + ([tags[victim]] if victim is not None else [])
            assert now in done or (now == before and (victim is not None or not wrote)), (k, now, before, results)
            key = "killed" if victim is not None else (
                "one wrote, one refused" if len(wrote) == 1 else "both wrote in turn")
            outcomes[key] += 1
    print(f"{TRIALS} trials: {outcomes}")
    assert outcomes["one wrote, one refused"] >= 5     # the writers did overlap: the lock was tested
    last = _start(WRITER, str(out), "z", "2", cwd=tmp_path)
    assert last.wait(60) == 0, last.stderr.read()
    assert _complete(out) == "z" and sorted(p.name for p in tmp_path.iterdir()) == ["SAME"]


def test_two_nifo_runs_on_one_folder_one_refused_naming_the_other(tmp_path):
    """The issue's case with real commands: ``nifo run --out SAME`` twice at once, then ``nifo identify --out SAME``
    while a ``nifo run`` writes it, and ``nifo identify --out SAME/identify`` (inside it)."""
    from test_kill import KNEE_MODEL, _record

    data = _record(tmp_path)
    model = tmp_path / "knee.yaml"
    model.write_text(KNEE_MODEL)
    out = tmp_path / "SAME"
    run = [sys.executable, "-m", "nifo", "run", str(data), "--out", str(out), "--no-loop", "--no-refine",
           "--no-recording", "-q"]
    a = subprocess.Popen(run, cwd=tmp_path, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lock = tmp_path / ".SAME.lock"      # a's imports done and its lock taken (a fixed sleep lost the race under load)
    t0 = time.monotonic()
    while not (lock.is_file() and f'"pid": {a.pid}' in lock.read_text()):
        assert a.poll() is None and time.monotonic() - t0 < 120, "the first nifo run never took its lock"
        time.sleep(0.05)
    b = subprocess.run(run, cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=120)
    inside = subprocess.run([sys.executable, "-m", "nifo", "identify", str(data), "--model", str(model), "--out",
                             str(out / "identify"), "-q"], cwd=tmp_path, env=_env(), capture_output=True, text=True,
                            timeout=120)
    assert a.wait(600) == 0, a.stderr.read()
    assert b.returncode == OutputBusyError.exit_code, b.stderr
    assert f"SAME: is being written by another nifo command (process {a.pid}: nifo run " in b.stderr, b.stderr
    assert inside.returncode == OutputBusyError.exit_code and "lies in" in inside.stderr and \
        f"(process {a.pid}: nifo run" in inside.stderr, inside.stderr
    assert read_marker(out)["complete"] and not unowned(out, limit=50)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".SAME")) == []


def test_a_held_lock_names_its_process_and_a_dead_ones_is_taken_over(tmp_path):
    out = tmp_path / "res"
    holder = _holding(out, tmp_path)
    try:
        with pytest.raises(OutputBusyError, match=rf"res: is being written by another nifo command \(process "
                                                  rf"{holder.pid}: nifo run --out .*res, since .*\)\. Fix: wait"):
            with output_lock(out):
                pass
        code, _, err = cli(["characterize", "whatever.csv", "--out", str(out)])     # before any work
        assert code == 15 and "is being written by another nifo command" in err and len(err.splitlines()) == 1
    finally:
        holder.kill()
        holder.wait()
    assert lock_path(out).is_file()       # SIGKILL: the file stays, its lock went with the process
    with output_lock(out):
        assert json.loads(lock_path(out).read_text())["pid"] == os.getpid()
    assert not lock_path(out).exists() and not out.exists()    # released: nothing left, the folder made for it gone


def _refused_while(holder: subprocess.Popen, match: str, block) -> None:
    """``block()`` raises OutputBusyError matching ``match`` while ``holder`` runs; then ``holder`` is ended."""
    try:
        with pytest.raises(OutputBusyError, match=match):
            block()
    finally:
        holder.kill()
        holder.wait()


def test_a_folder_being_written_refuses_writers_inside_it_and_a_writer_of_it_refuses_one_inside(tmp_path):
    def write(out):
        with staged_dir(out):
            pass

    run = tmp_path / "R"
    _refused_while(_holding(run, tmp_path), r"R/identify: lies in .*R, which another nifo command is writing",
                   lambda: write(run / "identify"))
    run.mkdir(exist_ok=True)
    _refused_while(_holding(run / "identify", tmp_path), r"R: holds .*identify, which another nifo command is writing",
                   lambda: write(run))


def test_in_one_process_the_lock_is_reentrant_and_a_step_of_a_run_takes_none_of_its_own(tmp_path):
    out = tmp_path / "res"
    with output_lock(out):
        with output_lock(out), staged_dir(out) as d:
            (d / "a.json").write_text("{}")
        assert lock_path(out).is_file()
    assert not lock_path(out).exists() and (out / "a.json").is_file() and (out / MARKER).is_file()


def test_without_flock_the_lock_file_is_created_exclusively_and_a_dead_processes_is_taken_over(tmp_path,
                                                                                               monkeypatch):
    """Some network file systems have no flock (ENOLCK): the lock file's own existence is the lock, and one left by
    a process that is gone is taken over."""
    def no_flock(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_flock)
    out = tmp_path / "res"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    lock_path(out).parent.mkdir(parents=True, exist_ok=True)
    lock_path(out).write_text(json.dumps({"pid": dead.pid, "host": lock.socket.gethostname(), "command": "x"}))
    with output_lock(out):
        assert json.loads(lock_path(out).read_text())["pid"] == os.getpid()
    assert not lock_path(out).exists()
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    lock_path(out).write_text(json.dumps({"pid": alive.pid, "host": lock.socket.gethostname(),
                                          "command": "nifo run --out res"}))

    def take():
        with output_lock(out):
            pass

    _refused_while(alive, rf"process {alive.pid}: nifo run --out res", take)
