"""A periodic input's prediction: the model's periodic response (docs/method.md §10).

A structure driven periodically answers periodically, up to its noise and to what the measured input itself varies
from period to period (a measured spindle or wing acceleration is not exactly periodic). A nonlinear model need not:
a play with no restoring force of its own slides on some cycles and not others, and its simulation wanders from
period to period — at the F-16's level 1, a model identified on levels 3/5/7 varies by 0.0089 m/s² RMS from period
to period when driven by the *exactly* periodic average of the input, the structure by 0.0028 m/s². That wandering
is uncorrelated with any periodic response, so it can only add to the error.

The periodic response keeps what the input's own variation causes and leaves out what the model invents::

    ŷ = SS[M(u)] + L(u) - SS[L(u)]

M(u) is the model's simulation, L(u) its linear twin's (the equivalent linearisation at the identification levels,
what ``nifo predict`` compares against), SS the average of a simulation's whole periods after the start-up window,
repeated (:func:`steady_state`): the model's periodic part, plus the part of the linear response that is not
periodic — the response to the input's own variation from period to period. Its period average is the model's:
every figure read from the period average (the band NMSE, the distortion at the lines not excited) is unchanged.
Before the start-up window ends the prediction is the simulation as it comes (the start-up from rest, not scored).
F-16, `nifo run` on levels 3/5/7 predicting the multisines (whole-signal RMS error, model as simulated → periodic
response, linear twin): level 1 0.01813 → 0.01566 (0.01803) m/s²; level 3, which it was identified on, 0.04416 →
0.04415 (0.04811); levels 5 and 7 unchanged to four digits. Averaging the simulation alone would throw away what
the input's variation causes (level 3: 0.04474). Whether a model predicts this way is chosen from the
identification records (:class:`~nifo_core.predict.scope.PeriodicResponse`, by
:func:`~nifo_core.predict.scope_fit.fit_scope`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .scope import input_name
from .time_prediction import Prediction
from .whole_signal import excited_lines

__all__ = ["steady_state", "periodic_prediction", "model_lines", "predicts_periodic", "record_periodic_response"]


def _average(x: np.ndarray, period: int, start: int) -> np.ndarray | None:
    """The average of the whole periods of ``x`` after ``start`` (None when fewer than two follow)."""
    k = (x.size - start) // period if period > 0 else 0
    if k < 2:
        return None
    return x[start:start + k * period].reshape(k, period).mean(axis=0)


def steady_state(y: np.ndarray, period_samples: int, start: int) -> np.ndarray:
    """``y`` with every sample from ``start`` on replaced by the average of its whole periods after ``start``,
    repeated (the samples before ``start``, the start-up from rest, as they are); ``y`` itself when fewer than two
    whole periods follow ``start`` (nothing to average)."""
    y = np.asarray(y, float)
    p, start = int(period_samples), max(int(start), 0)
    avg = _average(y, p, start)
    if avg is None:
        return y
    out = y.copy()
    out[start:] = np.resize(avg, y.size - start)
    return out


def model_lines(u: np.ndarray, period_samples: int, start: int, fs_hz: float,
                band_hz: tuple[float, float]) -> np.ndarray | None:
    """The lines of one period on which the model's period average is kept when its distortion gives way to its
    linear twin's: those the periodic input ``u`` excited inside ``band_hz``
    (:func:`~nifo_core.predict.whole_signal.excited_lines` of its period average after ``start``) and every line
    outside the band (DC included: outside the band the prediction band decides,
    :class:`~nifo_core.predict.scope.PredictionBand`). None when fewer than two whole periods follow ``start``."""
    p = int(period_samples)
    avg = _average(np.asarray(u, float), p, max(int(start), 0))
    if avg is None:
        return None
    f = np.fft.rfftfreq(p, 1.0 / fs_hz)
    return excited_lines(avg, fs_hz, band_hz) | (f < band_hz[0]) | (f > band_hz[1])


def periodic_prediction(prediction: Prediction, linear_prediction: Prediction, *, period_samples: int,
                        start: int, keep: np.ndarray | None = None) -> Prediction:
    """The model's simulation ``prediction`` as its periodic response (module docstring), given its linear twin's
    simulation of the same record; ``prediction`` itself when fewer than two whole periods follow ``start``.
    ``keep`` (lines of one period, :func:`model_lines`): the model's period average is kept on those, the linear
    twin's taken on every other (the model's distortion on the lines the input did not excite left out)."""
    p, start = int(period_samples), max(int(start), 0)
    if (prediction.body_accel.size - start) // max(p, 1) < 2:
        return prediction
    out = {}
    for k in ("body_accel", "z", "zdot"):
        m, lin = (np.asarray(getattr(x, k), float) for x in (prediction, linear_prediction))
        periodic = steady_state(m, p, start)
        if keep is not None:
            mp, lp = (np.fft.rfft(_average(x, p, start)) for x in (m, lin))
            periodic[start:] = np.resize(np.fft.irfft(np.where(keep, mp, lp), p), m.size - start)
        y = periodic + lin - steady_state(lin, p, start)
        y[:start] = m[:start]                 # the start-up from rest, as simulated
        out[k] = y
    return replace(prediction, **out, method=prediction.method + "; periodic response")


def predicts_periodic(model, period_samples: int | None) -> bool:
    """Whether ``model``'s prediction of a record of ``period_samples`` (None: not periodic) is its periodic response:
    a model with terms whose ``periodic_response`` says so (a linear model's simulation is periodic as it comes)."""
    pr = getattr(model, "periodic_response", None)
    return bool(period_samples and model.terms and pr is not None and pr.periodic)


def record_periodic_response(model, record, prediction: Prediction, linear_prediction: Prediction, *,
                             period_samples: int, start: int, band_hz: tuple[float, float],
                             distortion: str | None = None) -> Prediction:
    """:func:`periodic_prediction` of ``record``, keeping the model's lines of :func:`model_lines` (its driving input,
    ``band_hz``) when the model takes its linear twin's distortion (``distortion``, default the model's
    ``periodic_response``)."""
    d = distortion or model.periodic_response.distortion
    lines = None
    if d == "linear":
        drive = record.force if input_name(record, model.force_gain) == "force" else record.spindle_accel
        lines = model_lines(drive, period_samples, start, record.fs_hz, band_hz)
    return periodic_prediction(prediction, linear_prediction, period_samples=period_samples, start=start,
                               keep=lines)
