"""Profile the main job, ``nifo run``, end to end (issue 29): per-step wall time and the top functions.

Runs the job in-process under :mod:`cProfile` on the bundled sample (``bags/sample/*``, what ``./nifo.sh``
runs) or, with ``--f16``, on the F-16 ground vibration test levels 1/3/5/7 (``../shared/data/f16``, the columns
of docs/f16_loop.md); after ``--``, any ``nifo`` command line instead (``-- loop A.mcap B.mcap --model M.yaml
--out DIR``). Prints the job's own per-step timings (wall clock, profiler overhead included) and the
``--top`` functions by cumulative and by own time; ``--save FILE`` keeps the raw profile for
``python -m pstats FILE`` or snakeviz. cProfile slows Python-heavy code (plots, option handling) more than
compiled kernels (the simulator, FFTs): for the real wall time use ``benchmarks/bench_run.py``.

``--floor`` runs the command with one simulation thread and its figures drawn in its own process
(``NIFO_THREADS=1``, ``NIFO_FIGURE_WORKERS=0``), profiles every thread (:class:`FloorProfile`), times the
figures' layout and rendering with the profiler off (its overhead on matplotlib's many small calls), and sorts
the own time of every function by what runs there (:func:`own_time_by_kind`): the compiled arithmetic (numba's
simulation kernels, the FFTs, numpy's and scipy's other C code), the figures, the imports, waiting, and Python.
It prints the least wall time the compiled arithmetic, and that with the figures' rendering, would take on this
machine's cores if nothing else ran and every core were busy: a floor for the same method and the same figures,
whatever the Python around them is made to cost. A low one: numpy's operators and ufuncs are no calls to
cProfile, so their arithmetic counts as their Python caller's.

Measured with ``--floor`` (2026-11-29, 2 cores, wall-clock profiles of an idle machine; compiled arithmetic +
figures' rendering = CPU seconds, then the floor on 2 cores against issue 29's target):

- the bundled sample: 11.1 + 12.7 = 23.8 s, floor 11.9 s against 15 s: the other 3.1 s of wall time would have to
  hold the Python (11.6 s under the profiler), the imports and the figure helpers' start-up;
- ``nifo loop`` on ``benchmarks/bench_loop.py --keep DIR``'s 4 x 300 s records: 27.6 + 1.0 = 28.6 s, floor 14.3 s
  against 10 s (the compiled arithmetic alone 13.8 s): out of reach on 2 cores with this arithmetic;
- ``--f16``: 14.9 + 10.2 = 25.2 s, floor 12.6 s against 30 s.

Measured again on 2026-12-07 (each thread's CPU clock, beside two other jobs; issue 58):

- the bundled sample: 23.9 + 22.1 = 46.0 s, floor 23.0 s (the compiled arithmetic alone 11.9 s); the figures'
  rendering is the largest part (22.1 CPU-s), the Python 22.6 s under the profiler;
- the loop benchmark: 46.6 + 1.8 = 48.3 s, floor 24.2 s (the compiled arithmetic alone 23.3 s: the loop has
  grown since 2026-11-29: the re-tunes in the static frame, the stop re-tune, the bias correction's drive noise);
- ``nifo loop`` on held-out fleet case 64 (``tests/test_loop_vehicle.py``'s rational-part case, ``--no-refine
  --max-rounds 1``): 23.4 + 1.1 = 24.5 s, Python 39.5 s of 65 s; the rational linear part's order search
  (vector fitting every even order 2-40 for each candidate's model: 22 searches, 440 fits) is 27 s of it.

Measured on 2026-12-07 between 10:45 and 11:55, an idle machine (issue 58; the sample on 8068530, the other two on
95dbf45, whose report draws its figures in the helpers):

- the bundled sample: 12.0 + 8.3 = 20.3 s, floor 10.2 s (the compiled arithmetic alone 6.0 s); the Python 15.7 s
  under the profiler, the figures' building 2.4 s;
- the loop benchmark: 23.3 + 0.7 = 24.0 s, floor 12.0 s against 10 s (the compiled arithmetic alone 11.6 s: numba
  10.6, FFT 7.2, other C 5.5 CPU-s): out of reach with this many simulations;
- ``--f16``: 19.3 + 8.5 = 27.9 s, floor 13.9 s against 30 s.

Measured on 2026-12-07 at 22:30, another host (the loop benchmark on 8baeb1a, the static position's balance from
sorted z): 22.9 + 0.6 = 23.5 s, floor 11.5 s against 10 s (numba 11.7, FFT 7.4, other C 3.9 CPU-s; the Python 18.4 s
under the profiler).

Measured on 2026-12-08 at 00:15, a host 1.7-1.8x slower than the last (the loop benchmark on 8db6925, the sample on
36b122a): the loop benchmark 25.7 + 0.9 = 26.7 s, floor 13.3 s (numba 13.8, FFT 6.7, other C 5.2 CPU-s; the Python
19.8 s); the bundled sample 15.1 + 16.0 = 31.2 s, floor 15.6 s against 15 s: its figures' rendering (44 files, 16.0
CPU-s) is now its largest part, more than its compiled arithmetic (numba 4.0, FFT 4.3, other C 6.9 CPU-s).

Measured on 2026-12-08 at 02:50, a host like 2026-12-07's first (the loop benchmark and the sample on 326ac7b, the
synthetic refits stopped once converged): the loop benchmark 25.6 + 0.7 = 26.3 s, floor 13.1 s (numba 13.5, FFT 8.0,
other C 4.0 CPU-s; the Python 18.0 s); the bundled sample 11.3 + 8.7 = 20.0 s, floor 10.0 s (10.1 s on c9099cc, the
same hour), the Python 10.6 s under the profiler.

Measured on 2026-12-08 at 04:50-05:05, the same host (one model's simulations of several records of one length
marched together, :func:`nifo_core.predict.model.predict_records`): the loop benchmark (ac924a8) 22.0 + 0.7 = 22.7 s,
floor 11.4 s (numba 13.5 → 10.4, FFT 7.9, other C 3.8 CPU-s; the Python 17.8 s); the bundled sample (f2538b0)
10.6 + 9.0 = 19.6 s, floor 9.8 s (numba 4.0 → 2.9 CPU-s; the Python 11.1 s, the figures' building 1.9 s).

    PYTHONPATH=. python benchmarks/profile_run.py [--f16] [--floor] [--out DIR] [--top 40] [--save run.prof]
                                                  [-- nifo ARGS...]
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import io
import os
import pstats
import sys
import tempfile
import threading
import time
from pathlib import Path

from nifo.commands.run import sample_data
from nifo.pipeline.job import run_job
from nifo.pipeline.options import RunOptions

#: the F-16 benchmark's files and columns (docs/f16_loop.md)
F16_DIR = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "f16"
F16_LEVELS = (1, 3, 5, 7)
F16_COLUMNS = "spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"


def cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def job_options(*, f16: bool, out: Path) -> RunOptions:
    """The main job's options: the bundled sample, or the F-16 multisine levels 1/3/5/7."""
    if not f16:
        return RunOptions(data=sample_data(), out=out)
    data = [F16_DIR.resolve() / f"F16Data_FullMSine_Level{k}.mat" for k in F16_LEVELS]
    missing = [str(p) for p in data if not p.is_file()]
    if missing:
        sys.exit(f"profile_run: the F-16 data are missing: {', '.join(missing)}")
    return RunOptions(data=data, out=out, columns=F16_COLUMNS)


#: what runs, in the order printed (:func:`own_time_by_kind`)
KINDS = ("compiled: numba kernels", "compiled: FFT", "compiled: numpy, scipy and other C",
         "figures: rendering (without the profiler)", "figures: building (matplotlib, PIL)", "imports", "waiting",
         "Python")
_ARITHMETIC = KINDS[:3]
_RENDERING, _BUILDING = KINDS[3:5]
#: built-in functions whose own time is a thread waiting, not computing
_WAITING = ("'acquire' of", "time.sleep", "select.", ".poll", "'wait' of")
_FIGURES = ("matplotlib", "ft2font", "_backend_agg", "Imaging", "PIL.")


def numba_kernels() -> set[tuple[str, int, str]]:
    """(file, first line, name) of every numba-compiled function alive in this process. cProfile lists a call
    of one under its Python function's code (numba's dispatcher reports it so to profilers), all of its time
    its own: that is how :func:`own_time_by_kind` tells a compiled kernel from Python code."""
    try:
        from numba.core.dispatcher import Dispatcher
    except ImportError:
        return set()
    codes = (o.py_func.__code__ for o in gc.get_objects() if isinstance(o, Dispatcher))
    return {(c.co_filename, c.co_firstlineno, c.co_name) for c in codes}


def _kind(file: str, line: int, name: str, kernels: set[tuple[str, int, str]]) -> str:
    if (file, line, name) in kernels:
        return KINDS[0]
    if file == "~":   # a built-in (C) function, named like "<built-in method scipy.fft._pocketfft.pypocketfft.r2c>"
        if any(w in name for w in _WAITING):
            return "waiting"
        if any(f in name for f in _FIGURES):
            return _BUILDING
        if "pocketfft" in name:
            return "compiled: FFT"
        if "_imp." in name or "marshal.loads" in name:
            return "imports"
        return "compiled: numpy, scipy and other C"
    if file.startswith("<frozen importlib"):
        return "imports"
    if f"{os.sep}matplotlib{os.sep}" in file or f"{os.sep}PIL{os.sep}" in file:
        return _BUILDING
    return "Python"


def own_time_by_kind(stats: pstats.Stats, kernels: set[tuple[str, int, str]], rendering_s: float = 0.0
                     ) -> dict[str, float]:
    """Own time [s] of every profiled function summed by what runs there (:data:`KINDS`); ``kernels`` from
    :func:`numba_kernels`; ``rendering_s``: the figures' rendering, timed with the profiler off.

    A lower bound of the arithmetic: numpy's operators and ufuncs (``a * b``, ``np.abs``) are no function calls
    to cProfile, so their time is their Python caller's own ("Python")."""
    out = dict.fromkeys(KINDS, 0.0)
    for (file, line, name), (_, _, own, _, _) in stats.stats.items():
        out[_kind(file, line, name, kernels)] += own
    out[_RENDERING] = rendering_s
    return out


def floor_lines(kinds: dict[str, float], cores: int) -> list[str]:
    """The table of :func:`own_time_by_kind` and the least wall time of its compiled arithmetic (and of that with
    the figures' rendering) on ``cores`` busy cores."""
    total = sum(kinds.values())
    lines = [f"own CPU time by what runs ({total:.1f} s: every thread under cProfile on its own CPU clock, the "
             "figures' rendering timed apart):"]
    lines += [f"  {k:<42} {v:7.1f} s  {100 * v / total:5.1f} %" for k, v in kinds.items()]
    arith = sum(kinds[k] for k in _ARITHMETIC)
    both = arith + kinds[_RENDERING]
    lines.append(f"floor on {cores} core(s), every core busy and nothing else running: the compiled arithmetic "
                 f"{arith:.1f} s / {cores} = {arith / cores:.1f} s; with the figures' rendering "
                 f"{both:.1f} s / {cores} = {both / cores:.1f} s")
    return lines


class FloorProfile:
    """cProfile on every thread, with the figures' rendering timed apart (``--floor``); a context manager, whose
    ``profile`` is this thread's.

    cProfile sees only the thread that enabled it, and with ``NIFO_THREADS=1`` the job still runs some steps on
    one worker thread while its main thread waits for them: every thread started inside the ``with`` profiles
    itself. The figures' layout and rendering (:func:`nifo.plots.writer._write`, in the step's own process with
    ``NIFO_FIGURE_WORKERS=0``) run with their thread's profiler off and are timed by that thread's CPU clock:
    matplotlib's many small calls would otherwise carry the profiler's overhead into the floor.

    Every profile reads its thread's CPU clock (:func:`time.thread_time`), not the wall clock: a floor measured on a
    machine that also runs other work is the same as on an idle one (before 2026-12-07 the profiles read the wall
    clock, and a loaded machine's floor was its load's). A thread waiting for another's work then costs nothing."""

    def __init__(self) -> None:
        self.profiles: dict[int, cProfile.Profile] = {}
        self.profile: cProfile.Profile | None = None   # this thread's, once entered
        self.rendering_s = 0.0
        self._lock = threading.Lock()
        self._real_write = None

    def __enter__(self) -> FloorProfile:
        from nifo.plots import writer

        def begin(frame, event, arg):
            sys.setprofile(None)
            self._enable()

        self._real_write = real = writer._write

        def timed(*args, **kwargs):
            prof = self.profiles.get(threading.get_ident())
            if prof is not None:
                prof.disable()
            t = time.thread_time()
            try:
                return real(*args, **kwargs)
            finally:
                with self._lock:
                    self.rendering_s += time.thread_time() - t
                if prof is not None:
                    prof.enable()

        writer._write = timed
        threading.setprofile(begin)
        self.profile = self._enable()
        return self

    def __exit__(self, *exc) -> None:
        from nifo.plots import writer

        self.profile.disable()
        threading.setprofile(None)
        writer._write = self._real_write

    def _enable(self) -> cProfile.Profile:
        prof = cProfile.Profile(time.thread_time)   # the thread's own CPU: what other processes run does not count
        with self._lock:
            self.profiles[threading.get_ident()] = prof
        prof.enable()
        return prof

    def stats(self) -> pstats.Stats:
        """Every thread's profile, merged."""
        return pstats.Stats(*self.profiles.values())


def _table(prof: cProfile.Profile, sort: str, top: int) -> str:
    buf = io.StringIO()
    pstats.Stats(prof, stream=buf).strip_dirs().sort_stats(sort).print_stats(top)
    return buf.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--f16", action="store_true", help="F-16 levels 1/3/5/7 from ../shared/data/f16")
    ap.add_argument("--out", type=Path, help="the job's output directory (default: a temporary one)")
    ap.add_argument("--top", type=int, default=40, help="functions listed per table (default 40)")
    ap.add_argument("--save", type=Path, help="write the raw profile here")
    ap.add_argument("--floor", action="store_true",
                    help="one thread, figures in this process; own time by what runs and the floor on this machine")
    ap.add_argument("nifo", nargs="*", help="after --: any nifo command line instead (e.g. -- loop A B --out D)")
    args = ap.parse_args(argv)
    command = args.nifo or None
    floor = FloorProfile() if args.floor else None
    if floor is not None:
        os.environ.update({"NIFO_THREADS": "1", "NIFO_FIGURE_WORKERS": "0"})
    with tempfile.TemporaryDirectory(prefix="nifo_profile_run_") as tmp:
        if command is not None:
            from nifo.cli import main as nifo_main

            what, job = "nifo " + " ".join(command), lambda: nifo_main(command)
        else:
            what = f"nifo run on {'F-16 levels ' + '/'.join(map(str, F16_LEVELS)) if args.f16 else 'the bundled sample'}"
            opts = job_options(f16=args.f16, out=args.out or Path(tmp) / "results")
            job = lambda: run_job(opts)   # noqa: E731
        t0 = time.perf_counter()
        if floor is not None:
            with floor:
                result = job()
            prof = floor.profile
        else:
            prof = cProfile.Profile()
            prof.enable()
            result = job()
            prof.disable()
        took = time.perf_counter() - t0
    code = int(result.get("exit_code", 0)) if isinstance(result, dict) else int(result or 0)
    print("\n" + "=" * 100)
    print(f"{what}: {took:.1f} s under cProfile, exit code {code}")
    for step, sec in (result.get("timings_s", {}) if isinstance(result, dict) else {}).items():
        print(f"  {step:<14} {sec:7.1f} s  {100 * sec / took:5.1f} %")
    print(f"\ntop {args.top} by cumulative time (this thread):\n" + _table(prof, "cumulative", args.top))
    print(f"top {args.top} by own time (this thread):\n" + _table(prof, "tottime", args.top))
    if floor is not None:
        kinds = own_time_by_kind(floor.stats(), numba_kernels(), floor.rendering_s)
        print("\n".join(floor_lines(kinds, cores())))
    if args.save:
        (floor.stats() if floor is not None else pstats.Stats(prof)).dump_stats(str(args.save))   # every thread's
        print(f"profile written to {args.save}")
    return code


if __name__ == "__main__":
    raise SystemExit(main())
