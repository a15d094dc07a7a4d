"""What runs on a Dask worker: accumulate a batch of bags, merge partials, solve a group, run the loop.

Workers get paths and small settings, never sample arrays. One task
accumulates several bags (:func:`compute_batch`: a few tasks per worker,
each of many bags, so Dask's cost per task is spread over them), caches
every bag's partial on its own, and returns the small per-bag statuses and
compact partials (a :meth:`StreamingNifo.state_dict`: the block
cross-spectra of [a1, a2, g_i..] and a few counters) merged per group, which
stay on the workers until they are merged, and small per-group results.
Every function is module-level and picklable. A bag that cannot be used
gets ``{"ok": False, "reason": one line}`` instead of raising, so one bad
bag never stops its batch or the fleet.

The per-bag accumulation is the one ``nifo identify`` does per file (same
StreamingNifo set-up, same chunk length, merged in file order), so a group's
merged partial equals identify's merged accumulators and its coefficients
agree to rounding.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from nifo.fleet.cache import (cache_key, content_hash, load_note, load_partial, settings_hash, store_note,
                              store_partial)
from nifo.io.loader import detect_format, iter_record_chunks, load_record
from nifo.pipeline.identify import check_usable, summarize
from nifo_core.characterize.automatic import characterize
from nifo_core.kinds.describing import Term
from nifo_core.errors import NifoError, RecordTooShortError
from nifo_core.fleet import interval_halfwidth, standard_error
from nifo_core.signal.integrate import IntegrationBand, default_band
from nifo_core.signal.record import acceleration_means
from nifo_core.predict.linear_part import BODY_FIT_LIMIT, nominal_linear_part
from nifo_core.loop.closing import LoopSettings, close_loop
from nifo_core.predict.model import IdentifiedModel
from nifo_core.nifo.identify import StreamingNifo, nifo_from_spectra, static_fits
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

    def cache_settings(self) -> dict:
        """What shapes a partial (the cache key's settings part)."""
        opts = {k: (None if v is None else (v if isinstance(v, (str, int, float)) else repr(v)))
                for k, v in self.opts.items()}
        return {"terms": [t.to_dict() for t in self.terms], "spectral": self.spectral.to_dict(),
                "band": None if self.band is None else self.band.to_dict(), "with_tire_patch": self.with_tire_patch,
                "analysis_band_hz": list(self.analysis_band_hz), "cond_limit": self.cond_limit,
                "chunk_samples": self.chunk_samples, "opts": opts}


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
    """The set-up a bag is accumulated with: the group's band and tire patch where fixed, else its own.

    Own band: ``default_band(fs, this bag's length)`` (``nifo identify`` uses the
    group's shortest bag; equal whenever every bag is longer than 64 s, else the
    client recomputes the bags that differ).
    """
    fs = probe["fs_hz"]
    band = base.band or default_band(fs, probe["n_samples"] / fs)
    tp = probe["has_tire_patch"] if base.with_tire_patch is None else base.with_tire_patch
    return replace(base, band=band.validate(fs, n_samples=probe["n_samples"]), with_tire_patch=bool(tp))


def _accumulate(chunks, path: str, setup: GroupSetup):
    one = None
    n = 0
    for chunk in chunks:
        if one is None:   # the StreamingNifo nifo identify builds for each file (commands/identify.py)
            one = StreamingNifo(chunk.fs_hz, setup.terms, settings=setup.spectral, band=setup.band,
                                with_tire_patch=setup.with_tire_patch, analysis_band_hz=setup.analysis_band_hz,
                                on_ill_conditioned="warn", cond_limit=setup.cond_limit)
            means = acceleration_means(chunk)   # as nifo identify: the first chunk's offsets off every chunk
        chunk = chunk.centred(means)
        one.push(chunk.spindle_accel, chunk.body_accel, chunk.tire_patch_disp if setup.with_tire_patch else None)
        n += chunk.n
    if one is None:
        raise RecordTooShortError("the file holds no samples", source=path)
    if one.n_avg == 0:
        raise RecordTooShortError(f"{n} samples ({n / one.fs_hz:.1f} s) is too short for NIFO (needs "
                                  f"{one.min_samples} with block={one.settings.block})", source=path,
                                  hint="record longer, or choose a smaller block")
    return one, n


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
                                    on_ill_conditioned="ignore", cond_limit=setup.cond_limit)
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
    """The group's set-up from its bags' rates, lengths and channels, as ``nifo identify`` chooses it.

    Returns the set-up (None when no bag is left) and the reason for every bag left out (another rate).
    """
    from collections import Counter


    if not probes:
        return None, {}
    fs = Counter(p["fs_hz"] for p in probes.values()).most_common(1)[0][0]
    left = {i: f"sample rate {p['fs_hz']:g} Hz differs from the other bags of {label} ({fs:g} Hz); resample it"
            for i, p in probes.items() if p["fs_hz"] != fs}
    ok = [p for i, p in probes.items() if i not in left]
    band = base.band or default_band(fs, min(p["n_samples"] for p in ok) / fs)
    return replace(base, band=band, with_tire_patch=all(p["has_tire_patch"] for p in ok)), left


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
    probe = {"fs_hz": float(first.fs_hz), "has_tire_patch": bool(first.has_tire_patch),
             "n_samples": int(first.meta.get("chunk", {}).get("total_samples", first.n))}
    return raw, first, probe


def _group_note(note) -> dict[str, dict]:
    """A whole group's note ({content hash: probe}); anything else (absent, foreign) reads as empty."""
    if not isinstance(note, dict):
        return {}
    return {k: v for k, v in note.items()
            if isinstance(v, dict) and {"fs_hz", "has_tire_patch", "n_samples"} <= set(v)}


def _group_bags(group: tuple, base: GroupSetup, bags: list[tuple[int, str]], whole: bool, cache_dir: str | None):
    """Yield (index, status, accumulated StreamingNifo or None) for bags of one group, in their order.

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
                probe, opened = known.get(digest) or load_note(cache_dir, note_key), None
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
                yield index, {"ok": False, "reason": failed[index]}, None
                continue
            b = found[index]
            t0 = time.perf_counter()
            try:
                one, st = _partial(b, bag_setup(setup, b["probe"]), cache_dir)
            except Exception as err:  # noqa: BLE001
                yield index, {"ok": False, "reason": _one_line(err)}, None
                continue
            finally:
                if b["opened"] is not None:
                    b["opened"][0].close()
                    b["opened"] = None
            st["seconds"] = spent[index] + time.perf_counter() - t0     # this run's time for the bag
            yield index, st, one
    finally:
        for b in found.values():
            if b["opened"] is not None:
                b["opened"][0].close()


def _partial(b: dict, setup: GroupSetup, cache_dir: str | None):
    """(StreamingNifo, status) of one opened or recalled bag with its set-up: from the cache, else accumulated."""
    from itertools import chain


    setup_hash = settings_hash(setup.cache_settings())
    key = cache_key(b["hash"], setup_hash)
    common = {"ok": True, "hash": b["hash"], "key": key, "probe": b["probe"], "setup_hash": setup_hash,
              "setup": setup}
    hit = load_partial(cache_dir, key)
    if hit is not None:
        return StreamingNifo.from_state(hit["state"]), {**hit["info"], **common, "cached": True}
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
    return one, {**info, **common, "cached": False}


def compute_batch(groups: list[tuple[tuple, GroupSetup, list[tuple[int, str]], bool]], cache_dir: str | None) -> dict:
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
    dict
        ``status``: [(index, status)] for the client (a bag that cannot be used has
        ``ok`` False and its one-line reason; the others go on); ``parts``:
        {(vehicle, corner, set-up hash): {"ok", "state", "bags"}}: the bags of one
        group accumulated with one set-up, merged in the order given (as ``nifo
        identify`` merges its files), which stay on the worker until a merge or a
        solve picks them (:func:`pick`).
    """
    acc: dict[tuple, list] = {}
    status = []
    for group, base, bags, whole in groups:
        own: dict[tuple, list] = {}                  # per set-up: (status, band spectra, set-up) of each bag
        for index, st, one in _group_bags(tuple(group), base, bags, whole, cache_dir):
            status.append((index, st))
            if one is None:
                continue
            part = (*group, st["setup_hash"])
            t0 = time.perf_counter()
            setup = st.pop("setup")                  # the set-up this bag was accumulated with
            try:
                own.setdefault(part, []).append((st, _band_spectra(one, setup), setup))
            except NifoError:
                own.setdefault(part, []).append((st, None, setup))
            st["seconds"] += time.perf_counter() - t0
            if part in acc:
                acc[part][0] = acc[part][0].merge(one)
                acc[part][1].append(st)
            else:
                acc[part] = [one, [st]]
        for items in own.values():                   # every bag's own coefficients, solved together
            t0 = time.perf_counter()
            specs = [sp for _, sp, _ in items if sp is not None]
            coefs = iter(bag_coefficients(specs, items[0][2]))
            nan = {n: float("nan") for n, _, _ in coefficient_specs(items[0][2].terms)}
            share = (time.perf_counter() - t0) / len(items)
            for st, sp, _ in items:
                st["coefs"] = nan if sp is None else next(coefs)
                st["seconds"] += share
    return {"status": status,
            "parts": {p: {"ok": True, "state": a.state_dict(), "bags": bags} for p, (a, bags) in acc.items()}}


def batch_status(batch: dict) -> list[tuple[int, dict]]:
    """The small part of a batch's outcome the client needs (the partials stay on the worker)."""
    return batch["status"]


def pick(x: dict, part: tuple | None) -> dict:
    """The outcome of group and set-up ``part`` from a batch, or ``x`` itself when it is an outcome already."""
    if "parts" not in x:
        return x
    return x["parts"].get(part) or {"ok": False, "reason": "no usable bag", "reasons": []}


def merge_outcomes(*inputs: dict, part: tuple | None = None) -> dict:
    """Merge the usable partials of one group (``part`` of each batch given; failed bags are reported by status)."""
    outcomes = [pick(x, part) for x in inputs]
    ok = [o for o in outcomes if o["ok"]]
    if not ok:
        reasons = sorted({r for o in outcomes for r in o.get("reasons", [o.get("reason", "")])})
        return {"ok": False, "reason": "no usable bag", "reasons": reasons}
    if len(ok) == 1:
        return ok[0]
    acc = StreamingNifo.from_state(ok[0]["state"])
    for o in ok[1:]:
        acc = acc.merge(StreamingNifo.from_state(o["state"]))
    return {"ok": True, "state": acc.state_dict(), "bags": [b for o in ok for b in o["bags"]]}


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


def solve_group(outcome: dict, *, freqs_hz: tuple[float, ...], plot_max_hz: float,
                m2_kg: float | None = None, part: tuple | None = None) -> dict:
    """NIFO on a group's merged partial: coefficients with bounds, T21 at ``freqs_hz``, curves for the page.

    Coefficients per body mass always; in SI too when the sprung mass ``m2_kg`` [kg] is given.
    """
    outcome = pick(outcome, part)
    if not outcome["ok"]:
        return {"ok": False, "reason": outcome["reason"], "bags": []}
    bags = outcome["bags"]
    try:
        acc = StreamingNifo.from_state(outcome["state"])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = acc.result()
        check_usable(res, acc.cond_limit)
        summary, warn = summarize(res, acc.cond_limit)
    except Exception as err:  # noqa: BLE001 - a group that cannot be solved is reported, not fatal
        return {"ok": False, "reason": _one_line(err), "bags": bags}
    coefs = _coefficients(res)
    specs = coefficient_specs(res.terms)
    names = {"per_mass": [n for n, _, _ in specs], "si": []}
    values = {}
    for name, unit, _ in specs:
        per_bag = [b["coefs"].get(name, np.nan) for b in bags]
        se = standard_error(per_bag)
        half = interval_halfwidth(se, int(np.isfinite(per_bag).sum()))
        values[name] = {"value": coefs[name], "se": se, "lo": coefs[name] - half, "hi": coefs[name] + half,
                        "unit": unit}
    if m2_kg is not None:
        si = coefficient_specs(res.terms, si=True)
        for (name, unit, _), (pm, _, _) in zip(si, specs):
            v = values[pm]
            values[name] = {"value": v["value"] * m2_kg, "se": v["se"] * m2_kg, "lo": v["lo"] * m2_kg,
                            "hi": v["hi"] * m2_kg, "unit": unit}
        specs = specs + si
        names["si"] = [n for n, _, _ in si]
    keep = (res.freq_hz >= 1.5 * res.band.f_lo_hz) & (res.freq_hz <= plot_max_hz)   # integrator exact from 1.5·f_lo
    lo_b, hi_b = res.bounds("t21")
    return {"ok": True, "bags": bags, "coefficients": values, "specs": specs, "names": names, "t21": _t21_at(res, freqs_hz),
            "summary": summary, "warnings": warn, "n_avg": int(res.n_avg), "fs_hz": res.fs_hz,
            "duration_s": float(sum(b["n_samples"] for b in bags) / res.fs_hz),
            "curves": {"freq_hz": res.freq_hz[keep], "t21": res.static.t21[keep],
                       "t21_eps": res.static.random_error[keep], "h1": res.t21_h1[keep],
                       "coherence": res.coherence_h1[keep]},
            "analysis_band_hz": list(res.analysis_band_hz), "m2_kg": m2_kg}


def loop_group(paths: list[str], setup: GroupSetup) -> dict:
    """``nifo loop``'s residual loop on a group's records (loaded on this worker): its verdict."""
    try:
        recs = [load_record(p, **setup.opts) for p in paths]
        band = setup.band if setup.band_from_model else None     # as nifo loop: else its own suggestion
        res = close_loop(recs, list(setup.terms), band=band,
                         settings=LoopSettings(spectral=setup.spectral, analysis_band_hz=setup.analysis_band_hz))
    except Exception as err:  # noqa: BLE001
        return {"ok": False, "verdict": f"loop not run: {_one_line(err)}", "added": []}
    return {"ok": True, "verdict": res.verdict, "added": [c.term.label for c in res.added],
            "nothing_missing": res.nothing_missing, **_loop_scores(res)}


#: the loop's held-out scores a group reports: (key, when, the Errors attribute)
_SCORES = tuple((f"heldout_{what}_{when}_pct", when, attr) for when in ("before", "after")
                for what, attr in (("band_nmse", "prediction_nmse_pct"), ("whole_nmse", "whole_nmse_pct")))
LOOP_SCORES = tuple(k for k, _, _ in _SCORES)


def _loop_scores(res) -> dict:
    """The loop's held-out scores before and after: the band NMSE and, beside it, the whole-signal NMSE (the raw
    predicted output over all frequencies, offset included: :mod:`nifo_core.predict.whole_signal`)."""
    return {k: getattr(res.initial if when == "before" else res.final, attr) for k, when, attr in _SCORES}


def characterize_group(paths: list[str], setup: GroupSetup, m2_kg: float | None = None) -> dict:
    """``nifo characterize``'s restoring-force ranking on a group's records (loaded on this worker)."""
    try:
        recs = [load_record(p, **setup.opts) for p in paths]
        band = setup.band if setup.band_from_model else None
        ch = characterize(recs, band=band, m2_kg=m2_kg)
    except Exception as err:  # noqa: BLE001
        return {"ok": False, "text": f"characterization not run: {_one_line(err)}", "suggested": []}
    labels = [t.label for t in ch.suggested_terms]
    text = "nothing nonlinear found" if ch.nothing_found else "suggested: " + ", ".join(labels)
    return {"ok": True, "text": text, "suggested": labels}
