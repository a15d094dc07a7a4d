"""benchmarks/cpu_timeline.py: the CPU of a command and of its child processes read over time from /proc, and the
idle core-seconds per step (the tool itself is run by hand; its figures are in its docstring and issue 29's notes)."""

from __future__ import annotations

import sys

import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import cpu_timeline as ct  # noqa: E402

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

#: a command with one step: it spins a second of CPU itself and half a second in a child process of its own
_BUSY = """
import subprocess, sys, time

def spin(s):
    t = time.process_time()
    while time.process_time() - t < s:
        pass

print("== [1/1] busy", flush=True)
child = subprocess.Popen([sys.executable, "-c", "import time\\nt = time.process_time()\\n"
                          "while time.process_time() - t < 0.5: pass"])
spin(1.0)
child.wait()
print("done in 1 s", flush=True)
"""


def test_the_cpu_of_the_command_and_of_its_child_is_read_apart_and_the_step_named():
    rows, marks, code = ct.timeline([sys.executable, "-c", _BUSY], 0.1)
    assert code == 0
    assert [text for _, text in marks] == ["== [1/1] busy"]
    spans = [t - prev for (t, _, _), prev in zip(rows, [0.0, *(r[0] for r in rows)])]
    own = sum(s * o for s, (_, o, _) in zip(spans, rows))       # cores x interval: CPU seconds
    child = sum(s * h for s, (_, _, h) in zip(spans, rows))
    assert 0.6 < own < 1.6, rows
    assert 0.25 < child < 0.9, rows


def test_steps_split_the_cpu_at_the_banners_and_count_what_the_cores_left_idle():
    # one reading per second: 1 core busy, then 2, then 0.5 (own 0.5 + helpers 0), on 2 cores
    rows = [(1.0, 1.0, 0.0), (2.0, 1.5, 0.5), (3.0, 0.5, 0.0)]
    marks = [(1.0, "== [1/2] first step"), (2.0, "== [2/2] second step")]
    steps = ct._steps(rows, marks, cores=2, end=3.0)
    assert [s[0] for s in steps] == ["start-up (imports)", "first step", "second step"]
    assert [s[1] for s in steps] == [1.0, 1.0, 1.0]
    assert [s[2] for s in steps] == pytest.approx([1.0, 2.0, 0.5])
    assert [s[3] for s in steps] == pytest.approx([1.0, 0.0, 1.5])
