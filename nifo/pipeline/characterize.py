"""The characterize step (``nifo characterize``, ``nifo run``): restoring-force plots and an automatic characterization.

Reads each DATA file (several files = several excitation levels), integrates
ẍ2 - ẍ1 in one band, ranks the describing functions of the library by how much
of the restoring force they explain beyond a linear strut
(:mod:`nifo_core.characterize.automatic`) and writes, atomically, to DIR:

- ``characterize.json``   ranked candidates with parameters, scores and confidence,
                          the suggested model, the band and a per-file summary;
- ``suggested_model.yaml`` a model file ``nifo identify`` accepts;
- ``restoring_frequency*.png`` frequency slices of sweeps (paper Fig. 3);
- ``restoring_amplitude.png`` amplitude slices: one row per file, or amplitude bins
                          of one random record (paper Fig. 4);
- ``characteristic.png``  the nonlinear part of the force against z or ż, per term;
- ``ranking.png``         every kind's score against the threshold.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Callable

import numpy as np

from nifo.io.atomic import check_output, staged_dir
from nifo.plots import DRAWING
from nifo.plots.writer import figure_batch
from nifo.io.loader import input_options, load_record
from nifo.io.names import file_stems, record_labels
from nifo.io.modelfile import write_model_spec
from nifo.io.provenance import input_provenance, system_of, true_strut_model
from nifo.io.results import write_json
from nifo.pipeline.options import CharacterizeOptions
from nifo.progress import Progress
from nifo.settings import for_records, loader_options, resolve
from nifo_core import __version__
from nifo_core.characterize.automatic import Characterization, DEFAULT_KINDS, FittedModel, Thresholds, characterize_restoring
from nifo_core.errors import ConfigError
from nifo_core.settings import AnalysisSettings
from nifo_core.signal.integrate import band_for_records
from nifo_core.characterize.restoring import (FrequencyTrack, RestoringForce, amplitude_slices, frequency_slices, restoring_force,
                                 suggest_band, track_frequency)


def run_characterize(args: CharacterizeOptions, *, settings: AnalysisSettings | None = None,
                     echo: Callable[[str], None] = print, show_progress: bool = True) -> dict:
    """The step (module docstring); what it reports goes to ``echo`` (``nifo run`` collects the lines of steps it
    runs side by side and prints them in order), its progress bar only with ``show_progress``. ``settings``: the
    job's, resolved once (``nifo run``), taken on these records; None: resolved here."""
    # before any work: a file, a foreign folder or one holding an input of the command is refused
    check_output(args.out, reads=args.data)
    paths = [Path(p) for p in args.data]
    settings = (resolve(paths, args, opts=input_options(args)) if settings is None else
                for_records(settings, paths, opts=input_options(args), from_data=not args.no_settings_from_data))
    opts = loader_options(input_options(args), settings)
    records = [load_record(p, **opts, centred=True) for p in args.data]   # offsets of any size alike
    rates = {r.fs_hz for r in records}
    band = band_for_records(settings.band or suggest_band(records).band, records)
    kinds = tuple(k.strip() for k in args.kinds.split(",")) if args.kinds else DEFAULT_KINDS
    thresholds = Thresholds(min_err=args.min_err, min_err_cv=min(Thresholds.min_err_cv, args.min_err / 2))
    if args.top < 1 or args.amplitude_bins < 1:
        raise ConfigError("--top and --amplitude-bins must be at least 1")
    rfs = [restoring_force(r, band=band) for r in records]
    tracks = [track_frequency(rf.spindle_accel, rf.fs_hz) for rf in rfs]
    masks = None
    if args.freq_window:
        lo, hi = args.freq_window
        if not 0 < lo < hi:
            raise ConfigError(f"--freq-window {lo:g} {hi:g} must satisfy 0 < LO < HI")
        masks = [(t.freq_hz >= lo) & (t.freq_hz <= hi) for t in tracks]
    with Progress(1.0, "characterize") if show_progress else contextlib.nullcontext() as prog:
        last = [0.0]

        def step(frac: float) -> None:
            if prog is not None:
                prog.advance(frac - last[0])
            last[0] = frac

        char = characterize_restoring(rfs, m2_kg=args.m2, kinds=kinds, thresholds=thresholds, grid_points=args.grid,
                                      max_terms=args.max_terms, masks=masks, progress=step)
    with staged_dir(args.out) as tmp, figure_batch():   # figures rendered by helpers, all written before the commit
        with DRAWING:                                     # matplotlib: one thread at a time
            figures = _figures(tmp, args, rfs, tracks, masks, char)
        doc = _document(args, records, rfs, tracks, char, figures, band_source=_band_source(settings))
        doc["settings"] = settings.to_dict()
        write_json(tmp / "characterize.json", doc, atomic=False, indent=2)
        write_model_spec(tmp / "suggested_model.yaml", char.suggested_terms,
                         settings={"integration_band_hz": [band.f_lo_hz, band.f_hi_hz]},
                         note=_model_note(char), suggested_by=f"nifo characterize {__version__}")
    echo(_table(char, args.top, [str(p) for p in args.data], len(rates) > 1))
    echo(f"wrote {args.out}/ (characterize.json, suggested_model.yaml, {', '.join(figures)})")
    return {"out": str(args.out), "band_hz": [band.f_lo_hz, band.f_hi_hz], "nothing_found": char.nothing_found,
            "suggested": [c.term.label for c in char.suggested], "figures": figures}


def _band_source(settings) -> dict:
    c = settings.choices.get("band")
    return {"chosen_by": c.source if c else "default", "reason": c.reason if c else ""}


# ---------------------------------------------------------------------------------------------
# figures
# ---------------------------------------------------------------------------------------------
def _model_force(char: Characterization, rf: RestoringForce) -> np.ndarray | None:
    if char.model is None:
        return None
    return char.model.force(rf.z, rf.zdot, fs_hz=rf.fs_hz, band=rf.band)


def _default_centres(track: FrequencyTrack) -> list[float]:
    lo, hi = track.range_hz
    lo = max(lo, 0.5)
    return [round(float(f), 1) for f in lo + (hi - lo) * np.array([0.2, 0.4, 0.6, 0.85])]


def _short(label: str) -> str:
    """A record's label without the file's suffix (``day1/rec.csv`` -> ``day1/rec``)."""
    return label.removesuffix(Path(label).suffix) or label


def _figures(out: Path, args, rfs: list[RestoringForce], tracks: list[FrequencyTrack], masks, char) -> list[str]:
    from nifo.plots.restoring import (CharacteristicPlot, SlicePlot, plot_characteristics, plot_ranking,
                                      plot_restoring_slices)

    names = [_short(label) for label in record_labels(args.data)]    # unique where two records share a name
    stems = file_stems(names)
    written: list[str] = []
    models = [_model_force(char, rf) for rf in rfs]
    units = system_of(args)["units"]
    fitted = ("fitted model: linear + " + " + ".join(_label(t, units) for t in char.suggested_terms) if char.suggested
              else "fitted model: linear only (nothing nonlinear found)")
    if args.freq_window:
        fitted += f" (fitted on {args.freq_window[0]:g}-{args.freq_window[1]:g} Hz, drawn there only)"

    def model_at(i: int, idx: np.ndarray):
        """The model along the slice, if the slice lies (mostly) where the model was fitted."""
        if models[i] is None or (masks is not None and masks[i] is not None and masks[i][idx].mean() < 0.5):
            return None
        return models[i][idx]

    band = f"band {char.band.f_lo_hz:g}-{char.band.f_hi_hz:g} Hz"
    # frequency slices of each sweep (paper Fig. 3)
    sweeps = [i for i, t in enumerate(tracks) if t.is_sweep or args.slices_hz]
    for i in sweeps:
        centres = args.slices_hz or _default_centres(tracks[i])
        sl = frequency_slices(rfs[i], centres, inst_freq_hz=tracks[i].freq_hz)
        if not sl:
            continue
        rows = [SlicePlot(s.label, rfs[i].z[s.index], rfs[i].zdot[s.index], rfs[i].force[s.index],
                          model_at(i, s.index), True,
                          f"z peak {1e3 * np.max(np.abs(rfs[i].z[s.index])):.3g} mm") for s in sl]
        fname = "restoring_frequency.png" if len(sweeps) == 1 else f"restoring_frequency_{i + 1}_{stems[i]}.png"
        plot_restoring_slices(rows, out / fname, title=f"{names[i]}: restoring force by frequency ({band})",
                              m2_kg=args.m2, subtitle=fitted,
                              units=system_of(args)["units"])
        written.append(fname)
    # amplitude slices (paper Fig. 4): one row per file, or bins of one random record
    rows = []
    if len(rfs) > 1:
        fc = (args.slices_hz or [None])[0]
        if fc is None and args.freq_window:
            fc = 0.5 * sum(args.freq_window)
        for i, rf in enumerate(rfs):
            if fc is not None and tracks[i].is_sweep:
                sl = frequency_slices(rf, [fc], inst_freq_hz=tracks[i].freq_hz)
                if not sl:
                    continue
                idx, label, conn = sl[0].index, f"{names[i]} at {fc:g} Hz", True
            else:
                idx, label, conn = np.arange(rf.n), names[i], tracks[i].is_sweep
            rows.append(SlicePlot(label, rf.z[idx], rf.zdot[idx], rf.force[idx], model_at(i, idx), conn,
                                  f"z RMS {1e3 * np.std(rf.z[idx]):.3g} mm"))
    elif not tracks[0].is_sweep:
        for s in amplitude_slices(rfs[0], args.amplitude_bins):
            rows.append(SlicePlot(s.label, rfs[0].z[s.index], rfs[0].zdot[s.index], rfs[0].force[s.index],
                                  model_at(0, s.index), False))
    if rows:
        plot_restoring_slices(rows, out / "restoring_amplitude.png",
                              title=f"restoring force by amplitude ({band})", m2_kg=args.m2, subtitle=fitted,
                              units=system_of(args)["units"])
        written.append("restoring_amplitude.png")
    # characteristics of the suggested terms (or, if none, of the two best candidates)
    truths = [true_strut_model(p) for p in args.data]   # simulated data: the truth file beside each
    panels = _characteristics(char, rfs, masks, CharacteristicPlot,
                              truths=truths if all(t is not None for t in truths) else None)
    if panels:
        what = "suggested terms" if char.suggested else "best candidates (below threshold: not present)"
        plot_characteristics(panels, out / "characteristic.png", title=f"stiffness and damping characteristics: {what}",
                             m2_kg=args.m2, units=system_of(args)["units"])
        written.append("characteristic.png")
    cands = char.to_dict()["candidates"]
    plot_ranking(cands, out / "ranking.png", min_err=char.thresholds.min_err, units=system_of(args)["units"],
                 title="each kind's best form: suggested terms first (scored given the ones above), "
                       "then the rest by the variance they explain beyond linear")
    written.append("ranking.png")
    return written


def _characteristics(char: Characterization, rfs, masks, CharacteristicPlot, *, truths=None) -> list:
    """A stiffness and/or damping characteristic of the suggested model (one panel per variable its terms
    act on); with nothing suggested, of the best candidate fitted alone."""
    if char.suggested:
        return _panels_for(char.model, char, rfs, masks, CharacteristicPlot, truths=truths)
    c = char.candidates[0]
    m = FittedModel(char.linear["k_per_kg"], char.linear["c_per_kg"], ((c.term, c.theta),), char.linear["r2"])
    return _panels_for(m, char, rfs, masks, CharacteristicPlot, extra=" (best candidate, not present)",
                       truths=truths)


def _own_parts(model, rf) -> dict:
    """Each variable's part of ``model``'s force along ``rf``'s motion: k·z + its z-terms, c·ż + its ż-terms."""
    _, per = model.contributions(rf.z, rf.zdot, fs_hz=rf.fs_hz, band=rf.band)
    on = {v: sum((per[j] for j, (t, _) in enumerate(model.terms) if t.variable == v), np.zeros(rf.n))
          for v in ("z", "zdot")}
    return {"z": model.k_per_kg * rf.z + on["z"], "zdot": model.c_per_kg * rf.zdot + on["zdot"]}


def _panels_for(model, char: Characterization, rfs, masks, CharacteristicPlot, extra: str = "", *,
                truths=None) -> list:
    """Per variable (z, ż): data = -ẍ2 minus the other variable's fitted part; fitted = this variable's part;
    with ``truths`` (one true model per record, simulated data) the true part of that variable too."""
    variables = [v for v in ("z", "zdot") if any(t.variable == v for t, _ in model.terms)]
    parts = {v: ([], [], [], [], [], []) for v in variables}  # x, measured, fitted, split, reference, truth
    for i, rf in enumerate(rfs):
        sel = np.ones(rf.n, bool) if masks is None or masks[i] is None else masks[i]
        own = _own_parts(model, rf)
        true = _own_parts(truths[i], rf) if truths else None
        ref = {"z": char.linear["k_per_kg"] * rf.z, "zdot": char.linear["c_per_kg"] * rf.zdot}
        for v in variables:
            other = "zdot" if v == "z" else "z"
            xs, meas, fit, split, refs, tru = parts[v]
            xs.append((rf.z if v == "z" else rf.zdot)[sel])
            meas.append((rf.force - own[other])[sel])
            fit.append(own[v][sel])
            split.append(rf.zdot[sel])
            refs.append(ref[v][sel])
            if true is not None:
                tru.append(true[v][sel])
    out = []
    for v in variables:
        xs, meas, fit, split, refs = (np.concatenate(a) for a in parts[v][:5])
        tru = np.concatenate(parts[v][5]) if parts[v][5] else None
        terms = [f"{_label(t)},\nθ={th:.3g} ({t.spec.coef_unit})/kg" for t, th in model.terms if t.variable == v]
        what = "stiffness" if v == "z" else "damping"
        title = f"{what}: linear + " + "\n+ ".join(terms) + extra
        out.append(CharacteristicPlot(title, v, xs, meas, fit, split if v == "z" else None, refs, tru))
    return out


def _label(t, units: str = "m/s²") -> str:
    from nifo.plots.restoring import term_label

    return term_label(t.kind, dict(t.params), units=units)


# ---------------------------------------------------------------------------------------------
# text and JSON
# ---------------------------------------------------------------------------------------------


def _document(args, records, rfs, tracks, char: Characterization, figures, *, band_source: dict) -> dict:
    doc = {"nifo_characterize": 1, "nifo_version": __version__, "inputs": [str(p) for p in args.data],
           "band_choice": band_source, "freq_window_hz": args.freq_window, "figures": figures, **char.to_dict(),
           "input": input_provenance(args), "system": system_of(args)}
    for rec_doc, path, tr, rec in zip(doc["records"], args.data, tracks, records):
        rec_doc["path"] = str(path)
        if rec.meta.get("integrity_note"):   # a bag whose chunks carry no CRC: said once, here
            rec_doc["integrity_note"] = rec.meta["integrity_note"]
        rec_doc["sweep"] = {"detected": tr.is_sweep, "range_hz": list(tr.range_hz),
                            "reliable_fraction": tr.reliable_fraction, "trend": tr.trend}
    return doc


def _model_note(char: Characterization) -> str:
    if char.nothing_found:
        return "nifo characterize found no nonlinearity above its thresholds: a linear strut (plain H1) suffices"
    return ("suggested by nifo characterize: " + "; ".join(f"{c.term.label}: {c.describe()}" for c in char.suggested)
            + "".join(f". Ambiguity: {a.text()}" for a in char.ambiguities))


def _fmt_coef(c, m2: float | None) -> str:
    unit = c.term.spec.coef_unit
    hw = c.theta_half_width * (m2 or 1.0)
    pm = f" ± {hw:.2g}" if np.isfinite(hw) else ""
    if m2:
        return f"{c.coefficient:.4g}{pm} {unit}"
    return f"{c.theta:.4g}{pm} ({unit})/kg"


def _table(char: Characterization, top: int, paths: list[str], mixed_rates: bool) -> str:
    lines = [f"characterized {len(paths)} file(s) in band {char.band.f_lo_hz:g}-{char.band.f_hi_hz:g} Hz; "
             f"linear fit R² {char.linear['r2']:.4f}",
             f"{'#':>2}  {'candidate':<44} {'coefficient ± 95 %':>26}  {'ERR':>7} {'ERR_cv':>7} {'p':>8} {'spread':>6}  status",
             "    (suggested terms first, each scored given all the other suggested ones; then the rest, ranked alone)"]
    shown = [c for i, c in enumerate(char.candidates) if i < top or c.status == "suggested"]
    for i, c in enumerate(shown, 1):
        spread = f"{c.spread:6.2f}" if np.isfinite(c.spread) else "     -"
        status = c.status + (f" (≈ {c.alternative_to})" if c.alternative_to else "")
        lines.append(f"{i:>2}  {c.term.label[:44]:<44} {_fmt_coef(c, char.m2_kg):>26}  {c.err:7.4f} {c.err_cv:7.4f} "
                     f"{c.p_value:8.1e} {spread}  {status}")
    if char.nothing_found:
        lines.append("nothing nonlinear found: no candidate met the thresholds "
                     f"(ERR ≥ {char.thresholds.min_err:g}, held-out ERR ≥ {char.thresholds.min_err_cv:g}, "
                     f"p < {char.thresholds.alpha:g}, spread ≤ {char.thresholds.max_spread:g})")
    else:
        lines.append("suggested model: " + "; ".join(f"{c.term.label} ({c.describe()})" for c in char.suggested))
    lines += [f"ambiguity: {a.text()}." for a in char.ambiguities]
    lines += [f"note: {n}" for n in char.notes if not n.startswith("no nonlinear candidate")]
    if mixed_rates:
        lines.append("note: the files have different sample rates")
    return "\n".join(lines)

