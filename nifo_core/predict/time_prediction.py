"""Prediction in the time domain: what drives a model, its simulation and the prediction it gives.

:func:`nifo_core.predict.model.predict_body` chooses the engine; for the default, parametric prediction it is this
one: the model's linear part and terms simulated by :mod:`nifo_core.predict.timesim` from the record's measured
input v = ẍ1 [+ k3·x1] [- F/M2], on a fine step of at least :data:`FINE_RATE_HZ`, a response beyond
:data:`DIVERGENCE_FACTOR` times the linear part's own peak raised as :class:`PredictionDivergedError`.
:func:`predict_bodies` predicts several models on one record, :func:`predict_records` one model on several records,
marched side by side where they can be (:mod:`nifo_core.predict.timesim_lanes`), each the same bits as alone.

A ``model`` here is an :class:`~nifo_core.predict.model.IdentifiedModel`; it is not imported (model.py imports
this module, and the core's modules form no cycle).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.fft

from ..errors import ConfigError, IllConditionedError, InputError
from ..kinds.describing import Term
from ..nifo.result import read_only
from ..signal.integrate import integrate
from ..signal.memo import ArrayMemo
from .linear_part import LinearPart
from .timesim import simulate_response
from .timesim_lanes import MAX_LANES, simulate_responses

__all__ = ["DIVERGENCE_FACTOR", "FINE_RATE_HZ", "Prediction", "PredictionDivergedError", "fine_factor",
           "predict_bodies", "predict_records", "record_inputs", "time_method", "EngineInput", "engine_input"]


#: a response whose |z| exceeds this many times the linear part's peak counts as diverged
DIVERGENCE_FACTOR = 100.0


#: the time-domain engine steps at least this fast by default [Hz] (oversample = ceil(rate/fs), at least 2)
FINE_RATE_HZ = 2400.0


class PredictionDivergedError(IllConditionedError):
    """The identified model's response to this input grows without bound (the model is unstable at this level)."""

    exit_code = 12


@dataclass(frozen=True, eq=False)
class Prediction:
    """Predicted body response to a measured spindle acceleration (and force).

    Attributes
    ----------
    body_accel : ndarray, shape (n,)
        Predicted body acceleration [m/s²].
    z, zdot : ndarray, shape (n,)
        Predicted relative displacement [m] and velocity [m/s].
    iterations : int
        Frequency-domain iterations used (0 for the time-domain engine).
    residual : float
        Final relative change of z between iterations (0 for the time-domain engine).
    method : str
        What ran: the engine and the linear part.
    edge_samples : int
        Samples at each end affected by the record's unknown past (five times
        the slowest time constant of the linear part; ``valid`` selects the rest).
    engine : {'time', 'frequency'}
    oversample : int
        Fine steps per sample of the time-domain engine (0 for the frequency domain).
    """

    body_accel: np.ndarray
    z: np.ndarray
    zdot: np.ndarray
    iterations: int
    residual: float
    method: str
    edge_samples: int
    engine: str = "time"
    oversample: int = 0

    def __post_init__(self) -> None:
        for k in ("body_accel", "z", "zdot"):
            object.__setattr__(self, k, read_only(getattr(self, k)))

    @property
    def valid(self) -> slice:
        return slice(self.edge_samples, self.body_accel.size - self.edge_samples)


def _level(a1: np.ndarray | None, force: np.ndarray | None) -> str:
    parts = []
    if a1 is not None:
        parts.append(f"spindle RMS {np.sqrt(np.mean(a1 ** 2)):.3g} m/s²")
    if force is not None:
        parts.append(f"force RMS {np.sqrt(np.mean(force ** 2)):.3g} N")
    return ", ".join(parts)


def _external(model, linear: LinearPart, a1, force, fs_hz: float, n: int) -> np.ndarray:
    """v = ẍ1 [+ k3·x1] [- F/M2] [m/s²]: the measured input of the linear part."""
    v = np.zeros(n) if a1 is None else a1.copy()
    if linear.kind == "body" and linear.body.k3 != 0 and a1 is not None:
        v += linear.body.k3 * integrate(a1, fs_hz, band=model.band).displacement   # paper Eq. 2: K3·x2 = K3·(z + x1)
    if force is not None:
        if model.force_gain == 0:
            raise ConfigError("a force was given but the model has no force input (force_gain = 0)",
                              channel="force", hint="identify the model with the measured force")
        v -= model.force_gain * force
    return v


def record_inputs(record, model) -> tuple[np.ndarray | None, np.ndarray | None]:
    """What drives ``model`` in ``record``, about the model's operating point (:mod:`nifo_core.predict.scope`):
    (the spindle acceleration about the record's own mean, or None for a fixed spindle; the measured force about
    the model's ``offsets.force`` — the record's own mean when the model has none —, or None when the record has
    none or the model no force input). A model whose prediction is limited to its band
    (``prediction_band``) is still driven by the whole input, as it was fitted: only its output is limited
    (:func:`~nifo_core.predict.output_signal.dynamic_output`)."""
    a1 = None if getattr(record, "spindle_fixed", False) else _deviation(record.spindle_accel)
    f = getattr(record, "force", None)
    force = None
    if f is not None and model.force_gain > 0:
        offsets = getattr(model, "offsets", None)
        u0 = offsets.force if offsets is not None and offsets.force is not None else None
        force = _deviation(f, u0)
    return a1, force


def _checked_drive(spindle_accel, force) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(ẍ1, F) as the engine takes them, each checked (:func:`_check_input`; F as long as ẍ1); InputError when neither
    drives the model."""
    a1 = _check_input(spindle_accel, "spindle_accel", None)
    force = _check_input(force, "force", None if a1 is None else a1.size)
    if a1 is None and force is None:
        raise InputError("nothing drives the model: give the spindle acceleration or a force", channel="spindle_accel")
    return a1, force


def _deviation(x, about: float | None = None) -> np.ndarray:
    """``x`` about ``about`` (its own mean when None), in float64: offsets of any size leave the same deviation."""
    x = np.asarray(x, float)
    return x - (np.mean(x) if about is None else float(about))


def _check_input(x, name: str, n: int | None) -> np.ndarray | None:
    if x is None:
        return None
    a = np.asarray(x, dtype=float).ravel()
    if a.size == 0 or not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be a non-empty finite signal", channel=name)
    if n is not None and a.size != n:
        raise InputError(f"{name} has {a.size} samples, the spindle acceleration {n}", channel=name)
    return a


def _edge(linear: LinearPart, fs_hz: float, n: int) -> int:
    return int(min(n // 4, np.ceil(5 * linear.slowest_decay_s() * fs_hz)))


def _linear_peak(linear: LinearPart, v: np.ndarray, fs_hz: float) -> float:
    """max |z| of the stable realised linear part alone driven by v (FFT, zero-padded): the scale of "bounded"."""
    return float(_PEAK(v, _Realised(linear), float(fs_hz)))


class _Realised:
    """A linear part as a memo key: equal to another when the response it realises is the same (its kind, body,
    poles and residues, by value), whatever else differs (its paths, absorbed rates, fit notes)."""

    __slots__ = ("linear", "_key")

    def __init__(self, linear: LinearPart):
        self.linear = linear
        self._key = (linear.kind, repr(linear.body), np.asarray(linear.poles, complex).tobytes(),
                     np.asarray(linear.residues, complex).tobytes())

    def __hash__(self) -> int:
        return hash(self._key)

    def __eq__(self, other) -> bool:
        return isinstance(other, _Realised) and self._key == other._key


def _peak(v: np.ndarray, realised: _Realised, fs_hz: float) -> np.ndarray:
    linear = realised.linear
    nfft = scipy.fft.next_fast_len(v.size + int(5 * min(linear.slowest_decay_s(), 60.0) * fs_hz), real=True)
    f = np.fft.rfftfreq(nfft, 1.0 / fs_hz)
    hz = linear.hz_realised(f)
    hz[f == 0] = 0
    return np.max(np.abs(scipy.fft.irfft(hz * _SPECTRUM(v, nfft), nfft)))


def _spectrum(v: np.ndarray, nfft: int) -> np.ndarray:
    return scipy.fft.rfft(v, nfft)


#: the drive's spectrum for :func:`_linear_peak`: the same in every simulation of a record
_SPECTRUM = ArrayMemo(_spectrum, size=8)


#: the linear peak itself: the same in every simulation of a record by one linear part (the loop's candidates, the
#: refinement's steps in the terms alone, the bias correction's refits); its line response was 13 ms of a 100 ms
#: simulation of F-16 level 7 (22 poles' residues at 49 153 lines, then the inverse FFT)
_PEAK = ArrayMemo(_peak, size=16)


def _static_frame(terms) -> list[Term]:
    """The terms in the simulation's frame: z from the static position (the response starts from rest).

    A bump stop's ``offset`` places the static position in the mean-centred z the
    terms were identified on (:mod:`nifo_core.characterize.static`: a one-sided stop
    moves the mean); the simulation measures z from the static position itself, where
    the gap is, and its own mean moves with the stop as the strut's does.
    """
    return [Term(t.kind, {**dict(t.params), "offset": 0.0}) if t.spec.static_frame == "threshold" else t for t in terms]


def fine_factor(fs_hz: float, model_fs_hz: float | None = None) -> int:
    """The oversampling of the time-domain engine at ``fs_hz``: a fine rate of at least :data:`FINE_RATE_HZ`, and at
    least the fine rate the model was simulated at when identified at ``model_fs_hz`` (the nonlinear feedback is
    taken at the end of each fine step, an O(h) error the refined coefficients were fitted with: a record at a
    lower rate is simulated on the same fine step; measured on the Silverbox at a quarter of its rate: the error
    at the resonance 2.7 mV with the record's own fine step, against 1.0 mV at the full rate)."""
    q = max(2, int(np.ceil(FINE_RATE_HZ / fs_hz - 1e-9)))
    if model_fs_hz:
        q_model = max(2, int(np.ceil(FINE_RATE_HZ / model_fs_hz - 1e-9)))
        q = max(q, int(np.ceil(model_fs_hz * q_model / fs_hz - 1e-9)))
    return q


def _predict_time(model, linear, a1, force, fs_hz, oversample, label, what) -> Prediction:
    v, q, limit = _time_inputs(model, linear, a1, force, fs_hz, oversample)
    resp = simulate_response(linear, _static_frame(model.terms), model.c_over_m2, v, fs_hz, spindle_accel=a1,
                             oversample=q, z_limit=limit)
    return _time_prediction(model, linear, resp, a1, force, fs_hz, limit, label, what)


@dataclass(frozen=True)
class EngineInput:
    """What the time-domain engine is given for a model on a record: the input v at the record's rate [m/s²], the
    fine steps per sample and the bound of |z| [m] beyond which the response counts as diverged."""

    v: np.ndarray
    oversample: int
    z_limit: float


def engine_input(model, a1, force, fs_hz: float, oversample: int | None = None) -> EngineInput:
    """:class:`EngineInput` of ``model`` (its own linear part) driven by ``a1`` / ``force`` (:func:`record_inputs`)."""
    return EngineInput(*_time_inputs(model, model.linear, a1, force, fs_hz, oversample))


def _time_inputs(model, linear, a1, force, fs_hz, oversample) -> tuple[np.ndarray, int, float]:
    """The time-domain engine's input v, fine steps per sample and bound of |z| for ``model``."""
    n = (a1 if a1 is not None else force).size
    v = _external(model, linear, a1, force, fs_hz, n)
    q = int(oversample) if oversample is not None else fine_factor(fs_hz, model.fs_hz)
    limit = np.inf
    if model.terms or any(linear.absorbed):
        limit = DIVERGENCE_FACTOR * max(_linear_peak(linear, v, fs_hz), 1e-12)
    return v, q, limit


def _time_prediction(model, linear, resp, a1, force, fs_hz, limit, label, what) -> Prediction:
    """The prediction from the engine's response, or :class:`PredictionDivergedError` where it diverged."""
    n = (a1 if a1 is not None else force).size
    if model.terms or any(linear.absorbed):
        if resp.diverged_at >= 0:
            k = resp.diverged_at
            zk = resp.z[min(k, n - 1)]
            why = (f"|z| exceeded {DIVERGENCE_FACTOR:g}× the linear model's peak ({limit:.3g} m)"
                   if np.isfinite(zk) and abs(zk) > limit or not np.isfinite(zk)
                   else "the state escapes: the implicit step has no finite solution for the strut force")
            raise PredictionDivergedError(
                f"the identified model's response grows without bound at this level ({_level(a1, force)}): {why} "
                f"at t = {k / fs_hz:.2f} s", source=label,
                hint="the model is unstable at this amplitude (e.g. a softening or negative term outgrowing the "
                     "linear part): identify it on data that covers this level, or leave that term out")
    return Prediction(body_accel=resp.body_accel, z=resp.z, zdot=resp.zdot, iterations=0, residual=0.0,
                      method=what, edge_samples=_edge(linear, fs_hz, n), engine="time", oversample=resp.oversample)


def predict_bodies(models: Sequence, spindle_accel: np.ndarray | None, fs_hz: float, *,
                   force: np.ndarray | None = None, oversample: int | None = None,
                   label: str | None = None) -> list[Prediction | PredictionDivergedError]:
    """:func:`~nifo_core.predict.model.predict_body` of each model on one record with its defaults (parametric,
    time domain): the same predictions bit for bit, the models marched side by side where they can be
    (:mod:`nifo_core.predict.timesim_lanes`: the refinement's Jacobian columns). A model whose response diverges
    gets its :class:`PredictionDivergedError` in its place (not raised)."""
    a1, force = _checked_drive(spindle_accel, force)
    inputs = [_time_inputs(m, m.linear, a1, force, fs_hz, oversample) for m in models]
    # one input for all (every model of a parameter space but one with another k3): simulate_responses marches
    # them together where it can and says where it cannot
    if inputs and all(q == inputs[0][1] and np.array_equal(v, inputs[0][0]) for v, q, _ in inputs):
        v, q = inputs[0][0], inputs[0][1]
        responses = simulate_responses([m.linear for m in models], [_static_frame(m.terms) for m in models],
                                       [m.c_over_m2 for m in models], v, fs_hz, spindle_accel=a1, oversample=q,
                                       z_limits=[b for _, _, b in inputs])
    else:
        responses = [simulate_response(m.linear, _static_frame(m.terms), m.c_over_m2, v, fs_hz, spindle_accel=a1,
                                       oversample=q, z_limit=b) for m, (v, q, b) in zip(models, inputs)]
    out: list[Prediction | PredictionDivergedError] = []
    for m, resp, (_, _, limit) in zip(models, responses, inputs):
        try:
            out.append(_time_prediction(m, m.linear, resp, a1, force, fs_hz, limit, label, time_method(m.linear)))
        except PredictionDivergedError as e:
            out.append(e)
    return out


def predict_records(model, spindle_accels: Sequence[np.ndarray | None], fs_hz: float | Sequence[float], *,
                    forces: Sequence[np.ndarray | None] | None = None, oversample: int | None = None,
                    labels: Sequence[str | None] | None = None) -> list[Prediction | PredictionDivergedError]:
    """:func:`~nifo_core.predict.model.predict_body` of one model on several records (record i driven by
    ``spindle_accels[i]`` and ``forces[i]`` at its rate, ``fs_hz`` or ``fs_hz[i]``), with its defaults (parametric, time
    domain): the same predictions bit for bit, the records of one length and rate marched side by side
    (:mod:`nifo_core.predict.timesim_lanes`: the bias correction's synthetic records, the held-out parts of equal
    records; at most :data:`~nifo_core.predict.timesim_lanes.MAX_LANES` in a march). A record whose response diverges
    gets its :class:`PredictionDivergedError` in its place (not raised)."""
    n_rec = len(spindle_accels)
    rates = [float(fs_hz)] * n_rec if np.ndim(fs_hz) == 0 else [float(f) for f in fs_hz]
    forces = [None] * n_rec if forces is None else list(forces)
    labels = [None] * n_rec if labels is None else list(labels)
    drives = [_checked_drive(a1, force) for a1, force in zip(spindle_accels, forces, strict=True)]
    a1s, fs = [a1 for a1, _ in drives], [f for _, f in drives]
    inputs = [_time_inputs(model, model.linear, a1, f, rate, oversample)
              for a1, f, rate in zip(a1s, fs, rates, strict=True)]
    groups: dict[tuple, list[int]] = {}     # lanes share a length, a rate, a fine step and whether a spindle drives
    for i, (v, q, _) in enumerate(inputs):
        groups.setdefault((v.size, rates[i], q, a1s[i] is None), []).append(i)
    chunks = [(key, idx[k:k + MAX_LANES]) for key, idx in groups.items() for k in range(0, len(idx), MAX_LANES)]
    terms = _static_frame(model.terms)
    responses: list = [None] * n_rec
    for (_, rate, q, fixed), idx in chunks:
        got = simulate_responses([model.linear] * len(idx), [terms] * len(idx), [model.c_over_m2] * len(idx),
                                 np.stack([inputs[i][0] for i in idx]), rate,
                                 spindle_accel=None if fixed else np.stack([a1s[i] for i in idx]), oversample=q,
                                 z_limits=[inputs[i][2] for i in idx])
        for i, resp in zip(idx, got):
            responses[i] = resp
    out: list[Prediction | PredictionDivergedError] = []
    what = time_method(model.linear)
    for a1, f, rate, resp, (_, _, limit), label in zip(a1s, fs, rates, responses, inputs, labels):
        try:
            out.append(_time_prediction(model, model.linear, resp, a1, f, rate, limit, label, what))
        except PredictionDivergedError as e:
            out.append(e)
    return out


def time_method(linear: LinearPart, note: str = "") -> str:
    """What the time-domain engine ran, as :attr:`Prediction.method` says it."""
    return f"time domain, {linear.kind} linear part of order {linear.order}{note}"
