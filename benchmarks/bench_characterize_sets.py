"""Does ``nifo characterize`` suggest exactly the true set? (issue 28: name what is there and nothing else)

For every kind of the characterization library, a simulated strut holding the
paper's damper knee (velocity_deadzone knee 0.03 m/s, −700 N·s/m) plus that
kind, at four random-road levels (1, 2.5, 4, 6 mm RMS, 2 % noise on every
channel), characterized jointly (the four records as levels of one vehicle);
plus the knee alone. Prints per case and seed the suggested set beside the
true one, and how many cases match. For a true term that was not suggested it
also prints its detection limit at its true parameters given the suggested
terms (:func:`nifo_core.characterize.score.detection_limit`, the limit
characterize states for what it did not see): a true coefficient below that
limit could not have been seen in these data, a miss above it is the
characterization's. The in-process equivalent of::

    nifo simulate --preset paper_deadzone --nonlinearity KIND:...:coef=C --road-rms R --noise 0.02 \\
                  --duration 120 --seed S --out rR.mcap          (R = 1, 2.5, 4, 6)
    nifo characterize r1.mcap r2.5.mcap r4.mcap r6.mcap

Usage::

    .venv/bin/python benchmarks/bench_characterize_sets.py [--seeds 1 2] [--duration 120] [--kinds K ...]
"""

from __future__ import annotations

import argparse
import sys
import time

#: kind -> (parameters, coefficient) added beside the paper's knee; None: the knee alone
CASES = {
    "knee_only": None,
    "cubic_stiffness": ({}, 2e7),
    "quadratic_stiffness": ({}, 3e5),
    "clearance": ({"gap": 0.003}, 5e3),
    "bump_stop": ({"gap": 0.008, "side": "compression"}, 50e3),
    "backlash": ({"deadband": 0.00043}, 8e3),         # the paper's: below its detection limit at these levels
    "backlash_stiff": ({"deadband": 0.00043}, 6e4),   # the paper's play, a stiffness above that limit
    "coulomb": ({"eps": 0.005}, 100.0),
    "quadratic_damping": ({}, 2000.0),
    "asymmetric_damping": ({"side": "rebound"}, 1400.0),
}
LEVELS_MM = (1.0, 2.5, 4.0, 6.0)


def simulate_case(kind: str, seed: int, duration: float, noise: float = 0.02, levels=LEVELS_MM):
    """The records (one per road level) and the true set of kinds for ``kind`` (a key of :data:`CASES`)."""
    from nifo_core.kinds.describing import Term
    from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

    strut = [StrutForce(Term("velocity_deadzone", {"knee": 0.03}), -700.0)]
    if CASES[kind] is not None:
        params, coef = CASES[kind]
        strut.append(StrutForce(Term(_kind(kind), dict(params)), coef))
    recs = []
    for i, r in enumerate(levels):
        cfg = SimConfig(strut=tuple(strut), road=RandomRoad(rms_m=r * 1e-3), duration_s=duration,
                        noise=SensorNoise(relative=noise))
        recs.append(simulate(cfg, rng=1000 * seed + i).record)
    return recs, cfg.vehicle.m2, sorted({s.term.kind for s in strut})


def _kind(case: str) -> str:
    """The describing-function kind of a case of :data:`CASES` (``backlash_stiff`` is a backlash)."""
    return case.removesuffix("_stiff")


def missed_limits(kind: str, recs, m2: float, ch) -> list[str]:
    """For each true term ``ch`` did not suggest: its true coefficient against its detection limit at its true
    parameters given the suggested terms (the limit characterize's notes state for what it did not see)."""
    from nifo_core.characterize.data import RegressionData, candidate_grid
    from nifo_core.characterize.restoring import restoring_force
    from nifo_core.characterize.score import detection_limit
    from nifo_core.kinds.describing import Term

    true = {"velocity_deadzone": ({"knee": 0.03}, -700.0)}
    if CASES[kind] is not None:
        true[_kind(kind)] = CASES[kind]
    missed = sorted(set(true) - {c.kind for c in ch.suggested})
    if not missed:
        return []
    data = RegressionData([restoring_force(r, band=ch.band) for r in recs], n_groups=4, body_stiffness=False)
    base = [data.regressor(c.term, offsets=c.offsets or None) for c in ch.suggested]
    out = []
    for k in missed:
        params, coef = true[k]
        n_grid = len(candidate_grid(k, z_range=data.zmax, zdot_range=data.vmax, z_neg=data.zneg, z_pos=data.zpos))
        lim, _ = detection_limit(data, base, Term(k, dict(params)), thresholds=ch.thresholds, n_grid=n_grid)
        seen = "above" if abs(coef) > lim * m2 else "below"
        out.append(f"{k} {abs(coef):.3g} is {seen} its detection limit {lim * m2:.3g} given the suggestion")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--duration", type=float, default=120.0, help="record length per level [s] (default 120)")
    ap.add_argument("--kinds", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("-v", "--verbose", action="store_true", help="print every candidate's status")
    args = ap.parse_args(argv)

    from nifo_core.characterize.automatic import characterize

    ok = total = 0
    for kind in args.kinds:
        for seed in args.seeds:
            t0 = time.perf_counter()
            recs, m2, truth = simulate_case(kind, seed, args.duration)
            t1 = time.perf_counter()
            ch = characterize(recs, m2_kg=m2)
            got = [c.term.label for c in ch.suggested]
            match = sorted(c.kind for c in ch.suggested) == truth
            ok += match
            total += 1
            print(f"{kind:20s} seed {seed}: {'OK  ' if match else 'FAIL'} true {{{', '.join(truth)}}}  "
                  f"suggested [{'; '.join(got)}]  (sim {t1 - t0:.0f} s, characterize {time.perf_counter() - t1:.0f} s)",
                  flush=True)
            for line in missed_limits(kind, recs, m2, ch):
                print(f"      missed: {line}")
            if args.verbose:
                for c in ch.candidates:
                    print(f"      {c.status:11s} {c.term.label:45s} ERR {c.err:.3f} coef {c.coefficient:.4g} "
                          f"{c.alternative_to or ''} {'; '.join(c.failed)}")
    print(f"{ok}/{total} cases suggest exactly the true set")
    return 0 if ok == total else 1


if __name__ == "__main__":
    sys.exit(main())
