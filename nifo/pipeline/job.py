"""The whole job (``nifo run [DATA...] [--out DIR]``) — characterize, identify, predict, loop, report, recording.

With no DATA, the bundled sample (``bags/sample/*``: a simulated quarter car
at three road levels). Steps, each into its own subdirectory of ``--out``
(default ``results/``), by calling the steps' functions of :mod:`nifo.pipeline` with typed options
(:mod:`nifo.pipeline.options`: each step's own command-line defaults, and this job's input and settings options):

0. the settings, chosen once from the data where not given (the excitation's period and transient, the
   excited band, blocks, integration band: :mod:`nifo.settings`), printed with their reasons and passed to
   every step;
1. ``characterize/``  restoring-force plots and the suggested model (all DATA as levels);
2. ``identify/``      NIFO with the suggested model on every level (several levels that call for it: the
   paper's two-step model), then the output-error refinement of its coefficients, kept when it predicts a
   held-out part no worse (``nifo identify --refine``; ``--no-refine``: NIFO's equation-error values);
3. ``loop/``          from the linear model, what the data need: terms added while the held-out prediction
   improves, with the model class ``nifo identify`` writes (``nifo loop``): the run's final model,
   ``loop/model.json``;
4. ``predict/``       the final model and the linear model of the same data on every record;
5. ``report/report.html``  the self-contained HTML report of all of the above;
6. ``recording/nifo.rrd``  the Rerun recording (``rerun results/recording/nifo.rrd``), written on a thread
   beside the report.

Independent work runs side by side on threads (``NIFO_THREADS=1``: one after the other, the same results): the
two-step model's lowest and highest level, the report and the recording.
"""

from __future__ import annotations

import contextvars
import importlib
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import yaml

from nifo.io.atomic import check_output, claim, staged_run
from nifo.io.loader import input_options
from nifo.io.memo import reuse_reads
from nifo.plots.writer import deferred_figures, start_helpers, wait_figures
from nifo.io.modelfile import load_model_spec
from nifo.pipeline.characterize import run_characterize
from nifo.pipeline.identify import run_identify
from nifo.pipeline.options import CharacterizeOptions, IdentifyOptions, LoopOptions, PredictOptions, RunOptions
from nifo.pipeline.predict import run_predict
from nifo.settings import explain, resolve
from nifo.viz.report_html import write_report
from nifo.viz.results import read_results
from nifo_core.errors import NifoError
from nifo_core.settings import AnalysisSettings
from nifo_core.signal.parallel import max_threads

__all__ = ["run_job", "loop_available"]


def _banner(step: int, total: int, text: str) -> None:
    print(f"\n== [{step}/{total}] {text}", flush=True)


def _levels(char_dir: Path, data: list[Path]) -> list[Path]:
    """DATA ordered by excitation level (RMS of the relative displacement z from characterize.json)."""
    recs = json.loads((char_dir / "characterize.json").read_text()).get("records", [])
    rms = {str(r.get("path")): float(r.get("z_rms_m") or 0.0) for r in recs}
    return sorted(data, key=lambda p: rms.get(str(p), 0.0))


def _two_step_model(ordered: list[Path], char_dir: Path, given: RunOptions, settings: AnalysisSettings
                    ) -> tuple[Path, str] | None:
    """The paper's two-step model (§3.3) when the levels call for it, else None.

    The lowest and the highest level are characterized alone. The terms the
    highest level suggests are identified on every level but the lowest (step 2);
    the terms the lowest suggests on a different variable (a play in z where the
    high level shows a damper knee in ż) are identified first on the lowest level,
    where the high level's terms hardly act (step 1). Writes the model file
    ``two_step_model.yaml`` beside characterize/ and returns it with one line
    naming both steps.
    """
    base = char_dir.parent / "characterize_levels"
    levels = (("lowest", ordered[0]), ("highest", ordered[-1]))

    def one(level: tuple[str, Path]) -> list[str]:
        lines: list[str] = []
        run_characterize(CharacterizeOptions(data=[str(level[1])], out=base / level[0]).taking(given),
                         settings=settings, echo=lines.append, show_progress=False)
        return lines

    # the two levels side by side on threads (independent steps into their own folders; each thread in a copy of
    # this one's context: the job's read memo and deferred figures), their reports printed in order afterwards;
    # leaving the pool waits for both, so a failed or interrupted one leaves nothing writing behind it. Started beside
    # the main characterization instead (on a thread, the sample's order of levels known in advance): no gain, the step
    # GIL-bound (measured 2026-12-07, the sample, two runs each: characterize 7.5-7.8 s and 13.2-13.4 CPU-s against
    # 6.3-7.8 s and 9.7-12.0 CPU-s; benchmarks/cpu_timeline.py)
    with ThreadPoolExecutor(min(2, max_threads())) as pool:
        futures = [pool.submit(contextvars.copy_context().run, one, level) for level in levels]
        reports = [f.result() for f in futures]
    for lines in reports:
        print("\n".join(lines))
    suggested = {name: load_model_spec(base / name / "suggested_model.yaml").terms for name, _ in levels}
    high = list(suggested["highest"])
    variables = {t.variable for t in high}
    low = [t for t in suggested["lowest"] if t.variable not in variables and t.kind not in {h.kind for h in high}]
    if not high or not low:
        return None
    doc = {"nifo_model": 1, "suggested_by": "nifo run (two-step from the levels)",
           "steps": [{"name": f"{', '.join(t.kind for t in low)} on the lowest level",
                      "nonlinearities": [t.to_dict() for t in low], "data": [str(ordered[0].resolve())]},
                     {"name": f"{', '.join(t.kind for t in high)} on the higher level(s)",
                      "nonlinearities": [t.to_dict() for t in high],
                      "data": [str(p.resolve()) for p in ordered[1:]]}]}
    path = base / "two_step_model.yaml"
    claim(path)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    text = (f"step 1: {' + '.join(t.label for t in low)} on {ordered[0].name} (the lowest level); step 2: "
            f"{' + '.join(t.label for t in high)} on {', '.join(p.name for p in ordered[1:])}")
    return path, text


def _record(read, rrd: Path) -> None:
    from nifo.viz.offline import save_recording   # rerun (a second to import) only when a recording is asked for

    save_recording(read, rrd)


def loop_available() -> bool:
    """Whether the loop step (``nifo loop``) is part of this build (an optional part: imported by name)."""
    try:
        importlib.import_module("nifo.pipeline.loop")
    except ModuleNotFoundError as err:
        if err.name in ("nifo.pipeline.loop", "nifo_core.loop.closing"):
            return False
        raise
    return True


def run_job(args: RunOptions) -> dict:
    """The whole job on ``args.data`` into ``args.out`` (module docstring); a summary of what was written."""
    data = [Path(p) for p in args.data]
    check_output(args.out, reads=data)   # a file, a foreign folder or one holding a record: refused before any work
    start_helpers()      # the figure helpers import matplotlib while the settings are chosen
    # all old or all new: the old --out is kept aside until the run succeeds (INCOMPLETE marks a killed run)
    # the steps read the same files: each file is probed and read once (nifo.io.memo); a step's figures render
    # while the next steps compute (the run's folder is complete only at the end): waited for before the report
    with staged_run(args.out) as out, reuse_reads(), deferred_figures():
        return _run(args, data, out)


def _read_as_chosen(args: RunOptions, st: AnalysisSettings) -> RunOptions:
    """``args`` with the period and transient the job chose as its input options: they are also how the records are
    read, and every step records its input options (``"input"`` of its JSON) for whoever reads the records again
    (the report, the viewer: :func:`nifo.io.provenance.reader_options`). The settings themselves travel as ``st``."""
    if args.period_samples is not None or not st.period_samples:
        return args
    chosen = {"period_samples": st.period_samples}
    if args.skip_periods is None and args.skip_seconds is None:
        chosen["skip_periods"] = st.skip_periods
    return replace(args, **chosen)


def _run(args: RunOptions, data: list[Path], out: Path) -> dict:
    """The steps of the module docstring in order, each timed; the summary :func:`run` returns. Long because it
    is the job's script, one step after the other, read top to bottom."""
    t0 = time.monotonic()
    dirs = {k: out / k for k in ("characterize", "identify", "predict", "loop", "report", "recording")}
    do_loop = not args.no_loop and loop_available()
    total = 5 + (1 if do_loop else 0) + (0 if args.no_recording else 1)
    step, timings, notes, failed = 0, {}, [], None

    def begin(text: str) -> float:
        nonlocal step
        step += 1
        _banner(step, total, text)
        return time.monotonic()

    t = begin(f"settings from the data of {len(data)} record(s)")
    st = resolve(data, args, opts=input_options(args))
    print("\n".join("  " + line for line in st.describe()))
    args = _read_as_chosen(args, st)
    timings["settings"] = time.monotonic() - t

    t = begin(f"characterize {len(data)} record(s): restoring force, suggested model")
    run_characterize(CharacterizeOptions(data=[*map(str, data)], out=dirs["characterize"]).taking(args),
                     settings=st)
    model = dirs["characterize"] / "suggested_model.yaml"
    ordered = _levels(dirs["characterize"], data)

    two = _two_step_model(ordered, dirs["characterize"], args, st) if len(ordered) >= 2 else None
    timings["characterize"] = time.monotonic() - t     # with the lowest and highest level alone
    # identify's output-error refinement on the first 60 s of each record, unless --no-refine
    refine = {} if args.no_refine else {"refine": True, "refine_seconds": 60.0}
    if two is not None:
        model, text = two
        t = begin(f"identify (NIFO) in two steps: {text}")
        print(text)
        run_identify(IdentifyOptions(data=[], model=Path(model), out=dirs["identify"], **refine).taking(args),
                     settings=st)
        notes.append(f"Two-step model chosen from the data: {text}")
    else:
        t = begin(f"identify (NIFO) on {', '.join(p.name for p in ordered)} with the suggested model")
        run_identify(IdentifyOptions(data=[Path(p) for p in ordered], model=Path(model), out=dirs["identify"],
                                     **refine).taking(args), settings=st)
    timings["identify"] = time.monotonic() - t

    results = [dirs["characterize"], dirs["identify"]]
    final = dirs["identify"]
    if do_loop:
        t = begin("loop: from the linear model, what the data need; error before and after")
        try:
            run_loop = importlib.import_module("nifo.pipeline.loop").run_loop
            run_loop(LoopOptions(data=[*map(str, ordered)], out=dirs["loop"], no_refine=not refine).taking(args),
                     settings=st)
            results.append(dirs["loop"])
            if (dirs["loop"] / "model.json").is_file():
                final = dirs["loop"]
        except NifoError as err:   # the report still shows everything else; the exit code says it failed
            err = explain(err)
            print(f"nifo run: loop failed: {err}", file=sys.stderr)
            notes.append(f"The loop step failed: {err}")
            failed = err
        timings["loop"] = time.monotonic() - t
    elif not args.no_loop:
        notes.append("nifo loop is not available in this build: the loop step was skipped.")
        print("nifo run: nifo loop is not available in this build: skipped", file=sys.stderr)

    if (final / "model.json").is_file():
        t = begin(f"predict every record with the final model ({final.name}/model.json) and the linear model of "
                  f"the same data")
        run_predict(PredictOptions(data=[Path(p) for p in ordered], model=Path(final), out=dirs["predict"])
                    .taking(args), settings=st)
        timings["predict"] = time.monotonic() - t
        results.append(dirs["predict"])
    else:
        why = (f"no model.json in {final.name}/ (no linear part could be fitted; see its warnings): the predict "
               f"step was skipped")
        notes.append(why[0].upper() + why[1:] + ".")
        print(f"nifo run: {why}", file=sys.stderr)
        total -= 1

    wait_figures()      # the report reads the steps' figures
    read = read_results(results)
    rrd = dirs["recording"] / "nifo.rrd"
    # the report and the recording read the same results into their own folders: side by side (the recording on a
    # thread in a copy of this context; leaving the pool waits for it, so a failed report leaves nothing writing)
    side = not args.no_recording and max_threads() >= 2
    with ThreadPoolExecutor(1) as pool:
        recording = pool.submit(contextvars.copy_context().run, _record, read, rrd) if side else None
        t = begin("report: one self-contained HTML file")
        report = write_report(read, dirs["report"] / "report.html",
                              title="nifo run: " + ", ".join(p.name for p in data),
                              notes=notes, recording=None if args.no_recording else str(rrd))
        timings["report"] = time.monotonic() - t
        if not args.no_recording:
            t = begin("recording: Rerun .rrd with the live layout")
            if recording is not None:
                recording.result()
            else:
                _record(read, rrd)
            timings["recording"] = time.monotonic() - t

    took = time.monotonic() - t0
    print(f"\nnifo run finished in {took:.0f} s (" + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + ")")
    print("results:")
    for r in read:
        print(f"  {r.kind:<13} {r.path}/")
    print(f"  {'report':<13} {report}   <- open in a browser")
    if not args.no_recording:
        print(f"  {'recording':<13} {rrd}   <- rerun {rrd}")
    return {"out": str(out), "took_s": took, "timings_s": timings, "notes": notes, "report": str(report),
            "final_model": str(final / "model.json"), "settings": st.to_dict(),
            "recording": None if args.no_recording else str(rrd), "results": {r.kind: str(r.path) for r in read},
            "exit_code": 0 if failed is None else failed.exit_code}
