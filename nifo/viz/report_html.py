"""The HTML report: one self-contained file a test engineer can read, forward and print.

:func:`build_report` turns result directories (:mod:`nifo.viz.results`) into
one HTML document: every PNG embedded as base64 (no external assets, no
JavaScript), tables of the numbers, the loop's before/after, the settings and
where the data came from. :func:`levels_figure` adds the paper-style
"transmissibility across levels with the NIFO estimate" when the data are
reachable.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
import tempfile
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from nifo_core import __version__

from .results import ResultDir, data_paths, resolve_data

__all__ = ["build_report", "write_report", "levels_figure", "CAPTIONS"]

#: figure file name (prefix or suffix) -> caption; first match wins
CAPTIONS: tuple[tuple[str, str], ...] = (
    ("restoring_frequency", "Restoring force by frequency slice (cf. paper Fig. 3): the strut force per unit "
                            "sprung mass −ẍ2 against the relative velocity ż (damping, left) and displacement z "
                            "(stiffness, right). A linear strut gives ellipses; kinks and flat spots are "
                            "nonlinearities."),
    ("restoring_amplitude", "Restoring force by amplitude (cf. paper Fig. 4): one row per excitation level or "
                            "amplitude bin. Shapes that change with amplitude are nonlinear; the fitted model "
                            "is drawn over the data."),
    ("characteristic", "Stiffness and damping characteristics of the suggested terms: binned data with their "
                       "interquartile band, the fitted characteristic, and (bottom) the same minus the linear fit."),
    ("ranking", "Every kind of nonlinearity in the library, scored by how much of the linear fit's residual it "
                "explains; the dashed line is the 'present' threshold."),
    ("levels", "Spindle → body transmissibility at every excitation level (plain H1) with the NIFO estimate of "
               "the nominal linear T21 (cf. paper Fig. 9b/12b). The measured curves move with level because "
               "the strut is nonlinear; the NIFO estimate is what is left when the nonlinearity is taken out."),
    ("_transmissibility", "Predicted vs measured transmissibility at this level: the identified nonlinear model "
                          "against the linear model identified at the other level."),
    ("transmissibility", "Spindle → body transmissibility: measured H1 and the NIFO nominal linear T21 "
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
    ("_time", "Body acceleration, measured vs predicted from the measured spindle acceleration (an excerpt)."),
)

_SECTION_TITLES = {"characterize": "Characterization: which nonlinearities, how strong",
                   "identify": "Identification: nominal transmissibility and coefficient functions (NIFO)",
                   "predict": "Prediction at the other level(s)",
                   "loop": "Closing the loop: what the model lacked, error before and after"}

_CSS = """
:root { --ink: #1d2733; --muted: #5b6775; --rule: #d8dee6; --accent: #1f4e79; --good: #2e7d32; --warn: #a15c00; }
* { box-sizing: border-box; }
body { font: 15px/1.5 -apple-system, "Segoe UI", Roboto, "Helvetica Neue", Arial, sans-serif; color: var(--ink);
       margin: 0; background: #f5f7fa; }
main { max-width: 1040px; margin: 0 auto; padding: 28px 36px 60px; background: #fff; }
h1 { font-size: 26px; margin: 0 0 4px; color: var(--accent); }
h2 { font-size: 20px; margin: 36px 0 10px; padding-bottom: 4px; border-bottom: 2px solid var(--accent); }
h3 { font-size: 16px; margin: 22px 0 8px; }
p.meta, .muted { color: var(--muted); font-size: 13px; }
nav ol { margin: 6px 0 0; padding-left: 20px; columns: 2; font-size: 14px; }
a { color: var(--accent); }
.glance { display: grid; grid-template-columns: repeat(auto-fit, minmax(220px, 1fr)); gap: 12px; margin: 18px 0; }
.card { border: 1px solid var(--rule); border-left: 4px solid var(--accent); border-radius: 4px; padding: 10px 12px; }
.card .k { font-size: 12px; color: var(--muted); text-transform: uppercase; letter-spacing: .04em; }
.card { min-width: 0; }
.card .v { font-size: 15px; font-weight: 600; overflow-wrap: anywhere; }
.card .v small { font-weight: 400; color: var(--muted); }
table { border-collapse: collapse; width: 100%; margin: 8px 0 14px; font-size: 13.5px; }
th, td { text-align: left; padding: 5px 8px; border-bottom: 1px solid var(--rule); vertical-align: top; }
th { background: #eef2f7; font-weight: 600; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
tr.suggested td { background: #eef7ee; }
.good { color: var(--good); font-weight: 600; }
.warn { color: var(--warn); }
ul.warnings li { color: var(--warn); margin-bottom: 4px; }
figure { margin: 16px 0 22px; text-align: center; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--rule); }
figcaption { font-size: 13px; color: var(--muted); text-align: left; margin-top: 6px; }
code, pre { font: 12.5px/1.4 ui-monospace, Menlo, Consolas, monospace; }
pre { background: #f3f5f8; padding: 8px 10px; overflow-x: auto; white-space: pre-wrap; }
footer { margin-top: 40px; font-size: 12px; color: var(--muted); border-top: 1px solid var(--rule); padding-top: 8px; }
@media print {
  body { background: #fff; font-size: 11pt; }
  main { max-width: none; padding: 0; }
  nav { display: none; }
  h2 { break-before: page; }
  h2:first-of-type { break-before: auto; }
  figure, table, .card { break-inside: avoid; }
  a { color: inherit; text-decoration: none; }
}
"""


# ------------------------------------------------------------------------------------ small pieces
def _e(x) -> str:
    return html.escape(str(x), quote=True)


def _num(x, fmt: str = ".4g") -> str:
    if x is None:
        return "–"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return _e(x)
    return "–" if not np.isfinite(v) else format(v, fmt)


def _pct(x, fmt: str = ".1f") -> str:
    return "–" if x is None else f"{100 * float(x):{fmt}} %"


def _table(header: Sequence[str], rows: Iterable[Sequence], *, numeric: Sequence[int] = (),
           row_class: Sequence[str] | None = None) -> str:
    th = "".join(f'<th class="num">{_e(h)}</th>' if i in numeric else f"<th>{_e(h)}</th>"
                 for i, h in enumerate(header))
    body = []
    for k, r in enumerate(rows):
        cls = f' class="{row_class[k]}"' if row_class and row_class[k] else ""
        tds = "".join(f'<td class="num">{c}</td>' if i in numeric else f"<td>{c}</td>" for i, c in enumerate(r))
        body.append(f"<tr{cls}>{tds}</tr>")
    return f"<table><thead><tr>{th}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _caption(name: str) -> str:
    stem = Path(name).stem
    for key, text in CAPTIONS:
        if (key.startswith("_") and stem.endswith(key)) or (not key.startswith("_") and stem.startswith(key)):
            return text
    return stem.replace("_", " ")


def _png_data_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def _figure(path: Path, caption: str | None = None) -> str:
    cap = caption or _caption(path.name)
    return (f'<figure><img src="{_png_data_uri(path)}" alt="{_e(path.stem.replace("_", " "))}">'
            f"<figcaption><b>{_e(path.name)}</b> — {_e(cap)}</figcaption></figure>")


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


def _card(k: str, v: str) -> str:
    return f'<div class="card"><div class="k">{_e(k)}</div><div class="v">{v}</div></div>'


# ------------------------------------------------------------------------------------ sections
def _characterize(r: ResultDir) -> tuple[str, list[tuple[str, str]]]:
    d = r.doc
    band = d.get("band", {})
    cands = d.get("candidates", [])
    rows, classes = [], []
    for c in cands[:8]:
        coef = c.get("coefficient")
        coef_txt = (f"{_num(coef)} {_e(c.get('coefficient_unit', ''))}" if coef is not None
                    else f"{_num(c.get('theta_per_kg'))} ({_e(c.get('coefficient_unit', ''))})/kg")
        status = c.get("status", "")
        if c.get("alternative_to"):
            status += f" (≈ {c['alternative_to']})"
        rows.append([_e(c.get("label", c.get("kind"))), coef_txt, _num(c.get("err"), ".3f"),
                     _num(c.get("p_value"), ".1e"), _e(status), _e(c.get("meaning", ""))])
        classes.append("suggested" if c.get("status") == "suggested" else "")
    sug = d.get("suggested") or []
    verdict = ("no nonlinearity above the thresholds: a linear strut suffices" if d.get("nothing_found")
               else "; ".join(f"{s.get('label')}: {s.get('meaning', '')}" for s in sug))
    recs = [[_e(Path(x.get("path", x.get("source", ""))).name), _num(x.get("duration_s"), ".1f"),
             _num(1e3 * x["z_rms_m"], ".3g") if x.get("z_rms_m") is not None else "–",
             _num(x.get("zdot_rms_m_s"), ".3g"), _num(x.get("linear_r2"), ".4f")] for x in d.get("records", [])]
    parts = [f"<p><b>Suggested model:</b> {_e(verdict)}</p>",
             f"<p class='muted'>Integration band {_num(band.get('f_lo_hz'))}–{_num(band.get('f_hi_hz'))} Hz; "
             f"linear fit R² {_num(d.get('linear', {}).get('r2'), '.4f')}.</p>",
             "<h3>Levels</h3>",
             _table(["record", "duration [s]", "z RMS [mm]", "ż RMS [m/s]", "linear R²"], recs, numeric=(1, 2, 3, 4)),
             "<h3>Candidates (suggested first)</h3>",
             _table(["candidate", "coefficient", "ERR", "p", "status", "meaning"], rows, numeric=(1, 2, 3),
                    row_class=classes)]
    if d.get("notes"):
        parts.append("<ul class='warnings'>" + "".join(f"<li>{_e(n)}</li>" for n in d["notes"]) + "</ul>")
    parts += [_figure(f) for f in r.figures]
    glance = [("suggested model", "linear strut (nothing found)" if d.get("nothing_found") else "<br>".join(
        f"{_e(s.get('label'))} <small>{_e(s.get('meaning', ''))}</small>" for s in sug))]
    return "\n".join(parts), glance


def _identify(r: ResultDir, levels_png: Path | None) -> tuple[str, list[tuple[str, str]]]:
    d = r.doc
    s = d.get("summary", {})
    terms = s.get("terms", [])
    rows = [[_e(t.get("label")), _num(t.get("c_over_m2")), _e(t.get("unit", "")),
             "held fixed" if t.get("fixed") else f"{_num(t.get('per_line_mean_re'))} {_num(t.get('per_line_mean_im'), '+.3g')}j"]
            for t in terms]
    lo, hi = s.get("analysis_band_hz", [None, None])
    dh = s.get("t21_static_vs_h1_rel_diff", {})
    parts = [f"<p>{s.get('n_avg', '–')} spectral averages over {_num(s.get('duration_used_s'), '.1f')} s of data; "
             f"analysis band {_num(lo)}–{_num(hi)} Hz. The nominal (near-zero-level) T21 differs from the plain H1 "
             f"at this level by a median {_pct(dh.get('median'))}: that is the nonlinearity's share.</p>"]
    if rows:
        parts += ["<h3>Pooled coefficients c/M2 (constant over the band)</h3>",
                  _table(["term", "c/M2", "unit", "per-line band mean"], rows, numeric=(1, 3))]
    else:
        parts.append("<p>No nonlinear terms declared: T21 is the plain H1.</p>")
    parts.append(_table(["coherence (plain H1), median", "scaled cond(G_UU), median", "max", "ill-conditioned lines"],
                        [[_num(s.get("coherence_h1_median"), ".3f"), _num(s.get("cond_median"), ".3g"),
                          _num(s.get("cond_max"), ".3g"), _pct(s.get("ill_conditioned_fraction"), ".0f")]],
                        numeric=(0, 1, 2, 3)))
    if d.get("warnings"):
        parts.append("<ul class='warnings'>" + "".join(f"<li>{_e(w)}</li>" for w in d["warnings"]) + "</ul>")
    if levels_png is not None:
        parts.append(_figure(levels_png, _caption("levels")))
    parts += [_figure(f) for f in r.figures]
    glance = [("pooled coefficients", "<br>".join(f"{_e(t.get('label'))}: {_num(t.get('c_over_m2'))} {_e(t.get('unit'))}"
                                                   for t in terms) or "none (linear)"),
              ("coherence, median", _num(s.get("coherence_h1_median"), ".3f"))]
    return "\n".join(parts), glance


def _predict(r: ResultDir) -> tuple[str, list[tuple[str, str]]]:
    d = r.doc
    lo, hi = d.get("freq_range_hz", [None, None])
    rows = []
    for rec in d.get("records", []):
        m, li = rec.get("model", {}), rec.get("linear", {})
        better = (m.get("nmse_percent") is not None and li.get("nmse_percent") is not None
                  and m["nmse_percent"] < li["nmse_percent"])
        nm = _num(m.get("nmse_percent"), ".2f") + " %"
        rows.append([_e(rec.get("name")), f"<span class='good'>{nm}</span>" if better else nm,
                     _num(li.get("nmse_percent"), ".2f") + " %",
                     _pct((m.get("transmissibility_error") or {}).get("median")),
                     _pct((li.get("transmissibility_error") or {}).get("median")),
                     _pct(((rec.get("truth") or {}).get("model_nominal_t21_vs_true") or {}).get("median"))])
    parts = [f"<p>The identified model predicts the body acceleration from the measured spindle acceleration at "
             f"each other level. NMSE in time (below 5 % good, below 1 % excellent) and the median transmissibility "
             f"error over {_num(lo)}–{_num(hi)} Hz, for the identified model and for a linear model.</p>",
             _table(["record", "NMSE model", "NMSE linear", "|T| error model", "|T| error linear",
                     "nominal T21 vs truth"], rows, numeric=(1, 2, 3, 4, 5))]
    parts += [_figure(f) for f in r.figures]
    glance = [(f"NMSE at {rec.get('name')}", f"{_num(rec['model'].get('nmse_percent'), '.2f')} % "
                                             f"<span class='muted'>(linear {_num(rec['linear'].get('nmse_percent'), '.2f')} %)</span>")
              for rec in d.get("records", []) if "model" in rec and "linear" in rec]
    return "\n".join(parts), glance


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
    if isinstance(e, str):
        return e
    if isinstance(e, Mapping):
        if e.get("label"):
            return str(e["label"])
        term = e.get("term") if isinstance(e.get("term"), Mapping) else e
        kind = term.get("kind", "?")
        params = term.get("params") or {}
        return kind + ("(" + ", ".join(f"{k}={_num(v)}" for k, v in params.items()) + ")" if params else "")
    return str(e)


_NMSE_KEYS = ("prediction_nmse_pct", "nmse_percent", "nmse", "held_out_nmse_percent")


def _terms_text(terms) -> str:
    if not isinstance(terms, list):
        return ""
    return "linear strut" + "".join(" + " + _effect_label(t) for t in terms)


def _errors_table(before: Mapping, after: Mapping) -> str:
    """Metric | before | after, from the loop's error summaries (held-out NMSE, equation error, bands, T)."""
    rows = []
    for key, label, fmt in (("prediction_nmse_pct", "held-out prediction NMSE (body acceleration simulated) [%]",
                             ".3g"),
                            ("equation_nmse_pct", "held-out equation error (force balance) [%]", ".3g")):
        if key in before or key in after:  # a side without a prediction says so: never another metric instead
            rows.append([label] + [_num(d.get(key), fmt) if d.get(key) is not None or key != "prediction_nmse_pct"
                                   else "not computed" for d in (before, after)])
    bb, ba = before.get("band_residual_db") or {}, after.get("band_residual_db") or {}
    for band in bb or ba:
        rows.append([f"residual {band} Hz [dB]", _num(bb.get(band), ".1f"), _num(ba.get(band), ".1f")])
    tb = {e.get("record"): e.get("error_pct") for e in before.get("transmissibility_error_pct") or []
          if isinstance(e, Mapping)}
    ta = {e.get("record"): e.get("error_pct") for e in after.get("transmissibility_error_pct") or []
          if isinstance(e, Mapping)}
    for rec in tb or ta:
        rows.append([f"transmissibility error at {rec} [%]", _num(tb.get(rec), ".2g"), _num(ta.get(rec), ".2g")])
    return _table(["", "before", "after"], [[_e(a), b, c] for a, b, c in rows], numeric=(1, 2)) if rows else ""


def _loop(r: ResultDir) -> tuple[str, list[tuple[str, str]]]:
    d = r.doc
    rounds = [x for x in (d.get("rounds") or []) if isinstance(x, Mapping)]
    parts = []
    verdict = d.get("verdict") or d.get("conclusion") or d.get("message")
    if verdict:
        cls = "good" if d.get("nothing_missing") else ""
        parts.append(f"<p class='{cls}'><b>{_e(verdict)}</b></p>")
    if d.get("declared_model") is not None:
        parts.append(f"<p>Declared model: {_e(_terms_text(d.get('declared_model')))}"
                     + (f"<br>Refined model: {_e(_terms_text(d['refined_model']))}" if "refined_model" in d else "")
                     + "</p>")
    if isinstance(d.get("report"), str):
        parts.append("<h3>In words</h3>" + "".join(f"<p>{_e(line)}</p>" for line in d["report"].splitlines()
                                                     if line.strip()))
    eb, ea = d.get("errors_before"), d.get("errors_after")
    if isinstance(eb, Mapping) and isinstance(ea, Mapping):
        parts += ["<h3>Error before and after</h3>", _errors_table(eb, ea)]
    rows = []
    for i, rd in enumerate(rounds, 1):
        added = rd.get("added") or rd.get("effect")
        best = (rd.get("ranked") or [None])[0]
        rows.append([str(rd.get("round", i)), _e(_effect_label(added)) if added else "<i>nothing</i>",
                     _e(_effect_label(best)) if best else "–",
                     _num(_find(best or {}, "err", "score"), ".3g"), _num(_find(best or {}, "p_value"), ".1e"),
                     _num(_find(rd.get("before") or {}, *_NMSE_KEYS), ".3g"),
                     _num(_find(rd.get("after") or {}, *_NMSE_KEYS), ".3g"), _e(rd.get("text", ""))])
    if rows:
        parts += ["<h3>Rounds</h3>",
                  _table(["round", "added", "best candidate", "ERR", "p", "held-out prediction NMSE before [%]",
                          "after [%]", "why"], rows, numeric=(3, 4, 5, 6))]
    if not parts:
        parts.append("<pre>" + _e(json.dumps({k: v for k, v in d.items() if not isinstance(v, (list, dict))},
                                             indent=1)) + "</pre>")
    parts += [_figure(f) for f in r.figures]
    added = [_effect_label(x.get("added") or x.get("effect")) for x in rounds if x.get("added") or x.get("effect")]
    glance = [("loop", (_e(", ".join(added)) + " added") if added else "nothing significant missing")]
    return "\n".join(parts), glance


def _provenance(results: Sequence[ResultDir]) -> str:
    parts = []
    seen: set[str] = set()
    rows = []
    for r in results:
        entries = []
        if r.kind == "identify":
            data = r.doc.get("data") or []
            entries = data if isinstance(data, list) else [e for s in data.get("steps", []) for e in s.get("data", [])]
        for e in entries:
            if isinstance(e, Mapping) and e.get("path") not in seen:
                seen.add(e.get("path"))
                meta = e.get("meta") or {}
                rows.append([f"<code>{_e(e.get('path'))}</code>", _e(meta.get("format", "")),
                             _num(e.get("fs_hz"), "g"), _num(e.get("duration_s"), ".1f"),
                             _num((e.get("size_bytes") or 0) / 1e6, ".2f"),
                             _e(", ".join(f"{k}={v}" for k, v in (meta.get("topics") or {}).items()))])
        for p in data_paths(r):
            if p not in seen:
                seen.add(p)
                rows.append([f"<code>{_e(p)}</code>", "", "", "", "", ""])
    parts.append("<h3>Data</h3>")
    parts.append(_table(["path", "format", "fs [Hz]", "duration [s]", "size [MB]", "topics"], rows,
                        numeric=(2, 3, 4)))
    for r in results:
        d = r.doc
        settings = {k: d[k] for k in ("settings", "band", "band_choice", "thresholds", "freq_window_hz",
                                      "freq_range_hz", "method", "model_file", "model", "linear_model")
                    if k in d and d[k] is not None and not (r.kind == "loop" and k == "model")}
        flat = _flatten(settings)
        parts.append(f"<h3>{_e(r.kind)} — <code>{_e(r.path)}</code></h3>")
        parts.append(_table(["setting", "value"], [[f"<code>{_e(k)}</code>", _e(v)] for k, v in flat]))
    return "\n".join(parts)


# ------------------------------------------------------------------------------------ levels figure
def levels_figure(results: Sequence[ResultDir], out_png: Path) -> Path | None:
    """Plain H1 at every level found in the results' provenance, with the NIFO nominal T21 and (simulated
    data) the true linear T21, as one PNG; None when there is no identify result or no data is reachable."""
    from nifo.io.loader import load_record
    from nifo.io.results import read_identify
    from nifo.plots.nifo import plot_transmissibility
    from nifo_core.spectral import cross_spectra, h1

    ident = next((r for r in results if r.kind == "identify"), None)
    if ident is None:
        return None
    res, _ = read_identify(ident.path)
    paths: list[Path] = []
    for r in results:
        for p in data_paths(r):
            q = resolve_data(p, r)
            if q is not None and q.resolve() not in [x.resolve() for x in paths]:
                paths.append(q)
    if not paths:
        return None
    curves = []
    truth = None
    for p in paths:
        rec = load_record(p)
        if abs(rec.fs_hz - res.fs_hz) > 1e-6 * res.fs_hz:
            continue
        spec = cross_spectra(np.stack([rec.spindle_accel, rec.body_accel]), rec.fs_hz, res.settings)
        rms = float(np.std(rec.spindle_accel))
        curves.append((f"measured H1, {p.name} (spindle RMS {rms:.2g} m/s²)", spec.freq_hz, h1(spec, 0, 1),
                       {"lw": 1.0, "alpha": 0.85}))
        truth = truth or _truth_t21(p, spec.freq_hz)
    if not curves:
        return None
    curves.sort(key=lambda c: c[0])
    st = res.static if res.static is not None else res
    curves.append(("NIFO nominal linear T21 (pooled)", res.freq_hz, st.t21, {"color": "C3", "lw": 1.8, "ls": "--"}))
    if truth is not None:
        curves.append(("true nominal linear T21 (simulator)", truth[0], truth[1],
                       {"color": "k", "lw": 0.9, "ls": ":"}))
    return plot_transmissibility(out_png, curves, band_hz=res.analysis_band_hz,
                                 title="transmissibility across levels and the NIFO nominal estimate")


def _truth_t21(path: Path, f: np.ndarray):
    from nifo.commands.predict import truth_for
    from nifo_core.vehicle import QuarterCar

    tp = truth_for(path)
    if tp is None:
        return None
    try:
        return f, QuarterCar(**json.loads(tp.read_text())["vehicle"]).t21(f)
    except (OSError, ValueError, KeyError, TypeError):
        return None


# ------------------------------------------------------------------------------------ the document
def build_report(results: Sequence[ResultDir], *, title: str = "nifo report", notes: Sequence[str] = (),
                 levels_png: Path | None = None, recording: str | None = None) -> str:
    """The whole HTML document (a string)."""
    sections, glance = [], []
    for r in results:
        if r.kind == "characterize":
            body, g = _characterize(r)
        elif r.kind == "identify":
            body, g = _identify(r, levels_png)
        elif r.kind == "predict":
            body, g = _predict(r)
        else:
            body, g = _loop(r)
        glance += g
        anchor = f"{r.kind}-{len(sections) + 1}"
        sections.append((anchor, f"{_SECTION_TITLES[r.kind]}", r.path, body))
    if not any(r.kind == "loop" for r in results) and not any("loop" in n for n in notes):
        notes = [*notes, "No loop result was given: the search for effects the model lacks is not in this report."]
    nav = "".join(f'<li><a href="#{a}">{_e(t)}</a></li>' for a, t, _, _ in sections)
    nav += '<li><a href="#provenance">Settings and data provenance</a></li>'
    now = _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           '<meta name="viewport" content="width=device-width, initial-scale=1">',
           '<link rel="icon" href="data:,">',
           f"<title>{_e(title)}</title><style>{_CSS}</style></head><body><main>",
           f"<h1>{_e(title)}</h1>",
           f"<p class='meta'>Nonlinear suspension identification from spindle and body accelerations "
           f"(restoring force + output-only NIFO, Haroon &amp; Adams 2005). Generated {_e(now)} by nifo "
           f"{_e(__version__)} from {len(results)} result director{'y' if len(results) == 1 else 'ies'}.</p>"]
    if glance:
        out.append('<div class="glance">' + "".join(_card(k, v) for k, v in glance) + "</div>")
    if notes or recording:
        items = [_e(n) for n in notes]
        if recording:
            items.append(f"Rerun recording of the same results: <code>{_e(recording)}</code> "
                         f"(open with <code>rerun {_e(Path(recording).name)}</code>).")
        out.append("<ul class='muted'>" + "".join(f"<li>{i}</li>" for i in items) + "</ul>")
    out.append(f"<nav><b>Contents</b><ol>{nav}</ol></nav>")
    for anchor, t, path, body in sections:
        out.append(f'<section id="{anchor}"><h2>{_e(t)}</h2><p class="meta">from <code>{_e(path)}</code></p>'
                   f"{body}</section>")
    out.append(f'<section id="provenance"><h2>Settings and data provenance</h2>{_provenance(results)}</section>')
    out.append(f"<footer>nifo {_e(__version__)} · self-contained report: figures are embedded, "
               f"no external files needed.</footer></main></body></html>")
    return "\n".join(out)


def write_report(results: Sequence[ResultDir], out: Path, *, title: str = "nifo report", notes: Sequence[str] = (),
                 levels: bool = True, recording: str | None = None) -> Path:
    """Write the report to ``out`` atomically (with the levels figure when the data are reachable)."""
    from nifo.io.atomic import staged_file

    with tempfile.TemporaryDirectory(prefix="nifo-report-") as tmp:
        levels_png = levels_figure(results, Path(tmp) / "levels.png") if levels else None
        text = build_report(results, title=title, notes=notes, levels_png=levels_png, recording=recording)
    with staged_file(out) as f:
        f.write_text(text, encoding="utf-8")
    return Path(out)
