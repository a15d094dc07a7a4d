"""Is a change faster, and does it give the same results? One ``nifo`` command, an earlier commit against this
checkout, run alternately in the same hour on the same machine (issue 29: "ratios against a baseline measured in
the same run").

The earlier commit is checked out into a temporary git worktree; both versions run with this interpreter (the same
.venv: numpy, scipy, numba), each with ``PYTHONPATH`` at its own tree and from an empty working directory.

Why an empty working directory: ``python -m nifo`` puts the current directory first on ``sys.path``, before
``PYTHONPATH``; started from a checkout, both "versions" silently run that checkout's code (measured 2026-11-27:
``nifo info`` of the code before the lazy front doors timed 0.5 s, as the new; run from an empty directory it
takes 1.3-1.7 s). So the tool also asks each version which ``nifo`` it imports, and stops if it is not its own tree.

Each version runs once untimed first (a fresh tree compiles its numba kernels into its own cache), then ``--runs``
timed pairs, old and new alternating. Every JSON file both wrote is compared after the output folder's and the
trees' paths are replaced by placeholders and the timing keys are dropped: identical, or where it first differs.

    PYTHONPATH=. .venv/bin/python benchmarks/compare_versions.py BASE [--runs 3] -- COMMAND ARGS...

``--runs 0``: no timing, one run of each version and the comparison of what they wrote (a refactoring's "behaviour
unchanged", e.g. ``compare_versions.py main --runs 0 -- run`` for every JSON of the sample's ``nifo run``). CSV
tables are compared too (row by row, as text: floats written with ``repr`` compare exactly); ``--ignore KEY``
(repeatable) drops further clock keys and columns, e.g. ``--ignore seconds`` for ``nifo fleet``'s per-bag time.

for example, the F-16 main job against the commit before a change (the tool gives each run its ``--out``)::

    PYTHONPATH=. .venv/bin/python benchmarks/compare_versions.py HEAD~1 -- run \\
        ../shared/data/f16/F16Data_FullMSine_Level{1,3,5,7}.mat \\
        --columns spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: keys whose values are clocks, not results
VOLATILE = frozenset({"took_s", "timings_s", "elapsed_s", "created", "created_utc", "wall_s", "cpu_s"})


def _absolute(args: list[str]) -> list[str]:
    """Arguments naming existing files made absolute (the versions run from an empty directory)."""
    return [str(Path(a).resolve()) if not a.startswith("-") and Path(a).exists() else a for a in args]


def _env(tree: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(tree)}


def _check_imports(tree: Path, cwd: Path) -> None:
    code = "import nifo, nifo_core; print(nifo.__file__); print(nifo_core.__file__)"
    got = subprocess.run([sys.executable, "-c", code], cwd=cwd, env=_env(tree), capture_output=True, text=True,
                         check=True).stdout.split()
    if not all(Path(p).resolve().is_relative_to(tree.resolve()) for p in got):
        sys.exit(f"the version at {tree} imports {got}: not its own code")


def _run(tree: Path, cwd: Path, args: list[str], out: Path) -> tuple[float, float]:
    """(wall, CPU) seconds of ``python -m nifo -q ARGS --out OUT`` with ``tree``'s code."""
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "nifo", "-q", *args, "--out", str(out)], cwd=cwd, env=_env(tree),
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        sys.exit(f"{tree}: nifo {' '.join(args)} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return wall, (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)


def _normalised(x, replace: dict[str, str], volatile: frozenset = VOLATILE):
    if isinstance(x, dict):   # keys too: a record's path can be a key (the settings' sources per input)
        return {_normalised(k, replace): _normalised(v, replace, volatile) for k, v in x.items() if k not in volatile}
    if isinstance(x, list):
        return [_normalised(v, replace, volatile) for v in x]
    if isinstance(x, str):
        for old, new in replace.items():
            x = x.replace(old, new)
        return x
    return x


def _first_difference(a, b, where: str = "") -> str | None:
    if type(a) is not type(b):
        return f"{where or '/'}: {a!r} != {b!r}"
    if isinstance(a, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                return f"{where}/{k}: only in {'new' if k in b else 'old'}"
            got = _first_difference(a[k], b[k], f"{where}/{k}")
            if got:
                return got
        return None
    if isinstance(a, list):
        if len(a) != len(b):
            return f"{where}: {len(a)} != {len(b)} items"
        for i, (u, v) in enumerate(zip(a, b)):
            got = _first_difference(u, v, f"{where}[{i}]")
            if got:
                return got
        return None
    return None if a == b else f"{where}: {a!r} != {b!r}"


def _read_output(path: Path):
    """A JSON document, or a CSV table as a list of rows (dicts of the cells' text)."""
    if path.suffix == ".csv":
        with path.open(newline="") as f:
            return list(csv.DictReader(f))
    return json.loads(path.read_text())


def compare_outputs(old: Path, new: Path, trees: dict[str, Path], *, ignore: frozenset = frozenset()) -> list[str]:
    """One line per JSON or CSV file written by either version: identical, or its first difference."""
    lines = []
    names = sorted({p.relative_to(d) for d in (old, new) for pattern in ("*.json", "*.csv") for p in d.rglob(pattern)})
    for name in names:
        a, b = old / name, new / name
        if not (a.is_file() and b.is_file()):
            lines.append(f"  {name}: written by {'new' if b.is_file() else 'old'} only")
            continue
        docs = []
        for path, out in ((a, old), (b, new)):
            repl = {str(out.resolve()): "<out>", str(out): "<out>", **{str(t): "<tree>" for t in trees.values()}}
            docs.append(_normalised(_read_output(path), repl, VOLATILE | ignore))
        diff = _first_difference(*docs)
        lines.append(f"  {name}: " + ("identical" if diff is None else f"differs at {diff[:300]}"))
    return lines


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    cut = argv.index("--") if "--" in argv else len(argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("base", help="the earlier commit (any git revision)")
    p.add_argument("--runs", type=int, default=3,
                   help="timed runs of each version (default 3; 0: one untimed run of each, outputs compared)")
    p.add_argument("--ignore", action="append", default=[], metavar="KEY",
                   help="a further clock key (JSON) or column (CSV) left out of the comparison; repeatable")
    opts = p.parse_args(argv[:cut])
    args = _absolute(argv[cut + 1:])
    if opts.runs < 0:
        p.error("--runs must be 0 (outputs only) or more")
    if not args or "--out" in args:
        p.error("give the nifo command after --, without --out (each run gets its own)")
    with tempfile.TemporaryDirectory(prefix="nifo-compare-") as tmp:
        tmp = Path(tmp)
        old_tree, cwd = tmp / "base", tmp / "cwd"
        cwd.mkdir()
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(old_tree), opts.base],
                       check=True)
        try:
            trees = {"old": old_tree, "new": ROOT}
            for name, tree in trees.items():
                _check_imports(tree, cwd)
                print(f"{name}: {tree} (warm-up run)", flush=True)
                _run(tree, cwd, args, tmp / f"warm_{name}")
            if not opts.runs:
                print("outputs (JSON, paths and clocks aside):")
                print("\n".join(compare_outputs(tmp / "warm_old", tmp / "warm_new", trees,
                                                 ignore=frozenset(opts.ignore))))
                return 0
            times: dict[str, list[tuple[float, float]]] = {"old": [], "new": []}
            for k in range(opts.runs):
                for name, tree in trees.items():
                    wall, cpu = _run(tree, cwd, args, tmp / f"{name}_{k}")
                    times[name].append((wall, cpu))
                    print(f"run {k + 1} {name}: {wall:6.2f} s wall, {cpu:6.2f} s CPU (load {os.getloadavg()[0]:.1f})",
                          flush=True)
            mean = {n: (statistics.mean(w for w, _ in t), statistics.mean(c for _, c in t)) for n, t in times.items()}
            print(f"\nold {opts.base}: mean {mean['old'][0]:.2f} s wall, {mean['old'][1]:.2f} s CPU over "
                  f"{opts.runs} runs")
            print(f"new (this checkout): mean {mean['new'][0]:.2f} s wall, {mean['new'][1]:.2f} s CPU")
            print(f"new/old: wall {mean['new'][0] / mean['old'][0]:.3f}, CPU {mean['new'][1] / mean['old'][1]:.3f}")
            print("outputs of the last runs (JSON, paths and clocks aside):")
            print("\n".join(compare_outputs(tmp / f"old_{opts.runs - 1}", tmp / f"new_{opts.runs - 1}", trees,
                                             ignore=frozenset(opts.ignore))))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(old_tree)], check=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
