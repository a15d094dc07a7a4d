"""The predict step (``nifo predict``, ``nifo run``): apply an identified model to other data (docs/method.md §4, paper §3.3 validation).

For each record the measured spindle acceleration (and a measured force on
the body, for a model identified with one) drives the model
(:func:`nifo_core.predict.model.predict_body`: the identified model simulated in
time, from its linear part — one-mass body or rational, as model.json says —
with the strut forces fed back), and the predicted body acceleration is
compared with the measured one:

- NMSE in time, 100·Σ(y - ŷ)²/(N·σ_y²) % over the prediction's valid part
  (start-up edges left out; below 5 % good, below 1 % excellent);
- the band NMSE, 100·Σ|Y - Ŷ|²/Σ|Y|² over the DFT lines of ``--analysis-band``
  (:mod:`nifo_core.predict.prediction_error`; the same number ``nifo identify --refine``
  minimises): after the start-up edge, or — with ``--period-samples`` — on the
  period average after the first, transient period of the prediction (the
  multisine benchmarks' convention);
- the transmissibility error |T_pred/T_meas - 1|, median and max over the
  lines of ``--analysis-band`` (default: the model's analysis band), where T is the H1 from the
  measured spindle signal to the predicted or the measured body signal, on
  the same spectral settings.

The same is done with the linear model stored beside it in model.json (the
linear model identified on the same records with the same settings), so the
gain from the nonlinear terms is explicit; the RMS error is given in the
output's unit, and every record's signals (measured, model, linear) are written
as ``<record>_signals.parquet/.csv``. A record at another sample rate than the
model's is predicted at its own rate (the model is continuous-time). A record that cannot be predicted (unreadable, or a model whose
response grows without bound at that level) is named with the reason; every
other record is still predicted and written, and the command then exits
non-zero. MODEL may be a model.json or a directory holding one (from
``nifo identify`` or ``nifo loop``). When a simulator truth file ``<DATA>.truth.json`` lies beside the
data, the model's nominal T21 is also compared with the true linear T21.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from nifo.io.atomic import check_output, staged_dir
from nifo.plots.writer import figure_batch
from nifo.io.loader import input_options, load_record
from nifo.io.names import file_stems, record_labels
from nifo.io.provenance import input_provenance, system_of
from nifo.io.results import PREDICT_JSON, read_model, write_json
from nifo.io.signals import write_signals
from nifo.io.truth import truth_for
from nifo.pipeline.options import PredictOptions
from nifo.settings import for_records, given_from_args, loader_options, resolve
from nifo_core.errors import ConfigError, InputError, MissingChannelError, NifoError, RecordTooShortError
from nifo_core.signal.frf import coherence, h1
from nifo_core.predict.model import PredictionDivergedError, predict_bodies, predict_body, record_inputs
from nifo_core.predict.output_signal import measured_output, predicted_output
from nifo_core.predict.periodic import predicts_periodic, record_periodic_response
from nifo_core.predict.whole_signal import DistortionError, distortion_error, whole_signal_error
from nifo_core.predict.prediction_bounds import Z95, half_width, line_spread, prediction_spread
from nifo_core.predict.prediction_error import band_nmse, band_spectra
from nifo_core.settings import AnalysisSettings
from nifo_core.signal.spectral import cross_spectra
from nifo_core.simulate.vehicle import QuarterCar

EXCERPT_S = 4.0


def _rel(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> dict:
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.abs(a[mask] / b[mask] - 1)
    e = e[np.isfinite(e)]
    return {"median": float(np.median(e)) if e.size else None, "max": float(np.max(e)) if e.size else None}


def _interp(f_new: np.ndarray, f: np.ndarray, h: np.ndarray) -> np.ndarray:
    h = np.where(np.isfinite(h), h, 0)
    return np.interp(f_new, f, h.real) + 1j * np.interp(f_new, f, h.imag)


def _drive(record, model) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray, str]:
    """(spindle acceleration or None, force or None, the signal the transmissibility is taken from, its name).

    A model identified with a measured force needs the force: driven by the spindle alone it predicts nothing of
    what the force did (issue 56: exit 0, band NMSE 52 % for model and linear alike)."""
    if model.force_gain > 0 and record.force is None:
        raise MissingChannelError("the model was identified with a measured force on the body, and this record has "
                                  "no force channel", channel="force",
                                  hint="give the force (--columns force=NAME, or the bag's /nifo/force topic), or "
                                       "predict with a model identified without a force")
    a1, force = record_inputs(record, model)
    if a1 is None:
        return a1, force, force, "force"
    return a1, force, a1, "spindle"


def _skip(pred, period_samples: int | None, transient: int) -> int:
    """Samples left out of the scores: the transient the settings drop, and the prediction's own start-up (one
    period of periodic data, else its start-up edge)."""
    return max(int(transient), int(period_samples) if period_samples else pred.valid.start)


def _band_nmse(a2, pred, fs: float, band_hz, period_samples: int | None, transient: int = 0) -> dict:
    """Band NMSE [%] of a prediction, or why it could not be computed."""
    skip = _skip(pred, period_samples, transient)
    how = (f"period average after the first {skip // int(period_samples)} period(s) of {period_samples} samples"
           if period_samples else f"after the first {skip} samples (start-up edge)")
    try:
        return {"percent": band_nmse(a2, pred.body_accel, fs, band_hz=tuple(band_hz), period_samples=period_samples,
                                     skip_samples=skip), "band_hz": list(band_hz), "how": how}
    except (InputError, ConfigError) as err:
        return {"percent": None, "band_hz": list(band_hz), "how": how, "not_computed": err.message}


def _whole(y: np.ndarray, yhat: np.ndarray, skip: int) -> dict:
    """The raw predicted signal's error over all frequencies, offset included, or why it could not be computed."""
    try:
        return whole_signal_error(y, yhat, skip=skip).to_dict()
    except InputError as err:
        return {"rms_error": None, "nmse_percent": None, "after_samples": int(skip), "not_computed": err.message}


def _distortion(y: np.ndarray, yhat: np.ndarray, u: np.ndarray, fs: float, band_hz, period_samples: int,
                skip: int) -> DistortionError | dict:
    """The prediction on the lines the periodic input did not excite, or why it could not be computed (a dict)."""
    try:
        return distortion_error(y, yhat, u, fs, period_samples=period_samples, band_hz=tuple(band_hz), skip=skip)
    except InputError as err:
        return {"percent_of_none": None, "not_computed": err.message}


def _not_periodic(dm: DistortionError | dict, dl: DistortionError | dict, unit: str, periodic: bool) -> str | None:
    """One sentence when the model's simulation of a periodic record is not periodic where the structure was
    (``periodic``: its prediction is its periodic response, without the wandering)."""
    if not (isinstance(dm, DistortionError) and isinstance(dl, DistortionError) and dm.not_periodic(dl)):
        return None
    return (f"the model's response is not periodic at this level: {dm.period_variation_rms:.3g} {unit} RMS from "
            f"period to period, measured {dm.measured_period_variation_rms:.3g} {unit}, its linear model "
            f"{dl.period_variation_rms:.3g} {unit} (a nonlinearity that slips or jumps on some periods and not "
            f"others: " + ("the prediction is its periodic response, its period average and the part of the linear "
                           "model's response that is not periodic; the wandering the structure does not show is "
                           "left out)" if periodic else
                           "its signal carries a wandering the structure does not show)"))


def predict_one(path: Path, record, model, linear, *, band_hz, method: str,
                period_samples: int | None = None, transient: int = 0) -> tuple[dict, dict]:
    """Numbers (JSON-able) and arrays (for the figures and the signal tables) for one record, predicted from rest
    from its first sample; ``transient`` samples at its start are left out of every score."""
    fs = record.fs_hz
    rate_note = None
    if abs(fs - model.fs_hz) > 1e-3 * model.fs_hz:
        # the model is continuous-time (a linear part in s, coefficients per unit mass): it predicts at any rate
        # whose Nyquist frequency holds the band it is scored over
        if band_hz[1] >= 0.5 * fs:
            raise InputError(f"the record is sampled at {fs:g} Hz (Nyquist {0.5 * fs:g} Hz) and the band scored, "
                             f"{band_hz[0]:g}-{band_hz[1]:g} Hz, reaches beyond it (the model was identified at "
                             f"{model.fs_hz:g} Hz)", source=str(path),
                             hint=f"give --analysis-band LO HI with HI below {0.5 * fs:g} Hz")
        rate_note = (f"predicted at the record's rate, {fs:g} Hz; the model was identified at {model.fs_hz:g} Hz "
                     f"(its parameters are continuous-time)")
    if record.n < model.settings.block:    # the transmissibility needs one block of the model's settings
        raise RecordTooShortError(f"the record has {record.n} samples ({record.duration_s:.3g} s), fewer than one "
                                  f"spectral block of the model ({model.settings.block} samples)", source=str(path),
                                  hint="predict a longer record, or give a smaller --block")
    a1, force, drive, drive_name = _drive(record, model)
    if a1 is None and force is None:
        raise InputError("the spindle is fixed and the model has no force input: nothing drives the model",
                         source=str(path), hint="predict with a model identified with the measured force")
    a2 = np.asarray(record.body_accel)
    sim = predict_body(model, a1, fs, force=force, method=method, label=str(path))
    pl = predict_body(linear, a1, fs, force=force, method=method, label=str(path))
    skip = _skip(sim, period_samples, transient)
    periodic_model = predicts_periodic(model, period_samples)
    # the model's prediction: its periodic response to a periodic input when it predicts one (model.json)
    pm = (record_periodic_response(model, record, sim, pl, period_samples=period_samples, start=skip,
                                   band_hz=tuple(band_hz)) if periodic_model else sim)
    valid = slice(max(pm.valid.start, skip), pm.valid.stop)
    if valid.stop - valid.start < model.settings.block:
        valid = pm.valid
    spec = cross_spectra(np.stack([drive[valid], a2[valid], pm.body_accel[valid], pl.body_accel[valid]]), fs,
                         model.settings)
    t_meas, t_model, t_lin = h1(spec, 0, 1), h1(spec, 0, 2), h1(spec, 0, 3)
    f = spec.freq_hz
    mask = (f >= band_hz[0]) & (f <= band_hz[1])
    measured = measured_output(record)
    y_model, y_lin = predicted_output(model, record, pm), predicted_output(linear, record, pl)
    out = {
        "path": str(path), "name": path.name, "fs_hz": fs, "n_samples": record.n, "duration_s": record.duration_s,
        "valid_samples": [valid.start, valid.stop], "n_avg": int(spec.n_avg), "transmissibility_from": drive_name,
        "output": {"name": measured.name, "unit": measured.unit},
        "model": {"whole_signal": _whole(measured.values, y_model, skip),
                  "band_nmse": _band_nmse(a2, pm, fs, band_hz, period_samples, transient),
                  "transmissibility_error": _rel(t_model, t_meas, mask), "engine": pm.method,
                  "iterations": pm.iterations, "residual": pm.residual},
        "linear": {"whole_signal": _whole(measured.values, y_lin, skip),
                   "band_nmse": _band_nmse(a2, pl, fs, band_hz, period_samples, transient),
                   "transmissibility_error": _rel(t_lin, t_meas, mask), "source": linear.source,
                   "engine": pl.method},
        "coherence_measured_median": float(np.median(coherence(spec, 0, 1)[mask])),
    }
    raw_drive = np.asarray(record.force if drive_name == "force" else record.spindle_accel, float)
    if period_samples:
        # the model's simulation as it comes beside its prediction: how much it varies from period to period is
        # said even where the prediction is its periodic response
        dist = {key: _distortion(measured.values, yh, raw_drive, fs, band_hz, period_samples, skip)
                for key, yh in (("model", y_model), ("linear", y_lin))}
        as_simulated = (_distortion(measured.values, predicted_output(model, record, sim), raw_drive, fs, band_hz,
                                    period_samples, skip) if periodic_model else dist["model"])
        for key, d in dist.items():
            out[key]["distortion"] = d.to_dict() if isinstance(d, DistortionError) else d
        if periodic_model and isinstance(as_simulated, DistortionError) and isinstance(dist["model"], DistortionError):
            out["model"]["distortion"]["simulated_period_variation_rms"] = as_simulated.to_dict()[
                "period_variation_rms"]
        wandering = _not_periodic(as_simulated, dist["linear"], measured.unit, periodic_model)
        if wandering:
            out["model"]["not_periodic"] = wandering
    for key, m in (("model", model), ("linear", linear)):
        if m.prediction_band is not None:
            out[key]["prediction_band"] = m.prediction_band.describe()
        if period_samples and m.periodic_response is not None and m.terms:
            out[key]["periodic_response"] = m.periodic_response.describe()
    if model.validity is not None:
        out["validity"] = model.validity.check(raw_drive[transient:], fs).to_dict()
    drive_col = "force" if drive_name == "force" else "spindle_accel_m_s2"
    arrays = {"f": f, "t_meas": t_meas, "t_model": t_model, "t_linear": t_lin, "mask": mask,
              "a2": a2, "a2_model": pm.body_accel, "a2_linear": pl.body_accel, "valid": valid, "fs": fs,
              "signals": {"time_s": np.arange(record.n) / fs, drive_col: raw_drive,
                          f"{measured.name}_measured": measured.values, f"{measured.name}_model": y_model,
                          f"{measured.name}_linear": y_lin}}
    out["model"]["parameter_bounds"], eps = _parameter_bounds(
        model, dict(spindle_accel=a1, fs_hz=fs, force=force, label=str(path)), method, a2=a2, drive=drive,
        valid=valid, t_model=t_model, fs=fs, band_hz=band_hz, period_samples=period_samples,
        skip=int(period_samples) if period_samples else valid.start, settings=model.settings)
    if eps is not None:
        arrays["t_model_eps"] = eps
    if rate_note:
        out["note"] = rate_note
    tp = truth_for(path)
    if tp is not None and drive_name == "spindle":
        out["truth"] = _truth_comparison(tp, model, f, t_meas, mask)
        if out["truth"].get("t21") is not None:
            arrays["t_true"] = _from_cplx(out["truth"].pop("t21"))
    return out, arrays


def _parameter_bounds(model, drive_kw: dict, method: str, *, a2, drive, valid, t_model, fs, band_hz, period_samples,
                      skip, settings) -> tuple[dict, np.ndarray | None]:
    """The prediction's 95 % bounds from the model's parameter covariance (:mod:`nifo_core.predict.prediction_bounds`):
    (JSON-able numbers or why there are none, the transmissibility's ε per line for the plot's band). ``drive_kw``:
    predict_body's record arguments; a parametric (time-domain) prediction's sigma points are marched together, the
    same bits as one by one."""
    together = None if method != "parametric" else lambda ms: [
        p if isinstance(p, PredictionDivergedError) else p.body_accel for p in predict_bodies(ms, **drive_kw)]
    spread = prediction_spread(model, lambda m: predict_body(m, method=method, **drive_kw).body_accel,
                               together=together)
    if not spread.available:
        return {"available": False, "reason": spread.unavailable}, None
    kw = {"band_hz": tuple(band_hz), "period_samples": period_samples, "skip_samples": skip}
    try:
        nm = [[band_nmse(a2, y, fs, **kw) for y in ys] for ys in (spread.plus, spread.minus)]
        y_meas = band_spectra(a2, a2, fs, **kw)[0]
        yl = [[band_spectra(a2, y, fs, **kw)[1] for y in ys] for ys in (spread.plus, spread.minus)]
    except (InputError, ConfigError) as err:
        return {"available": False, "reason": err.message}, None
    sig_y = line_spread(*yl)
    tk = [[h1(cross_spectra(np.stack([drive[valid], y[valid]]), fs, settings), 0, 1) for y in ys]
          for ys in (spread.plus, spread.minus)]
    with np.errstate(divide="ignore", invalid="ignore"):
        eps = Z95 * line_spread(*tk) / (2 * np.abs(t_model))   # the plot's band is |T|(1 ∓ 2ε)
    return {"available": True, "level": 0.95, "n_parameters": spread.n_parameters,
            "simulations": 2 * len(spread.plus),
            "band_nmse_half_width_pct": half_width(nm[0], nm[1]),
            "parameter_share_of_band_nmse_pct": float(100 * np.sum(sig_y ** 2) / np.sum(np.abs(y_meas) ** 2)),
            "how": "refinement's parameter covariance carried by symmetric sigma points (random error of the "
                   "parameters only, not model-class error)"}, eps


def _from_cplx(d) -> np.ndarray:
    return np.asarray(d["re"]) + 1j * np.asarray(d["im"])


def _truth_comparison(tp: Path, model, f: np.ndarray, t_meas: np.ndarray, mask: np.ndarray) -> dict:
    try:
        doc = json.loads(tp.read_text())
        veh = QuarterCar(**doc["vehicle"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        return {"file": str(tp), "error": f"cannot read the truth ({err})"}
    t_true = veh.t21(f)
    t_nom = _interp(f, model.freq_hz, model.t21)
    return {"file": tp.name, "vehicle": doc["vehicle"], "strut": doc.get("strut"),
            "model_nominal_t21_vs_true": _rel(t_nom, t_true, mask),
            "model_linear_part_t21_vs_true": _rel(model.linear.t21(f), t_true, mask),
            "measured_h1_vs_true": _rel(t_meas, t_true, mask),
            "t21": {"re": t_true.real.tolist(), "im": t_true.imag.tolist()}}


def _figures(out: Path, name: str, stem: str, arr: dict, band_hz, model, *, system: dict | None = None) -> list[str]:
    from nifo.plots.nifo import plot_time_excerpt, plot_transmissibility

    f = arr["f"]
    model_style = {"color": "C3", "lw": 1.3, "ls": "--"}
    if "t_model_eps" in arr:
        model_style.update(random_error=arr["t_model_eps"], band_label="95 % bound (model parameters)")
    curves = [("measured H1", f, arr["t_meas"], {"color": "k", "lw": 1.2}),
              ("predicted, identified model", f, arr["t_model"], model_style),
              ("predicted, linear model (plain H1 at id. level)", f, arr["t_linear"], {"color": "C0", "lw": 1.0,
                                                                                       "ls": ":"})]
    if "t_true" in arr:
        curves.append(("true nominal linear T21", f, arr["t_true"], {"color": "C2", "lw": 0.9, "alpha": 0.8}))
    names = [f"{stem}_transmissibility.png", f"{stem}_time.png"]
    plot_transmissibility(out / names[0], curves, band_hz=tuple(band_hz),
                          title=f"{name}: predicted vs measured transmissibility")
    fs = arr["fs"]
    v = arr["valid"]
    n = int(min(EXCERPT_S * fs, v.stop - v.start))
    mid = (v.start + v.stop) // 2
    sl = slice(max(v.start, mid - n // 2), max(v.start, mid - n // 2) + n)
    t = np.arange(sl.start, sl.stop) / fs
    plot_time_excerpt(out / names[1], t, [("measured", arr["a2"][sl], {"color": "k", "lw": 1.0}),
                                          ("identified model", arr["a2_model"][sl], {"color": "C3", "lw": 1.0,
                                                                                     "ls": "--"}),
                                          ("linear model", arr["a2_linear"][sl], {"color": "C0", "lw": 0.8,
                                                                                  "ls": ":"})],
                      title=f"{name}: {_words(system)[1]}, measured vs predicted from the measured {_words(system)[0]}",
                      ylabel=f"{_words(system)[1]} [{(system or {}).get('units', 'm/s²')}]")
    return names


def _words(system: dict | None) -> tuple[str, str]:
    """(input, output) signal names: spindle and body acceleration on a vehicle, else neutral."""
    if system is None or system.get("vehicle", True):
        return "spindle", "body acceleration"
    return "input side", "output-side signal"


def _linear_part(model):
    """The model's nominal linear part alone (no terms): the fallback when model.json has no linear_h1."""
    from dataclasses import replace

    return replace(model, b=np.zeros((0, model.freq_hz.size), complex), terms=(), c_over_m2=np.zeros(0),
                   source="linear part")


def run_predict(args: PredictOptions, *, settings: AnalysisSettings | None = None) -> dict:
    """``nifo predict`` (module docstring). ``settings``: the job's, resolved once (``nifo run``: its analysis band,
    blocks, period and transient); None: resolved here from the command line and the model (its analysis band and
    blocks). Each file takes them through :func:`nifo.settings.for_records` (its own period and transient where
    none was given or chosen)."""
    # before any work: a file, a foreign folder or one holding an input of the command is refused
    check_output(args.out, reads=[*args.data, args.model])

    model, linear = read_model(args.model)
    if linear is None:
        linear = _linear_part(model)
    if settings is None:    # the analysis band: the command line's, else the model's (checked by read_model)
        band = args.analysis_band_hz if args.analysis_band_hz is not None else model.analysis_band_hz
        given = replace(given_from_args(args), analysis_band_hz=band, integration_band_hz=None)
        settings = resolve([], given=given, from_data=False)
        spectral = [k for k in ("block", "overlap", "window") if getattr(args, k) is not None]
    else:
        spectral = ["block", "overlap", "window"]
    lo, hi = settings.analysis_band_hz
    if spectral:    # the transmissibilities on other blocks than the model's
        model = replace(model, settings=replace(model.settings,
                                                **{k: getattr(settings.spectral, k) for k in spectral}))
    results, failed, figures, tables = [], [], [], []
    labels = record_labels(args.data)     # the file's name, told apart from a record of the same name elsewhere
    with staged_dir(args.out) as tmp, figure_batch():   # figures rendered by helpers, all written before the commit
        for p, label, stem in zip(args.data, labels, file_stems(labels)):   # every record it can do is written; the
            path = Path(p)                                                    # others are named at the end
            try:
                try:                                                           # its period and transient
                    st = for_records(settings, [path], opts=input_options(args))
                except NifoError:        # nothing to choose from these data (e.g. no clear excited band): as given
                    st = for_records(settings, [path], opts=input_options(args), from_data=False)
                opts = loader_options(input_options(args), st)
                opts.update(skip_periods=None, skip_seconds=None)              # from rest, from the first sample
                record = load_record(path, **opts)
                numbers, arrays = predict_one(path, record, model, linear, band_hz=(lo, hi), method=args.method,
                                              period_samples=st.period_samples,
                                              transient=st.skip_samples(record.fs_hz))
            except NifoError as err:
                failed.append((path, err.with_context(source=str(path))))
                continue
            numbers["settings"] = {k: c.to_dict() for k, c in st.choices.items()
                                   if k in ("period_samples", "skip_periods", "skip_seconds")}
            numbers["name"] = label
            numbers["signals"] = write_signals(tmp, stem, arrays["signals"],
                                               meta={"record": str(path), "model": str(args.model),
                                                     "output_unit": numbers["output"]["unit"]})
            tables += numbers["signals"]
            if not args.no_plots:
                numbers["figures"] = _figures(tmp, label, stem, arrays, (lo, hi), model, system=system_of(args))
                figures += numbers["figures"]
            results.append(numbers)
        doc = {"nifo_predict": 1, "model": str(args.model), "model_terms": [t.to_dict() for t in model.terms],
               "model_c_over_m2": model.c_over_m2.tolist(), "linear_part": model.linear.to_dict(),
               "linear_model": linear.source, "method": args.method, "freq_range_hz": [lo, hi], "records": results,
               "failed": [{"path": str(pth), "error": str(err), "exit_code": err.exit_code} for pth, err in failed],
               "input": input_provenance(args), "system": system_of(args)}
        if results:
            write_json(tmp / PREDICT_JSON, doc, atomic=False)
        else:
            raise failed[0][1] if len(failed) == 1 else type(failed[0][1])(
                f"none of the {len(failed)} records could be predicted: "
                + "; ".join(str(err) for _, err in failed))
    print(_summary(results, (lo, hi), args.out))
    if failed:
        first = failed[0][1]
        raise type(first)(f"{len(failed)} of {len(failed) + len(results)} records could not be predicted (the others "
                          f"are in {args.out}/{PREDICT_JSON}): " + "; ".join(str(err) for _, err in failed))
    return {"out": str(args.out), "freq_range_hz": [lo, hi], "figures": figures, "signals": tables,
            "records": [{k: r[k] for k in ("name", "path", "model", "linear") if k in r} for r in results]}


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def _num(x, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def _summary(results: list[dict], band, out: Path) -> str:
    w = max([24] + [len(r["name"]) for r in results])     # the whole name: records often differ at its end
    # the whole signal first: what the field scores (the raw predicted signal over all frequencies, offset
    # included); the band NMSE beside it is the diagnosis over --analysis-band
    periodic = any("distortion" in r["model"] for r in results)
    lines = [f"{'record':<{w}} RMS error model | linear   NMSE all frequencies model | linear   "
             f"band NMSE {band[0]:.4g}-{band[1]:.4g} Hz model | linear   "
             + ("distortion (non-excited lines, 100 % = none predicted) model | linear   " if periodic else "")
             + "|T| error model (median/max) | linear (median/max)"]
    for r in results:
        m, li = r["model"], r["linear"]
        bm, bl = (x["band_nmse"]["percent"] for x in (m, li))
        pb = m.get("parameter_bounds") or {}
        pm_txt = f" ± {pb['band_nmse_half_width_pct']:.2g}" if pb.get("available") else ""
        band_txt = ("not computed: " + m["band_nmse"].get("not_computed", "") if bm is None
                    else f"{bm:.3f}%{pm_txt} | {bl:.3f}%")
        wm, wl = m["whole_signal"], li["whole_signal"]
        unit = "m/s²" if r["output"]["name"] == "body_accel" else "(displacement unit)"
        rms_txt = f"{_num(wm['rms_error'], '.4g')} | {_num(wl['rms_error'], '.4g')} {unit}"
        nmse_txt = f"{_num(wm['nmse_percent'], '.3g')}% | {_num(wl['nmse_percent'], '.3g')}%"
        dist_txt = ""
        if periodic:
            dm, dl = (x.get("distortion") or {} for x in (m, li))
            dist_txt = (f"{_num(dm.get('percent_of_none'), '.3g')}% | {_num(dl.get('percent_of_none'), '.3g')}%"
                        f" of {_num(dm.get('share_percent'), '.2g')}% of the output   ")
        lines.append(f"{r['name']:<{w}} {rms_txt}   {nmse_txt}   {band_txt}   {dist_txt}"
                     f"{_pct(m['transmissibility_error']['median'])} / {_pct(m['transmissibility_error']['max'])}"
                     f" | {_pct(li['transmissibility_error']['median'])} / {_pct(li['transmissibility_error']['max'])}")
        if m.get("not_periodic"):
            lines.append(f"  note: {m['not_periodic']}")
        v = r.get("validity") or {}
        if v.get("outside"):
            lines.append(f"  NOT VALIDATED: {v['message']}")
        for note in v.get("notes") or ():
            lines.append(f"  note: {note}")
        if "truth" in r and "model_nominal_t21_vs_true" in r["truth"]:
            tr = r["truth"]
            lines.append(f"  truth ({tr['file']}): vs the true linear T21, median: model's linear part "
                         f"{_pct(tr['model_linear_part_t21_vs_true']['median'])}, NIFO nominal T21 "
                         f"{_pct(tr['model_nominal_t21_vs_true']['median'])}, measured H1 "
                         f"{_pct(tr['measured_h1_vs_true']['median'])}")
        if r.get("note"):
            lines.append(f"  note: {r['note']}")
    if results:
        r = results[0]
        after = r["model"]["whole_signal"].get("after_samples")
        lines.append(f"whole signal: the raw predicted {r['output']['name']} against the measured one, offset "
                     f"included, after the first {after} samples (start-up from rest)"
                     + (f"; the model's prediction: {r['model']['prediction_band']}"
                        if r["model"].get("prediction_band") else "")
                     + (f"; the linear model's: {r['linear']['prediction_band']}"
                        if r["linear"].get("prediction_band") else "")
                     + (f"; {r['model']['periodic_response']}" if r["model"].get("periodic_response") else ""))
    lines.append(f"wrote {out}/predict.json")
    return "\n".join(lines)
