"""The identify step (``nifo identify``, ``nifo run``): NIFO on the records, refined by output error on request.

Its parts: stream records into NIFO accumulators and merge them, check what is usable, summarise, write.

Shared by ``nifo identify``, ``nifo run``, the fleet's tasks (:mod:`nifo.fleet.tasks`) and the benchmarks, so a
group of bags in the fleet and the same files given to ``nifo identify`` give the same coefficients.
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from nifo.io.atomic import check_output, staged_dir
from nifo.plots.writer import figure_batch
from nifo.io.loader import input_options, iter_record_chunks, load_records
from nifo.io.names import record_labels
from nifo.io.modelfile import load_model_spec
from nifo.io.provenance import input_provenance, system_of, true_t21
from nifo.io.results import IDENTIFY_JSON, MODEL_JSON, data_entry, identify_document, write_json, write_model
from nifo.pipeline.options import CHUNK_SAMPLES, IdentifyOptions
from nifo.pipeline.refine import fit_feedback_paths, refine, with_scope
from nifo.progress import Progress
from nifo.settings import for_records, loader_options, resolve
from nifo_core.errors import ConfigError, IllConditionedError, InputError, NifoError, RecordTooShortError
from nifo_core.signal.frf import h1
from nifo_core.predict.vector_fit import RecordLines
from nifo_core.predict.model import IdentifiedModel
from nifo_core.nifo.engine import IdentifySetup, RecordProbe, accumulate_record
from nifo_core.nifo.identify import IllConditionedWarning, identify_two_step
from nifo_core.nifo.summary import summarize
from nifo_core.settings import AnalysisSettings
from nifo_core.signal.spectral import cross_spectra

__all__ = ["CHUNK_SAMPLES", "accumulate", "format_summary", "write_figures", "run_identify"]


# ---------------------------------------------------------------------------------------------
# single step: streamed and merged
# ---------------------------------------------------------------------------------------------
def accumulate(paths: list[Path], terms, cfg: AnalysisSettings, *, opts: dict, chunk_samples: int = CHUNK_SAMPLES,
               quiet: bool = False):
    """Stream every file into its own accumulator and merge them, through the core's engine
    (:mod:`nifo_core.nifo.engine`, which the fleet, the node and the viewer use too).

    Returns (merged StreamingNifo, [data provenance entries], [(name, freq, plain H1) per file], each file's
    :class:`~nifo_core.predict.vector_fit.RecordLines` (None for records driven by a measured force)).
    ``opts``: the loaders' input options with the settings' period and transient
    (:func:`nifo.settings.loader_options`). The integration band, when the settings have none, is
    ``default_band(fs, shortest duration)`` as in :func:`identify_nifo`, so the answer equals it on the same records.
    """
    iters, firsts = [], []
    for p in paths:
        gen = iter_record_chunks(p, chunk_samples=chunk_samples, **opts)
        try:
            first_chunk = next(gen)
        except StopIteration:
            raise RecordTooShortError("the file holds no samples", source=str(p)) from None
        iters.append(gen)
        firsts.append(first_chunk)
    probes = [RecordProbe.of(c) for c in firsts]
    setup = IdentifySetup.for_probes(probes, terms, spectral=cfg.spectral, band=cfg.band,
                                     analysis_band_hz=cfg.analysis_band_hz, cond_limit=cfg.cond_limit,
                                     sources=[str(p) for p in paths])
    total, data, per_file, lines = None, [], [], []
    n_total = float(sum(p.n_samples for p in probes))
    # progress only for long work (a minute of data streams in well under a second)
    with Progress(n_total, "identify", enabled=not quiet and n_total / setup.fs_hz > 600) as bar:
        for p, first, gen, label in zip(paths, firsts, iters, record_labels(paths)):
            one, n = accumulate_record(_chain(first, gen), setup, source=str(p),
                                       on_chunk=lambda _acc, chunk: bar.advance(chunk.n))
            meta = dict(first.meta)
            meta.pop("chunk", None)
            data.append({**data_entry(p, fs_hz=setup.fs_hz, n_samples=n, meta=meta), "name": label})
            spec = one.spectra()
            per_file.append((label, spec.freq_hz, h1(spec, 0, 1)))
            lines.append(None if (setup.with_force or setup.spindle_fixed) else RecordLines.from_spectra(
                spec.freq_hz, spec.G[:, 0, 0], spec.G[:, 0, 1], spec.G[:, 1, 1], cfg.analysis_band_hz))
            total = one if total is None else total.merge(one)
    return total, data, per_file, (None if any(x is None for x in lines) else lines)


def _chain(first, gen):
    yield first
    yield from gen


# ---------------------------------------------------------------------------------------------
# checks and summary
# ---------------------------------------------------------------------------------------------
def format_summary(summary: dict, warn: list[str], *, out: Path, files: int, model_written: bool) -> str:
    lo, hi = summary["analysis_band_hz"]
    lines = [f"identified on {files} file(s), {summary['duration_used_s']:.1f} s used, {summary['n_avg']} spectral "
             f"averages; integration band {summary['integration_band_hz'][0]:g}-"
             f"{summary['integration_band_hz'][1]:g} Hz, analysis band {lo:g}-{hi:g} Hz"]
    if summary["terms"]:
        lines.append("pooled coefficients c/M2 (constant over the band; per-line band mean Re/Im beside):")
        for tm in summary["terms"]:
            extra = " (held fixed from step 1)" if tm["fixed"] else (
                f"   per line: {tm['per_line_mean_re']:.4g} {tm['per_line_mean_im']:+.3g}j")
            lines.append(f"  {tm['label']:<40} {tm['c_over_m2']:>11.4g} {tm['unit']}{extra}")
    else:
        lines.append("no nonlinear terms declared: T21 is the plain H1")
    d, df = summary["t21_static_vs_h1_rel_diff"], summary["t21_free_vs_static_rel_diff"]
    lines.append(f"nominal T21 vs plain H1 at this level: median {100 * d['median']:.1f} %, max {100 * d['max']:.1f} % "
                 f"apart; per-line vs pooled T21: median {100 * df['median']:.1f} %")
    if "force" in summary:
        fo = summary["force"]
        lines.append(f"measured force{' (spindle fixed)' if fo['spindle_fixed'] else ''}: one-mass body M2 = "
                     f"{fo['m2_kg']:.4g} kg, K2 = {fo['k2_n_per_m']:.4g} N/m, C2 = {fo['c2_n_s_per_m']:.4g} N·s/m "
                     f"({fo['natural_frequency_hz']:.4g} Hz, damping {100 * fo['damping_ratio']:.3g} %; misfit "
                     f"{100 * fo['one_mass_misfit']:.2g} %); coefficients c = "
                     + ", ".join(f"{c:.4g}" for c in fo["c"]) + " (unit of c)")
    lines.append(f"coherence (plain H1) median {summary['coherence_h1_median']:.3f}; scaled cond(G_UU) median "
                 f"{summary['cond_median']:.3g}, max {summary['cond_max']:.3g}")
    if "linear_part" in summary:
        lines.append(f"linear part of model.json: {summary['linear_part']['reason']}")
    lines += [f"WARNING: {w}" for w in warn]
    lines.append(f"wrote {out}/identify.json" + (", model.json" if model_written else "") + " and figures")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# figures
# ---------------------------------------------------------------------------------------------
def write_figures(out: Path, res, per_file, cond_limit: float, *, paths=(), system: dict | None = None) -> list[str]:
    from nifo.plots.nifo import plot_coefficients, plot_conditioning, plot_tire, plot_transmissibility

    f = res.freq_hz
    curves = [(f"measured H1 {name}", fq, h, {"lw": 0.9, "alpha": 0.8}) for name, fq, h in per_file]
    truth = next((t for t in (true_t21(p, f) for p in paths) if t is not None), None)
    if truth is not None:   # simulated data: the truth file beside it gives the true nominal linear T21
        curves.append(("true nominal linear T21 (simulator)", f, truth, {"color": "k", "lw": 0.9, "ls": ":"}))
    sides = ("spindle → body" if (system or {}).get("vehicle", True) else "input → output")
    if res.terms:
        curves.append(("NIFO nominal T21, per line (Eq. 9)", f, res.t21, {"color": "C0", "lw": 0.8, "ls": ":",
                                                                          "random_error": res.random_error[0],
                                                                          "bound_k": res.bound_factor()}))
        curves.append(("NIFO nominal T21, pooled (recommended), 95 % band", f, res.static.t21,
                       {"color": "C3", "lw": 1.6, "ls": "--", "random_error": res.static.random_error,
                        "bound_k": res.bound_factor(static=True)}))
    plot_transmissibility(out / "transmissibility.png", curves, band_hz=res.analysis_band_hz,
                          title=f"{sides} transmissibility: measured and NIFO nominal linear (cf. Fig. 9b/12b)")
    names = ["transmissibility.png"]
    if res.terms:
        plot_coefficients(out / "coefficients.png", res,
                          title=r"coefficient functions $\mu_i(\omega)/K_2$ (cf. paper Fig. 10/13)")
        names.append("coefficients.png")
    plot_conditioning(out / "conditioning.png", res, cond_limit=cond_limit)
    names.append("conditioning.png")
    if res.input_measured is not None:
        plot_tire(out / "tire.png", res)
        names.append("tire.png")
    return names


# ---------------------------------------------------------------------------------------------
# run
# ---------------------------------------------------------------------------------------------
def _step_paths(args, spec) -> list[list[Path]]:
    """Each step's data files (command line --step-data or the model file's), checked."""
    if len(spec.steps) != 2:
        raise ConfigError(f"the model file has {len(spec.steps)} steps; two-step identification takes exactly 2",
                          source=str(args.model), hint="merge steps or split the model file")
    if args.data:
        raise ConfigError("DATA on the command line is for single-step models; this model file has steps",
                          source=str(args.model), hint="give each step's data with --step-data PATH... (once per "
                                                       "step) or under data: in the model file")
    if args.step_data is not None and len(args.step_data) != 2:
        raise ConfigError(f"--step-data given {len(args.step_data)} time(s) for 2 steps", channel="--step-data",
                          hint="repeat --step-data once per step, in order")
    paths = [list(args.step_data[i]) if args.step_data else list(s.data) for i, s in enumerate(spec.steps)]
    for s, ps in zip(spec.steps, paths):
        if not ps:
            raise ConfigError(f"step {s.name!r} has no data", source=str(args.model),
                              hint="list data: under the step or pass --step-data")
    return paths


def _two_step(args, spec, cfg, opts):
    paths = _step_paths(args, spec)
    recs = [load_records(ps, **opts, centred=True) for ps in paths]   # offsets of any size alike
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = identify_two_step(recs[0], spec.steps[0].terms, recs[1], spec.steps[1].terms,
                                settings=cfg.spectral, band=cfg.band, analysis_band_hz=cfg.analysis_band_hz,
                                cond_limit=cfg.cond_limit, on_ill_conditioned="warn")
    per_file = []
    for r in recs[1]:
        sp = cross_spectra(np.stack([r.spindle_accel, r.body_accel]), r.fs_hz, cfg.spectral)
        per_file.append((r.source, sp.freq_hz, h1(sp, 0, 1)))
    data = {"steps": [{"name": s.name, "terms": [t.to_dict() for t in s.terms],
                       "data": [data_entry(p, r) for p, r in zip(ps, rs)]}
                      for s, ps, rs in zip(spec.steps, paths, recs)]}
    return res, data, per_file, caught


def run_identify(args: IdentifyOptions, *, settings: AnalysisSettings | None = None) -> dict:
    """``nifo identify`` (module docstring): writes identify.json, model.json and the figures into ``args.out``,
    prints the summary; the command's summary dict. ``settings``: the job's, resolved once (``nifo run``), taken on
    these records; None: resolved here (the command line > the model file's ``settings:`` > the data)."""
    # before any work: a file, a foreign folder or one holding an input of the command is refused
    check_output(args.out, reads=[*args.data, args.model])
    if getattr(args, "feedback_paths", False) and (getattr(args, "refine", False)
                                                   or getattr(args, "refine_linear", False)):
        raise ConfigError("--feedback-paths and --refine/--refine-linear are two different fits of the terms",
                          hint="give one of them")

    spec = load_model_spec(args.model)
    if args.chunk_samples < 2:
        raise ConfigError(f"--chunk-samples {args.chunk_samples!r} must be at least 2", channel="--chunk-samples")
    if not spec.two_step and not args.data:
        raise InputError("no data files given", hint="nifo identify DATA... --model MODEL.yaml --out DIR")
    all_paths = [p for ps in _step_paths(args, spec) for p in ps] if spec.two_step else list(args.data)
    cfg = (resolve(all_paths, args, file_settings=spec.settings, opts=input_options(args)) if settings is None else
           for_records(settings, all_paths, opts=input_options(args), from_data=not args.no_settings_from_data))
    opts = loader_options(input_options(args), cfg)
    if not getattr(args, "quiet", False):
        print("settings:\n  " + "\n  ".join(cfg.describe()))
    record_lines = None
    if spec.two_step:
        res, data, per_file, caught = _two_step(args, spec, cfg, opts)
        files = sum(len(s["data"]) for s in data["steps"])
    else:
        terms = spec.terms
        acc, data, per_file, record_lines = accumulate(list(args.data), terms, cfg, opts=opts,
                                                       chunk_samples=args.chunk_samples,
                                                       quiet=getattr(args, "quiet", False))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = acc.result()
        res = replace(res, provenance={**dict(res.provenance), "sources": [d["name"] for d in data]})
        files = len(data)
    try:
        res.check_usable(cfg.cond_limit,
                         periodic=bool(cfg.period_samples) and cfg.spectral.block == cfg.period_samples)
    except IllConditionedError as err:   # name the data it was identified on
        raise err.with_context(source=", ".join(str(d["path"]) for d in _entries(data))) from None
    summary, warn = summarize(res, cfg.cond_limit)
    # the core's own warnings are covered by the plain sentences above; keep any other ones verbatim
    warn += [str(w.message) for w in caught if not issubclass(w.category, IllConditionedWarning)
             and not issubclass(w.category, (DeprecationWarning, RuntimeWarning))]
    model = linear = None
    try:   # the linear part: the one-mass body where it fits, a stable rational model otherwise (says why)
        model = IdentifiedModel.from_nifo(res, source="static")
        linear = IdentifiedModel.from_nifo(res, source="h1", records=record_lines)
        summary["linear_part"] = {"kind": model.linear.kind, "order": model.linear.order,
                                  "fit_rms": model.linear.fit_rms, "reason": model.linear.reason}
    except ConfigError as err:
        warn.append(f"no model.json: no linear part could be fitted to T21 ({err.message}); "
                    "identify.json holds the non-parametric result")
        model = None
    refinement = paths = None
    refining = getattr(args, "refine", False) or getattr(args, "refine_linear", False)
    if (refining or getattr(args, "feedback_paths", False)) and model is not None:
        flag = "--feedback-paths" if getattr(args, "feedback_paths", False) else "--refine"
        if not model.terms:
            warn.append(f"{flag}: the model has no nonlinear term, nothing to fit")
        elif flag == "--feedback-paths":
            try:
                paths = fit_feedback_paths(args, linear, model.terms, opts, [d["path"] for d in _entries(data)], cfg)
            except ConfigError as err:     # not determined by these data: say so, keep the constant coefficients
                warn.append(f"--feedback-paths: {err.message}" + (f" ({err.hint})" if err.hint else "")
                            + "; model.json holds the constant-coefficient model")
                summary["feedback_paths"] = {"error": err.message}
            else:
                model = paths.model
                summary["feedback_paths"] = paths.to_dict()
                summary["linear_part"] = {"kind": model.linear.kind, "order": model.linear.order,
                                          "fit_rms": model.linear.fit_rms, "reason": model.linear.reason}
        else:
            refinement, linear_refinement, check = refine(args, model, linear, opts,
                                                          [d["path"] for d in _entries(data)])
            summary["refinement"] = {**refinement.to_dict(), "held_out": check.to_dict()}
            if check.kept:
                model = refinement.model
                if linear_refinement is not None:  # the linear baseline of the joint procedure, refined the same way
                    linear = linear_refinement.model
            if linear_refinement is not None:
                summary["refinement"]["linear"] = linear_refinement.to_dict()
    if model is not None:
        model, linear = with_scope(model, linear, opts, [d["path"] for d in _entries(data)])
        summary["prediction_band"] = model.prediction_band.to_dict()
        if model.periodic_response is not None:
            summary["periodic_response"] = model.periodic_response.to_dict()
        summary["offsets"] = model.offsets.to_dict()
    prov = {"data": data, "model_file": str(args.model), "settings": _settings_doc(cfg, res), "system": system_of(args)}
    settings_doc = _settings_doc(cfg, res)
    model_file = {"path": str(args.model), "steps": [{"name": s.name, "terms": [t.to_dict() for t in s.terms]}
                                                    for s in spec.steps]}
    with staged_dir(args.out) as tmp, figure_batch():   # figures rendered by helpers, all written before the commit
        figures = [] if args.no_plots else write_figures(tmp, res, per_file, cfg.cond_limit,
                                                         paths=[d["path"] for d in _entries(data)],
                                                         system=system_of(args))
        doc = identify_document(res, data=data, summary=summary, warnings=warn, settings=settings_doc,
                                model_file=model_file, figures=figures)
        doc.update(input=input_provenance(args), system=system_of(args), noise=_noise_doc(data, opts))
        write_json(tmp / IDENTIFY_JSON, doc, atomic=False)
        if model is not None:
            model = replace(model, provenance={**dict(model.provenance), **prov})
            linear = replace(linear, provenance={**dict(linear.provenance), **prov})
            write_model(tmp / MODEL_JSON, model, linear=linear, atomic=False)
    print(format_summary(summary, warn, out=args.out, files=files, model_written=model is not None))
    _print_fits(paths, refinement, summary, check if refinement is not None else None)
    return {"out": str(args.out), "model_written": model is not None, "figures": figures, "warnings": warn,
            "summary": summary}


def _print_fits(paths, refinement, summary: dict, check) -> None:
    """What --feedback-paths or --refine did, after the summary."""
    if paths is not None:
        print(paths.message)
        for g in paths.grid:
            nmse = g.get("held_out_nmse_percent")
            print(f"  ridge {g['ridge']:g}: " + (
                "not eligible: a regime of the terms (stuck/active) is unstable" if not g["regimes_stable"] else
                "its held-out prediction could not be scored (its model diverges there)" if nmse is None else
                f"held-out prediction NMSE {nmse:.4g} %"))
    if refinement is not None:
        if "linear" in summary["refinement"]:
            print("linear baseline: " + summary["refinement"]["linear"]["message"])
        print(refinement.message)
        for prm in refinement.parameters:
            hw = prm.get("half_width_95")
            print(f"  {prm['name']}: {prm['before']:.5g} → {prm['after']:.5g}"
                  + ("" if hw is None else f" ± {hw:.2g}") + f" {prm['unit']}")
        print(check.message)


def _noise_doc(data, opts) -> list[dict]:
    """Each record's sensor noise per channel (:mod:`nifo_core.signal.noise`): what may bias the fit (errors in
    variables), read off its spectra. A file that cannot be read again gives its reason."""
    from nifo.io.loader import load_record
    from nifo_core.signal.noise import estimate_noise

    out = []
    for d in _entries(data):
        try:
            out.append(estimate_noise(load_record(d["path"], **opts, centred=True)).to_dict())
        except NifoError as err:
            out.append({"source": d.get("name"), "available": False, "unavailable": err.message, "channels": []})
    return out


def _entries(data) -> list[dict]:
    """Data provenance entries of a single- or two-step identification."""
    return data if isinstance(data, list) else [e for s in data["steps"] for e in s["data"]]


def _settings_doc(cfg: AnalysisSettings, res) -> dict:
    return {**cfg.to_dict(), "spectral": res.settings.to_dict(),
            "integration_band_hz": [res.band.f_lo_hz, res.band.f_hi_hz], "analysis_band_hz": list(res.analysis_band_hz),
            "fs_hz": res.fs_hz}
