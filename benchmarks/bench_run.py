"""``nifo run`` against plain ``nifo identify`` of the same records with the same model (issue 29 acceptance).

In one run, as two subprocesses of this interpreter (start-up and imports counted in both):

1. ``nifo run --out DIR`` on the bundled sample (``./nifo.sh``'s job), timed;
2. ``nifo identify`` of the same three records with the model the run identified with
   (``DIR/characterize_levels/two_step_model.yaml`` when the run chose the two-step model, else
   ``DIR/characterize/suggested_model.yaml``), no refinement, timed.

Prints both times — wall clock and CPU time (user + system of the subprocess) — the job's own per-step
times and the ratio run/identify with PASS/FAIL against the acceptance: **ratio ≤ 6 and run ≤ 15 s**, for
the wall clock and for CPU time. The machine is shared: both are measured in the same run, so the ratio is
the number to compare between runs, and on a loaded machine CPU time stands for an idle machine's wall clock.

Then checks that the run gave the same model and figures as the baseline (``--baseline``, default
``benchmarks/bench_run_baseline.json``, recorded on main before a change with
``--record-baseline FILE`` or ``--from-dir OLD_RUN_DIR --record-baseline FILE``; the one committed was recorded
at 42f2e46 on 2026-11-27 with numpy 2.4.6, scipy 1.17.1, numba 0.68.1 — the first one, of 2026-11-26, no longer
matched there: the identify and loop changes since gave a two-step model with a play 0.14 % narrower): the key numbers of the
run's outputs (:func:`key_numbers`: the terms and their parameters, the coefficients and the body's k, c
of identify's refined model and of the final model, the held-out and per-record band NMSE) compared as
printed: parameters and coefficients to 3 significant digits (relative difference ≤ 5e-4), NMSE to 2
(≤ 5e-3); the largest relative difference of each group is printed.

``--serial`` also times the run on one core (no simulation threads, no figure helpers) in the same run and
checks that both give the same key numbers to the last digit.

    PYTHONPATH=. python benchmarks/bench_run.py [--serial] [--keep DIR] [--baseline FILE] [--record-baseline FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASELINE = ROOT / "benchmarks" / "bench_run_baseline.json"
MAX_RATIO, MAX_RUN_S = 6.0, 15.0
#: relative tolerance of a printed figure: 3 significant digits for parameters and coefficients, 2 for NMSE
TOL = {"parameters": 5e-4, "nmse": 5e-3}


def _cpu_children() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


#: the environment of a run on one core: no simulation threads, no figure helpers (``--serial``)
SERIAL_ENV = {"NIFO_THREADS": "1", "NIFO_FIGURE_WORKERS": "0"}


def _nifo(*args: str, env_extra: dict | None = None) -> tuple[float, float, str]:
    """Run ``python -m nifo ARGS`` in this checkout; (wall seconds, CPU seconds, stdout+stderr). Exits on failure."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""), **(env_extra or {})}
    t0, c0 = time.perf_counter(), _cpu_children()
    done = subprocess.run([sys.executable, "-m", "nifo", *args], cwd=ROOT, env=env, capture_output=True, text=True)
    took, cpu = time.perf_counter() - t0, _cpu_children() - c0
    if done.returncode != 0:
        sys.exit(f"bench_run: nifo {' '.join(args)} failed ({done.returncode}):\n{done.stdout[-3000:]}"
                 f"\n{done.stderr[-3000:]}")
    return took, cpu, done.stdout + done.stderr


def _sample() -> list[str]:
    d = ROOT / "bags" / "sample"
    return sorted(str(p) for p in d.iterdir() if p.is_dir() and (p / "metadata.yaml").is_file())


def key_numbers(run_dir: Path) -> dict:
    """The run's key figures: {'parameters': {name: value}, 'nmse': {name: value}, 'terms': {where: [labels]}}."""
    par, nmse, terms = {}, {}, {}
    ident = json.loads((run_dir / "identify" / "identify.json").read_text())
    for t in ident["summary"]["terms"]:
        par[f"identify NIFO c/M2 {t['label']}"] = t["c_over_m2"]
    ref = ident["summary"].get("refinement")
    if ref:
        for p in ref["parameters"]:
            par[f"identify refined {p['name']}"] = p["after"]
        ho = ref["held_out"]
        nmse["identify held-out NMSE NIFO"] = ho["held_out_nmse_before"]["mean_percent"]
        nmse["identify held-out NMSE refined"] = ho["held_out_nmse_after"]["mean_percent"]
    final = run_dir / ("loop" if (run_dir / "loop" / "model.json").is_file() else "identify")
    model = json.loads((final / "model.json").read_text())
    terms["final"] = [f"{t['kind']}" for t in model["terms"]]
    for t, c in zip(model["terms"], model["c_over_m2"]):
        par[f"final c/M2 {t['kind']}"] = c
        for k, v in t.get("params", {}).items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                par[f"final {t['kind']}.{k}"] = v
    body = model.get("body") or {}
    for k in ("k", "c"):
        if isinstance(body.get(k), (int, float)):
            par[f"final body {k}"] = body[k]
    loop = run_dir / "loop" / "loop.json"
    if loop.is_file():
        doc = json.loads(loop.read_text())
        terms["loop added"] = [e["kind"] for e in doc.get("effects_added", [])]
        for k in ("linear_heldout_prediction_nmse_pct", "final_heldout_prediction_nmse_pct"):
            if isinstance(doc.get(k), (int, float)):
                nmse[f"loop {k}"] = doc[k]
        after = doc.get("errors_after") or {}
        if isinstance(after.get("prediction_nmse_pct"), (int, float)):
            nmse["loop errors_after prediction NMSE"] = after["prediction_nmse_pct"]
    pred = json.loads((run_dir / "predict" / "predict.json").read_text())
    for r in pred["records"]:
        for which in ("model", "linear"):
            v = r[which]["band_nmse"]["percent"]
            if v is not None:
                nmse[f"predict {r['name']} {which} band NMSE"] = v
        nmse[f"predict {r['name']} model NMSE"] = r["model"]["whole_signal"]["nmse_percent"]
    return {"parameters": par, "nmse": nmse, "terms": terms}


def compare(now: dict, base: dict) -> tuple[bool, list[str]]:
    """Whether ``now`` gives the baseline's figures as printed, and the lines saying so."""
    ok, lines = True, []
    if now["terms"] != base["terms"]:
        ok = False
        lines.append(f"terms differ: {now['terms']} vs baseline {base['terms']}")
    else:
        lines.append(f"terms: same ({now['terms']})")
    for group, tol in TOL.items():
        worst, name = 0.0, None
        for k, b in base[group].items():
            if k not in now[group]:
                ok = False
                lines.append(f"{group}: {k} missing")
                continue
            v = now[group][k]
            rel = abs(v - b) / max(abs(b), 1e-300)
            if rel > worst:
                worst, name = rel, k
            if rel > tol:
                ok = False
                lines.append(f"{group}: {k} = {v:.6g}, baseline {b:.6g} (relative difference {rel:.2g} > {tol:g})")
        extra = sorted(set(now[group]) - set(base[group]))
        if extra:
            lines.append(f"{group}: not in the baseline (not compared): {', '.join(extra)}")
        lines.append(f"{group}: {len(base[group])} compared, largest relative difference {worst:.2g}"
                     + (f" ({name})" if name else "") + f", tolerance {tol:g}")
    return ok, lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keep", type=Path, help="write the run here and keep it (default: a temporary directory)")
    ap.add_argument("--baseline", type=Path, default=BASELINE, help=f"key numbers to compare with ({BASELINE.name})")
    ap.add_argument("--record-baseline", type=Path, help="write this run's key numbers here (on main, before a change)")
    ap.add_argument("--from-dir", type=Path, help="take the key numbers of an existing run directory; no timing")
    ap.add_argument("--serial", action="store_true",
                    help="also time the run on one core (NIFO_THREADS=1, NIFO_FIGURE_WORKERS=0) in the same run: the "
                         "gain of the threads and figure helpers, and the same numbers to the last digit")
    args = ap.parse_args(argv)
    if args.from_dir:
        keys = key_numbers(args.from_dir)
        if args.record_baseline:
            args.record_baseline.write_text(json.dumps(keys, indent=1) + "\n")
            print(f"wrote {args.record_baseline}")
        else:
            print(json.dumps(keys, indent=1))
        return 0
    with tempfile.TemporaryDirectory(prefix="nifo_bench_run_") as tmp:
        out = args.keep or Path(tmp) / "results"
        t_run, c_run, text = _nifo("run", *_sample(), "--out", str(out))
        model = out / "characterize_levels" / "two_step_model.yaml"
        which = "two-step model" if model.is_file() else "suggested model"   # named now: the folder goes
        if model.is_file():
            ident = ["--model", str(model)]
        else:
            ident = [*_sample(), "--model", str(out / "characterize" / "suggested_model.yaml")]
        t_id, c_id, _ = _nifo("identify", *ident, "--out", str(Path(tmp) / "identify_plain"))
        steps = re.search(r"nifo run finished in .*", text)
        keys = key_numbers(out)
        if args.serial:
            serial_out = Path(tmp) / "results_serial"
            t_ser, c_ser, text_ser = _nifo("run", *_sample(), "--out", str(serial_out), env_extra=SERIAL_ENV)
            steps_ser = re.search(r"nifo run finished in .*", text_ser)
            identical = key_numbers(serial_out) == keys
    load = os.getloadavg()[0]
    print(f"load average {load:.1f} on {os.cpu_count()} cores (other jobs slow the wall clock; CPU time is what "
          f"an idle machine's wall clock would be, give or take the threads)")
    print(f"plain nifo identify ({which}, no refinement): "
          f"wall {t_id:.1f} s, CPU {c_id:.1f} s")
    print(f"nifo run: wall {t_run:.1f} s, CPU {c_run:.1f} s" + (f"   [{steps.group(0)}]" if steps else ""))
    if args.serial:
        print(f"nifo run on one core (NIFO_THREADS=1, no figure helpers): wall {t_ser:.1f} s, CPU {c_ser:.1f} s"
              + (f"   [{steps_ser.group(0)}]" if steps_ser else ""))
        print(f"  wall: this run is {t_ser / t_run:.2f}x faster than on one core; key numbers "
              f"{'identical to the last digit' if identical else 'DIFFERENT'}")
    ok_time = True
    for what, r, t in (("wall", t_run / t_id, t_run), ("CPU", c_run / c_id, c_run)):
        ok = r <= MAX_RATIO and t <= MAX_RUN_S
        ok_time = ok_time and ok
        print(f"{what:>4}: ratio run/identify {r:.1f} (acceptance ≤ {MAX_RATIO:g}), run {t:.1f} s (≤ {MAX_RUN_S:g} s): "
              f"{'PASS' if ok else 'FAIL'}")
    if args.record_baseline:
        args.record_baseline.write_text(json.dumps(keys, indent=1) + "\n")
        print(f"wrote {args.record_baseline}")
        return 0 if ok_time else 1
    if not args.baseline.is_file():
        print(f"no baseline {args.baseline}: figures not compared")
        return 0 if ok_time else 1
    same, lines = compare(keys, json.loads(args.baseline.read_text()))
    print(f"same model and figures as the baseline ({args.baseline.name}): {'YES' if same else 'NO'}")
    print("\n".join("  " + ln for ln in lines))
    return 0 if ok_time and same and (not args.serial or identical) else 1


if __name__ == "__main__":
    raise SystemExit(main())
