"""Shared fixtures. Paths: REPO (this checkout), SHARED_DATA (../shared/data, real measured data)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("NIFO_SHARED_DATA", REPO.parent / "shared" / "data"))


def built_once(tmp_path_factory, name: str, build) -> Path:
    """``build(directory)`` once for the whole test run, across pytest-xdist's workers too; the directory.

    The expensive results several test files read (a ``nifo run`` of the sample, of the F-16, of the simulated
    pair) are built by the first worker that asks and read by the others: the workers share the run's base
    temporary directory, and an exclusive lock on ``name.lock`` there makes a second asker wait for the first
    build rather than repeat it. A build that raised leaves no ``.built`` mark, so the next asker builds again
    (and fails the same way). Readers must not write into the directory."""
    import fcntl

    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    target = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (target / ".built").is_file():
            if target.exists():
                import shutil

                shutil.rmtree(target)
            target.mkdir()
            build(target)
            (target / ".built").touch()
    return target


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (set NIFO_SHARED_DATA)")
    return SHARED_DATA


@pytest.fixture
def sigint_deliverable():
    """Ctrl-C reaches the processes the test starts, as from a terminal. A process inherits an *ignored* SIGINT, and
    a pytest worker had one (measured: ``-n 3``, tests/test_interrupt.py's SIGINT never came, exit 1); nifo rightly
    leaves an ignored signal ignored. Python's handler is put in for the test (children start with the default)."""
    import signal

    before = signal.getsignal(signal.SIGINT)
    if before is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        if before is signal.SIG_IGN:
            signal.signal(signal.SIGINT, before)


#: measured seconds per test file (`--durations=0` of a whole run on 2 cores, summed per file; refresh with
#: ``python tests/durations.py LOG``). Used only to hand the longest files out first: ``./test.sh`` runs the files on
#: every core (pytest-xdist, ``--dist loadfile``: a file's module fixtures are built once), and a long file taken
#: last would leave the other cores idle while it runs.
#: The order also decides what runs beside test_kill.py, a fifth to a quarter of the suite's CPU. A refresh of
#: 2026-11-28 put test_fleet_cluster.py (its Dask workers) fourth in line, where test_f16_loop.py was: the run took
#: 616 s instead of 570 s and test_kill.py 264 CPU-s instead of 199 (one run each; the host's own spread is ±30 s).
#: Compare whole runs before keeping a refresh (the CPU table at the end of each: tests/cpu_usage.py).
_DURATIONS = Path(__file__).with_name("durations.json")


def _file_of(nodeid: str) -> str:
    """A test's file name, the key of durations.json and of the CPU table."""
    return nodeid.split("::")[0].rsplit("/", 1)[-1]


def pytest_collection_modifyitems(config, items):
    if not _DURATIONS.is_file():
        return
    import json

    seconds = json.loads(_DURATIONS.read_text())
    typical = sorted(seconds.values())[len(seconds) // 2] if seconds else 0.0
    rank = {}
    for it in items:
        rank.setdefault(it.nodeid.split("::")[0], -seconds.get(_file_of(it.nodeid), typical))
    items.sort(key=lambda it: rank[it.nodeid.split("::")[0]])   # stable: a file's tests keep their order


def static_cubic_problem(seed: int, n: int, *, read: int | None = None):
    """An errors-in-variables problem for the bias correction (nifo_core.signal.bias_correction): ẍ2 = θ0·ẍ1 +
    θ1·ẍ1³ (θ = 0.8, 0.05) on three records of ``n`` samples at 200 Hz, each with a noise estimate of 10 % of its
    channels' RMS. Returns (model(θ, record), its least squares on the first ``read`` samples of each record (all:
    None), the records, the noise estimates)."""
    import numpy as np

    from nifo_core.signal.noise import ChannelNoise, NoiseEstimate
    from nifo_core.signal.record import Record

    rng = np.random.default_rng(seed)
    fs = 200.0
    cut = slice(None, read)

    def model(theta, rec):          # a static nonlinearity
        a = np.asarray(rec.spindle_accel, float)
        return theta[0] * a + theta[1] * a * a * a

    def fit(recs):                  # least squares on the noisy ẍ1: errors in variables, biased
        a = np.concatenate([np.asarray(r.spindle_accel, float)[cut] for r in recs])
        y = np.concatenate([np.asarray(r.body_accel, float)[cut] for r in recs])
        return np.linalg.lstsq(np.column_stack([a, a * a * a]), y, rcond=None)[0]

    recs, noise = [], []
    for k in range(3):
        a1 = rng.standard_normal(n) * (1 + k)
        rec = Record(fs_hz=fs, spindle_accel=a1, body_accel=model(np.array([0.8, 0.05]), Record(fs, a1, a1)))
        recs.append(rec)
        s1, s2 = 0.1 * float(np.std(a1)), 0.1 * float(np.std(rec.body_accel))
        noise.append(NoiseEstimate(f"r{k}", (ChannelNoise("spindle_accel", s1, 2 * s1 ** 2 / fs, 0.1, (1.0, 2.0)),
                                             ChannelNoise("body_accel", s2, 2 * s2 ** 2 / fs, 0.1, (1.0, 2.0)))))
    return model, fit, recs, noise


# ----------------------------------------------------------------------------- CPU per test file (tests/cpu_usage.py)
_CPU: dict = {}
_SESSION_START: list[float] = []


def pytest_sessionstart(session):
    import time

    _SESSION_START.append(time.monotonic())


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """CPU and wall clock read before and after the test's setup, call and teardown (so a module's fixtures count
    with its first and last test), added to its file's row."""
    from cpu_usage import add, usage

    before = usage()
    yield
    add(_CPU, _file_of(item.nodeid), before, usage())


def pytest_sessionfinish(session):
    if hasattr(session.config, "workeroutput"):      # an xdist worker: its table goes to the controller
        session.config.workeroutput["nifo_cpu"] = dict(_CPU)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    from cpu_usage import merge

    merge(_CPU, getattr(node, "workeroutput", {}).get("nifo_cpu", {}))


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    import time

    from cpu_usage import summary_lines

    if not _CPU or not _SESSION_START or hasattr(config, "workeroutput"):
        return
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    terminalreporter.write_sep("-", "CPU per test file (tests/cpu_usage.py)")
    for line in summary_lines(_CPU, time.monotonic() - _SESSION_START[0], cores):
        terminalreporter.write_line(line)
