"""The HTML report: one self-contained file a test engineer can read, forward and print.

:func:`build_report` turns result directories (:mod:`nifo.viz.results`) into
one HTML document rendered from the Jinja2 templates in ``nifo/viz/templates``
(``report.html.j2`` is the page; one template per kind of result, one for the
provenance; ``_macros.html.j2`` the table and figure blocks; ``report.css``
inlined): every PNG embedded as base64 (no external assets, no JavaScript),
tables of the numbers, the loop's before/after, the settings and where the
data came from. This module only prepares the values the templates show.
:func:`levels_figure` adds the paper-style "transmissibility across levels
with the NIFO estimate" when the data are reachable; the data are re-read with
the input options stored in each result (``--columns``, ``--topics``, ...).
"""

from __future__ import annotations

import base64
import contextlib
import datetime as _dt
import json
import re
import tempfile
from functools import lru_cache
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from jinja2 import ChainableUndefined, Environment, PackageLoader, Undefined, pass_context, select_autoescape
from markupsafe import Markup

from nifo.io.names import record_labels
from nifo_core import __version__
from nifo_core.errors import NifoError

from .report_headline import outside_message, headline, noise_table, whole_signal
from .results import ResultDir, data_paths, resolve_data

__all__ = ["build_report", "write_report", "levels_figure", "CAPTIONS", "system_words"]

#: figure file name (prefix, or suffix when it starts with "_") -> caption; first match wins.
#: {input}, {output}, {element}, {mass} are the system's words (:func:`system_words`).
CAPTIONS: tuple[tuple[str, str], ...] = (
    ("restoring_frequency", "Restoring force by frequency slice (cf. paper Fig. 3): the {element} force per unit "
                            "{mass} −ẍ2 against the relative velocity ż (damping, left) and displacement z "
                            "(stiffness, right). A linear {element} gives ellipses; kinks and flat spots are "
                            "nonlinearities."),
    ("restoring_amplitude", "Restoring force by amplitude (cf. paper Fig. 4): one row per excitation level or "
                            "amplitude bin. Shapes that change with amplitude are nonlinear; the fitted model "
                            "is drawn over the data."),
    ("characteristic", "Stiffness and damping characteristics of the suggested terms: binned data with their "
                       "interquartile band, the fitted characteristic, and (bottom) the same minus the linear fit."),
    ("ranking", "Every kind of nonlinearity in the library, scored by how much of the linear fit's residual it "
                "explains; the dashed line is the 'present' threshold."),
    ("levels", "{Input} → {output} transmissibility at every excitation level (plain H1) with the NIFO estimate "
               "of the nominal linear T21 (cf. paper Fig. 9b/12b). The measured curves move with level because "
               "the {element} is nonlinear; the NIFO estimate is what is left when the nonlinearity is taken out."),
    ("_transmissibility", "Predicted vs measured transmissibility at this level: the identified nonlinear model "
                          "against the linear model identified at the other level."),
    ("transmissibility", "{Input} → {output} transmissibility: measured H1 and the NIFO nominal linear T21 "
                         "(cf. paper Fig. 9b/12b); shaded: the analysis band."),
    ("coefficients", "Coefficient functions μᵢ(ω)/K2, real and imaginary parts (cf. paper Fig. 10/13): per line "
                     "(Eq. 9) and from the pooled constant-coefficient fit. A static nonlinearity gives flat, "
                     "mostly real curves."),
    ("conditioning", "Coherences and the scaled condition number of G_UU per line: where the condition number "
                     "is high, the per-line estimate is noise-sensitive."),
    ("tire", "Tire patch → spindle: nominal vs measured (cf. paper Fig. 11/14)."),
    ("loop_errors", "Held-out NMSE and per-band residual before and after each round of the loop."),
    ("loop_round", "Evidence for the added effect: the residual against the effect's variable, before and after "
                   "adding it."),
    ("_time", "{Output} signal, measured vs predicted from the measured {input} signal (an excerpt)."),
)

_SECTION_TITLES = {"characterize": "Characterization: which nonlinearities, how strong",
                   "identify": "Identification: nominal transmissibility and coefficient functions (NIFO)",
                   "predict": "Prediction at the other level(s)",
                   "loop": "Closing the loop: what the model lacked, error before and after"}

_NMSE_KEYS = ("prediction_nmse_pct", "nmse_percent", "nmse", "held_out_nmse_percent")
_SETTING_KEYS = ("settings", "band", "band_choice", "thresholds", "freq_window_hz", "freq_range_hz", "method",
                 "model_file", "model", "linear_model", "input", "system")


# ------------------------------------------------------------------------------------ formatting
def _num(x, fmt: str = ".4g") -> str:
    if x is None or isinstance(x, Undefined):
        return "–"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    return "–" if not np.isfinite(v) else format(v, fmt)


def _pct(x, fmt: str = ".1f") -> str:
    if x is None or isinstance(x, Undefined):
        return "–"
    return f"{100 * float(x):{fmt}} %"


#: the quarter car's words in the core's sentences, and the word of :func:`system_words` each becomes elsewhere
_CAR_WORDS = (("sprung mass", "mass"), ("spindle", "input"), ("strut", "element"), ("body", "output"))


@pass_context
def _say(ctx, text):
    """A sentence of the core's (a verdict, a round's reason, a warning) in the system's words: for data that are
    not a vehicle, "spindle" is the input side, "body" the output side, "strut" the nonlinear element."""
    system, words = ctx.get("system") or {}, ctx.get("words") or {}
    if text is None or isinstance(text, (Undefined, Markup)) or system.get("vehicle", True):
        return text
    out = str(text)
    for car, key in _CAR_WORDS:
        out = re.sub(rf"\b{car}\b", words[key], out)
        out = re.sub(rf"\b{car.capitalize()}\b", words[key.capitalize()], out)
    return out


@lru_cache(maxsize=1)
def _env() -> Environment:
    env = Environment(loader=PackageLoader("nifo.viz", "templates"), autoescape=select_autoescape(["j2", "html"]),
                      undefined=ChainableUndefined, trim_blocks=True, lstrip_blocks=True)
    env.filters.update(num=_num, pct=_pct, say=_say)
    return env


def system_words(system: Mapping) -> dict:
    """Words for the two sides of the nonlinear element: quarter-car words only for a vehicle."""
    if system.get("vehicle", True):
        w = {"input": "spindle", "output": "body", "element": "strut", "mass": "sprung mass"}
    else:
        w = {"input": "input-side", "output": "output-side", "element": "nonlinear element",
             "mass": "output-side mass"}
    return {**w, **{k.capitalize(): v[:1].upper() + v[1:] for k, v in w.items()}}


def _system(results: Sequence[ResultDir]) -> dict:
    from nifo.io.provenance import system_of

    doc = next((r.doc for r in results if isinstance(r.doc.get("system"), Mapping)), {})
    return system_of(doc)


def _caption(name: str, words: Mapping) -> str:
    stem = Path(name).stem
    for key, text in CAPTIONS:
        if (key.startswith("_") and stem.endswith(key)) or (not key.startswith("_") and stem.startswith(key)):
            return text.format(**words)
    return stem.replace("_", " ")


def _figure(path: Path, words: Mapping, caption: str | None = None) -> dict:
    p = Path(path)
    vector = next((p.with_suffix(s).name for s in (".svg", ".pdf") if p.with_suffix(s).is_file()), None)
    uri = "data:image/png;base64," + base64.b64encode(p.read_bytes()).decode("ascii")
    return {"uri": uri, "name": p.name, "alt": p.stem.replace("_", " "), "vector": vector,
            "caption": caption or _caption(p.name, words)}


def _code(text) -> Markup:
    return Markup("<code>{}</code>").format(text)


def _flatten(d: Mapping, prefix: str = "") -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out += _flatten(v, key + ".")
        elif isinstance(v, list) and len(v) > 8:
            out.append((key, f"[{len(v)} values]"))
        else:
            out.append((key, json.dumps(v, ensure_ascii=False) if not isinstance(v, str) else v))
    return out


# ------------------------------------------------------------------------------------ data, read once
@lru_cache(maxsize=32)
def _load(path: str, options: str):
    """A record read with the stored input options (JSON of the result's ``"input"``), cached per report."""
    from nifo.io.loader import load_record
    from nifo.io.provenance import reader_options

    return load_record(path, **reader_options({"input": json.loads(options)}))


def _record(path: Path, r: ResultDir):
    return _load(str(path), json.dumps(r.doc.get("input") or {}, sort_keys=True))


# ------------------------------------------------------------------------------------ sections
def _units(system: Mapping) -> tuple[str, float, str, float]:
    """(z unit, scale from the stored SI value, ż unit, scale): mm and m/s for accelerations in m/s²."""
    u = system.get("units", "m/s²")
    return ("mm", 1e3, "m/s", 1.0) if u == "m/s²" else (f"{u}·s²", 1.0, f"{u}·s", 1.0)


def _term_text(c: Mapping, system: Mapping) -> str:
    """A candidate's label with its parameters in units (gap=0.135 mm), else as stored."""
    from nifo.plots.restoring import term_label

    if isinstance(c.get("params"), Mapping) and c.get("kind"):
        return term_label(c["kind"], dict(c["params"]), units=system.get("units", "m/s²"))
    return str(c.get("label", c.get("kind", "?")))


def _characterize(r: ResultDir, system: Mapping) -> dict:
    d = r.doc
    zu, zs, vu, vs = _units(system)
    cands, classes = [], []
    for c in (d.get("candidates") or [])[:8]:
        unit = c.get("coefficient_unit", "")
        hw = c.get("coefficient_half_width") if c.get("coefficient") is not None else c.get("theta_half_width_per_kg")
        pm = "" if hw is None else f" ± {_num(hw, '.2g')}"
        coef = (f"{_num(c['coefficient'])}{pm} {unit}" if c.get("coefficient") is not None
                else f"{_num(c.get('theta_per_kg'))}{pm} ({unit})/kg")
        status = c.get("status", "") + (f" (≈ {c['alternative_to']})" if c.get("alternative_to") else "")
        cands.append([_term_text(c, system), coef, _num(c.get("err"), ".3f"), _num(c.get("p_value"), ".1e"),
                      status, c.get("meaning", "")])
        classes.append("suggested" if c.get("status") == "suggested" else "")
    recs = d.get("records", [])
    names = record_labels([str(x.get("path", x.get("source", ""))) for x in recs])   # two rec.csv told apart
    levels = [[name, _num(x.get("duration_s"), ".1f"),
               _num(None if x.get("z_rms_m") is None else zs * x["z_rms_m"], ".3g"),
               _num(None if x.get("zdot_rms_m_s") is None else vs * x["zdot_rms_m_s"], ".3g"),
               _num(x.get("linear_r2"), ".4f")] for x, name in zip(recs, names)]
    sug = d.get("suggested") or []
    return {"candidates": cands, "candidate_classes": classes, "levels": levels, "z_unit": zu, "v_unit": vu,
            "suggested": [f"{_term_text(x, system)}: {x.get('meaning', '')}" for x in sug]}


def _mean(v) -> float | None:
    v = [x for x in v if x is not None]
    return sum(v) / len(v) if v else None


def _identify(r: ResultDir, system: Mapping) -> dict:
    s = r.doc.get("summary", {})
    terms = [{**t, "label": _term_text(t.get("term") or t, system)} for t in s.get("terms", [])]
    rows = [[t.get("label"), _num(t.get("c_over_m2")), t.get("unit", ""),
             "held fixed" if t.get("fixed") else
             f"{_num(t.get('per_line_mean_re'))} {_num(t.get('per_line_mean_im'), '+.3g')}j"] for t in terms]
    ref = s.get("refinement")
    refinement = None if not ref else {
        "message": (f"from the {ref.get('start')} start; mean band NMSE of the {len(ref.get('records') or [])} "
                    f"record(s) {_num(_mean(ref.get('nmse_before_pct', {}).get(ref.get('start')) or []), '.3g')} % → "
                    f"{_num(_mean(ref.get('nmse_pct') or []), '.3g')} %"),
        "rows": [[p.get("name"), _num(p.get("before")), _num(p.get("after")) + (
            "" if p.get("half_width_95") is None else f" ± {_num(p['half_width_95'], '.2g')}"), p.get("unit", "")]
                 for p in ref.get("parameters") or []]}
    fp = s.get("feedback_paths")
    paths = None if not fp else {
        "message": fp.get("message", ""),
        "rows": [[_num(g.get("ridge")), " / ".join(_num(v, ".3g") for v in g.get("nmse_percent") or [])
                  if g.get("regimes_stable", True) else "not eligible: a stuck/active regime is unstable",
                  _num(g.get("nmse_sum_percent"), ".4g") if g.get("regimes_stable", True) else "",
                  "chosen" if g.get("ridge") == fp.get("ridge") else ""] for g in fp.get("grid") or []]}
    return {"terms": rows, "t21_bounds": _t21_bounds(r.doc), "refinement": refinement, "paths": paths}


def _t21_bounds(doc: Mapping) -> list[list]:
    """Rows (estimate, median and largest half-width of the ~95 % band of |T21| over the analysis band [%])."""
    res, b = doc.get("result") or {}, doc.get("bounds") or {}
    f = np.asarray(res.get("freq_hz") or [], float)
    lo, hi = (res.get("analysis_band_hz") or [0.0, 0.0])[:2]
    rows = []
    for key, name in (("t21_static", "pooled (recommended)"), ("t21_free", "per line (Eq. 9)")):
        lower, upper = (np.asarray((b.get(key) or {}).get(k) or [], float) for k in ("lower", "upper"))
        if f.size == 0 or lower.size != f.size or upper.size != f.size:
            continue
        m = (f >= lo) & (f <= hi) & np.isfinite(lower) & np.isfinite(upper) & (upper + lower > 0)
        if not m.any():
            continue
        rel = (upper[m] - lower[m]) / (upper[m] + lower[m])   # half-width / |T21|
        rows.append([name, f"± {_num(100 * float(np.median(rel)), '.2g')} %", f"± {_num(100 * float(rel.max()), '.2g')} %"])
    return rows


def _loop_coefficients(d: Mapping) -> list[list]:
    """Rows (coefficient, value ± 95 % half-width, unit; × M2 when known) of a loop.json."""
    rows = []
    for c in d.get("coefficients") or []:
        if not isinstance(c, Mapping):
            continue
        m2 = c.get("value_times_m2")
        rows.append([c.get("name"), f"{_num(c.get('value'))} ± {_num(c.get('half_width'), '.2g')}", c.get("unit", ""),
                     "–" if m2 is None else f"{_num(m2)} ± {_num(c.get('half_width_times_m2'), '.2g')}"])
    return rows


def _predict(r: ResultDir) -> dict:
    """Rows per record, each pair final model / linear model: whole-signal RMS error and NMSE (the raw predicted
    signal over all frequencies, offset included), band NMSE (± its 95 % bound), |T| error; the nominal T21 against
    the truth; and the records outside the range the model was identified on, with their message."""
    rows, outside = [], []
    for rec in r.doc.get("records", []):
        m, li = rec.get("model", {}), rec.get("linear", {})
        (rm, nm, unit), (rl, nl, _) = whole_signal(m), whole_signal(li)
        unit = unit or (rec.get("output") or {}).get("unit", "")
        bm, bl = (x.get("band_nmse") or {} for x in (m, li))
        pb = m.get("parameter_bounds") or {}
        band = _num(bm.get("percent"), ".3g") + " %" if bm.get("percent") is not None else "not computed"
        if pb.get("available") and bm.get("percent") is not None:
            band += f" ± {_num(pb.get('band_nmse_half_width_pct'), '.2g')}"
        band_lin = _num(bl.get("percent"), ".3g") + " %" if bl.get("percent") is not None else "not computed"
        why = outside_message(rec)
        if why:
            outside.append(f"{rec.get('name')}: {why}")
        rows.append([str(rec.get("name")) + (" (outside the identified range)" if why else ""),
                     f"{_num(rm, '.3g')} / {_num(rl, '.3g')} {unit}", f"{_num(nm, '.3g')} / {_num(nl, '.3g')} %",
                     f"{band} / {band_lin}",
                     f"{_pct((m.get('transmissibility_error') or {}).get('median'))} / "
                     f"{_pct((li.get('transmissibility_error') or {}).get('median'))}",
                     _pct(((rec.get("truth") or {}).get("model_nominal_t21_vs_true") or {}).get("median"))])
    return {"rows": rows, "outside": outside}


def _find(d, *keys):
    """The first value found under any of ``keys`` in a nested dict (depth-first); None if absent."""
    if isinstance(d, Mapping):
        for k in keys:
            if k in d and not isinstance(d[k], (Mapping, list)):
                return d[k]
        for v in d.values():
            got = _find(v, *keys)
            if got is not None:
                return got
    return None


def _effect_label(e) -> str:
    if isinstance(e, Mapping):
        if e.get("label"):
            return str(e["label"])
        term = e.get("term") if isinstance(e.get("term"), Mapping) else e
        params = term.get("params") or {}
        return term.get("kind", "?") + ("(" + ", ".join(f"{k}={_num(v)}" for k, v in params.items()) + ")"
                                        if params else "")
    return str(e)


def _terms_text(terms, element: str) -> str:
    if not isinstance(terms, list):
        return ""
    return f"linear {element}" + "".join(" + " + _effect_label(t) for t in terms)


def _errors_rows(before: Mapping, after: Mapping) -> list[list[str]]:
    """Metric | before | after, from the loop's error summaries (held-out NMSE, equation error, bands, T)."""
    rows = []
    for key, label, fmt in (("prediction_nmse_pct", "held-out prediction NMSE (output simulated) [%]", ".3g"),
                            ("equation_nmse_pct", "held-out equation error (force balance) [%]", ".3g")):
        if key in before or key in after:  # a side without a prediction says so: never another metric instead
            rows.append([label] + [_num(d.get(key), fmt) if d.get(key) is not None or key != "prediction_nmse_pct"
                                   else "not computed" for d in (before, after)])
    bb, ba = before.get("band_residual_db") or {}, after.get("band_residual_db") or {}
    for band in bb or ba:
        rows.append([f"residual {band} Hz [dB]", _num(bb.get(band), ".1f"), _num(ba.get(band), ".1f")])

    def per_record(e):
        return {x.get("record"): x.get("error_pct") for x in e.get("transmissibility_error_pct") or []
                if isinstance(x, Mapping)}
    tb, ta = per_record(before), per_record(after)
    for rec in tb or ta:
        rows.append([f"transmissibility error at {rec} [%]", _num(tb.get(rec), ".2g"), _num(ta.get(rec), ".2g")])
    return rows


def _loop(r: ResultDir, words: Mapping) -> dict:
    d = r.doc
    rounds = [x for x in (d.get("rounds") or []) if isinstance(x, Mapping)]
    rows = []
    for i, rd in enumerate(rounds, 1):
        added = rd.get("added") or rd.get("effect")
        best = (rd.get("ranked") or [None])[0]
        rows.append([str(rd.get("round", i)), _effect_label(added) if added else Markup("<i>nothing</i>"),
                     _effect_label(best) if best else "–", _num(_find(best or {}, "err", "score"), ".3g"),
                     _num(_find(best or {}, "p_value"), ".1e"),
                     _num(_find(rd.get("before") or {}, *_NMSE_KEYS), ".3g"),
                     _num(_find(rd.get("after") or {}, *_NMSE_KEYS), ".3g"), rd.get("text", "")])
    eb, ea = d.get("errors_before"), d.get("errors_after")
    report = d.get("report")
    view = {"verdict": d.get("verdict") or d.get("conclusion") or d.get("message"),
            "declared": _terms_text(d.get("declared_model"), words["element"]) if "declared_model" in d else "",
            "refined": _terms_text(d.get("refined_model"), words["element"]) if "refined_model" in d else "",
            "report_lines": [ln for ln in report.splitlines() if ln.strip()] if isinstance(report, str) else [],
            "errors": _errors_rows(eb, ea) if isinstance(eb, Mapping) and isinstance(ea, Mapping) else [],
            "rounds": rows, "coefficients": _loop_coefficients(d)}
    return view



# ------------------------------------------------------------------------------------ provenance
def _missing(text: str) -> dict:
    return {"text": text, "cls": "missing"}


def _data_row(path: str, e: Mapping | None, why: str = "") -> list:
    if e is None:
        return [_code(path)] + [_missing(why)] * 5
    meta = e.get("meta") or {}
    fmt = meta.get("format") or "?"
    if meta.get("storage"):
        fmt += f" ({meta['storage']})"
    chans = meta.get("topics") or meta.get("columns") or {}
    chan_txt = ", ".join(f"{k}={v}" for k, v in chans.items() if v) or "default names"
    return [_code(path), fmt, _num(e.get("fs_hz"), "g"), _num(e.get("duration_s"), ".1f"),
            _num((e.get("size_bytes") or 0) / 1e6, ".2f"), chan_txt]


def _data_rows(results: Sequence[ResultDir]) -> list[list]:
    """One row per data file: the identify result's entries first (they hold the reader's metadata), then
    every other path, described by reading the file again with the result's input options."""
    from nifo.io.results import data_entry

    entries: dict[str, Mapping] = {}
    for r in results:
        if r.kind == "identify":
            data = r.doc.get("data") or []
            flat = data if isinstance(data, list) else [e for s in data.get("steps", []) for e in s.get("data", [])]
            for e in flat:
                if isinstance(e, Mapping) and e.get("path") and e.get("meta"):
                    entries.setdefault(str(e["path"]), e)
    rows, done = [], set()
    for r in results:
        for p in data_paths(r):
            if p in done:
                continue
            done.add(p)
            if p in entries:
                rows.append(_data_row(p, entries[p]))
                continue
            q = resolve_data(p, r)
            if q is None:
                rows.append(_data_row(p, None, "not reachable from here"))
                continue
            try:
                rows.append(_data_row(p, data_entry(q, _record(q, r))))
            except NifoError as err:
                rows.append(_data_row(p, None, f"unreadable: {err}"))
    return rows


def _choices(results: Sequence[ResultDir]) -> list[list]:
    """The settings of the first result that recorded how they were chosen (nifo.settings): setting, value, where
    from (command line, model file, data, default) and why."""
    for r in results:
        st = r.doc.get("settings_chosen") or r.doc.get("settings") or {}
        ch = st.get("choices") if isinstance(st, Mapping) else None
        if isinstance(ch, Mapping) and ch:
            rows = []
            for name, c in ch.items():
                if not isinstance(c, Mapping):
                    continue
                v = c.get("value")
                if isinstance(v, Mapping):
                    v = ", ".join(f"{k} {x}" for k, x in v.items() if k in ("block", "window", "overlap"))
                elif isinstance(v, list):
                    v = " - ".join(_num(x, ".4g") for x in v)
                rows.append([_code(name), "—" if v is None else str(v), c.get("source", ""), c.get("reason", "")])
            return rows
    return []


def _provenance(results: Sequence[ResultDir]) -> dict:
    settings = []
    for r in results:
        d = r.doc
        chosen = {k: d[k] for k in _SETTING_KEYS
                  if k in d and d[k] is not None and not (r.kind == "loop" and k == "model")}
        if isinstance(chosen.get("settings"), Mapping):    # how they were chosen: one table above
            chosen["settings"] = {k: v for k, v in chosen["settings"].items() if k not in ("choices", "excitation")}
        settings.append({"kind": r.kind, "path": str(r.path),
                         "rows": [[_code(k), v] for k, v in _flatten(chosen)]})
    return {"data": _data_rows(results), "settings": settings, "choices": _choices(results)}


# ------------------------------------------------------------------------------------ levels figure
def levels_figure(results: Sequence[ResultDir], out_png: Path) -> Path | None:
    """Plain H1 at every level found in the results' provenance, with the NIFO nominal T21 and (simulated
    data) the true linear T21, as one PNG; None when there is no identify result or no data is reachable."""
    from nifo.io.provenance import true_t21
    from nifo.io.results import read_identify
    from nifo.plots.nifo import plot_transmissibility
    from nifo_core.signal.frf import h1
    from nifo_core.signal.spectral import cross_spectra

    ident = next((r for r in results if r.kind == "identify"), None)
    if ident is None:
        return None
    res, _ = read_identify(ident.path)
    words = system_words(_system(results))
    units = _system(results)["units"]
    found: list[tuple[Path, ResultDir]] = []
    for r in results:
        for p in data_paths(r):
            q = resolve_data(p, r)
            if q is not None and q.resolve() not in [x.resolve() for x, _ in found]:
                found.append((q, r))
    curves, truth = [], None
    for (p, r), name in zip(found, record_labels([p for p, _ in found])):
        rec = _record(p, r)
        if abs(rec.fs_hz - res.fs_hz) > 1e-6 * res.fs_hz:
            continue
        spec = cross_spectra(np.stack([rec.spindle_accel, rec.body_accel]), rec.fs_hz, res.settings)
        rms = float(np.std(rec.spindle_accel))
        curves.append((f"measured H1, {name} ({words['input']} RMS {rms:.2g} {units})", spec.freq_hz,
                       h1(spec, 0, 1), {"lw": 1.0, "alpha": 0.85}))
        if truth is None and (t := true_t21(p, spec.freq_hz)) is not None:
            truth = (spec.freq_hz, t)
    if not curves:
        return None
    curves.sort(key=lambda c: c[0])
    st = res.static if res.static is not None else res
    curves.append(("NIFO nominal linear T21 (pooled)", res.freq_hz, st.t21,
                   {"color": "C3", "lw": 1.8, "ls": "--", "random_error": st.random_error,
                    "bound_k": res.bound_factor(static=res.static is not None)}))
    if truth is not None:
        curves.append(("true nominal linear T21 (simulator)", truth[0], truth[1],
                       {"color": "k", "lw": 0.9, "ls": ":"}))
    # the PNG alone: it is embedded, and a vector file would have nowhere to go beside a single-file report
    return plot_transmissibility(out_png, curves, band_hz=res.analysis_band_hz, vector=False,
                                 title="transmissibility across levels and the NIFO nominal estimate")


# ------------------------------------------------------------------------------------ the document
def build_report(results: Sequence[ResultDir], *, title: str = "nifo report", notes: Sequence[str] = (),
                 levels_png: Path | None = None, recording: str | None = None, head: Mapping | None = None) -> str:
    """The whole HTML document (a string), rendered from ``templates/report.html.j2``; ``head``: the first
    screen (:func:`nifo.viz.report_headline.headline`)."""
    system = _system(results)
    words = system_words(system)
    sections = []
    for r in results:
        if r.kind == "characterize":
            view = _characterize(r, system)
        elif r.kind == "identify":
            view = _identify(r, system)
            if levels_png is not None:
                view["levels_figure"] = _figure(levels_png, words, _caption("levels", words))
        elif r.kind == "predict":
            view = _predict(r)
        else:
            view = _loop(r, words)
        sections.append({**view, "kind": r.kind, "anchor": f"{r.kind}-{len(sections) + 1}",
                         "title": _SECTION_TITLES[r.kind], "path": str(r.path), "doc": r.doc,
                         "figures": [_figure(f, words) for f in r.figures]})
    if not any(r.kind == "loop" for r in results) and not any("loop" in n for n in notes):
        notes = [*notes, "No loop result was given: the search for effects the model lacks is not in this report."]
    top = None if head is None else {
        "facts": head["facts"], "outside": head["outside"],
        "figures": [_figure(f["path"], words, f["caption"]) for f in head["figures"]]}
    return _env().get_template("report.html.j2").render(
        title=title, sections=sections, head=top, notes=list(notes), recording=recording,
        recording_name=Path(recording).name if recording else None, system=system, words=words,
        noise=noise_table(results, words, system.get("units", "m/s²")),
        provenance=_provenance(results), version=__version__,
        generated=_dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z"))


def write_report(results: Sequence[ResultDir], out: Path, *, title: str = "nifo report", notes: Sequence[str] = (),
                 levels: bool = True, recording: str | None = None) -> Path:
    """Write the report to ``out`` atomically (with the levels figure when the data are reachable)."""
    from nifo.io.atomic import staged_file
    from nifo.plots.writer import figure_batch, helpers_started, wait_figures

    _load.cache_clear()
    try:
        with tempfile.TemporaryDirectory(prefix="nifo-report-") as tmp:
            # the report's own figures by the figure helpers where they are up (nifo run), side by side and beside
            # the next figure's building, then read into the page (inside nifo run a batch hands its figures on:
            # waited for here); nifo report alone draws them here (measured: starting the helpers for its three
            # figures saved no wall time and cost 0.8 CPU-s)
            with figure_batch() if helpers_started() else contextlib.nullcontext():
                levels_png = levels_figure(results, Path(tmp) / "levels.png") if levels else None
                system = _system(results)
                head = headline(results, Path(tmp), system=system, words=system_words(system))
            wait_figures()
            text = build_report(results, title=title, notes=notes, levels_png=levels_png, recording=recording,
                                head=head)
    finally:
        _load.cache_clear()   # records are large: keep none after the report
    with staged_file(out) as f:
        f.write_text(text, encoding="utf-8")
    return Path(out)
