"""The fleet's task graph on a Dask client: probe → accumulate per bag → tree-merge per group → solve.

::

    probe_bag(path) ──► group set-up (rate, integration band, tire patch, cache key)
    compute_bag(path, key) ─┐                      (cache hit: read the partial, no recompute)
    compute_bag(path, key) ─┼─ merge ─┐
    compute_bag(path, key) ─┘         ├─ merge ── solve_group ──► row of the fleet table
    compute_bag(path, key) ── merge ──┘            (loop_group, with --loop)

Only paths, settings and cache keys go out to the workers; partials stay on
the workers and move worker-to-worker into the merges; the client gathers a
small status per bag and one result per group.
"""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from nifo.fleet.cache import cache_key, settings_hash
from nifo.fleet.manifest import BagEntry
from nifo.fleet.tasks import (GroupSetup, bag_status, compute_bag, loop_group, merge_outcomes, probe_bag,
                              solve_group)
from nifo.progress import Progress
from nifo_core.errors import ConfigError, NifoError
from nifo_core.fleet import Estimate, HealthSettings, assess_health, reduction_plan

__all__ = ["FleetSettings", "FleetRun", "run_fleet", "group_setups"]


@dataclass(frozen=True)
class FleetSettings:
    """How a fleet run goes (the identification settings come from each group's model file).

    Parameters
    ----------
    chunk_samples : int
        Streaming chunk per bag [samples] (as ``nifo identify --chunk-samples``).
    freqs_hz : tuple of float
        Frequencies [Hz] at which the table gives |T21| (with ~95 % bounds) and its phase.
    plot_max_hz : float
        Highest frequency of the T21 curves kept for the page and Rerun [Hz].
    fanout : int
        Partials merged per reduction task.
    cache_dir : str or None
        Where partials are cached (must be visible to every worker); None: no cache.
    loop : bool
        Also run the residual loop per group (loads the group's records on one worker).
    health : HealthSettings
    """

    chunk_samples: int = 2 ** 18
    freqs_hz: tuple[float, ...] = (2.0, 5.0, 10.0, 20.0)
    plot_max_hz: float = 50.0
    fanout: int = 2
    cache_dir: str | None = None
    loop: bool = False
    health: HealthSettings = field(default_factory=HealthSettings)


@dataclass
class FleetRun:
    """What a fleet run produced: one row per bag, one result per group (with its health)."""

    bags: list[dict]
    groups: dict[tuple[str, str], dict]
    settings: FleetSettings
    setups: dict[tuple[str, str], dict]

    @property
    def n_failed(self) -> int:
        return sum(1 for b in self.bags if b["status"] != "ok")

    @property
    def n_cached(self) -> int:
        return sum(1 for b in self.bags if b.get("cached"))


def _model_cfgs(entries: list[BagEntry]) -> dict[Path, tuple]:
    from nifo.commands.identify import resolve_settings
    from nifo.io.modelfile import load_model_spec

    none = argparse.Namespace(block=None, overlap=None, window=None, band=None, freq_range=None,
                              cond_limit=1e4, chunk_samples=2)
    out = {}
    for model in dict.fromkeys(e.model for e in entries):
        spec = load_model_spec(model)
        if spec.two_step:
            raise ConfigError("nifo fleet takes single-step model files (nonlinearities:), not steps:",
                              source=str(model), hint="identify two-step models per vehicle with nifo identify")
        out[model] = (spec, resolve_settings(none, spec.settings))
    return out


def group_setups(entries: list[BagEntry], probes: list[dict], *, opts: dict, chunk_samples: int
                 ) -> tuple[dict, dict[int, str]]:
    """Per group: the GroupSetup all its bags share; and the reason for every bag left out.

    The integration band is the model file's, else ``default_band(fs, shortest bag)`` as in
    ``nifo identify``; the tire patch is used when every bag of the group has one; bags
    whose rate differs from the group's most common rate are left out.
    """
    from nifo_core.integrate import default_band

    cfgs = _model_cfgs(entries)
    left_out: dict[int, str] = {i: p["reason"] for i, p in enumerate(probes) if not p["ok"]}
    groups: dict[tuple[str, str], list[int]] = {}
    for i, e in enumerate(entries):
        groups.setdefault(e.group, []).append(i)
    setups = {}
    for g, idx in groups.items():
        ok = [i for i in idx if i not in left_out]
        if not ok:
            continue
        fs = Counter(probes[i]["fs_hz"] for i in ok).most_common(1)[0][0]
        for i in ok:
            if probes[i]["fs_hz"] != fs:
                left_out[i] = (f"{entries[i].path}: sample rate {probes[i]['fs_hz']:g} Hz differs from the other "
                               f"bags of {g[0]}/{g[1]} ({fs:g} Hz); resample it to {fs:g} Hz")
        ok = [i for i in ok if i not in left_out]
        spec, cfg = cfgs[entries[ok[0]].model]
        band = cfg["band"]
        while band is None:
            shortest = min(ok, key=lambda i: probes[i]["n_samples"])
            try:
                band = default_band(fs, probes[shortest]["n_samples"] / fs)
            except NifoError as err:
                left_out[shortest] = f"{entries[shortest].path}: {err}"
                ok.remove(shortest)
                if not ok:
                    break
        if not ok:
            continue
        try:
            band = band.validate(fs)
        except NifoError as err:
            for i in ok:
                left_out[i] = f"{entries[i].path}: {err}"
            continue
        setups[g] = GroupSetup(terms=tuple(spec.terms), spectral=cfg["spectral"], band=band,
                               with_tire_patch=all(probes[i]["has_tire_patch"] for i in ok),
                               analysis_band_hz=tuple(cfg["analysis_band_hz"]), cond_limit=cfg["cond_limit"],
                               chunk_samples=int(chunk_samples), opts=dict(opts))
    return setups, left_out


def run_fleet(client, entries: list[BagEntry], *, opts: dict, settings: FleetSettings = FleetSettings(),
              quiet: bool = False) -> FleetRun:
    """Run the fleet on ``client`` (module docstring); failed bags are recorded, never raised."""
    s = settings
    paths = [str(e.path) for e in entries]
    with Progress(float(len(entries)), "fleet: probing bags", enabled=not quiet) as bar:
        futs = client.map(probe_bag, paths, opts=opts, pure=False)
        probes = []
        for f in futs:
            probes.append(f.result())
            bar.advance(1)
        del futs
    setups, left_out = group_setups(entries, probes, opts=opts, chunk_samples=s.chunk_samples)
    digests = {g: settings_hash(st.cache_settings()) for g, st in setups.items()}
    bag_rows = [{"vehicle": e.vehicle, "corner": e.corner, "date": e.date, "path": str(e.path),
                 "status": "pending", "reason": "", "cached": False, "seconds": float("nan"),
                 "hash": probes[i].get("hash", ""), "key": ""} for i, e in enumerate(entries)]
    status, finals, loops = {}, {}, {}
    for g, st in setups.items():
        idx = [i for i, e in enumerate(entries) if e.group == g and i not in left_out]
        outs = []
        for i in idx:
            key = cache_key(probes[i]["hash"], digests[g])
            o = client.submit(compute_bag, paths[i], key, st, s.cache_dir, pure=False)
            outs.append(o)
            status[client.submit(bag_status, o, pure=False)] = i
        for level in reduction_plan(len(outs), fanout=s.fanout):
            outs = [outs[ix[0]] if len(ix) == 1 else client.submit(merge_outcomes, *[outs[j] for j in ix], pure=False)
                    for ix in level]
        m2 = next(entries[i].m2_kg for i in idx)
        finals[g] = client.submit(solve_group, outs[0], freqs_hz=tuple(s.freqs_hz), plot_max_hz=s.plot_max_hz,
                                  m2_kg=m2, pure=False)
        if s.loop:
            loops[g] = client.submit(loop_group, [paths[i] for i in idx], st, pure=False)
        del outs
    for i, reason in left_out.items():
        bag_rows[i].update(status="failed", reason=reason)
    from distributed import as_completed

    with Progress(float(len(status) + len(finals)), "fleet: bags and groups", enabled=not quiet) as bar:
        for fut in as_completed([*status, *finals.values()]):
            if fut in status:
                r = fut.result()
                row = bag_rows[status[fut]]
                if r["ok"]:
                    row.update(status="ok", cached=r["cached"], seconds=r["seconds"], key=r["key"])
                else:
                    row.update(status="failed", reason=r["reason"])
            bar.advance(1)
    groups = {g: f.result() for g, f in finals.items()}
    for g, f in loops.items():
        groups[g]["loop"] = f.result()
    del status, finals, loops
    for e in entries:   # groups with no usable bag at all
        if e.group not in groups:
            groups[e.group] = {"ok": False, "reason": "no usable bag", "bags": []}
    _health(groups, s.health)
    return FleetRun(bags=bag_rows, groups=groups, settings=s,
                    setups={g: st.cache_settings() for g, st in setups.items()})


def _health(groups: dict, hs: HealthSettings) -> None:
    """Strut health over SI coefficients when every solved group has its sprung mass, else per body mass."""
    ok = {g: r for g, r in groups.items() if r["ok"]}
    si = bool(ok) and all(r.get("m2_kg") is not None for r in ok.values())
    est, units = {}, {}
    for g, r in ok.items():
        names = r["names"]["si" if si else "per_mass"]
        est[g] = {n: Estimate(r["coefficients"][n]["value"], r["coefficients"][n]["se"], len(r["bags"]),
                              r["duration_s"]) for n in names}
        units.update({n: r["coefficients"][n]["unit"] for n in names})
    for g, h in assess_health(est, settings=hs, units=units).items():
        groups[g]["health"] = h
