"""Speed of the quarter-car simulator: wall time per simulated second.

Run: ``.venv/bin/python benchmarks/bench_simulate.py [--duration S] [--fs HZ]``.
Target: 300 s at 600 Hz (oversample 10) with every nonlinearity on in less
than 1/50 of the simulated time (6 s). The first call (numba compile or cache
load) is a warm-up and not timed.
"""

from __future__ import annotations

import argparse
import time

from nifo_core.simulate.quarter_car import SimConfig, preset, simulate

TARGET_RATIO = 1 / 50


def _timed(config: SimConfig, repeats: int) -> float:
    """Best wall time [s] of ``repeats`` runs."""
    best = float("inf")
    for k in range(repeats):
        t0 = time.perf_counter()
        simulate(config, rng=k)
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=300.0, help="simulated seconds (default 300)")
    p.add_argument("--fs", type=float, default=600.0, help="record sample rate [Hz] (default 600)")
    p.add_argument("--repeats", type=int, default=2, help="timed runs, best kept (default 2)")
    args = p.parse_args()

    t0 = time.perf_counter()
    simulate(SimConfig(strut=preset("all"), duration_s=2.0), rng=0)
    print(f"warm-up (compile or cache load): {time.perf_counter() - t0:.2f} s")

    runs = {"all nonlinearities": preset("all"), "linear": ()}
    ratio_all = None
    for name, strut in runs.items():
        cfg = SimConfig(strut=strut, duration_s=args.duration, fs_hz=args.fs)
        wall = _timed(cfg, args.repeats)
        ratio = wall / args.duration
        ratio_all = ratio if ratio_all is None else ratio_all
        print(f"{name:>20}: {args.duration:g} s at {args.fs:g} Hz × {cfg.oversample} in {wall:.2f} s "
              f"-> wall/simulated = 1/{1 / ratio:.0f}")
    ok = ratio_all < TARGET_RATIO
    print(f"target 1/{1 / TARGET_RATIO:.0f} with all nonlinearities: {'met' if ok else 'MISSED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
