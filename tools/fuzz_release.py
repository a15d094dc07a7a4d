"""The larger fuzz run for release checks (the CI suite runs a fixed, bounded slice of the same fuzzers).

1. The bag mutation fuzzer (``tests/fuzz_engine.py``) on lone ``.mcap`` files
   of several lengths, ``--cases`` mutants per seed and ``--seeds`` seeds; every
   10th case also through ``nifo info``.
2. Mutations of a bag directory's ``metadata.yaml`` (bit flips, wrong message
   counts, truncation): a read that succeeds must give the original record.
3. The hypothesis property tests of ``tests/test_fuzz_files.py`` (CSV, MAT,
   model files, output paths) with ``--examples`` examples each (CI: 100).
4. ``--hostile``: issue 56's classes (``tests/hostile_engine.py``: two commands at
   once on one folder, ``nifo run`` among them; kills followed by the user's files;
   forged or edited markers; records of one name; a force model without a force;
   clipping; nothing excited; offsets 1e-3 to 1e6; the issue's messages), more
   cases of each than CI runs, every command in a process of its own. ``--tree DIR``
   runs them against another checkout (the before of a change: ``git archive
   COMMIT | tar -x -C DIR``); ``--only NAME`` one class.

Prints the counts (cases, clear errors, tracebacks, hangs, wrong-with-exit-0,
errors not naming file and fix, files lost) and exits 1 if any of the last five is not 0::

    PYTHONPATH=. .venv/bin/python tools/fuzz_release.py [--cases 2000] [--seeds 3] [--examples 2000]
    PYTHONPATH=. .venv/bin/python tools/fuzz_release.py --hostile [--tree DIR] [--only CLASS]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from fuzz_engine import Tally, fuzz_bag, fuzz_metadata  # noqa: E402


def _record(n: int, seed: int):
    from nifo_core.signal.record import Record

    rng = np.random.default_rng(seed)
    return Record(600.0, rng.standard_normal(n), 0.1 * rng.standard_normal(n), 1e-3 * rng.standard_normal(n),
                  t0_ns=1_700_000_000_000_000_000 + seed, source="fuzz")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=2000, help="bag mutants per seed and record length")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--examples", type=int, default=2000, help="hypothesis examples per property test")
    p.add_argument("--no-hypothesis", action="store_true")
    p.add_argument("--hostile", action="store_true", help="issue 56's hostile classes only (tests/hostile_engine.py)")
    p.add_argument("--tree", type=Path, default=REPO, help="the checkout the hostile classes run (default: this one)")
    p.add_argument("--only", action="append", help="one hostile class (repeatable)")
    args = p.parse_args(argv)
    t0 = time.monotonic()
    if args.hostile:
        return _hostile(args, t0)
    total = Tally()
    with tempfile.TemporaryDirectory(prefix="nifo-fuzz-") as tmp:
        for seed in range(args.seeds):
            for n in (1500, 20000):
                t = fuzz_bag(_record(n, seed), Path(tmp) / f"bag{seed}-{n}", cases=args.cases, seed=1000 + seed,
                             via_cli_every=10)
                print(f"bag  seed {seed}, {n} samples: {t.line()}", flush=True)
                total.counts.update(t.counts)
                total.failures += t.failures
            t = fuzz_metadata(_record(3000, seed), Path(tmp) / f"meta{seed}", cases=max(args.cases // 4, 50), seed=seed)
            print(f"metadata.yaml seed {seed}: {t.line()}", flush=True)
            total.counts.update(t.counts)
            total.failures += t.failures
    print(f"bags total: {total.line()}")
    for case, what in total.failures[:20]:
        print(f"  FAIL {case}: {what}")
    code = 1 if total.bad else 0
    if not args.no_hypothesis:
        env = {**os.environ, "NIFO_FUZZ_EXAMPLES": str(args.examples), "PYTHONPATH": str(REPO)}
        r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                            str(REPO / "tests" / "test_fuzz_files.py")], env=env, cwd=REPO)
        print(f"hypothesis properties with {args.examples} examples each: "
              + ("passed" if r.returncode == 0 else "FAILED"))
        code |= r.returncode != 0
    print(f"fuzz_release: {'OK' if code == 0 else 'FAILURES'} in {time.monotonic() - t0:.0f} s")
    return code


def _hostile(args, t0: float) -> int:
    from hostile_engine import Nifo, run_classes

    with tempfile.TemporaryDirectory(prefix="nifo-hostile-") as tmp:
        tallies = run_classes(Nifo(args.tree.resolve()), Path(tmp), release=True, only=args.only)
    total = Tally()
    for t in tallies.values():
        total.counts.update(t.counts)
    print(f"hostile classes against {args.tree}: {total.line()} in {time.monotonic() - t0:.0f} s")
    return 1 if total.bad else 0


if __name__ == "__main__":
    sys.exit(main())
