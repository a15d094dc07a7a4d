"""Figures rendered by helper processes (nifo.plots.writer): the same files, all written before the batch ends,
nothing written after it fails, no figure lost with a helper, no helper left behind by a killed step."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nifo.plots import pyplot, save_figure
from nifo.plots import writer

ROOT = Path(__file__).resolve().parents[1]


def _figure(n: int = 200):
    import numpy as np

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(4, 3))
    x = np.linspace(1, 100, n)
    ax.loglog(x, 1 / (1 + (x / 10) ** 2), label="$|T_{21}|$")
    ax.set_xlabel("frequency [Hz]")
    ax.legend()
    return fig


def _helpers() -> list[int]:
    pool = writer._get_pool()
    assert pool is not None, "no helper pool on this machine"
    return [p.pid for p in pool._processes.values()]


@pytest.fixture(autouse=True)
def _two_helpers(monkeypatch):
    monkeypatch.setenv(writer.WORKERS_ENV, "2")
    writer._reset_pool()
    monkeypatch.setattr(writer, "_pool_failed", False)
    yield
    writer._reset_pool()


def test_batch_writes_the_same_files_as_the_calling_process_in_a_helper(tmp_path):
    writer.write_files(_figure(), tmp_path / "direct.png", 130)
    with writer.figure_batch():
        assert save_figure(_figure(), tmp_path / "helper.png") == tmp_path / "helper.png"
        (task,) = writer._batch.get()            # PNG and SVG in one task: one unpickling, one layout
        assert [Path(p).name for p in task[2]] == ["helper.png", "helper.svg"]
        helpers = _helpers()
    assert helpers and os.getpid() not in helpers
    for suffix in (".png", ".svg"):     # the same bytes, the SVG's ids included (a fixed salt)
        assert (tmp_path / f"helper{suffix}").read_bytes() == (tmp_path / f"direct{suffix}").read_bytes(), suffix
    assert (tmp_path / "helper.svg").stat().st_size > 1000 and (tmp_path / "helper.svg").read_text().startswith("<?xml")


def test_the_same_figure_gives_the_same_svg(tmp_path):
    """matplotlib salts an SVG's ids at random: two runs on the same data differed in every SVG they wrote."""
    for k in range(2):
        save_figure(_figure(), tmp_path / f"f{k}.png")
    assert (tmp_path / "f0.svg").read_bytes() == (tmp_path / "f1.svg").read_bytes()


def test_outside_a_batch_the_figure_is_written_at_once(tmp_path):
    save_figure(_figure(), tmp_path / "now.png")
    assert (tmp_path / "now.png").is_file() and (tmp_path / "now.svg").is_file()


def test_a_failing_block_leaves_nothing_written_after_it(tmp_path):
    out = tmp_path / "staged"
    out.mkdir()
    with pytest.raises(KeyboardInterrupt):
        with writer.figure_batch():
            for k in range(6):
                save_figure(_figure(4000), out / f"f{k}.png")
            raise KeyboardInterrupt
    before = sorted(os.listdir(out))
    time.sleep(1.5)
    assert sorted(os.listdir(out)) == before    # cancelled or finished when the batch ended, none later


def test_a_rendering_error_is_raised_as_it_was_when_the_batch_ends(tmp_path):
    with pytest.raises(FileNotFoundError):
        with writer.figure_batch():
            save_figure(_figure(), tmp_path / "no such folder" / "f.png")


def test_no_figure_is_lost_with_a_helper(tmp_path):
    with writer.figure_batch():
        for pid in _helpers():
            os.kill(pid, signal.SIGKILL)
        time.sleep(0.3)
        for k in range(3):
            save_figure(_figure(), tmp_path / f"f{k}.png")
    for k in range(3):
        assert (tmp_path / f"f{k}.png").stat().st_size > 1000 and (tmp_path / f"f{k}.svg").is_file()


def test_helpers_die_with_a_killed_step(tmp_path):
    code = ("import os, signal, sys\n"
            "from nifo.plots import writer\n"
            "pool = writer._get_pool(); pool.submit(writer._warm).result()\n"
            "print(' '.join(str(p.pid) for p in pool._processes.values()), flush=True)\n"
            "os.kill(os.getpid(), signal.SIGKILL)\n")
    p = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(ROOT), writer.WORKERS_ENV: "2"})
    assert p.returncode == -signal.SIGKILL, p.stderr
    pids = [int(v) for v in p.stdout.split()]
    assert pids
    deadline = time.monotonic() + 5
    alive = pids
    while alive and time.monotonic() < deadline:
        time.sleep(0.1)
        alive = [pid for pid in pids if _running(pid)]
    assert not alive, f"helpers {alive} outlived the killed step"


def test_abandoned_helpers_leave_no_manager_thread_for_the_exit_hook_to_race():
    """After abandon_helpers the pool's manager thread has ended and closed its pipe: Python 3.11's exit hook
    writes to that pipe unguarded (CI: a traceback, Bad file descriptor, after an interrupted nifo run)."""
    pool = writer._get_pool()
    pool.submit(writer._warm).result()
    manager, wakeup = pool._executor_manager_thread, pool._executor_manager_thread_wakeup
    assert manager.is_alive() and not wakeup._closed
    writer.abandon_helpers()
    assert not manager.is_alive() and wakeup._closed


def test_a_command_that_fails_ends_its_helpers_at_once_and_a_later_one_starts_them_anew(tmp_path):
    """A failed command (an input error after its helpers started) kills them at once rather than at exit, when they
    have finished importing matplotlib for nothing; a later command of the same process has helpers again."""
    from nifo.cli import main

    writer.start_helpers()
    pids = _helpers()
    assert main(["-q", "run", str(tmp_path / "missing.mcap"), "--out", str(tmp_path / "out")]) == 3
    assert writer._pool is None and not any(_running(p) for p in pids)
    assert sorted(_helpers()) != sorted(pids)     # started anew


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _slow_figure():
    """A figure whose rendering takes a second or two (a thousand text objects: 1.7 CPU-s for its PNG and SVG)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(4, 3))
    for k in range(1000):
        ax.text((k % 60) / 60, (k // 60) / 50, f"{k}", fontsize=4)
    return fig


def test_inside_a_run_a_step_does_not_wait_for_its_figures_and_the_run_lists_them(tmp_path):
    """nifo run (deferred_figures inside staged_run): a step's folder is written in place and its batch ends
    while its figures still render; the run's end waits for them and the step's marker lists them, so a later
    nifo may replace the folder."""
    from nifo.io.atomic import claim, staged_dir, staged_run
    from nifo.io.ownership import foreign_entries

    out = tmp_path / "res"
    with staged_run(out) as run, writer.deferred_figures():
        with staged_dir(run / "step") as here, writer.figure_batch():
            assert here == run / "step"                          # in place: no scratch folder to rename
            save_figure(_slow_figure(), here / "slow.png")
            t = time.monotonic()
        assert time.monotonic() - t < 1.0 and not (run / "step" / "slow.svg").exists()   # still rendering
        with staged_dir(run / "next") as here:
            claim(here / "result.json")     # as every writer inside a run does (nifo.io.results.write_json)
            (here / "result.json").write_text("{}")
        writer.wait_figures()
        assert (run / "step" / "slow.png").stat().st_size > 1000 and (run / "step" / "slow.svg").is_file()
    assert foreign_entries(out / "step") == [] and foreign_entries(out) == []
    assert sorted(p.name for p in out.iterdir()) == [".nifo-output", "next", "step"]


@pytest.mark.parametrize("error", [KeyboardInterrupt, RuntimeError])
def test_a_run_that_fails_after_a_step_leaves_the_old_output_and_nothing_written_later(tmp_path, monkeypatch, error):
    """An interruption (Ctrl-C or SIGTERM: a KeyboardInterrupt) while figures render kills the helpers at once rather
    than waiting for the running figures (before: SIGINT 3-5 s into ``nifo run`` of a 20 s record took 0.9-1.6 s to
    end); another error waits for them and keeps the helpers. Either way the old output stays and nothing is
    written later."""
    import nifo.interrupt
    from nifo.io.atomic import claim, staged_dir, staged_run

    monkeypatch.setattr(nifo.interrupt, "_signalled", False)   # this process was not signalled
    out = tmp_path / "res"
    with staged_run(out) as run:
        claim(run / "old.json")
        (run / "old.json").write_text("{}")
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(error):
        with staged_run(out) as run, writer.deferred_figures():
            with staged_dir(run / "step") as here, writer.figure_batch():
                for k in range(2):      # two rendering when the run fails
                    save_figure(_slow_figure(), here / f"f{k}.png")
            time.sleep(0.3)
            assert not any((here / f"f{k}.svg").exists() for k in range(2))   # still rendering: a wait to skip
            t = time.monotonic()
            raise error
    took = time.monotonic() - t
    if error is KeyboardInterrupt:
        assert took < 0.5 and writer._pool is None, f"the interrupted run waited {took:.2f} s for its figures"
    else:
        assert writer._pool is not None
    assert sorted(p.name for p in out.iterdir()) == before
    time.sleep(1.5)
    assert sorted(p.name for p in out.iterdir()) == before and not list(tmp_path.glob(".res*"))


_WAITING_SCRIPT = """
import sys
from pathlib import Path
from nifo.interrupt import watch
watch()
sys.path.insert(0, sys.argv[2])
from test_figure_writer import _slow_figure
from nifo.plots import save_figure, writer

out = Path(sys.argv[1])
with writer.deferred_figures():
    with writer.figure_batch():
        for k in range(2):
            save_figure(_slow_figure(), out / f"f{k}.png")
    print("waiting", flush=True)
    writer.wait_figures()
print("all written", flush=True)
"""


@pytest.mark.usefixtures("sigint_deliverable")   # (conftest.py: a pytest worker's children inherit an ignored SIGINT)
def test_ctrl_c_while_a_run_waits_for_its_figures_ends_it_at_once(tmp_path):
    """SIGINT while ``nifo run`` waits for its figures (``wait_figures``, before the report): raised at once, the
    helpers killed, not taken as one more figure error to raise after all of them are done."""
    out = tmp_path / "figs"
    out.mkdir()
    p = subprocess.Popen([sys.executable, "-c", _WAITING_SCRIPT, str(out), str(Path(__file__).parent)], cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT), writer.WORKERS_ENV: "2"})
    try:
        assert p.stdout.readline().strip() == "waiting", p.stderr.read()
        time.sleep(0.3)
        written = sorted(f.name for f in out.iterdir())
        assert not any(n.endswith(".svg") for n in written), written    # still rendering: there is a wait to skip
        t = time.monotonic()
        p.send_signal(signal.SIGINT)
        stdout, stderr = p.communicate(timeout=60)
        took = time.monotonic() - t
    finally:
        if p.poll() is None:
            p.kill()
    assert "all written" not in stdout and "KeyboardInterrupt" in stderr, stderr
    assert took < 1.0, f"the interrupted wait took {took:.2f} s to end"
    written = sorted(f.name for f in out.iterdir())
    time.sleep(1.5)
    assert sorted(f.name for f in out.iterdir()) == written     # the helpers are gone: nothing written later


def test_a_signal_while_the_helpers_are_spawned_is_held_until_they_are_whole():
    """A helper reads its start-up data from the command's process: Ctrl-C landing in that write left a half-started
    helper whose EOFError traceback reached the terminal (tests/test_kill.py, SIGINT 2.8 s into nifo run). The
    spawning holds SIGINT/SIGTERM back and delivers them when it is done."""
    from nifo.interrupt import signals_held as _signals_held

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    before = signal.signal(signal.SIGINT, interrupt)
    try:
        done = []
        with pytest.raises(KeyboardInterrupt, match="signal 2"):
            with _signals_held():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)            # a signal is handled at the next bytecode: held, nothing raised here
                done.append("spawned")
        assert done == ["spawned"]
        assert signal.getsignal(signal.SIGINT) is interrupt     # the command's own handler is back
    finally:
        signal.signal(signal.SIGINT, before)


def test_a_script_without_a_main_guard_is_not_run_again_by_the_helpers(tmp_path):
    # a user's script that calls nifo at module level (no `if __name__ == "__main__":`): spawned helpers import
    # the parent's main module, and would run the script once more each (measured: its nifo run three times at once,
    # into one folder). Every run of the script appends its pid; the figures must still come from the helpers.
    runs = tmp_path / "runs.txt"
    script = tmp_path / "user_script.py"
    script.write_text(
        "import os, sys\n"
        f"sys.path.insert(0, {str(ROOT)!r}); sys.path.insert(0, {str(ROOT / 'tests')!r})\n"
        f"open({str(runs)!r}, 'a').write(f'{{os.getpid()}}\\n')\n"
        "from test_figure_writer import _figure\n"
        "from nifo.plots import save_figure\n"
        "from nifo.plots import writer\n"
        "with writer.figure_batch():\n"
        f"    save_figure(_figure(), {str(tmp_path / 'fig.png')!r})\n"
        "print(len(writer._get_pool()._processes))\n")
    env = {**os.environ, writer.WORKERS_ENV: "2"}
    p = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "2"                                   # two helpers rendered
    assert len(runs.read_text().split()) == 1, runs.read_text()     # the script ran once (3 times before)
    assert (tmp_path / "fig.png").is_file() and (tmp_path / "fig.svg").is_file()


_CRASH_IN_A_HELPER = """
import faulthandler
from concurrent.futures.process import BrokenProcessPool
from nifo.plots import writer

try:   # a fault in the helper's native code (Agg, FreeType, the PNG encoder), as a figure's rendering could have
    writer._get_pool().submit(faulthandler._sigsegv).result(timeout=120)
except BrokenProcessPool:
    print("the pool is broken")
"""


def test_a_helper_that_crashes_in_native_code_prints_where_it_was():
    """A helper that dies of SIGSEGV was only a broken pool (its figure rendered again by the step): its stderr,
    which is the step's, now carries the crash and the helper's stack, as the step's own process does."""
    env = {**os.environ, writer.WORKERS_ENV: "1", "PYTHONPATH": str(ROOT)}
    p = subprocess.run([sys.executable, "-c", _CRASH_IN_A_HELPER], env=env, capture_output=True, text=True,
                       timeout=180)
    assert p.returncode == 0 and p.stdout.strip() == "the pool is broken", (p.returncode, p.stdout, p.stderr)
    assert "Fatal Python error: Segmentation fault" in p.stderr, p.stderr
    assert "_process_worker" in p.stderr, p.stderr     # the helper's stack: concurrent.futures' worker loop
