#!/usr/bin/env python
"""Silverbox multilevel: identify at one level with the measured input, predict every other level.

Data: Noël & Schoukens, "Grey-box state-space identification of nonlinear
mechanical vibrations", Int. J. Control 91(5), 2018, doi 10.1080/00207179.2017.1308557
(``../shared/data/silverbox_multilevel``). An electronic circuit that behaves
as m·ÿ + d·ẏ + (a + b·y²)·y = u: input u (``um``, V) and output y (``ym``, V, a
displacement analogue) in separate files; 30 periods × 8192 samples of one
random-phase multisine (bins 1..1007, 0.3-300 Hz) at 2441.4 Hz, five levels
(5, 20, 50, 100, 150 mV RMS). Published: 68.58 Hz, 4.68 % damping at the low level.

Everything runs through the CLI, as a user would (``nifo identify``, ``nifo predict``):

    --columns body_disp=ym,force=um@{name:_ym_=_um_},spindle_accel=fixed
    --skip-periods 5 --period-samples 8192

(the output is a displacement: differentiated exactly for whole periods; the
input comes from the partner file; the spindle does not exist: a single mass
driven by the force). Model files: ``cubic_stiffness`` (the nonlinearity
``nifo characterize`` ranks first on these data) and, for the baseline, no
nonlinearity (the linear model identified on the same level).
Spectral settings: one period per block, boxcar, no overlap (leakage-free);
integration band 1-900 Hz, analysis band 5-250 Hz.

Two metrics per predicted level:

- ``nifo predict``'s band NMSE of the body acceleration over 5-250 Hz (period-averaged, what the CLI prints
  beside the whole signal);
- the benchmark's output: NMSE of the displacement y on the period-averaged
  steady state (the transient periods and the model's first period dropped,
  mean removed: DC is neither excited nor identified), from the same model and
  engine (:func:`nifo_core.predict.model.predict_body`). Beside it the best linear
  baseline there is: the non-parametric FRF measured at the identification
  level applied line by line (exact for periodic data).

Run: ``python tools/silverbox.py [--data DIR] [--identify-at 150 50] [--img docs/img/silverbox] [--json out.json]``
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nifo.cli import main as nifo  # noqa: E402
from nifo.io.loader import load_record  # noqa: E402
from nifo.io.results import read_model  # noqa: E402
from nifo_core.predict.model import predict_body  # noqa: E402
from nifo_core.signal.record import Record  # noqa: E402

DATA = Path(os.environ.get("NIFO_SHARED_DATA", ROOT.parent / "shared" / "data")) / "silverbox_multilevel"
LEVELS = (5, 20, 50, 100, 150)
PERIOD = 8192
SKIP = 5
COLUMNS = "body_disp=ym,force=um@{name:_ym_=_um_},spindle_accel=fixed"
SETTINGS = "settings: {block: 8192, overlap: 0.0, window: boxcar, band_hz: [1.0, 900.0], freq_range_hz: [5, 250]}\n"
MODELS = {"cubic": "nifo_model: 1\nnonlinearities:\n  - {kind: cubic_stiffness}\n" + SETTINGS,
          "linear": "nifo_model: 1\nnonlinearities: []\n" + SETTINGS}
PUBLISHED = {"natural_frequency_hz": 68.58, "damping_ratio": 0.0468}


def ym_file(data: Path, level: int) -> Path:
    return data / f"SNJP_ym_full_FNSI_{level}.mat"


def cli(*args: str) -> str:
    """Run one ``nifo`` command in-process; its printed output (a failing exit code raises)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = nifo([str(a) for a in args])
    if code != 0:
        raise SystemExit(f"nifo {' '.join(map(str, args))} exited {code}:\n{buf.getvalue()}")
    return buf.getvalue()


def identify(data: Path, level: int, kind: str, work: Path) -> Path:
    spec = work / f"{kind}.yaml"
    spec.write_text(MODELS[kind])
    out = work / f"identify_{kind}_{level}"
    cli("identify", ym_file(data, level), "--model", spec, "--out", out, "--columns", COLUMNS,
        "--skip-periods", SKIP, "--period-samples", PERIOD, "--no-plots", "--quiet")
    return out


def predict(data: Path, model_dir: Path, work: Path) -> dict[int, float]:
    """``nifo predict`` on every level: {level: band NMSE of the body acceleration over 5-250 Hz [%]}."""
    out = work / f"predict_{model_dir.name}"
    cli("predict", *[ym_file(data, lv) for lv in LEVELS], "--model", model_dir, "--out", out, "--columns", COLUMNS,
        "--skip-periods", SKIP, "--period-samples", PERIOD, "--no-plots", "--freq-range", 5, 250)
    doc = json.loads((out / "predict.json").read_text())
    by_name = {r["name"]: r for r in doc["records"]}
    return {lv: float(by_name[ym_file(data, lv).name]["model"]["band_nmse"]["percent"]) for lv in LEVELS}


def displacement(rec: Record) -> np.ndarray:
    """y from the record's acceleration (exact for whole periods; DC set to zero)."""
    w = 2 * np.pi * np.fft.rfftfreq(rec.n, 1 / rec.fs_hz)
    a = np.fft.rfft(rec.body_accel)
    a[1:] /= -(w[1:] ** 2)
    a[0] = 0.0
    return np.fft.irfft(a, rec.n)


def period_average(x: np.ndarray, *, drop: int = 1) -> np.ndarray:
    """Mean over the whole periods after the first ``drop`` (mean removed)."""
    p = np.asarray(x)[drop * PERIOD:]
    p = p[:p.size // PERIOD * PERIOD].reshape(-1, PERIOD).mean(axis=0)
    return p - p.mean()


def nmse(y: np.ndarray, yhat: np.ndarray) -> float:
    return float(100 * np.mean((y - yhat) ** 2) / np.var(y))


def predicted_displacement(model_dir: Path, rec: Record) -> np.ndarray:
    model, _ = read_model(model_dir)
    p = predict_body(model, None, rec.fs_hz, force=rec.force - rec.force.mean(), label=rec.source)
    return period_average(p.z)


def bla(rec_id: Record, rec: Record) -> np.ndarray:
    """The FRF measured at the identification level (period-averaged, line by line) applied to ``rec``'s input."""
    u_id = np.fft.rfft(period_average(rec_id.force, drop=0))
    y_id = np.fft.rfft(period_average(displacement(rec_id), drop=0))
    ok = np.abs(u_id) > 1e-6 * np.abs(u_id).max()              # the excited lines
    g = np.where(ok, y_id / np.where(ok, u_id, 1), 0)
    return np.fft.irfft(g * np.fft.rfft(period_average(rec.force, drop=0)), PERIOD)


def run(data: Path, identify_at: list[int], work: Path) -> dict:
    t0 = time.perf_counter()
    recs = {lv: load_record(ym_file(data, lv), columns=dict(kv.split("=", 1) for kv in COLUMNS.split(",")),
                            skip_periods=SKIP, period_samples=PERIOD) for lv in LEVELS}
    out: dict = {"published": PUBLISHED, "levels_mv": list(LEVELS)}
    # the linear part at the lowest level
    lin5 = json.loads((identify(data, LEVELS[0], "linear", work) / "identify.json").read_text())["summary"]["force"]
    out["linear_part_5mv"] = {k: lin5[k] for k in ("natural_frequency_hz", "damping_ratio", "one_mass_misfit")}
    out["identified"] = {}
    for lid in identify_at:
        row: dict = {}
        for kind in ("cubic", "linear"):
            mdir = identify(data, lid, kind, work)
            summ = json.loads((mdir / "identify.json").read_text())["summary"]["force"]
            cli_nmse = predict(data, mdir, work)
            disp = {}
            for lv in LEVELS:
                y = period_average(displacement(recs[lv]))
                disp[lv] = nmse(y, predicted_displacement(mdir, recs[lv]))
            row[kind] = {"linear_part": {k: summ[k] for k in ("natural_frequency_hz", "damping_ratio",
                                                              "one_mass_misfit", "m2_kg", "c")},
                         "nmse_accel_cli": cli_nmse, "nmse_disp": disp, "model_dir": str(mdir)}
            print(f"identified at {lid} mV, {kind}: {summ['natural_frequency_hz']:.3f} Hz, "
                  f"{100 * summ['damping_ratio']:.3f} %", flush=True)
        row["bla_nmse_disp"] = {lv: nmse(period_average(displacement(recs[lv])), bla(recs[lid], recs[lv]))
                                for lv in LEVELS}
        out["identified"][lid] = row
    out["seconds"] = time.perf_counter() - t0
    return out


def table(res: dict) -> str:
    lp = res["linear_part_5mv"]
    pub = res["published"]
    lines = [f"linear part at 5 mV: {lp['natural_frequency_hz']:.3f} Hz "
             f"({100 * (lp['natural_frequency_hz'] / pub['natural_frequency_hz'] - 1):+.2f} % from "
             f"{pub['natural_frequency_hz']}), damping {100 * lp['damping_ratio']:.3f} % "
             f"({100 * (lp['damping_ratio'] / pub['damping_ratio'] - 1):+.2f} % from {100 * pub['damping_ratio']:.2f} %)"]
    for lid, row in res["identified"].items():
        c, li = row["cubic"], row["linear"]
        lines.append(f"\nidentified at {lid} mV (cubic model: {c['linear_part']['natural_frequency_hz']:.3f} Hz, "
                     f"{100 * c['linear_part']['damping_ratio']:.3f} %)")
        lines.append(f"{'level':>6} | {'accel NMSE % (nifo predict)':^34} | {'displacement NMSE %, period-averaged':^44}")
        lines.append(f"{'mV':>6} | {'cubic':>9} {'linear':>9} {'ratio':>7}       | {'cubic':>9} {'linear':>9} "
                     f"{'ratio':>7} {'FRF(BLA)':>9}")
        for lv in res["levels_mv"]:
            a_c, a_l = c["nmse_accel_cli"][lv], li["nmse_accel_cli"][lv]
            d_c, d_l, d_b = c["nmse_disp"][lv], li["nmse_disp"][lv], row["bla_nmse_disp"][lv]
            mark = " (id)" if lv == lid else ""
            lines.append(f"{lv:>6} | {a_c:9.3f} {a_l:9.2f} {a_l / a_c:6.1f}x{mark:>6} | {d_c:9.3f} {d_l:9.2f} "
                         f"{d_l / d_c:6.1f}x {d_b:9.2f}")
    return "\n".join(lines)


def figures(res: dict, data: Path, img: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    img.mkdir(parents=True, exist_ok=True)
    written = []
    lids = list(res["identified"])
    fig, axes = plt.subplots(1, len(lids), figsize=(5.2 * len(lids), 4.0), squeeze=False, sharey=True)
    for ax, lid in zip(axes[0], lids):
        row = res["identified"][lid]
        lv = res["levels_mv"]
        for key, lab, st in (("cubic", "cubic model (nifo predict)", "o-"), ("linear", "linear model, same level", "s--")):
            ax.semilogy(lv, [row[key]["nmse_disp"][v] for v in lv], st, label=f"{lab}: y")
            ax.semilogy(lv, [row[key]["nmse_accel_cli"][v] for v in lv], st, alpha=0.45, label=f"{lab}: ÿ")
        other = [v for v in lv if v != lid]
        ax.semilogy(other, [row["bla_nmse_disp"][v] for v in other], "k:", label="measured FRF of that level: y")
        ax.axvline(lid, color="0.6", lw=0.8)
        ax.set_xlabel("excitation level [mV RMS]")
        ax.set_title(f"identified at {lid} mV")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("NMSE [%]")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=3, frameon=False)
    fig.suptitle("Silverbox: prediction of every level from one (Noël & Schoukens 2018 data)", fontsize=10)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    p = img / "nmse_by_level.png"
    fig.savefig(p, dpi=150)
    plt.close(fig)
    written.append(p)

    # one period at the highest held-out level: measured y and both predictions
    lid = lids[0]
    show = max(lv for lv in LEVELS if lv != lid)
    rec = load_record(ym_file(data, show), columns=dict(kv.split("=", 1) for kv in COLUMNS.split(",")),
                      skip_periods=SKIP, period_samples=PERIOD)
    y = period_average(displacement(rec))
    t = np.arange(PERIOD) / rec.fs_hz
    fig, (a0, a1) = plt.subplots(2, 1, figsize=(9, 5.5))
    sl = slice(int(1.0 * rec.fs_hz), int(1.25 * rec.fs_hz))
    for key, lab, col in (("cubic", "cubic model", "C3"), ("linear", "linear model", "C0")):
        yh = predicted_displacement(Path(res["identified"][lid][key]["model_dir"]), rec)
        a0.plot(t[sl], yh[sl], color=col, lw=1.0, label=f"{lab} identified at {lid} mV")
        a1.plot(t, yh - y, color=col, lw=0.5, label=f"{lab}: error")
    a0.plot(t[sl], y[sl], "k", lw=1.4, alpha=0.6, label="measured")
    a0.set_ylabel("y [V]")
    a0.set_title(f"{show} mV (held out), period-averaged steady state: detail 1.0-1.25 s", fontsize=9)
    a0.set_xlabel("time in the period [s]")
    a0.legend(fontsize=7)
    a1.set_ylabel("prediction error [V]")
    a1.set_xlabel("time in the period [s] (whole period)")
    a1.legend(fontsize=7)
    for a in (a0, a1):
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    p = img / f"time_{show}mv.png"
    fig.savefig(p, dpi=150)
    plt.close(fig)
    written.append(p)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--identify-at", type=int, nargs="+", default=[150, 50], choices=LEVELS)
    ap.add_argument("--img", type=Path, default=None, help="write the figures here (e.g. docs/img/silverbox)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--work", type=Path, default=None, help="keep the identify/predict outputs here")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="nifo-silverbox-") as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        res = run(args.data, args.identify_at, work)
        print(table(res))
        if args.img:
            for p in figures(res, args.data, args.img):
                print(f"wrote {p}")
        if args.json:
            args.json.write_text(json.dumps(res, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
