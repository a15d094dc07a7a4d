"""The fleet's task graph on a Dask client: accumulate batches of bags → tree-merge per group → solve.

::

    compute_batch(bags 0-12) ─┐   (each bag read once, or its partial read from the cache;
    compute_batch(bags 13-25) ┼─ merge ─┐      the bags of one group merged within the task)
    compute_batch(bags 26-38) ┘         ├─ merge ── solve_group ──► row of the fleet table
    compute_batch(bags 39-51) ── merge ─┘            (loop_group, with --loop)

Bags are taken in groups' order and cut into batches (:func:`nifo_core.fleet.batch_plan`:
about 8 tasks per worker thread, at most 32 bags each; a group of up to 32
bags stays in one task), so a run has tens of tasks, not several per bag. A
batch returns a small status per bag to the client and keeps, on its worker,
one partial per group and set-up it holds; merges and solves pick the group's
partial out of each batch holding its bags.

A task holding a whole group fixes the group's set-up as ``nifo identify``
would (band from the model file, else ``default_band(fs, shortest bag)``; tire
patch when every bag has one; bags at another rate left out) before it
streams the bags. A group cut over several tasks is accumulated with each
bag's own band and tire patch; when all its bags are in, the client fixes the
group's set-up the same way and accumulates again only the bags whose set-up
differs (a bag shorter than 64 s in the group, a bag without tire patch).
Only paths, settings and cache keys go out to the workers; partials move
worker-to-worker into the merges; the client gathers the statuses and one
result per group. A batch whose task dies (a worker lost) is run again one
bag per task, so a bag that kills its worker fails alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from nifo.fleet.cache import settings_hash
from nifo.fleet.manifest import BagEntry
from nifo.fleet.results import BagStatus, CharacterizeOutcome, GroupResult, LoopOutcome
from nifo.fleet.tasks import (GroupSetup, batch_status, characterize_group, compute_batch, group_setup, loop_group,
                              merge_outcomes, solve_group)
from nifo.io.modelfile import load_model_spec
from nifo.progress import Progress
from nifo.settings import resolve
from nifo_core.errors import ConfigError
from nifo_core.settings import AnalysisSettings, GivenSettings
from nifo_core.fleet import Estimate, HealthSettings, assess_health, batch_plan, reduction_plan

__all__ = ["FleetSettings", "FleetRun", "run_fleet", "fleet_settings", "base_setups", "group_setup"]


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
    batch : int or None
        Bags per accumulation task; None: :func:`nifo_core.fleet.batch_plan`'s choice
        (about 8 tasks per worker thread, at most 32 bags each).
    cache_dir : str or None
        Where partials are cached (must be visible to every worker); None: no cache.
    loop : bool
        Also run the residual loop per group (loads the group's records on one worker).
    characterize : bool
        Also rank the restoring force's nonlinearities per group (``nifo characterize``, records loaded whole).
    health : HealthSettings
    """

    chunk_samples: int = 2 ** 18
    freqs_hz: tuple[float, ...] = (2.0, 5.0, 10.0, 20.0)
    plot_max_hz: float = 50.0
    fanout: int = 2
    batch: int | None = None
    cache_dir: str | None = None
    loop: bool = False
    characterize: bool = False
    health: HealthSettings = field(default_factory=HealthSettings)


@dataclass
class FleetRun:
    """What a fleet run produced: one row per bag, one result per group (with its health)."""

    bags: list[dict]
    groups: dict[tuple[str, str], GroupResult]
    settings: FleetSettings
    setups: dict[tuple[str, str], dict]

    @property
    def n_failed(self) -> int:
        return sum(1 for b in self.bags if b["status"] != "ok")

    @property
    def n_redone(self) -> int:
        """Bags accumulated a second time with their group's set-up (band set by a bag shorter than 64 s)."""
        return sum(1 for b in self.bags if b.get("passes", 0) > 1)

    @property
    def n_cached(self) -> int:
        return sum(1 for b in self.bags if b.get("cached"))


def fleet_settings(entries: list[BagEntry], *, given: GivenSettings | None = None) -> dict[Path, AnalysisSettings]:
    """Per model file of ``entries``, its :class:`~nifo_core.settings.AnalysisSettings`, resolved once by the
    precedence function every command uses (:func:`nifo.settings.resolve`: ``given`` > the model file's
    ``settings:`` > defaults; not read off the data: one fleet, one set of settings, so a vehicle's bags are compared
    on the same blocks and bands). The caller (``nifo fleet``, a benchmark) hands them to :func:`run_fleet`."""
    out = {}
    for model in dict.fromkeys(e.model for e in entries):
        out[model] = resolve([], given=given, file_settings=_single_step(model).settings, from_data=False)
    return out


def _single_step(model: Path):
    spec = load_model_spec(model)
    if spec.two_step:
        raise ConfigError("nifo fleet takes single-step model files (nonlinearities:), not steps:",
                          source=str(model), hint="identify two-step models per vehicle with nifo identify")
    return spec


def base_setups(entries: list[BagEntry], analysis: Mapping[Path, AnalysisSettings], *, opts: dict,
                chunk_samples: int) -> dict[tuple[str, str], GroupSetup]:
    """Per group, the set-up from its model file's terms and the settings resolved for it (``analysis``:
    :func:`fleet_settings`, never resolved here); band and tire patch still open (None) unless the settings fix
    the band."""
    terms = {model: tuple(_single_step(model).terms) for model in dict.fromkeys(e.model for e in entries)}
    out = {}
    for e in entries:
        if e.group in out:
            continue
        try:
            cfg = analysis[e.model]
        except KeyError:
            raise ConfigError("no resolved settings for this model file", source=str(e.model),
                              hint="resolve them with nifo.fleet.runner.fleet_settings(entries)") from None
        out[e.group] = GroupSetup(terms=terms[e.model], spectral=cfg.spectral, band=cfg.band,
                                  with_tire_patch=None, analysis_band_hz=tuple(cfg.analysis_band_hz),
                                  cond_limit=cfg.cond_limit, chunk_samples=int(chunk_samples), opts=dict(opts),
                                  band_from_model=cfg.band is not None)
    return out


def run_fleet(client, entries: list[BagEntry], *, analysis: Mapping[Path, AnalysisSettings], opts: dict,
              settings: FleetSettings = FleetSettings(), quiet: bool = False) -> FleetRun:
    """Run the fleet on ``client`` (module docstring); failed bags are recorded, never raised. ``analysis``: the
    settings of each model file, resolved once by the caller (:func:`fleet_settings`).

    Long because the scheduler's state (which task holds which bag's partial, which group still waits for which
    bag, each group's fixed set-up) is shared by the ``submit`` and ``group_ready`` closures and the completion
    loop that drives them; splitting it further means turning that state into a class.
    """
    from distributed import as_completed


    s = settings
    bases = base_setups(entries, analysis, opts=opts, chunk_samples=s.chunk_samples)
    paths = [str(e.path) for e in entries]
    rows = [{"vehicle": e.vehicle, "corner": e.corner, "date": e.date, "path": p, "status": "pending",
             "reason": "", "cached": False, "seconds": float("nan"), "hash": "", "key": "", "passes": 0}
            for e, p in zip(entries, paths)]
    members: dict[tuple[str, str], list[int]] = {}
    for i, e in enumerate(entries):
        members.setdefault(e.group, []).append(i)
    group_of = {i: e.group for i, e in enumerate(entries)}
    n_threads = max(1, sum(client.nthreads().values()))
    holder, used, status, waiting, probes, final_setup, digests = {}, {}, {}, {}, {}, {}, {}
    solves, loops, chars = {}, {}, {}
    ac = as_completed()

    def submit(idx: list[int], setup_of, *, batch: int | None = s.batch) -> None:
        """Accumulation tasks for bags ``idx`` (in groups' order), batched by :func:`batch_plan`."""
        by_group: dict[tuple[str, str], list[int]] = {}
        for i in idx:
            by_group.setdefault(group_of[i], []).append(i)
        keys = list(by_group)
        for task in batch_plan([len(by_group[g]) for g in keys], n_workers=n_threads, batch=batch):
            spec, chunk = [], []
            for k, r, whole in task:
                g = keys[k]
                these = [by_group[g][j] for j in r]
                whole = whole and set(these) == set(members[g])    # all the group's bags: set-up fixed there
                for i in these:
                    rows[i]["passes"] += 1
                    used[i] = setup_of(i)
                spec.append((g, used[these[0]], [(i, paths[i]) for i in these], whole))
                chunk += these
            fut = client.submit(compute_batch, spec, s.cache_dir, pure=False)
            st = client.submit(batch_status, fut, pure=False)
            status[st] = chunk
            for i in chunk:
                holder[i] = fut       # the task holding this bag's partial of its latest pass
            ac.add(st)

    for g, idx in members.items():
        waiting[g] = set(idx)
    submit([i for idx in members.values() for i in idx], lambda i: bases[group_of[i]])

    def group_ready(g) -> None:
        ok = [i for i in members[g] if rows[i]["status"] == "ok"]
        if g not in final_setup:            # first pass done: fix the group's set-up
            setup, left = group_setup(bases[g], {i: probes[i] for i in ok}, label=f"{g[0]}/{g[1]}")
            for i, why in left.items():
                rows[i].update(status="failed", reason=f"{paths[i]}: {why}")
            final_setup[g] = setup
            digests[g] = None if setup is None else settings_hash(setup.cache_settings())
            redo = [i for i in ok if i not in left and probes[i]["setup_hash"] != digests[g]]
            if redo:
                bar.total += len(redo)
                waiting[g] = set(redo)
                submit(redo, lambda i: setup)
                return
        ok = [i for i in members[g] if rows[i]["status"] == "ok"]
        for i in ok:
            if probes[i]["setup_hash"] != digests[g]:     # never expected: say so rather than merge it wrongly
                rows[i].update(status="failed", reason=f"{paths[i]}: accumulated with another set-up than its "
                                                       "group's (internal error; please report)")
        ok = [i for i in ok if rows[i]["status"] == "ok"]
        parts = list(dict.fromkeys(holder[i] for i in ok))     # the batches holding this group's partials
        for i in members[g]:
            holder.pop(i, None)
        if not parts:
            return
        part = (*g, digests[g])
        for level in reduction_plan(len(parts), fanout=s.fanout):
            parts = [parts[ix[0]] if len(ix) == 1 else
                     client.submit(merge_outcomes, *[parts[j] for j in ix], part=part, pure=False) for ix in level]
        m2 = entries[members[g][0]].m2_kg
        solves[g] = client.submit(solve_group, parts[0], freqs_hz=tuple(s.freqs_hz), plot_max_hz=s.plot_max_hz,
                                  m2_kg=m2, part=part, pure=False)
        ac.add(solves[g])
        if s.loop:
            loops[g] = client.submit(loop_group, [paths[i] for i in ok], final_setup[g], pure=False)
        if s.characterize:
            chars[g] = client.submit(characterize_group, [paths[i] for i in ok], final_setup[g], m2, pure=False)

    with Progress(float(len(entries) + len(members)), "fleet: bags and groups", enabled=not quiet) as bar:
        for fut in ac:
            if fut not in status:
                bar.advance(1)
                continue
            chunk = status.pop(fut)
            try:
                results = fut.result()
            except Exception:  # noqa: BLE001 - the task died (worker lost): each bag again on its own
                if len(chunk) > 1:
                    for i in chunk:
                        rows[i]["passes"] -= 1
                    submit(chunk, lambda i: used[i], batch=1)
                    continue
                results = [(chunk[0], _result(fut, lambda why: BagStatus.failed(f"{paths[chunk[0]]}: {why}")))]
            bar.advance(len(chunk))
            for i, r in results:
                if r.ok:
                    rows[i].update(status="ok", reason="", cached=r.cached, seconds=r.seconds, key=r.key, hash=r.hash)
                    probes[i] = {**r.probe, "setup_hash": r.setup_hash}
                else:
                    rows[i].update(status="failed", reason=r.reason)
                g = group_of[i]
                waiting[g].discard(i)
                if not waiting[g]:
                    group_ready(g)
    groups = _collect(solves, loops, chars, members)
    del solves, loops, chars, holder, status
    _health(groups, s.health)
    return FleetRun(bags=rows, groups=groups, settings=s,
                    setups={g: st.cache_settings() for g, st in final_setup.items() if st is not None})


def _collect(solves: dict, loops: dict, chars: dict, members: dict) -> dict[tuple[str, str], GroupResult]:
    """Every group's result in the manifest's order (not completion order), with its loop and characterization;
    a group with no usable bag at all says so."""
    groups = {g: _result(f, GroupResult.failed) for g, f in solves.items()}
    for g, f in loops.items():
        loop = _result(f, lambda why: LoopOutcome(ok=False, verdict=f"loop not run: {why}"))
        groups[g] = groups[g].with_(loop=loop)
    for g, f in chars.items():
        ch = _result(f, lambda why: CharacterizeOutcome(ok=False, text=f"characterization not run: {why}"))
        groups[g] = groups[g].with_(characterization=ch)
    for g in members:
        if g not in groups:
            groups[g] = GroupResult.failed("no usable bag")
    return {g: groups[g] for g in members}


def _result(fut, failed):
    """A task's result; a task that died (worker lost, bug) becomes ``failed(one line)``, not the fleet's end."""
    try:
        return fut.result()
    except Exception as err:  # noqa: BLE001
        first = str(err).splitlines()[0] if str(err) else "no message"
        return failed(f"task failed on the cluster ({type(err).__name__}: {first})")


def _health(groups: dict[tuple[str, str], GroupResult], hs: HealthSettings) -> None:
    """Strut health over SI coefficients when every solved group has its sprung mass, else per body mass."""
    ok = {g: r for g, r in groups.items() if r.ok}
    si = bool(ok) and all(r.m2_kg is not None for r in ok.values())
    est, units = {}, {}
    for g, r in ok.items():
        names = r.names["si" if si else "per_mass"]
        est[g] = {n: Estimate(r.coefficients[n].value, r.coefficients[n].se, len(r.bags), r.duration_s)
                  for n in names}
        units.update({n: r.coefficients[n].unit for n in names})
    for g, h in assess_health(est, settings=hs, units=units).items():
        groups[g] = groups[g].with_(health=h)
