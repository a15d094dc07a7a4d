#!/usr/bin/env python
"""F-16 prediction study: identify on some levels, predict the others; nonlinear vs linear on one metric.

Data: Noël & Schoukens (2017), F-16 ground vibration test benchmark,
nonlinearbenchmark.org (``../shared/data/f16``): ``FullMSine`` levels 1, 3, 5, 7,
9 periods × 8192 samples at 400 Hz, random-phase multisine 2-15 Hz. Row 1 of
``Acceleration`` (wing, next to the interface) is the "spindle" input, row 2
(payload) the "body" output.

For every identification set (3/5/7 → all; leave-one-out: three levels → the
fourth) and every model form, the model is identified with NIFO
(:func:`nifo_core.nifo.identify.identify_nifo`: one block per period, boxcar,
integration band 1.5-40 Hz, analysis band 2-15 Hz; the transient first
period left out of the spectra) and made into an
:class:`~nifo_core.predict.model.IdentifiedModel` with the linear part the library
selects (:func:`nifo_core.predict.linear_part.select_linear_part`) or a rational model
of fixed order; the linear baseline is the same with no nonlinear term
(identified on the same levels, same linear-part choice). Every level is then
predicted in the time domain (:func:`nifo_core.predict.model.predict_body`) from its
measured wing acceleration, from rest, over the whole record (the test also
started from rest), and scored on

    NMSE = 100·Σ|Y - Ŷ|²/Σ|Y|² over the 2-15 Hz lines of the period average of periods 2-9

(Y: DFT of the measured payload acceleration's period average). A model.json
is written for every identification (``--out``), as ``nifo identify`` does.

Every model also predicts the benchmark's **sine sweeps** (``SineSw``, 15 → 2 Hz
at -0.05 Hz/s, levels 1/3/5/7, force amplitude 4.8-95.6 N), from rest, scored
as the band-passed (2-15 Hz) time-domain NMSE over the whole record: a second
excitation, never used to identify or to choose anything — the check that a
model did not just learn the one multisine realisation it was fitted on.

``--paths`` adds every form with backlash, clearance or saturation terms through its own **feedback paths** on
the linear model's poles (:mod:`nifo_core.predict.feedback_paths`, ``nifo identify --feedback-paths``): the interface
force reaching the payload through the payload's modes instead of through one constant coefficient.

Run: ``python tools/f16_predict.py [--data DIR] [--out DIR] [--json FILE] [--quick] [--plays] [--paths] [--refine P]
[--joint P] [--sets SET...]``;
the choice on the identification levels alone from earlier runs: ``python tools/f16_predict.py --select FILE...``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nifo.io.loader import load_record  # noqa: E402
from nifo.io.results import write_model  # noqa: E402
from nifo_core.kinds.describing import make_term  # noqa: E402
from nifo_core.errors import NifoError  # noqa: E402
from nifo_core.predict.feedback_paths import PATH_KINDS  # noqa: E402
from nifo_core.signal.integrate import IntegrationBand  # noqa: E402
from nifo_core.predict.model import IdentifiedModel, predict_body  # noqa: E402
from nifo_core.nifo.identify import identify_nifo  # noqa: E402
from nifo_core.predict.prediction_error import band_nmse  # noqa: E402
from nifo_core.signal.spectral import SpectralSettings  # noqa: E402

DATA = Path(os.environ.get("NIFO_SHARED_DATA", ROOT.parent / "shared" / "data")) / "f16"
LEVELS = (1, 3, 5, 7)
PERIOD = 8192
COLUMNS = {"spindle_accel": "Acceleration[1]", "body_accel": "Acceleration[2]", "fs": "Fs"}
SETTINGS = SpectralSettings(block=PERIOD, overlap=0.0, window="boxcar")
BAND = IntegrationBand(1.5, 40.0)
ANALYSIS = (2.0, 15.0)
SETS = {"3/5/7": (3, 5, 7), "1/3/5 (LOO 7)": (1, 3, 5), "1/3/7 (LOO 5)": (1, 3, 7), "1/5/7 (LOO 3)": (1, 5, 7)}
#: model forms: label -> terms (backlash 0.14 mm: what nifo characterize suggests on level 7, docs/f16_nifo.md)
FORMS = {
    "clearance 0.02 mm": [{"kind": "clearance", "params": {"gap": 2e-5}}],
    "backlash 0.14 mm": [{"kind": "backlash", "params": {"deadband": 1.4e-4}}],
    "friction (coulomb)": [{"kind": "coulomb", "params": {"eps": 1e-3}}],
    "backlash 0.14 mm + friction": [{"kind": "backlash", "params": {"deadband": 1.4e-4}},
                                    {"kind": "coulomb", "params": {"eps": 1e-3}}],
}
#: softening forms (``--extra``): the modes soften with level (docs/f16.md)
EXTRA = {
    "saturation 0.05 mm": [{"kind": "saturation", "params": {"limit": 5e-5}}],
    "saturation 0.14 mm": [{"kind": "saturation", "params": {"limit": 1.4e-4}}],
    "velocity saturation 1 mm/s": [{"kind": "velocity_saturation", "params": {"limit": 1e-3}}],
    "backlash 0.14 mm + vel. saturation": [{"kind": "backlash", "params": {"deadband": 1.4e-4}},
                                           {"kind": "velocity_saturation", "params": {"limit": 1e-3}}],
}

#: several plays of different widths (``--plays``): a discrete Iwan model, a spring through a distribution of
#: frictional slips (two: half and twice the play nifo characterize suggests, 0.14 mm)
PLAYS = {
    "plays 0.07/0.28 mm": [{"kind": "backlash", "params": {"deadband": 7e-5}},
                           {"kind": "backlash", "params": {"deadband": 2.8e-4}}],
    "plays 0.05/0.14/0.4 mm": [{"kind": "backlash", "params": {"deadband": 5e-5}},
                               {"kind": "backlash", "params": {"deadband": 1.4e-4}},
                               {"kind": "backlash", "params": {"deadband": 4e-4}}],
}


def load(level: int, data: Path, *, skip: int) -> "object":
    return load_record(data / f"F16Data_FullMSine_Level{level}.mat", columns=COLUMNS, skip_periods=skip or None,
                       period_samples=PERIOD)


def load_sweep(level: int, data: Path):
    """The sine sweep at ``level`` (None when the file is not there)."""
    path = data / f"F16Data_SineSw_Level{level}.mat"
    return load_record(path, columns=COLUMNS) if path.exists() else None


def sweep_score(y: np.ndarray, yhat: np.ndarray, fs_hz: float) -> float:
    """NMSE [%] of the 2-15 Hz band-passed sweep response over the whole record (both start from rest)."""
    return band_nmse(y, yhat, fs_hz, band_hz=ANALYSIS)


def score(y: np.ndarray, yhat: np.ndarray, fs_hz: float) -> float:
    """NMSE [%] over the 2-15 Hz lines of the period average of periods 2.. (the first dropped)."""
    return band_nmse(y, yhat, fs_hz, band_hz=ANALYSIS, period_samples=PERIOD, skip_samples=PERIOD)


def _levels(row: dict) -> str:
    out = " ".join(f"L{lv} {row['nmse'].get(lv, float('nan')):7.3f}" for lv in LEVELS)
    if row.get("sweep"):
        out += "  | sweep " + " ".join(f"L{lv} {row['sweep'].get(lv, float('nan')):7.3f}" for lv in LEVELS)
    return out


def predict_levels(model, full: dict, row: dict, sweeps: dict | None = None) -> None:
    """Predict every level from rest; its score into ``row['nmse']``, or why not into ``row['errors']``; the
    sine sweeps (``sweeps``) likewise into ``row['sweep']`` (errors under ``'sweep L<level>'``)."""
    runs = [(lv, full[lv], score, row["nmse"], lv) for lv in LEVELS]
    runs += [(lv, rec, sweep_score, row.setdefault("sweep", {}), f"sweep L{lv}")
             for lv, rec in (sweeps or {}).items() if rec is not None]
    for lv, rec, scorer, into, err_key in runs:
        try:
            p = predict_body(model, rec.spindle_accel, rec.fs_hz, label=rec.source)
            into[lv] = scorer(rec.body_accel, p.body_accel, rec.fs_hz)
        except NifoError as err:
            row["errors"][err_key] = str(err)


def refine(model, linear, full: dict, ids, periods: int, log=print):
    """Output-error refinement (:func:`nifo_core.predict.refine.refine_model`) on the first ``periods`` periods of the
    identification levels, from rest, scored as the study scores (2-15 Hz, period average, first period dropped)."""
    from nifo_core.predict.refine import refine_model

    return refine_model(model, _first(full, ids, periods), linear=linear, **_SCORED)


#: the refinement scored as the study scores: 2-15 Hz, period average, the first period dropped
_SCORED = dict(band_hz=ANALYSIS, period_samples=PERIOD, skip_samples=PERIOD)


def _first(full: dict, ids, periods: int) -> list:
    """The first ``periods`` periods of the identification levels (simulated from rest, as the test began)."""
    return [full[lv].slice(0, periods * PERIOD) for lv in ids]


def joint_linear(linear, full: dict, ids, periods: int):
    """The linear model's rational residues refined alone by output error (its poles kept): the linear
    baseline of :func:`joint`, on the first ``periods`` periods of the identification levels (a Refinement)."""
    from nifo_core.predict.refine import refine_model

    return refine_model(linear, _first(full, ids, periods), linear_residues=True, max_iterations=40, **_SCORED)


def joint(model, lin, full: dict, ids, periods: int, log=print):
    """The linear part identified jointly with the terms by output error (``--joint``):
    :func:`nifo_core.predict.refine.refine_jointly` on ``lin`` (:func:`joint_linear`) and the first ``periods``
    periods of the identification levels, scored as the study scores. Returns the refined nonlinear model."""
    from nifo_core.predict.refine import refine_jointly

    t0 = time.perf_counter()
    nl = refine_jointly(model, lin, _first(full, ids, periods), **_SCORED)
    log(f"  joint output error on {periods} periods of {'/'.join(map(str, ids))}: {nl.message} "
        f"[{time.perf_counter() - t0:.0f}s]")
    return nl.model


def path_row(linear, spec, steady: dict, full: dict, ids, row: dict, sweeps: dict | None) -> dict:
    """The terms of ``spec`` through their own feedback paths on ``linear``'s poles (``--paths``,
    :func:`nifo_core.predict.feedback_paths.path_model`): fitted on the steady periods of the identification levels, the
    ridge chosen on their prediction from rest (scored as the study scores); a row (source "paths")."""
    from nifo_core.predict.feedback_paths import path_model

    t0 = time.perf_counter()
    prow = {**row, "source": "paths", "nmse": {}, "errors": {}, "sweep": {}}
    try:
        res = path_model(linear, [make_term(t) for t in spec], [steady[lv] for lv in ids], [full[lv] for lv in ids],
                         period_samples=PERIOD, skip_samples=PERIOD)
    except NifoError as err:
        prow["errors"]["identify"] = str(err)
        prow["seconds"] = time.perf_counter() - t0
        return prow
    prow["paths"] = res.to_dict()
    prow["linear_order"] = int(res.model.linear.order)
    predict_levels(res.model, full, prow, sweeps)
    prow["seconds"] = time.perf_counter() - t0
    prow["model"] = res.model
    return prow


def study(data: Path, out: Path | None, *, sets: dict, forms: dict, linear_parts: dict, sources=("static",),
          log=print, partial: Path | None = None, refine_periods: int = 0, joint_periods: int = 0,
          paths: bool = False) -> list[dict]:
    """Identify and predict every (set, linear part, form, source); rows of results (``partial``: JSON after each).

    ``refine_periods`` > 0: every nonlinear model is also refined (output error) on that many periods of its
    identification levels and predicted again (row ``source`` + " refined"). ``paths``: every nonlinear form also
    through its own feedback paths on the linear model's poles (:func:`path_row`, source "paths").
    ``joint_periods`` > 0: also the
    linear part identified jointly with the terms (:func:`joint`; rows with source "joint": the linear model
    of that procedure and the nonlinear one).
    """
    steady = {lv: load(lv, data, skip=1) for lv in LEVELS}      # identification: periods 2-9
    full = {lv: load(lv, data, skip=0) for lv in LEVELS}        # prediction: the whole record, from rest
    sweeps = {lv: load_sweep(lv, data) for lv in LEVELS}        # the second excitation: validation only
    linear_models, joint_linears = {}, {}
    rows = []
    for set_name, ids in sets.items():
        for lp_name, order in linear_parts.items():
            for form_name, spec in {"linear": [], **forms}.items():
                for source in (sources if spec else ("static",)):
                    t0 = time.perf_counter()
                    row = {"set": set_name, "identified_on": list(ids), "linear_part": lp_name, "form": form_name,
                           "source": source, "nmse": {}, "errors": {}}
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        try:
                            res = identify_nifo([steady[lv] for lv in ids], [make_term(t) for t in spec],
                                                settings=SETTINGS, band=BAND, analysis_band_hz=ANALYSIS)
                            model = IdentifiedModel.from_nifo(res, source=source, order=order)
                            if not spec:
                                linear_models[(set_name, lp_name)] = model
                        except NifoError as err:
                            row["errors"]["identify"] = str(err)
                            rows.append(row)
                            log(f"{set_name:14} {lp_name:11} {form_name:28} {source:6} identify failed: {err}")
                            continue
                    row["linear_part_reason"] = model.linear.reason
                    row["linear_order"] = int(model.linear.order)
                    row["c_over_m2"] = [float(v) for v in model.c_over_m2]
                    if out is not None:
                        d = out / f"{set_name.split()[0].replace('/', '')}_{lp_name.replace(' ', '')}_" \
                                  f"{form_name.split()[0]}{len(spec)}_{source}"
                        d.mkdir(parents=True, exist_ok=True)
                        write_model(d / "model.json", model)
                        row["model_json"] = str(d / "model.json")
                    predict_levels(model, full, row, sweeps)
                    row["seconds"] = time.perf_counter() - t0
                    rows.append(row)
                    log(f"{set_name:14} {lp_name:11} {form_name:28} {source:6} {_levels(row)}"
                        f"   [{model.linear.kind} {model.linear.order}] {row['seconds']:.0f}s")
                    if partial is not None:
                        partial.write_text(json.dumps({"rows": rows}, indent=1, default=str))
                    if paths and spec and (set_name, lp_name) in linear_models \
                            and all(t["kind"] in PATH_KINDS for t in spec):
                        prow = path_row(linear_models[(set_name, lp_name)], spec, steady, full, ids, row, sweeps)
                        rows.append(prow)
                        log(f"{set_name:14} {lp_name:11} {form_name:28} {'paths':6} {_levels(prow)}"
                            f"   [ridge {prow.get('paths', {}).get('ridge', float('nan')):g}] {prow['seconds']:.0f}s")
                        if out is not None and "model" in prow:
                            write_model(Path(row["model_json"]).with_name("model_paths.json"), prow.pop("model"))
                        prow.pop("model", None)
                    if joint_periods and spec:
                        todo = []
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            if (set_name, lp_name) not in joint_linears:     # once per set and linear part
                                joint_linears[(set_name, lp_name)] = joint_linear(
                                    linear_models[(set_name, lp_name)], full, ids, joint_periods)
                                todo.append(("linear", joint_linears[(set_name, lp_name)].model))
                            todo.append((form_name, joint(model, joint_linears[(set_name, lp_name)], full, ids,
                                                          joint_periods, log=log)))
                        for name, m in todo:
                            jrow = {**row, "form": name, "source": "joint", "nmse": {}, "errors": {}, "sweep": {}}
                            predict_levels(m, full, jrow, sweeps)
                            rows.append(jrow)
                            log(f"{set_name:14} {lp_name:11} {name:28} {'joint':6} {_levels(jrow)}")
                    if refine_periods and spec:
                        t0 = time.perf_counter()
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            ref = refine(model, linear_models.get((set_name, lp_name)), full, ids, refine_periods)
                        rrow = {**row, "source": source + " refined", "nmse": {}, "errors": {}, "sweep": {},
                                "refinement": ref.to_dict()}
                        predict_levels(ref.model, full, rrow, sweeps)
                        rrow["seconds"] = time.perf_counter() - t0
                        rows.append(rrow)
                        log(f"{set_name:14} {lp_name:11} {form_name:28} {'refined':6} {_levels(rrow)}"
                            f"   [from the {ref.start} start] {rrow['seconds']:.0f}s")
                        if out is not None:
                            write_model(Path(row["model_json"]).with_name("model_refined.json"), ref.model)
    return rows


def verdicts(rows: list[dict]) -> list[dict]:
    """Per (set, linear part, form, source): is the nonlinear NMSE below the linear one at every predicted level?"""
    base = {(r["set"], r["linear_part"], r["source"] == "joint"): r for r in rows if r["form"] == "linear"}
    out = []
    for r in rows:
        if r["form"] == "linear" or not r["nmse"]:
            continue
        lin = base.get((r["set"], r["linear_part"], r["source"] == "joint"))
        held = [lv for lv in LEVELS if lv not in r["identified_on"]]
        pred = [lv for lv in LEVELS]
        better = {lv: (lv in r["nmse"] and lv in lin["nmse"] and r["nmse"][lv] < lin["nmse"][lv]) for lv in pred}
        out.append({"set": r["set"], "linear_part": r["linear_part"], "form": r["form"], "source": r["source"],
                    "better_at_every_level": all(better.values()),
                    "better_at_held_out": all(better[lv] for lv in held),
                    "ratio": {lv: (lin["nmse"][lv] / r["nmse"][lv]) if lv in r["nmse"] and lv in lin["nmse"]
                              else None for lv in pred},
                    **_sweep_verdict(r, lin)})
    return out


def _sweep_verdict(row: dict, lin: dict | None) -> dict:
    """Better than ``lin`` on the sine sweep at every level (None: ``row`` or ``lin`` has no sweep score, or
    ``lin`` lacks a level), and the ratios; a level the row could not predict counts as not better."""
    a, b = row.get("sweep") or {}, (lin or {}).get("sweep") or {}
    if not a or any(lv not in b for lv in LEVELS):
        return {"sweep_better_at_every_level": None, "sweep_ratio": {}}
    return {"sweep_better_at_every_level": all(lv in a and lv in b and a[lv] < b[lv] for lv in LEVELS),
            "sweep_ratio": {lv: b[lv] / a[lv] if lv in a and lv in b else None for lv in LEVELS}}


def select(rows: list[dict], *, strict: bool = False) -> list[dict]:
    """Per set, the model chosen on the identification levels alone, and how it predicts the held-out ones.

    A candidate (any nonlinear row) qualifies when it predicts every identification level better than its
    linear baseline: the linear model of its own procedure (the library's for NIFO and refined rows, the
    linear model refined the same way for joint rows), or with ``strict`` at each level the better of all
    the set's linear models. Of those the one with the widest margin (largest smallest ratio) is kept; none
    qualifying keeps the linear model (the better one on the identification levels). The held-out levels
    play no part in the choice: they score it.
    """
    out = []
    for set_name, lp in dict.fromkeys((r["set"], r["linear_part"]) for r in rows):
        mine = [r for r in rows if (r["set"], r["linear_part"]) == (set_name, lp)]
        ids = mine[0]["identified_on"]
        held = [lv for lv in LEVELS if lv not in ids]
        linears = {r["source"] == "joint": r for r in mine if r["form"] == "linear"}
        floor = {lv: min(r["nmse"].get(lv, np.inf) for r in linears.values()) for lv in LEVELS}

        def baseline(r):
            own = linears.get(r["source"] == "joint")
            return floor if strict else (own["nmse"] if own is not None else None)

        best, margin = None, 1.0
        for r in mine:
            b = baseline(r)
            if r["form"] == "linear" or b is None or any(lv not in r["nmse"] or lv not in b for lv in LEVELS):
                continue
            m = min(b[lv] / r["nmse"][lv] for lv in ids)
            if m > margin:
                best, margin = r, m
        chosen = best or min(linears.values(), key=lambda r: sum(r["nmse"][lv] for lv in ids))
        b = baseline(chosen)
        own = linears.get(chosen["source"] == "joint")
        sweep_floor = {lv: min(r.get("sweep", {}).get(lv, np.inf) for r in linears.values()) for lv in LEVELS}
        sweep_floor = {lv: v for lv, v in sweep_floor.items() if np.isfinite(v)}
        out.append({"set": set_name, "linear_part": lp, "form": chosen["form"], "source": chosen["source"],
                    "strict": strict, "sweep": chosen.get("sweep") or {},
                    **_sweep_verdict(chosen, {"sweep": sweep_floor} if strict else own),
                    "margin": margin, "nmse": chosen["nmse"], "baseline": b,
                    "held_out_better": {lv: best is not None and chosen["nmse"][lv] < b[lv] for lv in held},
                    "every_level_better": best is not None and all(chosen["nmse"][lv] < b[lv] for lv in LEVELS)})
    return out


def _print_selection(rows: list[dict]) -> list[dict]:
    sel = []
    for strict, what in ((False, "the linear model of its own procedure"),
                         (True, "at each level the better of the set's linear models")):
        print(f"\nchosen on the identification levels alone: beats {what} at each by the widest margin (none: "
              "the linear model); NMSE [%] chosen | baseline:")
        for s in select(rows, strict=strict):
            held = ", ".join(f"L{lv} {'yes' if ok else 'no'}" for lv, ok in s["held_out_better"].items())
            print(f"  {s['set']:14} {s['form']:24} {s['source']:15} "
                  + " ".join(f"L{lv} {s['nmse'][lv]:.3f}|{s['baseline'][lv]:.3f}" for lv in LEVELS)
                  + f"   held out better: {held}; every level: {'yes' if s['every_level_better'] else 'no'}"
                  + ("" if s["sweep_better_at_every_level"] is None else
                     "; sweep " + " ".join(f"L{lv} {v:.3f}" for lv, v in s["sweep"].items())
                     + f", better at every sweep level: {'yes' if s['sweep_better_at_every_level'] else 'no'}"))
            sel.append(s)
    return sel


def _rows_from(paths: list[Path]) -> list[dict]:
    """Rows of earlier ``--json`` files (levels back to int), the later file's row winning on a repeat."""
    rows = {}
    for p in paths:
        for r in json.loads(p.read_text())["rows"]:
            r = {**r, "nmse": {int(k): v for k, v in r["nmse"].items()},
                 "sweep": {int(k): v for k, v in (r.get("sweep") or {}).items()}}
            rows[(r["set"], r["linear_part"], r["form"], r["source"])] = r
    return list(rows.values())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--out", type=Path, default=None, help="write every model.json under this directory")
    ap.add_argument("--json", type=Path, default=None, help="write all rows and verdicts here")
    ap.add_argument("--sets", nargs="+", default=None, choices=[k.split()[0] for k in SETS], metavar="SET",
                    help=f"only these identification sets ({', '.join(k.split()[0] for k in SETS)})")
    ap.add_argument("--quick", action="store_true", help="3/5/7 only, backlash and clearance 0.02 mm, auto linear part")
    ap.add_argument("--free", action="store_true", help="also per-line (free) coefficients")
    ap.add_argument("--all", action="store_true", help="also backlash + friction")
    ap.add_argument("--extra", action="store_true", help="the softening forms instead (saturation, velocity "
                    "saturation, backlash + velocity saturation)")
    ap.add_argument("--plays", action="store_true", help="the multi-play forms instead (two or three plays of "
                    "different widths: a discrete Iwan model)")
    ap.add_argument("--joint", type=int, default=0, metavar="PERIODS",
                    help="also identify the linear part jointly with the terms by output error on this many periods "
                         "(its residues; compared with the linear model refined the same way)")
    ap.add_argument("--paths", action="store_true",
                    help="also every form with backlash/clearance/saturation terms through its own feedback paths on "
                         "the linear model's poles (nifo identify --feedback-paths)")
    ap.add_argument("--order", type=int, default=None, help="a rational linear part of this order for every model")
    ap.add_argument("--refine", type=int, default=0, metavar="PERIODS",
                    help="also refine every nonlinear model (output error) on this many periods of its levels")
    ap.add_argument("--select", type=Path, nargs="+", default=None, metavar="JSON",
                    help="no new run: the choice on the identification levels (and its held-out score) from the "
                         "rows of earlier --json files")
    args = ap.parse_args(argv)
    if args.select:
        _print_selection(_rows_from(args.select))
        return 0
    sets, forms, lps = SETS, FORMS, {"auto": None}
    if args.quick:
        sets = {"3/5/7": SETS["3/5/7"]}
        forms = {k: FORMS[k] for k in ("clearance 0.02 mm", "backlash 0.14 mm")}
        lps = {"auto": None}
    if args.sets:
        sets = {k: v for k, v in sets.items() if k.split()[0] in args.sets}
    print(f"NMSE [%] of the period-averaged steady state, 2-15 Hz lines; levels {LEVELS}; | sweep: the sine sweeps' "
          "2-15 Hz band-passed NMSE [%] (validation only)")
    sources = ("static", "free") if args.free else ("static",)
    if args.order:   # a fixed rational order instead of the library's selection
        lps = {f"rational {args.order}": args.order}
    if not args.all:
        forms = {k: v for k, v in forms.items() if k != "backlash 0.14 mm + friction"}
    if args.extra:
        forms = EXTRA
    if args.plays:
        forms = PLAYS
    rows = study(args.data, args.out, sets=sets, forms=forms, linear_parts=lps, sources=sources,
                 partial=args.json, refine_periods=args.refine, joint_periods=args.joint, paths=args.paths)
    ver = verdicts(rows)
    print("\nnonlinear below linear (same set, same linear part) at every level / at the held-out levels:")
    for v in ver:
        print(f"  {v['set']:14} {v['linear_part']:11} {v['form']:28} {v['source']:6} "
              f"{'yes' if v['better_at_every_level'] else 'no ':>4} / {'yes' if v['better_at_held_out'] else 'no'}   "
              + " ".join(f"L{lv} {r:5.2f}x" if r else f"L{lv}   n/a" for lv, r in v["ratio"].items())
              + ("" if v["sweep_better_at_every_level"] is None else
                 f"   sweep: {'yes' if v['sweep_better_at_every_level'] else 'no'} "
                 + " ".join(f"L{lv} {r:5.2f}x" if r else f"L{lv}   n/a" for lv, r in v["sweep_ratio"].items())))
    sel = _print_selection(rows)
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "verdicts": ver, "selection": sel}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
