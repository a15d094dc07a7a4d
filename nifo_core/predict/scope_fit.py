"""A model's static part, prediction band, periodic response and validity, taken from the records it was identified on.

:func:`fit_scope` completes a model with the four objects of :mod:`nifo_core.predict.scope`:

1. the force it is driven about (the records' pooled mean after their transients);
2. the band its prediction covers, chosen by the held-out whole-signal error (:mod:`nifo_core.predict.whole_signal`):
   every record simulated from its first sample, once as it comes and once limited to the analysis band; the
   output offset of each taken from the fit parts, the error scored on the held-out parts
   (:class:`~nifo_core.predict.heldout.HeldOut`); the band is kept when it lowers the mean held-out whole-signal
   NMSE by at least :data:`BAND_GAIN` — a limit costs what the data show outside the band, so it has to earn its place;
3. for periodic records and a model with terms, the periodic response (:mod:`nifo_core.predict.periodic`: its
   simulation's period average, plus the part of its linear twin's that is not periodic) unless that raises the
   held-out whole-signal NMSE beyond :data:`PERIODIC_TOLERANCE`; on the lines the input did not excite, the
   model's distortion when it lowers that NMSE by :data:`BAND_GAIN` against its linear twin's there, else the
   twin's;
4. the output offset from the whole records (after their transients) with the band chosen: ȳ - ȳ_dynamics (the
   body acceleration's common mode, the spindle's mean, passes one to one and is not part of it);
5. the validity: the analysis band and the driving input's RMS and peak over the records, and the strut's measured
   range of deflection and velocity (:func:`~nifo_core.predict.force_law.motion_range`).

One simulation of every record (and of its linear twin's for the periodic response).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import NifoError
from .force_law import motion_range
from .heldout import HeldOut
from .model import IdentifiedModel, predict_body, record_inputs
from .output_signal import common_mode, dynamic_output, measured_output, output_name
from .periodic import record_periodic_response
from .scope import Offsets, PeriodicResponse, PredictionBand, Validity, input_name
from .time_prediction import Prediction
from .whole_signal import whole_signal_error

__all__ = ["fit_scope", "BAND_GAIN", "PERIODIC_TOLERANCE"]

#: the band is kept when it lowers the mean held-out whole-signal NMSE by at least this fraction
BAND_GAIN = 0.02
#: the periodic response is kept unless it raises the mean held-out whole-signal NMSE by more than this fraction —
#: the margin the band limit must earn: where the model does not wander the two predictions differ by less (F-16,
#: `nifo run` on levels 3/5/7: 7.5745 against 7.5746 %)
PERIODIC_TOLERANCE = BAND_GAIN


def _pooled(values, weights) -> float:
    w = np.asarray(weights, float)
    return float(np.sum(np.asarray(values, float) * w) / np.sum(w)) if w.sum() > 0 else 0.0


def _force_about(model: IdentifiedModel, held: HeldOut) -> float | None:
    """The records' pooled force mean after their transients (None: the model has no force input)."""
    if model.force_gain <= 0 or any(r.force is None for r in held.records):
        return None
    return _pooled([np.mean(r.force[s:]) for r, s in zip(held.records, held.skip)],
                   [r.n - s for r, s in zip(held.records, held.skip)])


def _static_residue(model, held: HeldOut, i: int, dyn: np.ndarray, lo: int, hi: int) -> tuple[float, int]:
    """(mean of y - common mode - predicted deviation over samples lo:hi of record i, their number)."""
    r = held.records[i]
    y = measured_output(r).values
    cm = common_mode(r) if output_name(r) == "body_accel" else 0.0
    return float(np.mean(y[lo:hi] - cm - dyn[lo:hi])), hi - lo


def _simulate(model: IdentifiedModel, held: HeldOut,
              policies: tuple[str, ...]) -> tuple[dict[str, list[np.ndarray]], list[Prediction]]:
    """Per policy, the predicted deviation of every record's output, simulated from its first sample: one simulation
    a record (the model is driven by the whole input under either policy; only its output is limited); and the
    simulations."""
    out: dict[str, list[np.ndarray]] = {p: [] for p in policies}
    preds = []
    for r in held.records:
        a1, force = record_inputs(r, model)
        pred = predict_body(model, a1, r.fs_hz, force=force, label=r.source)
        preds.append(pred)
        for p in policies:
            out[p].append(dynamic_output(replace(model, prediction_band=PredictionBand(p, model.analysis_band_hz)),
                                         r, pred))
    return out, preds


def _held_out_nmse(model: IdentifiedModel, held: HeldOut, dyns: list[np.ndarray]) -> float:
    """Mean over records of the held-out whole-signal NMSE [%], the output offset taken from the fit parts."""
    parts = [_static_residue(model, held, i, d, held.skip[i], held.split[i]) for i, d in enumerate(dyns)]
    y0 = _pooled([m for m, _ in parts], [n for _, n in parts])
    scores = []
    for i, (r, d) in enumerate(zip(held.records, dyns)):
        cm = common_mode(r) if output_name(r) == "body_accel" else 0.0
        k = held.split[i]
        y = measured_output(r).values
        scores.append(whole_signal_error(y[k:], d[k:] + cm + y0).nmse_percent)
    return float(np.mean(scores))


def _periodic(model: IdentifiedModel, held: HeldOut, preds: list[Prediction], lins: list[Prediction],
              distortion: str) -> list[np.ndarray]:
    """Each record's predicted deviation as the model's periodic response (:mod:`nifo_core.predict.periodic`),
    after one period (at least the transient), limited as ``model``'s prediction is; ``distortion='linear'``: the
    linear twin's period average on the lines the input did not excite."""
    p = int(held.period_samples)
    out = []
    for r, s, pred, lin in zip(held.records, held.skip, preds, lins):
        out.append(dynamic_output(model, r, record_periodic_response(
            model, r, pred, lin, period_samples=p, start=max(p, s), band_hz=held.band_hz, distortion=distortion)))
    return out


def _periodic_response(model: IdentifiedModel, linear: IdentifiedModel, held: HeldOut, preds: list[Prediction],
                       simulated: float) -> tuple[PeriodicResponse, list[np.ndarray]]:
    """The periodic response unless it raises the held-out whole-signal NMSE of the simulation as it comes
    (``simulated`` [%]) by more than :data:`PERIODIC_TOLERANCE` — with the model's distortion on the lines the input
    did not excite when that lowers it by :data:`BAND_GAIN` against the linear twin's there, as a term must earn its
    place; and its predicted deviations."""
    lins = []
    for r in held.records:
        a1, force = record_inputs(r, linear)
        lins.append(predict_body(linear, a1, r.fs_hz, force=force, label=r.source))
    dyns = {d: _periodic(model, held, preds, lins, d) for d in ("model", "linear")}
    scores = {d: _held_out_nmse(model, held, dyns[d]) for d in dyns}
    distortion = "model" if scores["model"] <= (1 - BAND_GAIN) * scores["linear"] else "linear"
    periodic = scores[distortion]
    held_out = {"periodic": periodic, "simulated": simulated, "periodic_model_distortion": scores["model"],
                "periodic_linear_distortion": scores["linear"]}
    lines = (f"; on the lines the input did not excite the {'model' if distortion == 'model' else 'linear model'}'s "
             f"period average ({scores['model']:.4g} % with the model's distortion, {scores['linear']:.4g} % with "
             f"the linear model's)")
    if periodic <= (1 + PERIODIC_TOLERANCE) * simulated:
        return PeriodicResponse("periodic", f"the model's periodic response: held-out whole-signal NMSE "
                                f"{periodic:.4g} % against {simulated:.4g} % as simulated" + lines, held_out,
                                distortion), dyns[distortion]
    return PeriodicResponse("simulated", f"as simulated: held-out whole-signal NMSE {simulated:.4g} % against "
                            f"{periodic:.4g} % for its periodic response (the data answer with more than the "
                            f"input's period)", held_out), dyns[distortion]


def fit_scope(model: IdentifiedModel, held: HeldOut, *, choose_band: bool = True,
              linear: IdentifiedModel | None = None) -> IdentifiedModel:
    """``model`` with its offsets, prediction band and validity from the records of ``held`` (module docstring);
    with periodic records, a model with terms and its ``linear`` twin (already scoped), its periodic response too.

    ``choose_band=False`` keeps the prediction unlimited (one simulation of every record). A model that cannot be
    simulated on a record keeps an unlimited prediction and takes its output offset from the measured means alone
    (the reason in ``offsets.how``).
    """
    recs = held.records
    name = output_name(recs[0])
    u0 = _force_about(model, held)
    how = ("the spindle acceleration drives the model about each record's own mean, which passes to the body one "
           "to one (a constant acceleration of both masses does not deflect the strut)"
           if not recs[0].spindle_fixed else
           f"the force drives the model about {u0:.6g} N, the identification records' mean" if u0 is not None else "")
    base = replace(model, offsets=Offsets(force=u0, output=0.0, output_name=name, how=how), prediction_band=None,
                   periodic_response=None)
    band = model.analysis_band_hz
    policies = ("whole", "band") if choose_band else ("whole",)
    sims, scores = {}, {}
    try:
        sims, preds = _simulate(base, held, policies)
        scores = {p: _held_out_nmse(base, held, sims[p]) for p in policies}
    except (NifoError, np.linalg.LinAlgError) as err:
        sims, why = {}, f"not simulated on the identification records ({err}): the output offset from their means"
    if "band" in scores and scores["band"] <= (1 - BAND_GAIN) * scores["whole"]:
        policy = "band"
        reason = (f"limited to the analysis band: held-out whole-signal NMSE {scores['band']:.4g} % against "
                  f"{scores['whole']:.4g} % unlimited (the linear part's gain outside the band it was fitted on is "
                  f"not identified)")
    elif sims:
        policy = "whole"
        reason = ("not limited: " + (f"held-out whole-signal NMSE {scores['whole']:.4g} % unlimited against "
                                     f"{scores['band']:.4g} % limited to the analysis band" if "band" in scores
                                     else "not chosen (one policy asked for)"))
    else:
        policy, reason = "whole", why
    pb = PredictionBand(policy, band, reason, {k: v for k, v in scores.items()})
    pr = None
    if sims and held.period_samples and linear is not None and model.terms:
        try:
            pr, periodic = _periodic_response(replace(base, prediction_band=pb), linear, held, preds, scores[policy])
        except (NifoError, np.linalg.LinAlgError) as err:
            pr, periodic = PeriodicResponse("simulated", f"as simulated: its periodic response could not be "
                                                         f"simulated ({err})"), []
        if pr.periodic:
            sims[policy] = periodic
    if sims:
        parts = [_static_residue(base, held, i, d, held.skip[i], r.n) for i, (r, d) in enumerate(zip(recs, sims[policy]))]
    else:
        parts = [_static_residue(base, held, i, np.zeros(r.n), held.skip[i], r.n) for i, r in enumerate(recs)]
    y0 = _pooled([m for m, _ in parts], [n for _, n in parts])
    unit = measured_output(recs[0]).unit
    how += ("; " if how else "") + (f"the output offset {y0:.6g} ({unit}) is what the identification records "
                                    f"show at DC beyond the model's dynamics" + ("" if sims else f" ({why})"))
    drive = input_name(recs[0], model.force_gain)
    inputs = [(np.asarray(r.force if drive == "force" else r.spindle_accel, float))[s:]
              for r, s in zip(recs, held.skip)]
    try:
        strut = motion_range([r.slice(s, r.n) for r, s in zip(recs, held.skip)], model.band)
    except NifoError:     # no record longer than the integrator's start-up edges: no measured range to state
        strut = None
    validity = Validity.of_inputs(inputs, [r.fs_hz for r in recs], band, input_name=drive, strut_range=strut)
    return replace(base, offsets=Offsets(force=u0, output=y0, output_name=name, how=how), prediction_band=pb,
                   periodic_response=pr, validity=validity)
