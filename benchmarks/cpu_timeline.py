"""Where the cores stand idle while ``nifo`` runs (issue 29): CPU of the command and of its helpers over time.

Runs any ``nifo`` command line as a child process (default: ``nifo run`` on the bundled sample; ``--f16``:
the F-16 levels 1/3/5/7 with their columns) and reads, every ``--interval`` seconds, the CPU time of that
process and of its child processes (the figure helpers) from ``/proc``. Prints one line per interval: the
cores the command's own process kept busy (its threads), the cores its helpers kept busy, and a bar; the
step banners (``== [k/n] ...``) where they were printed; then per step the wall time, the CPU seconds and
the idle core-seconds (the machine's cores times the step's wall time, less the CPU the step used). A step
whose idle core-seconds are large has work that could run beside it; a step without is bound by its CPU,
and only less CPU shortens it.

cProfile and py-spy say *what* runs; this says *when the machine is not busy*, with nothing attached to the
process (no profiler overhead). Linux only (``/proc``).

    PYTHONPATH=. python benchmarks/cpu_timeline.py [--f16] [--interval 0.5] [-- nifo ARGS...]

Measured (2026-11-29, 2 cores; the host's speed drifted by a third within the hour, so the shares matter, not
the seconds): ``--f16`` 35.6 s, 57.5 CPU-s, 13.7 idle core-seconds: the loop 4.7 (12.1 s at 1.6 cores), the
characterize step 2.7 (its own arithmetic on one core before its figures reach the helpers), the start-up 2.0
(imports, one core), the report and the recording 2.8 (the recording's thread beside the report's). The bundled
sample 25.0 s, 40.5 CPU-s, 9.6 idle: characterize 2.8, loop 2.5, start-up 1.4, report and recording 2.1; identify
and predict ran the machine full. So on 2 cores the main job is bound by its CPU: work run side by side gains at
most those idle seconds (identify beside the loop on a thread, measured: no gain), and only less CPU shortens it.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from profile_run import F16_COLUMNS, cores, job_options

ROOT = Path(__file__).resolve().parents[1]
_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of ``pid`` (all its threads), None once it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / _TICK


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(x) for x in f.read().split()]
    except OSError:
        return []


def _command(args: argparse.Namespace) -> list[str]:
    base = [sys.executable, "-m", "nifo"]
    if args.nifo:
        return [*base, *args.nifo]
    if args.f16:
        data = [str(p) for p in job_options(f16=True, out=args.out).data]
        return [*base, "run", *data, "--columns", F16_COLUMNS, "--out", str(args.out)]
    return [*base, "run", "--out", str(args.out)]


def timeline(cmd: list[str], interval: float) -> tuple[list[tuple[float, float, float]], list[tuple[float, str]], int]:
    """Run ``cmd``; ([(t, own cores, helper cores)] per interval, [(t, banner)], exit code)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    marks: list[tuple[float, str]] = []

    def read() -> None:
        for line in proc.stdout:
            if line.startswith("== [") or "finished in" in line:
                marks.append((time.monotonic() - t0, line.strip()))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    seen: dict[int, float] = {}
    rows = []
    last = t0
    while proc.poll() is None:
        time.sleep(interval)
        now = time.monotonic()
        own = helpers = 0.0
        for pid in [proc.pid, *_children(proc.pid)]:
            c = _cpu_s(pid)
            if c is None:
                continue
            d, seen[pid] = c - seen.get(pid, 0.0), c
            if pid == proc.pid:
                own += d
            else:
                helpers += d
        rows.append((now - t0, own / (now - last), helpers / (now - last)))
        last = now
    reader.join(timeout=5)
    return rows, marks, proc.returncode


def _steps(rows, marks, cores: int, end: float) -> list[tuple[str, float, float, float]]:
    """(step, wall s, CPU s, idle core-s) from the start-up to the first banner, then banner to banner."""
    edges = [(0.0, "start-up (imports)"), *[(t, text.split("] ", 1)[-1][:60]) for t, text in marks
                                             if text.startswith("== [")], (end, "")]
    out = []
    for (a, name), (b, _) in zip(edges[:-1], edges[1:]):
        cpu = 0.0
        prev = 0.0
        for t, own, hel in rows:     # each row covers (prev, t]; the part inside (a, b] counts
            part = max(0.0, min(t, b) - max(prev, a))
            cpu += part * (own + hel)
            prev = t
        out.append((name, b - a, cpu, max(0.0, cores * (b - a) - cpu)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--f16", action="store_true", help="nifo run on F-16 levels 1/3/5/7 (../shared/data/f16)")
    ap.add_argument("--interval", type=float, default=0.5, help="seconds between readings (default 0.5)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/nifo_cpu_timeline"),
                    help="the run's --out (default /tmp/nifo_cpu_timeline; replaced)")
    ap.add_argument("nifo", nargs="*", help="after --: any nifo command line instead (e.g. -- loop A B --out D)")
    args = ap.parse_args(argv)
    if not Path("/proc/self/stat").exists():
        print("cpu_timeline: needs Linux's /proc", file=sys.stderr)
        return 2
    n_cores = cores()
    rows, marks, code = timeline(_command(args), args.interval)
    mi = 0
    for t, own, hel in rows:
        while mi < len(marks) and marks[mi][0] <= t:
            print(f"        {marks[mi][0]:6.1f} s  {marks[mi][1][:90]}")
            mi += 1
        print(f"{t:6.1f} s  nifo {own:4.2f}  helpers {hel:4.2f} cores  {'#' * round(10 * (own + hel))}")
    for t, text in marks[mi:]:
        print(f"        {t:6.1f} s  {text[:90]}")
    end = rows[-1][0] if rows else 0.0
    print(f"\n{n_cores} core(s); exit code {code}")
    print(f"{'step':<62} {'wall s':>7} {'CPU s':>7} {'idle core-s':>11}")
    total = [0.0, 0.0, 0.0]
    for name, wall, cpu, idle in _steps(rows, marks, n_cores, end):
        print(f"{name:<62} {wall:7.1f} {cpu:7.1f} {idle:11.1f}")
        total = [total[0] + wall, total[1] + cpu, total[2] + idle]
    print(f"{'all':<62} {total[0]:7.1f} {total[1]:7.1f} {total[2]:11.1f}")
    return code


if __name__ == "__main__":
    sys.exit(main())
