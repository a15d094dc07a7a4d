"""Kill ``nifo run`` and ``nifo identify`` at random points: the output is all old, all new, or marked incomplete.

Each command first runs once to completion (the reference "new" file set), timed;
once more when that run compiled anything (a fresh checkout compiles its kernels in
the first run: the kills spread over what a run takes). Then,
4 times each (20 with ``NIFO_SLOW_TESTS=1``), the output directory is given an old content (the
previous result plus ``sentinel.json``, listed in the folder's ``.nifo-output``
marker as nifo's own), the command is started as a real
process and sent SIGINT, SIGTERM or SIGKILL after a random delay drawn
uniformly over its full run time (fixed seed). After each kill the output
must be exactly the old content (after a SIGKILL, the next run puts the last
complete one back before it starts), exactly the new file set (no sentinel), or
hold the ``INCOMPLETE`` marker; a SIGINT/SIGTERM message saying "nothing was
written" must be true. A last complete run must succeed and leave no
``.partial-*``/``.old-*`` directory anywhere.
"""

from __future__ import annotations

import hashlib
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nifo.io.atomic import INCOMPLETE
from nifo.io.ownership import write_marker
from nifo.io.loader import save_record
from nifo_core.simulate.quarter_car import SimConfig, simulate

from conftest import REPO

pytestmark = pytest.mark.usefixtures("sigint_deliverable")   # (conftest.py)

#: ./test.sh kills each command 4 times (issue 58: a short random series stays in the suite); the full series of
#: 20 (issue 56's acceptance) runs with NIFO_SLOW_TESTS=1, and NIFO_KILLS=N sets any other count
KILLS = int(os.environ.get("NIFO_KILLS", 20 if os.environ.get("NIFO_SLOW_TESTS") == "1" else 4))
#: how Python reports an interrupt while it is still starting up (importing site), before it runs any module
INTERPRETER_STARTING = "Fatal Python error: init_import_site"
SEED = 14
#: the preset's strut (paper Fig. 12a): a damper knee
KNEE_MODEL = "nifo_model: 1\nnonlinearities:\n  - {kind: velocity_deadzone, params: {knee: 0.03}}\n"


def _env() -> dict:
    env = {**os.environ, "PYTHONPATH": str(REPO), "PYTHONUNBUFFERED": "1"}
    env.pop("NIFO_FIGURE_WORKERS", None)   # killed with its figure helpers, as a user's nifo is (./test.sh turns them off)
    return env


def _snapshot(out: Path) -> dict[str, str] | None:
    if not out.exists():
        return None
    return {str(p.relative_to(out)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file()}


def _leftovers(root: Path) -> list[Path]:
    return [p for p in root.rglob(".*") if ".partial-" in p.name or ".old-" in p.name]


def _nifo(argv: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "nifo", *argv], cwd=cwd, env=_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def _full(argv: list[str], cwd: Path) -> float:
    t = time.monotonic()
    p = _nifo(argv, cwd)
    _, err = p.communicate(timeout=900)
    assert p.returncode == 0, err
    return time.monotonic() - t


def _record(tmp: Path) -> Path:
    """20 s of the paper's damper-knee strut on a 2.5 mm road: a run's time is then mostly its fixed part (imports,
    figures, report), which the kills must cover anyway."""
    from nifo_core.simulate.quarter_car import RandomRoad, preset

    sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=20.0, road=RandomRoad(2.5e-3)), rng=2)
    return save_record(tmp / "road.mcap", sim.record)


def _kill_trials(argv: list[str], out: Path, cwd: Path, t_full: float, rng: random.Random) -> dict[str, int]:
    reference = set(_snapshot(out) or {})
    assert reference and INCOMPLETE not in reference
    outcomes = {"old": 0, "new": 0, "incomplete": 0}
    whole = None     # the last complete content: a run killed by SIGKILL keeps it beside, the next run puts it back
    for k in range(KILLS):
        if not (out / INCOMPLETE).exists():
            (out / "sentinel.json").write_text(f'{{"trial": {k}}}')
            write_marker(out)   # old content nifo wrote: its marker lists the sentinel too
            whole = _snapshot(out)
        before = _snapshot(out)
        olds = (before, whole)
        sig = rng.choice([signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
        delay = rng.uniform(0.0, t_full)
        p = _nifo(argv, cwd)
        try:
            p.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            p.send_signal(sig)
        _, err = p.communicate(timeout=120)
        after = _snapshot(out)
        where = f"trial {k}: {sig.name} after {delay:.1f} s, exit {p.returncode}: {err.strip()[-300:]}"
        if after in olds:
            outcomes["old"] += 1
        elif after is not None and INCOMPLETE in after:
            outcomes["incomplete"] += 1
        else:
            assert after is not None and set(after) == reference, f"mixed output after {where}"
            outcomes["new"] += 1
        if "nothing was written" in err:
            assert after in olds, f"the message says nothing was written, but the output changed: {where}"
        if err.startswith(INTERPRETER_STARTING):
            # Ctrl-C in the interpreter's own first milliseconds (site.py reading the .pth files), before any line of
            # nifo runs: Python itself reports it, traceback and all, and exits 1. Measured here: a SIGINT 0.01-0.02 s
            # after the start; from 0.04 s nifo says "interrupted while starting". Out of nifo's reach; nothing can
            # have been written (a local run hit it: trial 0 of identify's series, SIGINT after 0.1 s on a busy host)
            assert after in olds and p.returncode == 1 and f"{REPO}{os.sep}nifo{os.sep}" not in err, where
            continue
        assert "Traceback" not in err, where
        if p.returncode == 130:   # SIGINT/SIGTERM caught: one line saying what was (not) written
            assert "interrupted" in err, where
        else:   # finished, or died of the signal before nifo had started writing anything
            # the whole stderr: a crash prints every thread's stack there (faulthandler, nifo.__main__); a local
            # suite run had one exit -11 after SIGTERM in ~200 kills of nifo run, before the stacks were printed
            assert p.returncode in (0, -signal.SIGKILL, -signal.SIGTERM, -signal.SIGINT), f"{where}\n{err}"
    return outcomes


def _compiled() -> list[float]:
    """When the checkout's compiled caches (numba's kernels and Python's bytecode, in nifo's and nifo_core's
    ``__pycache__``) and matplotlib's font cache last changed: a run that changed none compiled nothing."""
    import matplotlib

    dirs = [*(REPO / "nifo").rglob("__pycache__"), *(REPO / "nifo_core").rglob("__pycache__"),
            Path(matplotlib.get_cachedir())]
    return sorted(p.stat().st_mtime for d in dirs if d.is_dir() for p in d.iterdir())


def _series(argv: list[str], out: Path, cwd: Path, seed: int) -> dict[str, int]:
    """Reference run, KILLS random kills, then a complete run that must succeed."""
    caches = _compiled()
    t_full = _full(argv, cwd)     # the reference output; on a fresh checkout this run also compiles the kernels
    if _compiled() != caches:     # it compiled (or another process did beside it): the kills spread over what a
        print(f"nifo {argv[0]}: the reference run compiled ({t_full:.1f} s); timed again")
        t_full = _full(argv, cwd)  # run takes, not over a first compilation, so time a second complete one
    outcomes = _kill_trials(argv, out, cwd, t_full, random.Random(seed))
    _full(argv, cwd)
    assert not (out / INCOMPLETE).exists() and not (out / "sentinel.json").exists()
    return outcomes


@pytest.mark.slow
def test_run_and_identify_killed_at_random_points_leave_old_new_or_marked_output(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    data = _record(tmp_path)
    model = tmp_path / "model.yaml"
    model.write_text(KNEE_MODEL)
    # one record, without the loop and the refinement (their writing is the same atomic swap as the steps left):
    # the kills spread over a run of ~15 s rather than a minute
    run_argv = ["run", str(data), "--no-loop", "--no-refine", "--no-recording", "--out", str(tmp_path / "res")]
    id_argv = ["identify", str(data), "--model", str(model), "--out", str(tmp_path / "ident"), "--quiet"]
    # the two series run side by side (separate outputs, separate processes) to keep the test short
    with ThreadPoolExecutor(2) as pool:
        run = pool.submit(_series, run_argv, tmp_path / "res", tmp_path, SEED)
        ident = pool.submit(_series, id_argv, tmp_path / "ident", tmp_path, SEED + 1)
        run, ident = run.result(), ident.result()
    print(f"nifo run killed {KILLS}x: {run}; nifo identify killed {KILLS}x: {ident}")
    assert sum(run.values()) == sum(ident.values()) == KILLS
    assert not _leftovers(tmp_path), _leftovers(tmp_path)


_TERM_WHILE_READING = """
import os, signal, sys
import nifo.pipeline.identify as cmd   # the identify step, which nifo identify calls
from nifo.cli import main

real = cmd.accumulate
def accumulate(*args, **kwargs):   # the command is reading its data when the signal comes
    os.kill(os.getpid(), signal.SIGTERM)
    return real(*args, **kwargs)
cmd.accumulate = accumulate
sys.exit(main(sys.argv[1:]))
"""


_TEARDOWN = """
import os, signal, sys
import nifo.cli as cli
from nifo.__main__ import entry

class Teardown:
    def __del__(self):   # a module global's finalizer: runs when the interpreter tears its modules down
        sys.stderr.write("teardown ran\\n")

kept = Teardown()
real_main = cli.main

def main():   # the command's modules imported once entry() has started, as in nifo itself
    import nifo.pipeline.identify as cmd
    if sys.argv[1] == "identify-whole":   # the same command, not interrupted
        sys.argv[1] = "identify"
    elif sys.argv[1] == "identify":
        real = cmd.accumulate
        def accumulate(*args, **kwargs):
            os.kill(os.getpid(), signal.SIGTERM)
            return real(*args, **kwargs)
        cmd.accumulate = accumulate
    return real_main()

cli.main = main
sys.exit(entry())
"""


def test_a_command_that_returns_ends_without_the_interpreter_teardown_interrupted_or_not(tmp_path):
    """CI: SIGTERM 3.3 s into ``nifo identify`` printed its one line, then the interpreter's teardown aborted
    (``Fatal Python error: PyThreadState_Get``, exit -6): the interrupt had landed inside native library state.
    A command that returns, interrupted or finished, now ends after the exit hooks and before the teardown
    (nifo.__main__; it also saved 0.84 s at the end of nifo run). The control: a command line that argparse ends
    itself (``--version``) exits as Python does, its module globals finalized."""
    data = _record(tmp_path)
    model = tmp_path / "model.yaml"
    model.write_text(KNEE_MODEL)

    def nifo(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-c", _TEARDOWN, *argv], cwd=tmp_path, env=_env(), capture_output=True,
                              text=True, timeout=300)

    out = tmp_path / "ident"
    cut = nifo("identify", str(data), "--model", str(model), "--out", str(out))
    assert cut.returncode == 130, (cut.returncode, cut.stderr)
    assert cut.stderr.strip() == "nifo identify: interrupted; nothing was written", cut.stderr
    assert not out.exists() and not _leftovers(tmp_path)
    done = nifo("identify-whole", str(data), "--model", str(model), "--out", str(out), "--quiet")
    assert done.returncode == 0 and done.stderr == "", (done.returncode, done.stderr)
    assert (out / "identify.json").is_file() and (out / "model.json").is_file()
    own = nifo("--version")
    assert own.returncode == 0 and "teardown ran" in own.stderr, (own.returncode, own.stderr)


_CRASH_WHILE_READING = """
import os, signal, sys
import nifo.pipeline.identify as cmd
from nifo.__main__ import entry

real = cmd.accumulate
def accumulate(*args, **kwargs):   # a fault in native code while the command reads its data
    os.kill(os.getpid(), signal.SIGSEGV)
    return real(*args, **kwargs)
cmd.accumulate = accumulate
sys.exit(entry())
"""


def _identify_in_script(script: str, tmp: Path) -> tuple[subprocess.CompletedProcess, Path]:
    """``nifo identify`` of the kill test's record with the damper-knee model, run by ``script`` (``python -c``) in a
    process of its own; the finished process and the output folder it was given."""
    data = _record(tmp)
    model = tmp / "model.yaml"
    model.write_text(KNEE_MODEL)
    out = tmp / "ident"
    p = subprocess.run([sys.executable, "-c", script, "identify", str(data), "--model", str(model), "--out", str(out)],
                       cwd=tmp, env=_env(), capture_output=True, text=True, timeout=300)
    return p, out


def test_a_crash_in_native_code_prints_where_every_thread_was(tmp_path):
    """A segmentation fault (a local suite run: nifo run exited -11 after a SIGTERM, stderr empty but for the
    resource tracker) says where it happened: nifo's entry enables faulthandler, which prints every thread's
    Python stack before the process dies of the signal. Here the process faults itself inside identify's reading
    of its data (a real command otherwise); without faulthandler its stderr holds nothing of it."""
    p, out = _identify_in_script(_CRASH_WHILE_READING, tmp_path)
    assert p.returncode == -signal.SIGSEGV, (p.returncode, p.stderr)
    assert "Fatal Python error: Segmentation fault" in p.stderr, p.stderr
    assert "(most recent call first)" in p.stderr and "in accumulate" in p.stderr, p.stderr
    assert not out.exists()


def test_identify_terminated_by_sigterm_exits_130_as_run_does(tmp_path):
    """Issue 26: nifo identify killed with SIGTERM while computing exited -15 (run: 130). The signal is sent by
    the process itself while it reads its data (a real identify otherwise), so the point is deterministic."""
    p, out = _identify_in_script(_TERM_WHILE_READING, tmp_path)
    assert p.returncode == 130, (p.returncode, p.stderr)
    assert "interrupted; nothing was written" in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert not out.exists() and not _leftovers(tmp_path)
