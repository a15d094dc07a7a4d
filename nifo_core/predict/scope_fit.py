"""A model's static part, prediction band and validity, taken from the records it was identified on.

:func:`fit_scope` completes a model with the three objects of :mod:`nifo_core.predict.scope`:

1. the force it is driven about (the records' pooled mean after their transients);
2. the band its prediction covers, chosen by the held-out whole-signal error (:mod:`nifo_core.predict.whole_signal`):
   every record simulated from its first sample, once as it comes and once limited to the analysis band; the
   output offset of each taken from the fit parts, the error scored on the held-out parts
   (:class:`~nifo_core.predict.heldout.HeldOut`); the band is kept when it lowers the mean held-out whole-signal
   NMSE by at least :data:`BAND_GAIN` — a limit costs what the data show outside the band, so it has to earn its place;
3. the output offset from the whole records (after their transients) with the band chosen: ȳ - ȳ_dynamics (the
   body acceleration's common mode, the spindle's mean, passes one to one and is not part of it);
4. the validity: the analysis band and the driving input's RMS and peak over the records, and the strut's measured
   range of deflection and velocity (:func:`~nifo_core.predict.force_law.motion_range`).

One simulation of every record.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import NifoError
from .force_law import motion_range
from .heldout import HeldOut
from .model import IdentifiedModel, predict_body, record_inputs
from .output_signal import common_mode, dynamic_output, measured_output, output_name
from .scope import Offsets, PredictionBand, Validity, input_name
from .whole_signal import whole_signal_error

__all__ = ["fit_scope", "BAND_GAIN"]

#: the band is kept when it lowers the mean held-out whole-signal NMSE by at least this fraction
BAND_GAIN = 0.02


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


def _simulate(model: IdentifiedModel, held: HeldOut, policies: tuple[str, ...]) -> dict[str, list[np.ndarray]]:
    """Per policy, the predicted deviation of every record's output, simulated from its first sample: one simulation
    a record (the model is driven by the whole input under either policy; only its output is limited)."""
    out: dict[str, list[np.ndarray]] = {p: [] for p in policies}
    for r in held.records:
        a1, force = record_inputs(r, model)
        pred = predict_body(model, a1, r.fs_hz, force=force, label=r.source)
        for p in policies:
            out[p].append(dynamic_output(replace(model, prediction_band=PredictionBand(p, model.analysis_band_hz)),
                                         r, pred))
    return out


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


def fit_scope(model: IdentifiedModel, held: HeldOut, *, choose_band: bool = True) -> IdentifiedModel:
    """``model`` with its offsets, prediction band and validity from the records of ``held`` (module docstring).

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
    base = replace(model, offsets=Offsets(force=u0, output=0.0, output_name=name, how=how), prediction_band=None)
    band = model.analysis_band_hz
    policies = ("whole", "band") if choose_band else ("whole",)
    sims, scores = {}, {}
    try:
        sims = _simulate(base, held, policies)
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
                   validity=validity)
