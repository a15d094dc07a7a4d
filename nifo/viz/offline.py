"""Offline results into a Rerun recording, through the same ``log_*`` functions as live.

:func:`log_results` reads result directories (:mod:`nifo.viz.results`) and,
when the data named in their provenance are reachable, the data themselves:
accelerations and restoring-force points at the samples' stamps, and the
identification replayed through :class:`nifo_core.nifo.identify.StreamingNifo` (the
engine the identifier node runs) so the estimate converges along the timeline
exactly as it did live. :func:`save_recording` writes a ``.rrd``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import numpy as np

from nifo.io.names import file_stems, record_labels

from . import rerun_log as rl
from .results import ResultDir, data_paths, resolve_data

__all__ = ["log_results", "save_recording", "REPLAY_STEP_S"]

#: data pushed between two logged estimates when replaying an identification [s]
REPLAY_STEP_S = 10.0
_NS = 1_000_000_000


def _stamps(t0_ns: int, start: int, n: int, fs_hz: float) -> np.ndarray:
    return int(t0_ns) + np.round((start + np.arange(n)) * (1e9 / fs_hz)).astype(np.int64)


def _band(results: Sequence[ResultDir]):
    from nifo_core.signal.integrate import IntegrationBand

    for r in results:
        b = r.doc.get("band") if r.kind == "characterize" else (r.doc.get("result") or {}).get("band")
        if isinstance(b, dict) and "f_lo_hz" in b:
            return IntegrationBand(float(b["f_lo_hz"]), float(b["f_hi_hz"]))
    return None


def _records(results: Sequence[ResultDir]) -> list[tuple[Path, object]]:
    from nifo.io.loader import load_record
    from nifo.io.provenance import reader_options

    seen, out = set(), []
    for r in results:
        for p in data_paths(r):
            q = resolve_data(p, r)
            if q is None or q.resolve() in seen:
                continue
            seen.add(q.resolve())
            out.append((q, load_record(q, **reader_options(r.doc))))   # the same --columns/--topics
    return out


def _log_data(records, band, *, recording, notes: list[str]) -> None:
    from nifo_core.characterize.restoring import restoring_force

    palette = [(31, 78, 121), (192, 57, 43), (46, 139, 87), (161, 92, 0), (120, 60, 160)]
    # one entity per record: records of the same name (from two folders, or "rec 1.csv" and rec_1.csv) kept apart
    names = file_stems(record_labels([path for path, _ in records]))
    for k, ((path, rec), name) in enumerate(zip(records, names)):
        rl.log_record_styling(name, recording=recording)
        rl.log_accelerations(name, _stamps(rec.t0_ns, 0, rec.n, rec.fs_hz), rec.spindle_accel, rec.body_accel,
                             recording=recording)
        rf = restoring_force(rec, band=band)
        rl.log_restoring_styling(name, colour=palette[k % len(palette)], recording=recording)
        rl.log_restoring(name, _stamps(rec.t0_ns, rf.start, rf.n, rec.fs_hz), rf.z, rf.zdot, -rf.force,
                         scale=(np.std(rf.z), np.std(rf.zdot), np.std(rf.force)), recording=recording)
        notes.append(f"- `{path}`: {rec.n} samples at {rec.fs_hz:g} Hz ({rec.duration_s:.1f} s), "
                     f"restoring force in band {rf.band.f_lo_hz:g}-{rf.band.f_hi_hz:g} Hz")


def _log_identify(r: ResultDir, records, *, recording) -> str:
    """Replay the identification when its data files are reachable (each file streamed in turn, the estimate of every
    file so far logged along its stamps), else log the final estimate."""
    import warnings

    from nifo.io.results import read_identify
    from nifo_core.nifo.identify import StreamingNifo

    res, doc = read_identify(r.path)
    paths = [resolve_data(p, r) for p in data_paths(r)]
    recs = [rec for p in paths if p is not None for q, rec in records if q.resolve() == p.resolve()]
    if recs and len(recs) == len(paths) and all(rec.fs_hz == res.fs_hz for rec in recs) and not any(res.fixed) \
            and not any(rec.has_force or rec.spindle_fixed for rec in recs):
        done = None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for rec in recs:
                s = StreamingNifo(rec.fs_hz, res.terms, settings=res.settings, band=res.band,
                                  analysis_band_hz=res.analysis_band_hz, on_ill_conditioned="warn")
                step = max(int(REPLAY_STEP_S * rec.fs_hz), 1)
                for i in range(0, rec.n, step):
                    j = min(i + step, rec.n)
                    s.push(rec.spindle_accel[i:j], rec.body_accel[i:j])
                    if s.n_avg == 0:
                        continue
                    now = s if done is None else done.merge(s)
                    rl.log_nifo_result(int(rec.t0_ns + round((j - 1) * 1e9 / rec.fs_hz)), now.result(),
                                       recording=recording)
                if s.n_avg:
                    done = s if done is None else done.merge(s)
        return (f"replayed through StreamingNifo in {REPLAY_STEP_S:g} s steps, file after file (scrub the timeline "
                f"to see it converge)")
    data = doc.get("data") or []
    n = max((e.get("n_samples") or 0 for e in data if isinstance(e, dict)), default=0)
    rl.log_nifo_result(int(round(n * 1e9 / res.fs_hz)) if n else 0, res, recording=recording)
    return "final estimate only (data not reachable, or a two-step identification)"


def _loop(r: ResultDir, *, recording) -> None:
    from .report_html import _NMSE_KEYS, _effect_label, _find

    rounds = [dict(x) for x in (r.doc.get("rounds") or []) if isinstance(x, dict)]
    nmse = []
    if rounds:
        nmse.append(_find(rounds[0].get("before") or {}, *_NMSE_KEYS))
        for x in rounds:
            x["_label"] = _effect_label(x.get("added") or x.get("effect")) if (x.get("added") or x.get("effect")) \
                else "nothing significant"
            nmse.append(_find(x.get("after") or {}, *_NMSE_KEYS))
    text = r.doc.get("verdict") or r.doc.get("conclusion") or ""
    rl.log_loop(rounds, nmse=nmse if any(v is not None for v in nmse) else None, text=str(text),
                recording=recording)


def _summary(results: Sequence[ResultDir], notes: list[str]) -> str:
    lines = ["# nifo results", ""]
    for r in results:
        d = r.doc
        lines.append(f"## {r.kind}: `{r.path}`")
        if r.kind == "characterize":
            sug = d.get("suggested") or []
            lines.append("suggested model: " + ("; ".join(f"**{s.get('label')}** ({s.get('meaning', '')})"
                                                          for s in sug) or "linear strut (nothing found)"))
        elif r.kind == "identify":
            s = d.get("summary", {})
            for t in s.get("terms", []):
                lines.append(f"- pooled c/M2 **{t.get('label')}**: {t.get('c_over_m2'):.4g} {t.get('unit', '')}")
            lines.append(f"- {s.get('n_avg')} spectral averages, coherence median {s.get('coherence_h1_median', 0):.3f}, "
                         f"median scaled cond {s.get('cond_median', 0):.3g}")
            lines += [f"- warning: {w}" for w in d.get("warnings", [])]
            lines.append(f"- settings: `{json.dumps(d.get('settings', {}))}`")
        elif r.kind == "predict":
            for rec in d.get("records", []):
                wm, wl = (rec[k].get("whole_signal") or {} for k in ("model", "linear"))
                lines.append(f"- {rec.get('name')}: whole-signal NMSE model {wm.get('nmse_percent', float('nan')):.3g} %, "
                             f"linear {wl.get('nmse_percent', float('nan')):.3g} %")
        lines.append("")
    lines += ["## data", *notes]
    return "\n".join(lines)


def log_results(results: Sequence[ResultDir], *, recording=None, with_data: bool = True) -> list[str]:
    """Log everything the results hold (and their data, when reachable); returns notes on what was logged."""
    notes: list[str] = []
    rl.log_styling(recording=recording)
    records = _records(results) if with_data else []
    if records:
        _log_data(records, _band(results), recording=recording, notes=notes)
    elif with_data:
        notes.append("- the data named in the results are not reachable from here: time-domain views are empty")
    for r in results:
        if r.kind == "identify":
            notes.append(f"- identification `{r.path}`: " + _log_identify(r, records, recording=recording))
        elif r.kind == "loop":
            _loop(r, recording=recording)
    rl.log_summary(_summary(results, notes), recording=recording)
    return notes


def save_recording(results: Sequence[ResultDir], path: str | Path, *, with_data: bool = True) -> Path:
    """Write ``path`` (``.rrd``) with the blueprint, atomically."""
    import rerun as rr

    from nifo.io.atomic import staged_file

    with staged_file(path) as tmp:
        rec = rr.RecordingStream(rl.APP_ID)
        rl.use_data_stamps(rec)
        rec.save(tmp, default_blueprint=rl.blueprint())
        log_results(results, recording=rec, with_data=with_data)
        rec.flush()
        rec.disconnect()
    return Path(path)
