"""The loop step (``nifo loop``, ``nifo run``): trace the residual to the effect the model lacks, add it.

Fits the declared model on the first part of each record, forms the residual
that can show what is missing (force-balance equation error, and the
prediction error on the held-out part), ranks every describing function of
the library by how much of it it explains, adds the best one that is
significant, stable, lowers the held-out error and is not a tire artefact, and
repeats (:mod:`nifo_core.loop.closing`). Writes, atomically, to DIR:

- ``loop.json``          declared model, ranked candidates of each round, effects added
                         (kind and parameters as in the library), errors before/after, verdict;
- ``model.json``         the loop's final model with its linear counterpart: ``nifo predict --model
                         DIR/model.json`` takes it directly. The equation-error fit on the fit parts,
                         refined by output error (:mod:`nifo_core.predict.refine`, ``--no-refine``: not) when the
                         refined model's held-out prediction NMSE is not worse; loop.json's
                         ``refinement`` holds both fits' parameters and held-out NMSE and says which was
                         written. Absent, with the reason in loop.json and on screen, when no predictive
                         model could be made (e.g. a non-physical one-mass fit);
- ``refined_model.yaml`` the declared model plus the added effects (``nifo identify`` reads it);
- ``loop_errors.png``    held-out NMSE and per-band residual before and after each round;
- ``loop_roundN.png``    the residual against the added effect's variable, before and after.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from nifo.io.atomic import check_output, staged_dir
from nifo.plots.writer import figure_batch, start_helpers
from nifo.io.loader import input_options, load_record
from nifo.io.modelfile import load_model_spec, write_model_spec
from nifo.io.provenance import input_provenance, system_of
from nifo.io.results import MODEL_JSON, data_entry, write_json, write_model
from nifo.pipeline.options import LoopOptions
from nifo.progress import Progress
from nifo.settings import for_records, loader_options, resolve
from nifo_core import __version__
from nifo_core.characterize.automatic import DEFAULT_KINDS, Thresholds
from nifo_core.signal.integrate import band_for_records
from nifo_core.loop.closing import close_loop
from nifo_core.loop.results import LoopResult
from nifo_core.loop.settings import LoopSettings
from nifo_core.settings import AnalysisSettings


def run_loop(args: LoopOptions, *, settings: AnalysisSettings | None = None) -> dict:
    """``nifo loop`` (module docstring). ``settings``: the job's, resolved once (``nifo run``), taken on these
    records; None: resolved here."""
    # before any work: a file, a foreign folder or one holding an input of the command is refused
    check_output(args.out, reads=[*args.data, args.model])
    start_helpers()          # the figure helpers import matplotlib while the records are read (one core busy)
    spec = load_model_spec(args.model) if args.model else None
    declared = list(spec.terms) if spec else []
    paths = [Path(p) for p in args.data]
    data = (resolve(paths, args, file_settings=spec.settings if spec else None, opts=input_options(args))
            if settings is None else
            for_records(settings, paths, opts=input_options(args), from_data=not args.no_settings_from_data))
    if not getattr(args, "quiet", False):
        print("settings:\n  " + "\n  ".join(data.describe()))
    opts = loader_options(input_options(args), data)
    opts.update(skip_periods=None, skip_seconds=None)   # whole records: simulated from rest, the transient not scored
    records = [load_record(p, **opts) for p in args.data]   # as measured: the loop removes the offsets itself
    if data.band is not None:   # an edge too low for the shortest record: refused before any work, naming it
        data = replace(data, band=band_for_records(data.band, records))
    kinds = tuple(k.strip() for k in args.kinds.split(",")) if args.kinds else DEFAULT_KINDS
    settings = LoopSettings(max_rounds=args.max_rounds, fit_fraction=args.fit_fraction, kinds=kinds,
                            grid_points=args.grid, spectral=data.spectral, analysis_band_hz=data.analysis_band_hz,
                            prediction=args.prediction, structure=args.structure, retune=not args.no_retune,
                            refine=not args.no_refine, refine_seconds=args.refine_seconds, thresholds=Thresholds())
    with Progress(1.0, "loop") as prog:
        last = [0.0]

        def step(frac: float, what: str) -> None:
            prog.desc = f"loop ({what})"
            prog.advance(max(frac - last[0], 0.0))
            last[0] = max(frac, last[0])

        res = close_loop(records, declared, m2_kg=args.m2, settings=settings, data=data, progress=step)
    doc = res.to_dict()
    doc["nifo_version"] = __version__
    doc["data"] = [str(p) for p in args.data]
    doc["model_file"] = None if args.model is None else str(args.model)
    doc.update(input=input_provenance(args), system=system_of(args), settings_chosen=data.to_dict())
    with staged_dir(args.out) as tmp, figure_batch():   # figures rendered by helpers, all written before the commit
        figures = _figures(tmp, doc, args.m2, units=doc["system"]["units"])
        doc["figures"] = figures
        write_json(tmp / "loop.json", doc, atomic=False, indent=2)
        model_settings = {"block": data.spectral.block, "overlap": data.spectral.overlap,
                          "window": data.spectral.window, "integration_band_hz": [res.band.f_lo_hz, res.band.f_hi_hz],
                          "analysis_band_hz": list(data.analysis_band_hz)}
        write_model_spec(tmp / "refined_model.yaml", res.terms, settings=model_settings,
                         note=_note(res), suggested_by=f"nifo loop {__version__}")
        written = ["loop.json", "refined_model.yaml", *figures]
        if res.model is not None:   # with the data and words it was identified on (nifo export, nifo.api)
            prov = {**dict(res.model.provenance), "data": [data_entry(p, r) for p, r in zip(args.data, records)],
                    "system": doc["system"]}
            write_model(tmp / MODEL_JSON, replace(res.model, provenance=prov), linear=res.linear_model,
                        atomic=False)
            written.insert(1, MODEL_JSON)
    print(res.report())
    if res.model is None:
        print(f"no {MODEL_JSON} written: {res.model_unavailable}")
    print(f"wrote {args.out}/ ({', '.join(written)})")
    return {"out": str(args.out), "added": [c.term.label for c in res.added], "files": written,
            "model_json": None if res.model is None else str(args.out / MODEL_JSON),
            **{k: doc[k] for k in ("errors_before", "errors_after") if k in doc}}


def _note(res: LoopResult) -> str:
    if not res.added:
        return "nifo loop: nothing significant is missing from the declared model"
    return "nifo loop added: " + ", ".join(f"{c.term.label} ({c.describe()})" for c in res.added)


def _figures(out: Path, doc: dict, m2: float | None, *, units: str = "m/s²") -> list[str]:
    from nifo.plots.loop import plot_errors, plot_round_evidence

    names = []
    plot_errors(doc, out / "loop_errors.png")
    names.append("loop_errors.png")
    for r in doc["rounds"]:
        if r.get("added") and r.get("evidence"):
            n = f"loop_round{r['round']}.png"
            plot_round_evidence(r, out / n, m2_kg=m2, units=units)
            names.append(n)
    return names


