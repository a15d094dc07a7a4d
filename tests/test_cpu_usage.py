"""The suite's CPU table (tests/cpu_usage.py): what a test burns itself and what its processes burn land apart."""

from __future__ import annotations

import subprocess
import sys
import time

from cpu_usage import add, merge, summary_lines, usage

BURN = "import time\nt = time.process_time()\nwhile time.process_time() - t < {s}:\n    pass\n"


def _burn(seconds: float) -> None:
    t = time.process_time()
    while time.process_time() - t < seconds:
        pass


def test_cpu_in_the_process_and_in_a_started_process_are_told_apart():
    table: dict = {}
    before = usage()
    _burn(0.3)
    subprocess.run([sys.executable, "-c", BURN.format(s=0.6)], check=True)
    add(table, "f.py", before, usage())
    own, started, wall = table["f.py"]
    assert 0.28 <= own < 0.55, table          # the child's interpreter start is the child's
    assert 0.6 <= started < 1.2, table
    assert wall >= 0.85, table


def test_worker_tables_merge_and_the_summary_ranks_files_by_cpu():
    table = {"a.py": [10.0, 0.0, 12.0]}
    merge(table, {"a.py": [1.0, 2.0, 3.0], "b.py": [1.0, 40.0, 30.0], "c.py": [0.4, 0.0, 60.0]})
    assert table == {"a.py": [11.0, 2.0, 15.0], "b.py": [1.0, 40.0, 30.0], "c.py": [0.4, 0.0, 60.0]}
    lines = summary_lines(table, wall_s=50.0, cores=2, top=2)
    assert lines[0] == ("54 CPU-s in 50 s on 2 core(s): 54% busy; in the test processes 12 s, in the processes the "
                        "tests started 42 s")
    assert "the 2 of 3 with the most CPU" in lines[1]
    assert [ln.split()[-1] for ln in lines[2:]] == ["b.py", "a.py"]      # c.py waits the longest, burns the least
    assert lines[2].split()[:4] == ["41.0", "1.0", "40.0", "30.0"]
