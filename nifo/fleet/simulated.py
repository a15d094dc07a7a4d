"""A simulated fleet on disk, for tests, benchmarks and demonstrations (what ``nifo simulate`` writes, per bag).

Every vehicle gets its own quarter car: the nominal one (``QuarterCar()``, the
paper's velocity deadzone, knee 0.03 m/s, -700 N·s/m) with each of m2, k1, k2,
c2 and the deadzone coefficient scaled by its own factor drawn uniformly in
1 ± ``spread``. Planted faults: ``worn`` vehicles lose ``worn_loss`` of their
damping C2 (a worn damper), ``knee_moved`` vehicles have the deadzone knee
scaled by ``knee_factor``. Each bag is an independent random-road record
(its own seed) saved as a real bag (``.mcap``) with ``<bag>.truth.json``
beside it, under ``ROOT/<vehicle>/<corner>/``, plus ``ROOT/manifest.csv``,
``ROOT/model.yaml`` (the declared model) and ``ROOT/fleet_truth.json``.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Sequence

import numpy as np

from nifo.io.loader import save_record
from nifo.io.modelfile import write_model_spec
from nifo_core.kinds.describing import LIBRARY, Term
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, StrutForce, simulate
from nifo_core.simulate.vehicle import QuarterCar

__all__ = ["write_simulated_fleet", "NOMINAL_KNEE", "NOMINAL_DEADZONE"]

NOMINAL_KNEE = 0.03        # m/s
NOMINAL_DEADZONE = -700.0  # N·s/m
#: the fleet's one strut nonlinearity: the paper's damper knee
KNEE = LIBRARY.velocity_deadzone.name


def _vehicle(rng: np.random.Generator, spread: float, *, worn_loss: float, knee_factor: float):
    f = 1 + rng.uniform(-spread, spread, size=5)
    car = QuarterCar(m2=300.0 * f[0], k1=250e3 * f[1], k2=22e3 * f[2], c2=1400.0 * f[3] * (1 - worn_loss))
    strut = (StrutForce(Term(KNEE, {"knee": NOMINAL_KNEE * knee_factor}), NOMINAL_DEADZONE * f[4]),)
    return car, strut


def _write_bag(job: dict) -> str:
    """Simulate one bag and write it with its truth (module-level: runs on a worker too)."""
    path = Path(job["path"])
    truth = path.with_name(path.name + ".truth.json")
    if path.exists() and truth.exists():     # written by an earlier, interrupted call (truth comes last)
        return str(path)
    sim = simulate(job["config"], rng=job["seed"])
    save_record(path, sim.record)
    truth.write_text(json.dumps(
        {"nifo_truth": 1, "record": path.name, **sim.truth.to_dict(), "config": job["config"].to_dict()}) + "\n")
    return str(path)


def write_simulated_fleet(root: str | Path, *, n_vehicles: int = 20, bags_per_vehicle: int = 10,
                          duration_s: float | Sequence[float] = 60.0, spread: float = 0.10,
                          worn: Sequence[int] = (3, 11), worn_loss: float = 0.30, knee_moved: Sequence[int] = (7,),
                          knee_factor: float = 2.0, corner: str = "FL", road_rms_mm: float = 2.5,
                          block: int = 6144, with_mass: bool = True, seed: int = 0, mapper=map) -> Path:
    """Write the fleet under ``root``; returns the manifest path. Vehicles are ``v00``, ``v01``, ...

    ``duration_s`` is one length [s] or (lo, hi): each bag's length drawn uniformly in it. With
    ``with_mass`` the manifest gives every vehicle's sprung mass (``m2_kg``, as weighed).
    ``mapper(func, jobs)`` runs the bag simulations (default: the built-in ``map``, in this
    process; e.g. ``lambda f, xs: client.gather(client.map(f, xs))`` on a Dask cluster).
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    rows, truth, jobs = [], {}, []
    for v in range(n_vehicles):
        name = f"v{v:02d}"
        car, strut = _vehicle(rng, spread, worn_loss=worn_loss if v in worn else 0.0,
                              knee_factor=knee_factor if v in knee_moved else 1.0)
        truth[name] = {"vehicle": car.to_dict(), "strut": [s.to_dict() for s in strut],
                       "planted": "worn damper" if v in worn else ("knee moved" if v in knee_moved else None),
                       "c2_over_m2": car.c2 / car.m2, "k2_over_m2": car.k2 / car.m2,
                       "c_over_m2_velocity_deadzone": strut[0].coefficient / car.m2,
                       "k2": car.k2, "c2": car.c2, "c_velocity_deadzone": strut[0].coefficient}
        folder = root / name / corner
        folder.mkdir(parents=True, exist_ok=True)
        for b in range(bags_per_vehicle):
            dur = float(duration_s) if np.isscalar(duration_s) else float(rng.uniform(*duration_s))
            cfg = SimConfig(vehicle=car, strut=strut, road=RandomRoad(road_rms_mm * 1e-3), duration_s=dur)
            path = folder / f"bag{b:02d}.mcap"
            jobs.append({"config": cfg, "seed": seed * 1_000_003 + v * 1000 + b, "path": str(path)})
            rows.append({"vehicle": name, "corner": corner, "date": f"2026-01-{1 + b % 28:02d}",
                         "path": path.relative_to(root).as_posix(), "m2_kg": f"{car.m2:.6g}" if with_mass else ""})
    list(mapper(_write_bag, jobs))
    with (root / "manifest.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["vehicle", "corner", "date", "path", "m2_kg"])
        w.writeheader()
        w.writerows(rows)
    write_model_spec(root / "model.yaml", [Term(KNEE, {"knee": NOMINAL_KNEE})],
                     settings={"block": int(block)})
    (root / "fleet_truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return root / "manifest.csv"
