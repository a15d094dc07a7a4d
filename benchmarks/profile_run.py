"""Profile the main job, ``nifo run``, end to end (issue 29): per-step wall time and the top functions.

Runs the job in-process under :mod:`cProfile` on the bundled sample (``bags/sample/*``, what ``./nifo.sh``
runs) or, with ``--f16``, on the F-16 ground vibration test levels 1/3/5/7 (``../shared/data/f16``, the columns
of docs/f16_loop.md). Prints the job's own per-step timings (wall clock, profiler overhead included) and the
``--top`` functions by cumulative and by own time; ``--save FILE`` keeps the raw profile for
``python -m pstats FILE`` or snakeviz. cProfile slows Python-heavy code (plots, option handling) more than
compiled kernels (the simulator, FFTs): for the real wall time use ``benchmarks/bench_run.py``.

    PYTHONPATH=. python benchmarks/profile_run.py [--f16] [--out DIR] [--top 40] [--save run.prof]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import tempfile
import time
from pathlib import Path

from nifo.commands.run import sample_data
from nifo.pipeline.job import run_job
from nifo.pipeline.options import RunOptions

#: the F-16 benchmark's files and columns (docs/f16_loop.md)
F16_DIR = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "f16"
F16_LEVELS = (1, 3, 5, 7)
F16_COLUMNS = "spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"


def job_options(*, f16: bool, out: Path) -> RunOptions:
    """The main job's options: the bundled sample, or the F-16 multisine levels 1/3/5/7."""
    if not f16:
        return RunOptions(data=sample_data(), out=out)
    data = [F16_DIR.resolve() / f"F16Data_FullMSine_Level{k}.mat" for k in F16_LEVELS]
    missing = [str(p) for p in data if not p.is_file()]
    if missing:
        sys.exit(f"profile_run: the F-16 data are missing: {', '.join(missing)}")
    return RunOptions(data=data, out=out, columns=F16_COLUMNS)


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
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="nifo_profile_run_") as tmp:
        out = args.out or Path(tmp) / "results"
        opts = job_options(f16=args.f16, out=out)
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        summary = run_job(opts)
        prof.disable()
        took = time.perf_counter() - t0
    print("\n" + "=" * 100)
    print(f"nifo run on {'F-16 levels ' + '/'.join(map(str, F16_LEVELS)) if args.f16 else 'the bundled sample'}: "
          f"{took:.1f} s under cProfile")
    for step, sec in summary["timings_s"].items():
        print(f"  {step:<14} {sec:7.1f} s  {100 * sec / took:5.1f} %")
    print(f"\ntop {args.top} by cumulative time:\n" + _table(prof, "cumulative", args.top))
    print(f"top {args.top} by own time:\n" + _table(prof, "tottime", args.top))
    if args.save:
        prof.dump_stats(str(args.save))
        print(f"profile written to {args.save}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
