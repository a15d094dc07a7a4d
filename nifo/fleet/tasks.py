"""What runs on a Dask worker: accumulate a batch of bags, merge partials, solve a group, run the loop.

Workers get paths and small settings, never sample arrays. One task
accumulates several bags (:func:`compute_batch`: a few tasks per worker,
each of many bags, so Dask's cost per task is spread over them), caches
every bag's partial on its own, and returns the small per-bag statuses and
compact partials (a :meth:`StreamingNifo.state_dict`: the block
cross-spectra of [a1, a2, g_i..] and a few counters) merged per group, which
stay on the workers until they are merged, and small per-group results.
Every function is module-level and picklable, and hands on the named, frozen objects of
:mod:`nifo.fleet.results`. A bag that cannot be used gets a :class:`BagStatus` with ``ok`` False and its one-line
reason instead of raising, so one bad bag never stops its batch or the fleet.

The per-bag accumulation is the one ``nifo identify`` does per file: the core's engine
(:mod:`nifo_core.nifo.engine`: the same set-up decision from the bags' probes, the same accumulator, the same
channels pushed — a measured force and a fixed spindle included), the same chunk length, merged in file order;
so a group's merged partial equals identify's merged accumulators and its coefficients agree to rounding.
"""

from __future__ import annotations

import time
import warnings
from collections import Counter
from dataclasses import dataclass, field, replace
from itertools import chain

import numpy as np

from nifo.fleet.cache import (cache_key, content_hash, load_note, load_partial, settings_hash, store_note,
                              store_partial)
from nifo.fleet.results import (Batch, BagStatus, CharacterizeOutcome, Coefficient, Curves, GroupPartial, GroupResult,
                                LoopOutcome)
from nifo.io.loader import detect_format, iter_record_chunks, load_record
from nifo_core.characterize.automatic import characterize
from nifo_core.kinds.describing import Term
from nifo_core.errors import NifoError, RecordTooShortError
from nifo_core.fleet import interval_halfwidth, standard_error
from nifo_core.signal.integrate import IntegrationBand, default_band
from nifo_core.predict.linear_part import BODY_FIT_LIMIT, nominal_linear_part
from nifo_core.loop.closing import close_loop
from nifo_core.loop.settings import LoopSettings
from nifo_core.predict.model import IdentifiedModel
from nifo_core.nifo.engine import IdentifySetup, RecordProbe, accumulate_record
from nifo_core.nifo.identify import StreamingNifo, nifo_from_spectra, static_fits
from nifo_core.nifo.summary import summarize
from nifo_core.signal.spectral import SpectralSettings

__all__ = ["GroupSetup", "coefficient_specs", "bag_setup", "group_setup", "bag_coefficients", "compute_batch",
           "batch_status", "pick", "merge_outcomes", "solve_group", "loop_group", "characterize_group", "LOOP_SCORES"]

@dataclass(frozen=True)
class GroupSetup:
    """Everything a worker needs to accumulate one bag of a group (picklable, JSON-able)."""

    terms: tuple[Term, ...]
    spectral: SpectralSettings
    band: IntegrationBand | None           # None: each bag's default_band until the group's is known
    with_tire_patch: bool | None           # None: each bag's own until the group's is known
    analysis_band_hz: tuple[float, float]
    cond_limit: float
    chunk_samples: int
    opts: dict = field(default_factory=dict)
    band_from_model: bool = False
    with_force: bool | None = None         # None: each bag's own until the group's is known
    spindle_fixed: bool | None = None      # None: each bag's own until the group's is known

    def cache_settings(self) -> dict:
        """What shapes a partial (the cache key's settings part). The force and the fixed spindle appear only
        when taken, so the partials of bags without them keep their keys (and a cached partial of a force-driven
        bag accumulated without its force, before the fleet took it, is never read)."""
        opts = {k: (None if v is None else (v if isinstance(v, (str, int, float)) else repr(v)))
                for k, v in self.opts.items()}
        return {"terms": [t.to_dict() for t in self.terms], "spectral": self.spectral.to_dict(),
                "band": None if self.band is None else self.band.to_dict(), "with_tire_patch": self.with_tire_patch,
                "analysis_band_hz": list(self.analysis_band_hz), "cond_limit": self.cond_limit,
                "chunk_samples": self.chunk_samples, "opts": opts,
                **{k: True for k in ("with_force", "spindle_fixed") if getattr(self, k)}}

    def engine(self, fs_hz: float) -> IdentifySetup:
        """The core's set-up of a bag accumulated with this (complete) set-up at ``fs_hz``."""
        return IdentifySetup(fs_hz=fs_hz, terms=self.terms, spectral=self.spectral, band=self.band,
                             analysis_band_hz=self.analysis_band_hz, cond_limit=self.cond_limit,
                             with_tire_patch=bool(self.with_tire_patch), with_force=bool(self.with_force),
                             spindle_fixed=bool(self.spindle_fixed))


def coefficient_specs(terms, *, si: bool = False) -> list[tuple[str, str, str]]:
    """(column name, unit, meaning) of every coefficient a group reports.

    Per body mass (what output-only NIFO identifies): K2/M2, C2/M2, then c_i/M2
    per term; with ``si`` (sprung mass known) the same times M2: K2, C2, c_i.
    """
    if si:
        out = [("k2", "N/m", "K2, strut stiffness (K2/M2 times the given M2)"),
               ("c2", "N·s/m", "C2, strut damping (C2/M2 times the given M2)")]
    else:
        out = [("k2_over_m2", "1/s²", "K2/M2, strut stiffness per body mass (body model fitted to T21)"),
               ("c2_over_m2", "1/s", "C2/M2, strut damping per body mass (body model fitted to T21)")]
    seen: dict[str, int] = {}
    for t in terms:
        seen[t.kind] = seen.get(t.kind, 0) + 1
        stem = f"c_{t.kind}" if si else f"c_over_m2_{t.kind}"
        name = stem + (f"_{seen[t.kind]}" if seen[t.kind] > 1 else "")
        u = t.spec.coef_unit
        if si:
            out.append((name, u or "-", f"c of {t.label} (c/M2 times the given M2)"))
        else:
            out.append((name, f"({u})/kg" if u else "1/kg", f"c/M2 of {t.label} (pooled constant, NIFO static fit)"))
    return out


def _one_line(err: BaseException) -> str:
    if isinstance(err, NifoError):
        return str(err).replace("\n", " ")
    return f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else 'no message'}"


def _coefficients(res, *, body_first: bool = False) -> dict[str, float]:
    """Coefficient values of one NIFO result (NaN where the body model cannot be fitted).

    The body model is the one ``nifo identify`` reports (``IdentifiedModel.from_nifo``,
    linear form chosen automatically), whose choice needs the rational fit only when
    the one-mass body is not physical or misfits T21 by more than ``BODY_FIT_LIMIT``.
    With ``body_first`` the body alone is fitted first and the automatic choice is run
    only in those cases: the same values (the automatic choice keeps a physical body
    within the limit whatever the rational fit gives) at a hundredth of the cost
    (the rational fit tries every order up to 40 by vector fitting: ~0.4 s per bag).
    """
    names = [n for n, _, _ in coefficient_specs(res.terms)]
    body = None
    if body_first:
        try:
            model = IdentifiedModel.from_nifo(res, source="static", linear_form="body")
            if model.linear.body.fit_rms <= BODY_FIT_LIMIT:
                body = model.body
        except NifoError:       # not physical: the automatic choice decides
            body = None
    try:
        if body is None:
            body = IdentifiedModel.from_nifo(res, source="static").body
    except NifoError:
        body = None
    k, c = (float("nan"), float("nan")) if body is None else (body.k, body.c)   # None: a rational linear part
    gam = [float(x) for x in res.static.c_over_m2]
    return dict(zip(names, [float(k), float(c), *gam]))


# ---------------------------------------------------------------------------------------------
# per bag
# ---------------------------------------------------------------------------------------------
def bag_setup(base: GroupSetup, probe: dict) -> GroupSetup:
    """The set-up a bag is accumulated with: the group's band and channels where fixed, else its own
    (:meth:`IdentifySetup.for_probes` of this bag alone: its force, its spindle, its tire patch).

    Own band: ``default_band(fs, this bag's length)`` (``nifo identify`` uses the
    group's shortest bag; equal whenever every bag is longer than 64 s, else the
    client recomputes the bags that differ).
    """
    own = RecordProbe.from_dict(probe)
    force = own.has_force if base.with_force is None else base.with_force
    tp = own.has_tire_patch if base.with_tire_patch is None else base.with_tire_patch
    setup = IdentifySetup.for_probes([own], base.terms, spectral=base.spectral, band=base.band,
                                     analysis_band_hz=base.analysis_band_hz, cond_limit=base.cond_limit,
                                     input_measured=bool(tp) and not force, use_force=bool(force))
    return replace(base, band=setup.band, with_tire_patch=setup.with_tire_patch, with_force=setup.with_force,
                   spindle_fixed=setup.spindle_fixed)


def _accumulate(chunks, path: str, setup: GroupSetup):
    """One bag into its accumulator, as ``nifo identify`` accumulates a file (:func:`accumulate_record`)."""
    chunks = iter(chunks)
    first = next(chunks, None)
    if first is None:
        raise RecordTooShortError("the file holds no samples", source=path)
    return accumulate_record(chain([first], chunks), setup.engine(first.fs_hz), source=path)


def _band_spectra(one, setup: GroupSetup):
    """A bag's spectra on the analysis band's lines, without the tire patch: what its own coefficients use."""
    spec = one.spectra(setup.analysis_band_hz)
    if setup.with_tire_patch:
        spec = spec.select(list(range(spec.n_channels - 1)))
    return spec


def _coefficients_alone(spec, setup: GroupSetup) -> dict[str, float]:
    """One bag's coefficients by the full NIFO solve of its band spectra (NaN where it cannot give them)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = nifo_from_spectra(spec, setup.terms, band=setup.band, analysis_band_hz=setup.analysis_band_hz,
                                    on_ill_conditioned="ignore", cond_limit=setup.cond_limit,
                                    with_force=bool(setup.with_force), spindle_fixed=bool(setup.spindle_fixed))
        return _coefficients(res, body_first=True)
    except NifoError:
        return {n: float("nan") for n, _, _ in coefficient_specs(setup.terms)}


def bag_coefficients(specs: list, setup: GroupSetup) -> list[dict[str, float]]:
    """Each bag's own coefficients (for the group's standard errors), NaN where one bag cannot give them.

    ``specs``: the bags' :func:`_band_spectra` (one set-up). The values are those of
    ``nifo identify`` on each bag alone (the static fit and the one-mass body use only
    the analysis band's lines): the static fits of all bags are solved as one batch
    (:func:`nifo_core.nifo.identify.static_fits`, 0.1 instead of ~1 ms per bag), then each
    bag's body (:func:`nominal_linear_part`); a bag whose body is not physical or
    misfits T21 takes the full solve and the automatic choice of its linear part.
    """
    if not specs:
        return []
    names = [n for n, _, _ in coefficient_specs(setup.terms)]
    if setup.with_force:        # the batch static fit takes [a1, a2, g..] only: each bag's full solve
        return [_coefficients_alone(sp, setup) for sp in specs]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gam, t21s = static_fits(specs, len(setup.terms), analysis_band_hz=setup.analysis_band_hz)
    except NifoError:           # e.g. spectra with other channels: each bag on its own
        return [_coefficients_alone(sp, setup) for sp in specs]
    out = []
    for sp, g, t in zip(specs, gam, t21s):
        body = None
        if np.isfinite(g).all():
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    lin, body = nominal_linear_part(sp.freq_hz, t, setup.terms, g, band_hz=setup.analysis_band_hz,
                                                    form="body")
                if lin.body.fit_rms > BODY_FIT_LIMIT:
                    body = None
            except NifoError:
                body = None
        out.append(_coefficients_alone(sp, setup) if body is None else
                   dict(zip(names, [float(body.k), float(body.c), *(float(x) for x in g)])))
    return out


def group_setup(base: GroupSetup, probes: dict[int, dict], *, label: str) -> tuple[GroupSetup | None, dict[int, str]]:
    """The group's set-up from its bags' rates, lengths and channels, as ``nifo identify`` chooses it
    (:meth:`IdentifySetup.for_probes`: the force when every bag has one, the tire patch when every bag has it and
    no force is taken, the band of the shortest bag).

    Where ``nifo identify`` refuses files that cannot be identified together, the fleet leaves out the bags that
    differ from most of the group (another rate; a fixed spindle among moving ones or the reverse) with their
    reason, and goes on. Returns the set-up (None when no bag is left) and the reason for every bag left out.
    """
    if not probes:
        return None, {}
    fs = Counter(p["fs_hz"] for p in probes.values()).most_common(1)[0][0]
    left = {i: f"sample rate {p['fs_hz']:g} Hz differs from the other bags of {label} ({fs:g} Hz); resample it"
            for i, p in probes.items() if p["fs_hz"] != fs}
    fixed = Counter(bool(p["spindle_fixed"]) for i, p in probes.items() if i not in left).most_common(1)[0][0]
    left.update({i: ("its spindle is fixed" if p["spindle_fixed"] else "its spindle moves")
                 + f", unlike the other bags of {label}; identify it with bags of its kind"
                 for i, p in probes.items() if i not in left and bool(p["spindle_fixed"]) != fixed})
    ok = [RecordProbe.from_dict(p) for i, p in probes.items() if i not in left]
    band = base.band or default_band(fs, min(p.n_samples for p in ok) / fs)
    force = all(p.has_force for p in ok)
    return replace(base, band=band, with_tire_patch=all(p.has_tire_patch for p in ok) and not force,
                   with_force=force, spindle_fixed=fixed), left


def _open(path: str, base: GroupSetup):
    """(chunk iterator, first chunk, probe: the bag's rate, length and channels) of an opened bag."""
    raw = iter_record_chunks(path, chunk_samples=base.chunk_samples, **base.opts)
    try:
        first = next(raw, None)
        if first is None:
            raise RecordTooShortError("the file holds no samples", source=path)
    except BaseException:
        raw.close()
        raise
    return raw, first, RecordProbe.of(first).to_dict()


def _group_note(note) -> dict[str, dict]:
    """A whole group's note ({content hash: probe}); anything else (absent, foreign) reads as empty."""
    if not isinstance(note, dict):
        return {}
    return {k: v for k, v in note.items() if _probe_note(v) is not None}


def _probe_note(note) -> dict | None:
    """A bag's probe from its note; None for anything else (absent, foreign, or a note written before the probes
    told the force and the spindle apart: the bag is opened again)."""
    if isinstance(note, dict) and set(RecordProbe.__dataclass_fields__) <= set(note):
        return note
    return None


def _group_bags(group: tuple, base: GroupSetup, bags: list[tuple[int, str]], whole: bool, cache_dir: str | None):
    """Yield (index, :class:`BagStatus`, accumulated StreamingNifo or None, its set-up or None) for bags of one
    group, in their order.

    As ``nifo identify`` does: every bag is opened first (its first chunk tells its
    rate, length and channels; a rerun reads them from a small note in the cache
    instead: one note for a whole group, else one per bag), then, when ``whole``
    (these are all the group's bags), the group's
    set-up is fixed from them (:func:`group_setup`: the band of its shortest bag, the
    tire patch if every bag has it) and each bag streamed with it; otherwise each bag
    takes its own set-up (:func:`bag_setup`) and the client accumulates again those
    that differ from the group's. A bag's partial is read from the cache when there
    (key: content hash and set-up), else accumulated and cached at once.
    """
    found, failed, spent, digests = {}, {}, {}, {}
    opts_hash = settings_hash({"note": base.cache_settings()["opts"]})
    try:
        for index, path in bags:                                  # 1. every bag's content hash
            t0 = time.perf_counter()
            try:
                detect_format(path)          # a missing or foreign file: the loader's one-line reason
                digests[index] = content_hash(path)
            except Exception as err:  # noqa: BLE001 - a bad bag is recorded, the fleet goes on
                failed[index] = _one_line(err)
            spent[index] = time.perf_counter() - t0
        group_key = cache_key(":".join(sorted(set(digests.values()))), opts_hash) if whole else None
        known = _group_note(load_note(cache_dir, group_key)) if group_key else {}
        for index, path in bags:                                  # 2. open (or recall) every bag
            if index in failed:
                continue
            t0 = time.perf_counter()
            try:
                digest = digests[index]
                note_key = cache_key(digest, opts_hash)
                probe, opened = known.get(digest) or _probe_note(load_note(cache_dir, note_key)), None
                if probe is None:
                    raw, first, probe = _open(path, base)
                    opened = (raw, first)
                    if not whole:         # a whole group's bags get one note below
                        store_note(cache_dir, note_key, probe)
                found[index] = {"path": path, "hash": digest, "probe": probe, "opened": opened}
            except Exception as err:  # noqa: BLE001
                failed[index] = _one_line(err)
            spent[index] += time.perf_counter() - t0
        if group_key and any(b["hash"] not in known for b in found.values()):
            t0 = time.perf_counter()
            try:
                store_note(cache_dir, group_key, {b["hash"]: b["probe"] for b in found.values()})
            except OSError:       # only the rerun's shortcut is lost: it opens the bags again
                pass
            for index in found:
                spent[index] += (time.perf_counter() - t0) / len(found)
        setup, left = base, {}                                    # 3. the set-up
        if whole:
            try:
                setup, left = group_setup(base, {i: b["probe"] for i, b in found.items()},
                                          label=f"{group[0]}/{group[1]}")
            except NifoError:     # e.g. a bag too short to integrate: each bag on its own, that one fails alone
                setup, left = base, {}
            failed.update({i: f"{found[i]['path']}: {why}" for i, why in left.items()})
        for index, path in bags:                                  # 4. accumulate (or read the cache)
            if index in failed:
                yield index, BagStatus.failed(failed[index]), None, None
                continue
            b = found[index]
            t0 = time.perf_counter()
            own = bag_setup(setup, b["probe"])
            try:
                one, st = _partial(b, own, cache_dir)
            except Exception as err:  # noqa: BLE001
                yield index, BagStatus.failed(_one_line(err)), None, None
                continue
            finally:
                if b["opened"] is not None:
                    b["opened"][0].close()
                    b["opened"] = None
            yield index, replace(st, seconds=spent[index] + time.perf_counter() - t0), one, own   # this run's time
    finally:
        for b in found.values():
            if b["opened"] is not None:
                b["opened"][0].close()


def _partial(b: dict, setup: GroupSetup, cache_dir: str | None) -> tuple[StreamingNifo, BagStatus]:
    """(StreamingNifo, status) of one opened or recalled bag with its set-up: from the cache, else accumulated."""
    setup_hash = settings_hash(setup.cache_settings())
    key = cache_key(b["hash"], setup_hash)
    common = {"ok": True, "hash": b["hash"], "key": key, "probe": b["probe"], "setup_hash": setup_hash}
    hit = load_partial(cache_dir, key)
    if hit is not None:
        return StreamingNifo.from_state(hit["state"]), _status(hit["info"], common, cached=True)
    if b["opened"] is not None:
        raw, first = b["opened"]
        one, n = _accumulate(chain([first], raw), b["path"], setup)
    else:
        raw = iter_record_chunks(b["path"], chunk_samples=setup.chunk_samples, **setup.opts)
        try:
            one, n = _accumulate(raw, b["path"], setup)
        finally:
            raw.close()
    one.end_record()          # the partial keeps the sums, not the stream's edge samples
    info = {"path": b["path"], "n_samples": int(n), "fs_hz": one.fs_hz}
    try:
        store_partial(cache_dir, key, one.state_dict(), info)
    except OSError as err:
        info["cache_note"] = f"not cached: {err}"
    return one, _status(info, common, cached=False)


def _status(info: dict, common: dict, *, cached: bool) -> BagStatus:
    """A usable bag's status from its cached ``info`` (path, samples, rate) and this run's ``common`` facts."""
    known = {k: v for k, v in info.items() if k in ("path", "n_samples", "fs_hz", "cache_note")}
    return BagStatus(**known, **common, cached=cached)


def compute_batch(groups: list[tuple[tuple, GroupSetup, list[tuple[int, str]], bool]], cache_dir: str | None) -> Batch:
    """Several bags in one task: per-bag statuses, and the partials merged per group and set-up.

    Parameters
    ----------
    groups : list of (group, set-up, [(index, path)], whole)
        The bags of this task, by group (``index`` is the client's number for the
        bag); ``whole``: these are all the bags of the group, whose set-up is then
        fixed here as ``nifo identify`` fixes it (:func:`_group_bags`).
    cache_dir : str or None
        Every bag's partial is cached on its own, as soon as it is done.

    Returns
    -------
    Batch
        ``status``: ((index, :class:`BagStatus`), ...) for the client (a bag that cannot be used has
        ``ok`` False and its one-line reason; the others go on); ``parts``:
        {(vehicle, corner, set-up hash): :class:`GroupPartial`}: the bags of one
        group accumulated with one set-up, merged in the order given (as ``nifo
        identify`` merges its files), which stay on the worker until a merge or a
        solve picks them (:func:`pick`).
    """
    acc: dict[tuple, StreamingNifo] = {}
    members: dict[tuple, list[int]] = {}     # per part: the positions of its bags in ``done``
    done: list[list] = []                    # per bag: [index, status, band spectra, set-up, seconds spent here]
    for group, base, bags, whole in groups:
        own: dict[tuple, list[int]] = {}     # per set-up: the bags whose own coefficients are solved together
        for index, st, one, setup in _group_bags(tuple(group), base, bags, whole, cache_dir):
            if one is None:
                done.append([index, st, None, None, 0.0])
                continue
            part = (*group, st.setup_hash)
            t0 = time.perf_counter()
            try:
                spec = _band_spectra(one, setup)
            except NifoError:
                spec = None
            own.setdefault(part, []).append(len(done))
            members.setdefault(part, []).append(len(done))
            done.append([index, st, spec, setup, time.perf_counter() - t0])
            acc[part] = acc[part].merge(one) if part in acc else one
        for ks in own.values():              # every bag's own coefficients, solved together
            t0 = time.perf_counter()
            setup = done[ks[0]][3]
            coefs = iter(bag_coefficients([done[k][2] for k in ks if done[k][2] is not None], setup))
            nan = {n: float("nan") for n, _, _ in coefficient_specs(setup.terms)}
            share = (time.perf_counter() - t0) / len(ks)
            for k in ks:
                st, spec = done[k][1], done[k][2]
                done[k][1] = replace(st, coefs=nan if spec is None else next(coefs),
                                     seconds=st.seconds + done[k][4] + share)
    return Batch(status=tuple((d[0], d[1]) for d in done),
                 parts={p: GroupPartial(ok=True, state=a.state_dict(), bags=tuple(done[k][1] for k in members[p]))
                        for p, a in acc.items()})


def batch_status(batch: Batch) -> tuple[tuple[int, BagStatus], ...]:
    """The small part of a batch's outcome the client needs (the partials stay on the worker)."""
    return batch.status


def pick(x: Batch | GroupPartial, part: tuple | None) -> GroupPartial:
    """The partial of group and set-up ``part`` from a batch, or ``x`` itself when it is a partial already."""
    if not isinstance(x, Batch):
        return x
    return x.parts.get(part) or GroupPartial.none_usable()


def merge_outcomes(*inputs: Batch | GroupPartial, part: tuple | None = None) -> GroupPartial:
    """Merge the usable partials of one group (``part`` of each batch given; failed bags are reported by status)."""
    outcomes = [pick(x, part) for x in inputs]
    ok = [o for o in outcomes if o.ok]
    if not ok:
        return GroupPartial.none_usable(sorted({r for o in outcomes for r in o.reasons}))
    if len(ok) == 1:
        return ok[0]
    acc = StreamingNifo.from_state(ok[0].state)
    for o in ok[1:]:
        acc = acc.merge(StreamingNifo.from_state(o.state))
    return GroupPartial(ok=True, state=acc.state_dict(), bags=tuple(b for o in ok for b in o.bags))


# ---------------------------------------------------------------------------------------------
# per group
# ---------------------------------------------------------------------------------------------
def _t21_at(res, freqs_hz) -> dict:
    st = res.static
    f = res.freq_hz
    k = res.bound_factor(static=True)
    out = {}
    for fq in freqs_hz:
        i = int(np.argmin(np.abs(f - fq)))
        mag = float(np.abs(st.t21[i]))
        eps = float(st.random_error[i])
        key = f"t21_{fq:g}hz"
        out[f"{key}_mag"] = mag
        out[f"{key}_mag_lo"] = mag * max(1 - k * eps, 0.0)
        out[f"{key}_mag_hi"] = mag * (1 + k * eps)
        out[f"{key}_phase_deg"] = float(np.degrees(np.angle(st.t21[i])))
        out[f"{key}_line_hz"] = float(f[i])
    return out


def solve_group(outcome: Batch | GroupPartial, *, freqs_hz: tuple[float, ...], plot_max_hz: float,
                m2_kg: float | None = None, part: tuple | None = None) -> GroupResult:
    """NIFO on a group's merged partial: coefficients with bounds, T21 at ``freqs_hz``, curves for the page.

    Coefficients per body mass always; in SI too when the sprung mass ``m2_kg`` [kg] is given.
    """
    outcome = pick(outcome, part)
    if not outcome.ok:
        return GroupResult.failed(outcome.reason)
    bags = outcome.bags
    try:
        acc = StreamingNifo.from_state(outcome.state)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = acc.result()
        res.check_usable(acc.cond_limit)
        summary, warn = summarize(res, acc.cond_limit)
    except Exception as err:  # noqa: BLE001 - a group that cannot be solved is reported, not fatal
        return GroupResult.failed(_one_line(err), bags)
    coefs = _coefficients(res)
    specs = coefficient_specs(res.terms)
    names = {"per_mass": tuple(n for n, _, _ in specs), "si": ()}
    values = {}
    for name, unit, _ in specs:
        per_bag = [b.coefs.get(name, np.nan) for b in bags]
        se = standard_error(per_bag)
        half = interval_halfwidth(se, int(np.isfinite(per_bag).sum()))
        values[name] = Coefficient(coefs[name], se, coefs[name] - half, coefs[name] + half, unit)
    if m2_kg is not None:
        si = coefficient_specs(res.terms, si=True)
        for (name, unit, _), (pm, _, _) in zip(si, specs):
            values[name] = values[pm].scaled(m2_kg, unit)
        specs = specs + si
        names["si"] = tuple(n for n, _, _ in si)
    keep = (res.freq_hz >= 1.5 * res.band.f_lo_hz) & (res.freq_hz <= plot_max_hz)   # integrator exact from 1.5·f_lo
    return GroupResult(ok=True, bags=bags, coefficients=values, specs=tuple(specs), names=names,
                       t21=_t21_at(res, freqs_hz), summary=summary, warnings=tuple(warn), n_avg=int(res.n_avg),
                       fs_hz=res.fs_hz, duration_s=float(sum(b.n_samples for b in bags) / res.fs_hz),
                       curves=Curves(freq_hz=res.freq_hz[keep], t21=res.static.t21[keep],
                                     t21_eps=res.static.random_error[keep], h1=res.t21_h1[keep],
                                     coherence=res.coherence_h1[keep]),
                       analysis_band_hz=tuple(res.analysis_band_hz), m2_kg=m2_kg)


def loop_group(paths: list[str], setup: GroupSetup) -> LoopOutcome:
    """``nifo loop``'s residual loop on a group's records (loaded on this worker): its verdict."""
    try:
        recs = [load_record(p, **setup.opts) for p in paths]
        band = setup.band if setup.band_from_model else None     # as nifo loop: else its own suggestion
        res = close_loop(recs, list(setup.terms), band=band,
                         settings=LoopSettings(spectral=setup.spectral, analysis_band_hz=setup.analysis_band_hz))
    except Exception as err:  # noqa: BLE001
        return LoopOutcome(ok=False, verdict=f"loop not run: {_one_line(err)}")
    return LoopOutcome(ok=True, verdict=res.verdict, added=tuple(c.term.label for c in res.added),
                       nothing_missing=res.nothing_missing, scores=_loop_scores(res))


#: the loop's held-out scores a group reports: (key, when, the Errors attribute)
_SCORES = tuple((f"heldout_{what}_{when}_pct", when, attr) for when in ("before", "after")
                for what, attr in (("band_nmse", "prediction_nmse_pct"), ("whole_nmse", "whole_nmse_pct")))
LOOP_SCORES = tuple(k for k, _, _ in _SCORES)


def _loop_scores(res) -> dict:
    """The loop's held-out scores before and after: the band NMSE and, beside it, the whole-signal NMSE (the raw
    predicted output over all frequencies, offset included: :mod:`nifo_core.predict.whole_signal`)."""
    return {k: getattr(res.initial if when == "before" else res.final, attr) for k, when, attr in _SCORES}


def characterize_group(paths: list[str], setup: GroupSetup, m2_kg: float | None = None) -> CharacterizeOutcome:
    """``nifo characterize``'s restoring-force ranking on a group's records (loaded on this worker)."""
    try:
        recs = [load_record(p, **setup.opts) for p in paths]
        band = setup.band if setup.band_from_model else None
        ch = characterize(recs, band=band, m2_kg=m2_kg)
    except Exception as err:  # noqa: BLE001
        return CharacterizeOutcome(ok=False, text=f"characterization not run: {_one_line(err)}")
    labels = tuple(t.label for t in ch.suggested_terms)
    text = "nothing nonlinear found" if ch.nothing_found else "suggested: " + ", ".join(labels)
    return CharacterizeOutcome(ok=True, text=text, suggested=labels)
