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
    settings of each model file, resolved once by the caller (:func:`fleet_settings`)."""
    bases = base_setups(entries, analysis, opts=opts, chunk_samples=settings.chunk_samples)
    return _Scheduler(client, entries, bases, settings).run(quiet=quiet)


class _Scheduler:
    """The client's state of one fleet run, and the completion loop that drives it (:meth:`run`).

    Which task holds which bag's partial of its latest pass (``holder``), the set-up each bag was last submitted
    with (``used``), which bags each status task reports (``status``), which bags each group still waits for
    (``waiting``), each bag's probe and each group's fixed set-up (``final_setup``, ``digests``), and the futures
    of every group's solve, loop and characterization.
    """

    def __init__(self, client, entries: list[BagEntry], bases: dict[tuple[str, str], GroupSetup],
                 s: FleetSettings) -> None:
        from distributed import as_completed

        self.client, self.entries, self.bases, self.s = client, entries, bases, s
        self.paths = [str(e.path) for e in entries]
        self.rows = [{"vehicle": e.vehicle, "corner": e.corner, "date": e.date, "path": p, "status": "pending",
                      "reason": "", "cached": False, "seconds": float("nan"), "hash": "", "key": "", "passes": 0}
                     for e, p in zip(entries, self.paths)]
        self.members: dict[tuple[str, str], list[int]] = {}
        for i, e in enumerate(entries):
            self.members.setdefault(e.group, []).append(i)
        self.group_of = {i: e.group for i, e in enumerate(entries)}
        self.n_threads = max(1, sum(client.nthreads().values()))
        self.holder, self.used, self.status, self.probes, self.final_setup, self.digests = {}, {}, {}, {}, {}, {}
        self.waiting = {g: set(idx) for g, idx in self.members.items()}
        self.solves, self.loops, self.chars = {}, {}, {}
        self.ac = as_completed()
        self.bar = None

    def run(self, *, quiet: bool) -> FleetRun:
        self.submit([i for idx in self.members.values() for i in idx], lambda i: self.bases[self.group_of[i]])
        with Progress(float(len(self.entries) + len(self.members)), "fleet: bags and groups",
                      enabled=not quiet) as self.bar:
            for fut in self.ac:
                if fut in self.status:
                    self.take(fut)
                else:                     # a group's solve
                    self.bar.advance(1)
        groups = _collect(self.solves, self.loops, self.chars, self.members)
        _health(groups, self.s.health)
        return FleetRun(bags=self.rows, groups=groups, settings=self.s,
                        setups={g: st.cache_settings() for g, st in self.final_setup.items() if st is not None})

    def submit(self, idx: list[int], setup_of, *, one_per_task: bool = False) -> None:
        """Accumulation tasks for bags ``idx`` (in groups' order), batched by :func:`batch_plan`."""
        by_group: dict[tuple[str, str], list[int]] = {}
        for i in idx:
            by_group.setdefault(self.group_of[i], []).append(i)
        keys = list(by_group)
        batch = 1 if one_per_task else self.s.batch
        for task in batch_plan([len(by_group[g]) for g in keys], n_workers=self.n_threads, batch=batch):
            spec, chunk = [], []
            for k, r, whole in task:
                g = keys[k]
                these = [by_group[g][j] for j in r]
                whole = whole and set(these) == set(self.members[g])    # all the group's bags: set-up fixed there
                for i in these:
                    self.rows[i]["passes"] += 1
                    self.used[i] = setup_of(i)
                spec.append((g, self.used[these[0]], [(i, self.paths[i]) for i in these], whole))
                chunk += these
            fut = self.client.submit(compute_batch, spec, self.s.cache_dir, pure=False)
            st = self.client.submit(batch_status, fut, pure=False)
            self.status[st] = chunk
            for i in chunk:
                self.holder[i] = fut       # the task holding this bag's partial of its latest pass
            self.ac.add(st)

    def take(self, fut) -> None:
        """A batch's statuses into the bags' rows; a group whose bags are all in is made ready. A batch whose task
        died (a worker lost) is run again one bag per task."""
        chunk = self.status.pop(fut)
        try:
            results = fut.result()
        except Exception:  # noqa: BLE001 - the task died (worker lost): each bag again on its own
            if len(chunk) > 1:
                for i in chunk:
                    self.rows[i]["passes"] -= 1
                self.submit(chunk, lambda i: self.used[i], one_per_task=True)
                return
            results = [(chunk[0], _result(fut, lambda why: BagStatus.failed(f"{self.paths[chunk[0]]}: {why}")))]
        self.bar.advance(len(chunk))
        for i, r in results:
            if r.ok:
                self.rows[i].update(status="ok", reason="", cached=r.cached, seconds=r.seconds, key=r.key,
                                    hash=r.hash)
                self.probes[i] = {**r.probe, "setup_hash": r.setup_hash}
            else:
                self.rows[i].update(status="failed", reason=r.reason)
            g = self.group_of[i]
            self.waiting[g].discard(i)
            if not self.waiting[g]:
                self.group_ready(g)

    def _ok(self, idx) -> list[int]:
        return [i for i in idx if self.rows[i]["status"] == "ok"]

    def group_ready(self, g) -> None:
        """All of group ``g``'s bags are in: on the first pass fix its set-up (and accumulate again the bags whose
        set-up differs), else merge its partials and solve it."""
        if g not in self.final_setup and self._fix_setup(g):
            return
        ok = self._ok(self.members[g])
        for i in ok:
            if self.probes[i]["setup_hash"] != self.digests[g]:   # never expected: say so rather than merge wrongly
                self.rows[i].update(status="failed", reason=f"{self.paths[i]}: accumulated with another set-up "
                                                            "than its group's (internal error; please report)")
        ok = self._ok(ok)
        parts = list(dict.fromkeys(self.holder[i] for i in ok))     # the batches holding this group's partials
        for i in self.members[g]:
            self.holder.pop(i, None)
        if parts:
            self._solve(g, parts, ok)

    def _fix_setup(self, g) -> bool:
        """Fix group ``g``'s set-up from its bags' probes (:func:`group_setup`); True when bags are accumulated
        again with it (the group is then ready again when they are in)."""
        ok = self._ok(self.members[g])
        setup, left = group_setup(self.bases[g], {i: self.probes[i] for i in ok}, label=f"{g[0]}/{g[1]}")
        for i, why in left.items():
            self.rows[i].update(status="failed", reason=f"{self.paths[i]}: {why}")
        self.final_setup[g] = setup
        self.digests[g] = None if setup is None else settings_hash(setup.cache_settings())
        redo = [i for i in ok if i not in left and self.probes[i]["setup_hash"] != self.digests[g]]
        if not redo:
            return False
        self.bar.total += len(redo)
        self.waiting[g] = set(redo)
        self.submit(redo, lambda i: setup)
        return True

    def _solve(self, g, parts: list, ok: list[int]) -> None:
        """Tree-merge group ``g``'s partials (held by the tasks ``parts``) and solve it; its loop and
        characterization on the records of its usable bags ``ok`` when asked."""
        s, client = self.s, self.client
        part = (*g, self.digests[g])
        for level in reduction_plan(len(parts), fanout=s.fanout):
            parts = [parts[ix[0]] if len(ix) == 1 else
                     client.submit(merge_outcomes, *[parts[j] for j in ix], part=part, pure=False) for ix in level]
        m2 = self.entries[self.members[g][0]].m2_kg
        self.solves[g] = client.submit(solve_group, parts[0], freqs_hz=tuple(s.freqs_hz), plot_max_hz=s.plot_max_hz,
                                       m2_kg=m2, part=part, pure=False)
        self.ac.add(self.solves[g])
        paths = [self.paths[i] for i in ok]
        if s.loop:
            self.loops[g] = client.submit(loop_group, paths, self.final_setup[g], pure=False)
        if s.characterize:
            self.chars[g] = client.submit(characterize_group, paths, self.final_setup[g], m2, pure=False)


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
