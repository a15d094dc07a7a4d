#!/usr/bin/env python
"""Why nifo runs one BLAS thread per process: the rational fit of an F-16-like transmissibility, timed in fresh
processes with OpenBLAS's own thread count and with one thread, in the same run; prints the ratio.

nifo's linear algebra is small (vector fitting solves a few hundred rows by ~80 columns, a few hundred times); on
such sizes OpenBLAS's threads cost more than they give, and on a machine whose cores are busy with something else
they spin against it. ``nifo_core`` therefore sets ``OPENBLAS_NUM_THREADS`` to ``NIFO_BLAS_THREADS`` (default 1)
before numpy and scipy load. Run: ``python benchmarks/bench_blas_threads.py [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import sys, time
sys.path.insert(0, {root!r})
import numpy as np
from nifo_core.predict.linear_part import fit_rational
rng = np.random.default_rng(3)
f = np.linspace(2.0, 15.0, 266)
s = 2j * np.pi * f
poles = np.array([p for w in np.linspace(3, 14, 10) for p in (-0.02 * 2 * np.pi * w + 2j * np.pi * w,
                                                                    -0.02 * 2 * np.pi * w - 2j * np.pi * w)])
res = rng.normal(size=poles.size) + 1j * rng.normal(size=poles.size)
hz = np.sum(res[:, None] / (s[None, :] - poles[:, None]), axis=0) * 1e-3
t21 = (1 - (2 * np.pi * f) ** 2 * hz) * (1 + 0.05 * (rng.normal(size=f.size) + 1j * rng.normal(size=f.size)))
t0 = time.perf_counter()
fit_rational(f, t21, band_hz=(2.0, 15.0))
print(time.perf_counter() - t0)
"""


def timed(threads: str | None) -> float:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "NIFO_BLAS_THREADS")}
    if threads is not None:
        env["NIFO_BLAS_THREADS"] = threads
    else:   # OpenBLAS's own default: every core
        env["NIFO_BLAS_THREADS"] = str(os.cpu_count() or 1)
    out = subprocess.run([sys.executable, "-c", CHILD.format(root=str(ROOT))], env=env, capture_output=True,
                         text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    many = min(timed(None) for _ in range(args.repeat))
    one = min(timed("1") for _ in range(args.repeat))
    print(f"rational fit (orders 2-40, 266 lines): {os.cpu_count()} BLAS threads {many:.3f} s, one thread "
          f"{one:.3f} s: ratio {many / one:.2f}× (load average {os.getloadavg()[0]:.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
