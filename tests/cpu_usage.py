"""Where the suite's time goes: CPU seconds per test file, in the test's own process and in the processes it started.

Issue 29 asks for ``./test.sh`` under 8 minutes on 2 idle cores. A wall-clock table (``--durations``) cannot say
whether a file is slow because it computes, because it starts processes that compute, or because it waits (a ROS
replay paced in real time). conftest.py wraps every test in :func:`usage` readings (``getrusage`` of the process and
of its reaped children, and the wall clock), sums them per file, gathers the xdist workers' sums in the controller
and prints :func:`summary_lines` at the end of the run.

What the children column holds: the CPU of every process the test started and waited for, with the processes those
started and waited for in turn (a ``nifo`` command's figure helpers, a ROS node's), killed ones included. A process
still running when the run ends is not counted.
"""

from __future__ import annotations

import resource
import time
from typing import Mapping

#: per file: [CPU-s in the test process, CPU-s in the processes it started, wall s]
Table = dict[str, list[float]]


def usage() -> tuple[float, float, float]:
    """(CPU-s of this process, its threads included; CPU-s of its reaped children; monotonic wall clock s)."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime, time.monotonic()


def add(table: Table, key: str, before: tuple[float, float, float], after: tuple[float, float, float]) -> None:
    """Add the usage between two :func:`usage` readings to ``table[key]``."""
    merge(table, {key: [a - b for a, b in zip(after, before)]})


def merge(table: Table, other: Mapping[str, list[float]]) -> None:
    """Add another table (an xdist worker's) into ``table``."""
    for key, row in other.items():
        mine = table.setdefault(key, [0.0, 0.0, 0.0])
        for i in range(3):
            mine[i] += float(row[i])


def summary_lines(table: Table, wall_s: float, cores: int, *, top: int = 15) -> list[str]:
    """The whole run's CPU against what its cores could give, then the ``top`` files by CPU."""
    own = sum(r[0] for r in table.values())
    kids = sum(r[1] for r in table.values())
    total = own + kids
    busy = total / (wall_s * cores) if wall_s > 0 and cores > 0 else float("nan")
    lines = [f"{total:.0f} CPU-s in {wall_s:.0f} s on {cores} core(s): {busy:.0%} busy; in the test processes "
             f"{own:.0f} s, in the processes the tests started {kids:.0f} s",
             f"{'CPU s':>8} {'own':>8} {'started':>8} {'wall s':>8}  file (the {min(top, len(table))} of "
             f"{len(table)} with the most CPU)"]
    for key, (o, k, w) in sorted(table.items(), key=lambda kv: -(kv[1][0] + kv[1][1]))[:top]:
        lines.append(f"{o + k:8.1f} {o:8.1f} {k:8.1f} {w:8.1f}  {key}")
    return lines
