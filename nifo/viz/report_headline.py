"""The report's first screen: what the strut does, how well the final model predicts, what the loop changed.

:func:`headline` reads the final model (``loop/model.json``, else ``identify/``: :class:`nifo.api.Model`), the
predict and loop results, draws the two headline figures (the force law: :mod:`nifo.plots.force_law`; the
prediction against the linear model: :mod:`nifo.plots.headline`) and words the numbers in physical units
("damper knee at 0.030 m/s: −701 N·s/m beyond it"). :func:`noise_table` is the sensor noise as one table.
Whole-signal errors come from predict.json's ``whole_signal`` where present, else its ``rms_error.value``; a
record whose ``validity.outside`` is set is shown with its message, never as validated.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from nifo.api import ForceLaw, Model, find_model
from nifo.io.signals import read_signals
from nifo.plots.restoring import term_words
from nifo_core.errors import NifoError
from nifo_core.kinds.describing import make_term

from .results import ResultDir

__all__ = ["headline", "noise_table", "whole_signal", "outside_message"]

EXCERPT_S = 3.0


def _of(results: Sequence[ResultDir], kind: str) -> ResultDir | None:
    return next((r for r in results if r.kind == kind), None)


def whole_signal(side: Mapping) -> tuple[float | None, float | None, str | None]:
    """(RMS error, NMSE [%], unit) of one model's raw predicted signal over all frequencies, offset included:
    predict.json's ``whole_signal`` (Nones when it has none)."""
    ws = side.get("whole_signal")
    if isinstance(ws, Mapping):
        return ws.get("rms_error"), ws.get("nmse_percent"), ws.get("unit")
    return None, None, None


def outside_message(rec: Mapping) -> str | None:
    v = rec.get("validity")
    return str(v.get("message") or "outside the range the model was identified on") \
        if isinstance(v, Mapping) and v.get("outside") else None


def _fmt(v: float, digits: int = 3) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{v:.{digits}g}".replace("-", "−")


def _range(values: Sequence[float | None], unit: str) -> str:
    v = [x for x in values if x is not None]
    if not v:
        return "not computed"
    lo, hi = min(v), max(v)
    return f"{_fmt(lo)} {unit}" if np.isclose(lo, hi, rtol=5e-3) else f"{_fmt(lo)}–{_fmt(hi)} {unit}"


def _strut_facts(model: Model, law: ForceLaw | None, system: Mapping) -> str:
    """The strut in words: the linear spring and damper, each term with its coefficient, the measured range."""
    m, mass = model.identified, model.mass_kg
    scale = 1.0 if mass is None else mass
    bits = []
    if m.linear.kind == "body":
        bits.append(f"linear spring {_fmt(scale * m.body.k)} N/m and damper {_fmt(scale * m.body.c)} N·s/m")
    else:
        hz = sorted({abs(p) / (2 * np.pi) for p in m.linear.all_poles()})
        bits.append(f"a flexible linear part (rational, {m.linear.order} states; modes at "
                    + ", ".join(f"{f:.3g}" for f in hz[:4]) + " Hz)")
    for t, g in zip(m.terms, m.c_over_m2):
        what = "beyond it" if t.spec.beyond else ""
        bits.append(f"{term_words(t, units=model.units)}: {_fmt(scale * g)} {t.spec.coef_unit} {what}".rstrip())
    head = ("" if mass is not None else
            f"per kg of {'sprung mass' if system.get('vehicle', True) else 'output-side mass'}: ")
    text = head + "; ".join(bits)
    if law is not None and law.deflection.measured is not None:
        zs = 1e3 if law.units["z"] == "m" else 1.0
        zu = "mm" if law.units["z"] == "m" else law.units["z"]
        lo, hi = (zs * v for v in law.deflection.measured)
        vlo, vhi = law.velocity.measured
        text += (f". Measured over deflection {_fmt(lo)} to {_fmt(hi)} {zu} and velocity {_fmt(vlo)} to "
                 f"{_fmt(vhi)} {law.units['zdot']}")
        errs = [c.truth_error() for c in (law.deflection, law.velocity)]
        if all(e is not None for e in errs):
            text += f"; the total force is within {_fmt(100 * max(errs), 2)} % of the simulator's truth there"
    return text[:1].upper() + text[1:] + "."


def _loop_facts(loop: ResultDir | None) -> str:
    if loop is None:
        return "no loop result: the search for what the model lacks is not in this report."
    d = loop.doc
    added = []
    for rd in d.get("rounds") or []:
        a = rd.get("added") if isinstance(rd, Mapping) else None
        if isinstance(a, Mapping) and a.get("kind"):
            try:
                added.append("a " + make_term({"kind": a["kind"], "params": a.get("params") or {}}).spec.noun)
            except NifoError:
                added.append(str(a.get("label", a["kind"])))
    lin, fin = d.get("linear_heldout_prediction_nmse_pct"), d.get("final_heldout_prediction_nmse_pct")
    text = ("from the linear model it added " + ", then ".join(added) if added else
            "it added nothing to the linear model")
    if lin is not None and fin is not None:
        text += f"; held-out prediction NMSE {_fmt(lin)} % (linear) → {_fmt(fin)} % (final model)"
    wb, wa = (d[k].get("whole_signal_nmse_pct") if isinstance(d.get(k), Mapping) else None
              for k in ("errors_before", "errors_after"))
    if wb is not None and wa is not None:
        text += f", over all frequencies {_fmt(wb)} % → {_fmt(wa)} %"
    verdict = str(d.get("verdict") or "")
    if "Nothing significant is missing" in verdict:
        text += "; nothing significant is missing"
    elif verdict.startswith("The model class"):
        text += "; " + verdict.split(":")[0]
    elif not d.get("nothing_missing", True):     # the verdict names what these data cannot pin or tell apart
        text += "; not everything could be told apart (see the loop's verdict)"
    return text + "."


def _prediction(predict: ResultDir, words: Mapping, tmp: Path) -> tuple[str, dict | None, list[str]]:
    """The prediction in words, its figure (or None) and the records outside the identified range."""
    from nifo.plots.headline import plot_prediction_summary

    recs = [r for r in predict.doc.get("records") or [] if isinstance(r, Mapping)]
    if not recs:
        return "nothing predicted.", None, []
    unit = (recs[0].get("output") or {}).get("unit", "m/s²")
    rms, band, outside = [], [], []
    for r in recs:
        m, li = r.get("model") or {}, r.get("linear") or {}
        (rm, _, um), (rl, _, _) = whole_signal(m), whole_signal(li)
        unit = um or unit
        why = outside_message(r)
        if why:
            outside.append(f"{r.get('name')}: {why}")
        rms.append((r.get("name"), rm, rl, why is not None))
        band.append((r.get("name"), (m.get("band_nmse") or {}).get("percent"),
                     (li.get("band_nmse") or {}).get("percent"), why is not None))
    inside = [i for i, r in enumerate(rms) if not r[3]] or list(range(len(rms)))
    text = (f"On {len(recs)} record(s), whole-signal RMS error {_range([rms[i][1] for i in inside], unit)} "
            f"(linear model of the same data {_range([rms[i][2] for i in inside], unit)}); band NMSE "
            f"{_range([band[i][1] for i in inside], '%')} (linear {_range([band[i][2] for i in inside], '%')})")
    if outside:
        text += f"; {len(outside)} record(s) outside the identified range, not validated"
    # the excerpt: the record where the linear model misses most (where the nonlinearity shows)
    pick = max(inside, key=lambda i: -1 if rms[i][2] is None else rms[i][2])
    rec = recs[pick]
    sig = next((predict.path / s for s in rec.get("signals") or [] if str(s).endswith(".parquet")), None)
    if sig is None or not sig.is_file():
        return text + ".", None, outside
    cols = read_signals(sig)
    out_name = (rec.get("output") or {}).get("name", "body_accel")
    fs = float(rec.get("fs_hz") or 1.0)
    lo, hi = (rec.get("valid_samples") or [0, len(cols["time_s"])])[:2]
    n = int(min(EXCERPT_S * fs, hi - lo))
    start = max(lo, (lo + hi) // 2 - n // 2)
    sl = slice(start, start + n)
    band_hz = tuple((recs[0].get("model") or {}).get("band_nmse", {}).get("band_hz") or
                    predict.doc.get("freq_range_hz") or (0, 0))
    out = plot_prediction_summary(
        tmp / "headline_prediction.png", t_s=cols["time_s"][sl], measured=cols[f"{out_name}_measured"][sl],
        model=cols[f"{out_name}_model"][sl], linear=cols[f"{out_name}_linear"][sl], record=str(rec.get("name")),
        output=f"{words['output']} acceleration" if out_name == "body_accel" else f"{words['output']} displacement",
        unit=unit, rms=rms, band=band, band_hz=band_hz)
    return text + ".", {"path": out, "record": rec.get("name")}, outside


def headline(results: Sequence[ResultDir], tmp: Path, *, system: Mapping, words: Mapping) -> dict | None:
    """The first screen's facts and figures (module docstring); None when there is no model to show."""
    from nifo.plots.force_law import plot_force_law

    loop, ident, predict = (_of(results, k) for k in ("loop", "identify", "predict"))
    model = law = None
    why_no_law = ""
    for r in (loop, ident):
        if r is None:
            continue
        try:
            model = Model.load(find_model(r.path))
            break
        except NifoError:
            continue
    if model is not None:
        try:
            law = model.force_law()
        except NifoError as err:
            why_no_law = err.message
    if model is None and predict is None:
        return None
    facts, figures = [], []
    if model is not None:
        facts.append({"key": f"What the {words['element']} does", "text": _strut_facts(model, law, system)})
    if law is not None:
        per = f"forces in {law.units['force']}" if law.mass_kg is not None else f"forces per kg of {words['mass']}"
        png = plot_force_law(tmp / "headline_force_law.png", law, vector=False, size=(12.0, 3.0),
                             element="strut" if system.get("vehicle", True) else "element",
                             title=f"the identified {words['element']}: force against deflection and velocity ({per})")
        figures.append({"path": png, "caption": f"The {words['element']}'s force law over the measured range (grey: "
                        "beyond it): total force solid with its 95 % bound shaded, linear part dashed"
                        + (", the simulator's truth dotted" if law.deflection.truth is not None else "")
                        + ". Tables of it: nifo export."})
    elif why_no_law:
        facts.append({"key": "Force law", "text": f"not drawn: {why_no_law}."})
    outside = []
    if predict is not None:
        text, fig, outside = _prediction(predict, words, tmp)
        facts.append({"key": "How well it predicts", "text": text})
        if fig is not None:
            figures.append({"path": fig["path"], "caption": f"Measured and predicted {words['output']} signal "
                            f"({fig['record']}), and on every record the error of the final model against the "
                            "linear model of the same data: the whole signal (all frequencies, offset included) "
                            "and the band NMSE."})
    facts.append({"key": "What the loop changed", "text": _loop_facts(loop)})
    return {"facts": facts, "figures": figures, "outside": outside}


def noise_table(results: Sequence[ResultDir], words: Mapping, units: str) -> list[list[str]]:
    """One row per record: the sensor noise of each side (% of the channel's RMS, its standard deviation) and the
    octave it was read in — from the result covering the most records (the loop's, else identify's)."""
    docs = [r.doc.get("noise") for r in results if r.kind in ("loop", "identify") and r.doc.get("noise")]
    noise = max(docs, key=len) if docs else []
    rows = []
    for e in noise:
        if not isinstance(e, Mapping):
            continue
        if not e.get("available", bool(e.get("channels"))):
            rows.append([str(e.get("source")), f"no estimate: {e.get('unavailable')}", "", ""])
            continue
        side = {}
        octave = ""
        for c in e.get("channels") or []:
            who = "input" if str(c.get("channel", "")).startswith("spindle") else "output"
            side[who] = f"{_fmt(c.get('percent_of_rms'), 2)} % ({_fmt(c.get('std'))} {units})"
            lo, hi = (c.get("octave_hz") or [None, None])[:2]
            octave = "" if lo is None else f"{_fmt(lo)}–{_fmt(hi)} Hz"
        rows.append([str(e.get("source")), side.get("input", "–"), side.get("output", "–"), octave])
    return rows
