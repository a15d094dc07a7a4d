#!/usr/bin/env python
"""The main job, hands off, on the two real structures: accuracy against the linear model of the same data, and time.

Everything runs through the command line as a user would, with only the
columns given (the period, the transient, the bands, the blocks are chosen
from the data; ``nifo.settings``):

- **F-16** ground-vibration test (Noël & Schoukens 2017, nonlinearbenchmark.org; ``../shared/data/f16``):
  leave one of the shared levels out in turn — ``nifo run`` on the other three, then ``nifo predict`` of the
  held-out level's multisine *and* its sine sweep (a second excitation, used for nothing else) with the run's
  final model (``loop/model.json``). The baseline printed beside it, measured in the same run, is the linear
  model of the same three levels that ``nifo predict`` reports from the same model.json (identified on the same
  records with the same settings). Also: ``nifo loop`` on level 1 alone (practically linear) must add nothing.
- **Silverbox** (Noël & Schoukens, IJC 2018; ``../shared/data/silverbox_multilevel``): ``nifo run`` on each level in
  turn (force and displacement columns), then ``nifo predict`` of every level: the raw RMS error in mV of the output
  as measured (the displacement, offset included), and the final model against the linear model of the same record.

Beside the band NMSE every prediction is scored as the field scores a model: the raw predicted signal over all
frequencies, offset included (``whole_signal`` in predict.json).

Prints one table per structure, writes ``--json`` and, with ``--img DIR``, the figure of docs/f16_loop.md
(``hands_off.png``; ``--replot out.json`` redraws it from a saved run). About 20 minutes on two idle cores.

    python benchmarks/bench_hands_off.py [--data ../shared/data] [--json out.json] [--img docs/img] [--f16-sets 3/5/7 ...]
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
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nifo.cli import main as nifo  # noqa: E402

DATA = Path(os.environ.get("NIFO_SHARED_DATA", ROOT.parent / "shared" / "data"))
F16_COLUMNS = "spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"
#: the multisine settings of docs/f16_predict.md (an expert's), for the second baseline: a plain linear model
F16_EXPERT = ["--period-samples", "8192", "--skip-periods", "1", "--block", "8192", "--overlap", "0", "--window",
              "boxcar", "--band", "1.5", "40", "--freq-range", "2", "15"]
SB_COLUMNS = "body_disp=ym,force=um@{name:_ym_=_um_},spindle_accel=fixed"
LEVELS = (1, 3, 5, 7)
SB_LEVELS = (5, 20, 50, 100, 150)


def cli(*args) -> int:
    """One ``nifo`` command in-process, its text swallowed; the exit code."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return nifo(["-q", *map(str, args)])


def predicted(out: Path) -> dict:
    """Per record of a predict.json: band NMSE of the model and of the linear model, and the whole signal (the raw
    predicted output over all frequencies, offset included): RMS error, NMSE and offset error of each."""
    doc = json.loads((out / "predict.json").read_text())
    return {r["name"]: {"model": r["model"]["band_nmse"]["percent"], "linear": r["linear"]["band_nmse"]["percent"],
                        "rms_model": r["model"]["whole_signal"]["rms_error"],
                        "rms_linear": r["linear"]["whole_signal"]["rms_error"],
                        "whole_nmse_model": r["model"]["whole_signal"]["nmse_percent"],
                        "whole_nmse_linear": r["linear"]["whole_signal"]["nmse_percent"],
                        "offset_model": r["model"]["whole_signal"]["offset_error"],
                        "outside": (r.get("validity") or {}).get("outside", False),
                        "band_hz": [repr(float(x)) for x in r["model"]["band_nmse"]["band_hz"]],
                        "unit": r["output"]["unit"]} for r in doc["records"]}


def f16(data: Path, tmp: Path, sets: list[str]) -> list[dict]:
    rows = []
    for s in sets:
        ids = [int(x) for x in s.split("/")]
        held = [lv for lv in LEVELS if lv not in ids]
        out = tmp / f"f16_{''.join(map(str, ids))}"
        t0 = time.perf_counter()
        code = cli("run", *[data / f"F16Data_FullMSine_Level{lv}.mat" for lv in ids], "--columns", F16_COLUMNS,
                   "--out", out, "--no-recording")
        took = time.perf_counter() - t0
        loop = json.loads((out / "loop" / "loop.json").read_text())
        row = {"set": s, "exit_code": code, "seconds": took, "added": [e["label"] for e in loop["effects_added"]],
               "verdict": loop["verdict"], "held_out": {}}
        expert = tmp / f"f16_expert_{''.join(map(str, ids))}"      # a plain linear model, an expert's settings
        (tmp / "linear.yaml").write_text("nifo_model: 1\nnonlinearities: []\n")
        cli("identify", *[data / f"F16Data_FullMSine_Level{lv}.mat" for lv in ids], "--columns", F16_COLUMNS,
            "--model", tmp / "linear.yaml", "--out", expert, "--no-plots", *F16_EXPERT)
        for lv in held:
            for exc in ("FullMSine", "SineSw"):
                p = out / f"pred_{exc}_{lv}"
                cli("predict", data / f"F16Data_{exc}_Level{lv}.mat", "--columns", F16_COLUMNS, "--model",
                    out / "loop", "--out", p)
                got = next(iter(predicted(p).values()))
                q = expert / f"pred_{exc}_{lv}"
                cli("predict", data / f"F16Data_{exc}_Level{lv}.mat", "--columns", F16_COLUMNS, "--model", expert,
                    "--out", q, "--freq-range", *got["band_hz"])
                got["expert_linear"] = next(iter(predicted(q).values()))["model"]
                row["held_out"][f"{exc} L{lv}"] = got
        rows.append(row)
        print(f"F-16 {s:8} ({took:4.0f} s) added {', '.join(row['added']) or 'nothing'}", flush=True)
        for k, v in row["held_out"].items():
            verdict = "better" if v["model"] < v["linear"] else "NOT better"
            whole = "better" if v["rms_model"] < v["rms_linear"] else "NOT better"
            print(f"    held out {k:13} whole signal RMS error {v['rms_model']:.4g} | {v['rms_linear']:.4g} m/s² "
                  f"(NMSE {v['whole_nmse_model']:.3g} | {v['whole_nmse_linear']:.3g} %, {whole}); band NMSE "
                  f"{v['model']:.4f} % | linear of the same levels {v['linear']:.4f} %"
                  f"  ({v['linear'] / v['model']:.2f}×, {verdict}) | plain linear, expert settings "
                  f"{v['expert_linear']:.4f} % ({v['expert_linear'] / v['model']:.2f}×)", flush=True)
    return rows


def f16_level1_alone(data: Path, tmp: Path) -> dict:
    out = tmp / "f16_loop_l1"
    t0 = time.perf_counter()
    cli("loop", data / "F16Data_FullMSine_Level1.mat", "--columns", F16_COLUMNS, "--out", out)
    loop = json.loads((out / "loop.json").read_text())
    row = {"added": [e["label"] for e in loop["effects_added"]], "verdict": loop["verdict"],
           "seconds": time.perf_counter() - t0}
    print(f"F-16 nifo loop on level 1 alone: added {', '.join(row['added']) or 'nothing'} "
          f"({row['seconds']:.0f} s)", flush=True)
    return row


def silverbox(data: Path, tmp: Path, level: int) -> dict:
    out = tmp / f"sb_{level}"
    t0 = time.perf_counter()
    code = cli("run", data / f"SNJP_ym_full_FNSI_{level}.mat", "--columns", SB_COLUMNS, "--out", out,
               "--no-recording")
    took = time.perf_counter() - t0
    loop = json.loads((out / "loop" / "loop.json").read_text())
    p = out / "pred"
    cli("predict", *[data / f"SNJP_ym_full_FNSI_{lv}.mat" for lv in SB_LEVELS], "--columns", SB_COLUMNS, "--model",
        out / "loop", "--out", p)
    got = predicted(p)
    added = [e["label"] for e in loop["effects_added"]] + [f"{e['term']['kind']} (by output error)"
                                                           for e in loop.get("effects_added_by_output_error", [])]
    print(f"Silverbox nifo run at {level} mV ({took:.0f} s): added {', '.join(added)}", flush=True)
    for name, v in got.items():
        print(f"    {name:28} raw RMS error {1e3 * v['rms_model']:.3f} mV (offset {1e3 * v['offset_model']:+.3f} mV) | "
              f"linear {1e3 * v['rms_linear']:.3f} mV; band NMSE {v['model']:.4f} % | linear of the same record "
              f"{v['linear']:.4f} % ({v['linear'] / v['model']:.0f}×)", flush=True)
    return {"level": level, "exit_code": code, "seconds": took, "added": added,
            "refinement": loop.get("refinement"), "predicted": got}


def _mv(name: str) -> int:
    """The level in mV of a Silverbox record's name (SNJP_ym_full_FNSI_150.mat → 150)."""
    return int(Path(name).stem.rsplit("_", 1)[-1])


def figure(doc: dict, path: Path) -> None:
    """Held-out band NMSE of the hands-off model against the two linear baselines (F-16) and the linear model of
    the same level (Silverbox), log scale, one group per held-out record."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    cases = [(f"{k.split()[1]} {'multisine' if k.startswith('Full') else 'sweep'}\nfrom {row['set']}", v)
             for row in doc["f16"] for k, v in row["held_out"].items()]
    sbs = doc["silverbox"] if isinstance(doc["silverbox"], list) else [doc["silverbox"]]
    fig, (ax, wx, bx) = plt.subplots(1, 3, figsize=(15, 4.4), gridspec_kw={"width_ratios": [len(cases), len(cases), 6]})
    x = np.arange(len(cases))
    def bars(axis, series, ylabel, title):
        width = 0.8 / len(series)
        for i, (key, label, colour) in enumerate(series):
            axis.bar(x + (i - (len(series) - 1) / 2) * width, [v[key] for _, v in cases], width, label=label,
                     color=colour)
        axis.set_xticks(x, [c for c, _ in cases], fontsize=7, rotation=35, ha="right")
        axis.set_yscale("log")
        axis.set_ylabel(ylabel)
        axis.set_title(title)
        axis.legend(fontsize=7, loc="upper left")
        axis.grid(axis="y", which="both", alpha=0.3)

    final, same = ("nifo run (final model)", "C0"), ("linear, same levels and settings", "C7")
    bars(ax, [("model", *final), ("linear", *same), ("expert_linear", "linear, an expert's settings", "C1")],
         "held-out band NMSE of ẍ₂ [%]", "F-16 GVT: band NMSE, held-out level")
    bars(wx, [("rms_model", *final), ("rms_linear", *same)], "held-out RMS error of ẍ₂, all frequencies [m/s²]",
         "F-16 GVT: the whole signal, offset included")
    for k, run in enumerate(sbs):
        pts = sorted(run["predicted"].items(), key=lambda kv: _mv(kv[0]))
        bx.plot([_mv(n) for n, _ in pts], [1e3 * v["rms_model"] for _, v in pts], "o-", color=f"C{k}",
                label=f"identified at {run['level']} mV")
        bx.plot([run["level"]], [1e3 * run["predicted"][next(n for n in run["predicted"] if _mv(n) == run["level"])]
                ["rms_model"]], "s", color=f"C{k}", ms=9, mfc="none")
    bx.set_xscale("log")
    bx.set_yscale("log")
    bx.set_xlabel("level predicted [mV RMS input]")
    bx.set_ylabel("raw RMS error of y, offset included [mV]")
    bx.set_title("Silverbox: every level from one (□ identified)")
    bx.legend(fontsize=7)
    bx.grid(which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--img", type=Path, help="directory for hands_off.png")
    ap.add_argument("--replot", type=Path, help="a --json of an earlier run: redraw the figure only")
    ap.add_argument("--f16-sets", nargs="*", default=["3/5/7", "1/3/5", "1/3/7", "1/5/7"])
    ap.add_argument("--silverbox-levels", type=int, nargs="*", default=list(SB_LEVELS),
                    help="identification levels [mV]: nifo run on each, every level predicted (the matrix of "
                         "docs/silverbox.md)")
    ap.add_argument("--skip-f16", action="store_true", help="the Silverbox matrix only (the F-16 part is slow)")
    args = ap.parse_args()
    if args.skip_f16 and args.img:
        ap.error("--img draws the F-16 panels too: not with --skip-f16")
    if args.replot:
        figure(json.loads(args.replot.read_text()), (args.img or Path(".")) / "hands_off.png")
        return 0
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        doc = {"f16": [] if args.skip_f16 else f16(args.data / "f16", tmp, args.f16_sets),
               "f16_level1_alone": None if args.skip_f16 else f16_level1_alone(args.data / "f16", tmp),
               "silverbox": [silverbox(args.data / "silverbox_multilevel", tmp, lv) for lv in args.silverbox_levels]}
    if args.json:
        args.json.write_text(json.dumps(doc, indent=1, default=str))
    if args.img:
        figure(doc, args.img / "hands_off.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
