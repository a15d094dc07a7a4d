"""benchmarks/profile_run.py ``--floor``: own time sorted by what runs, every thread profiled, the figures' rendering
timed with the profiler off (the tool itself is run by hand; its figures are in its docstring and issue 29's notes)."""

from __future__ import annotations

import sys
import threading

import numpy as np
import pytest
import scipy.fft

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import profile_run as pr  # noqa: E402


def _spin_python(n: int) -> float:
    s = 0.0
    for i in range(n):
        s += (i % 7) * 0.5
    return s


def test_the_floor_sorts_own_time_by_what_runs_and_sees_threads_and_rendering_apart(tmp_path):
    numba = pytest.importorskip("numba")
    from nifo.plots import pyplot
    from nifo.plots import writer

    kernel = numba.njit(_spin_python)
    kernel(10)   # compiled before the profile starts
    x = np.random.default_rng(0).standard_normal(2 ** 18)
    real_write = writer._write
    with pr.FloorProfile() as floor:
        kernel(50_000_000)
        _spin_python(300_000)
        worker = threading.Thread(target=lambda: [scipy.fft.rfft(x) for _ in range(50)])
        worker.start()
        worker.join()
        fig = pyplot().figure(figsize=(4, 3))
        fig.gca().plot(x[:2000])
        writer.write_files(fig, tmp_path / "f.png", 100)
        pyplot().close(fig)
    assert writer._write is real_write and threading.getprofile() is None   # nothing left behind
    assert (tmp_path / "f.png").is_file() and (tmp_path / "f.svg").is_file()
    assert len(floor.profiles) == 2                                       # this thread and the worker
    stats = floor.stats()
    names = {(file, name) for file, _, name in stats.stats}
    # the rendering ran with the profiler off: no draw of matplotlib's in the profile, its CPU timed apart
    assert not any("matplotlib" in file and name == "draw" for file, name in names)
    assert floor.rendering_s > 0.01
    kinds = pr.own_time_by_kind(stats, pr.numba_kernels(), floor.rendering_s)
    assert set(kinds) == set(pr.KINDS)
    assert kinds["compiled: numba kernels"] > 0.01                 # the kernel, known from its dispatcher
    assert kinds["compiled: FFT"] > 0.005                          # on the worker thread
    assert kinds["Python"] > kinds["compiled: numba kernels"] / 100   # the interpreted loop is not a kernel
    assert kinds["figures: rendering (without the profiler)"] == floor.rendering_s
    lines = pr.floor_lines(kinds, 2)
    arith = sum(kinds[k] for k in pr.KINDS[:3])
    assert lines[-1].startswith("floor on 2 core(s)") and f"{arith / 2:.1f} s" in lines[-1]


def test_a_built_in_is_sorted_by_its_name_and_a_kernel_by_its_code():
    kernels = {("/x/timesim.py", 191, "run")}
    assert pr._kind("/x/timesim.py", 191, "run", kernels) == "compiled: numba kernels"
    assert pr._kind("/x/timesim.py", 12, "helper", kernels) == "Python"
    assert pr._kind("~", 0, "<built-in method scipy.fft._pocketfft.pypocketfft.r2c>", kernels) == "compiled: FFT"
    assert pr._kind("~", 0, "<method 'acquire' of '_thread.lock' objects>", kernels) == "waiting"
    assert pr._kind("~", 0, "<built-in method matplotlib.ft2font.set_text>", kernels).startswith("figures")
    assert pr._kind("~", 0, "<method 'reduce' of 'numpy.ufunc' objects>", kernels) == \
        "compiled: numpy, scipy and other C"
    assert pr._kind("<frozen importlib._bootstrap>", 1, "_load", kernels) == "imports"
