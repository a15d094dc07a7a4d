"""What a model carries besides its dynamics: the static part, the band its prediction covers, where it holds.

docs/method.md §10. A model's time simulation gives the *deviation* of the output about an operating point,
driven by the input's deviation about its own. What a user compares with is the raw measured signal, offset
included, over all frequencies. Three small frozen objects, each written into ``model.json``:

:class:`Offsets`
    The static part. The simulation is driven by the input about its operating point: a spindle acceleration
    about the record's own mean (a constant acceleration of both masses — gravity along a tilted axis, a sensor
    bias — does not deflect the strut, and passes to the body acceleration one to one, T21(0) = 1), a measured
    force about ``force`` (the training records' mean: the force the dynamics were identified about; a change of
    the force's mean passes at the model's static gain). The prediction adds ``output``: what the training
    records show at DC that the dynamics do not (a sensor's bias, a circuit's offset), ``ȳ - ȳ_dynamics``
    pooled over the training records.
:class:`PredictionBand`
    ``'whole'``: the prediction is the simulation as it comes, at every frequency. ``'band'``: the predicted
    deviation is limited to ``band_hz`` (:func:`nifo_core.signal.band.band_limit`), where the model was
    identified: a linear part fitted on a band has whatever gain the fit left outside it. The model is still driven
    by the whole input, as it was fitted (limiting the input too moved the F-16's band NMSE at levels 5 and 7 from
    0.301 to 0.313 % and 0.425 to 0.440 %). Chosen per model by the held-out whole-signal error
    (:func:`nifo_core.predict.scope_fit.fit_scope`).
:class:`PeriodicResponse`
    What the prediction of a *periodic* input is. ``'periodic'``: the model's periodic response — its
    simulation's period average plus the part of its linear twin's that is not periodic
    (:mod:`nifo_core.predict.periodic`). ``'simulated'``: the simulation as it comes. A structure driven
    periodically answers periodically, up to its noise and the input's own variation; a model may not (a play that
    slips on some periods and not others wanders from period to period). Chosen per model by the held-out
    whole-signal error on the identification records (:func:`nifo_core.predict.scope_fit.fit_scope`).
:class:`Validity`
    The band and the input amplitudes (RMS and peak about the mean) of the records the model was identified on;
    :meth:`Validity.check` says how far another record's input lies outside them (:class:`RecordValidity`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Mapping

import numpy as np

from ..errors import ConfigError
from ..signal.band import fraction_outside

__all__ = ["Offsets", "PredictionBand", "PeriodicResponse", "Validity", "RecordValidity", "OUTSIDE_BAND_FRACTION", "AMPLITUDE_MARGIN",
           "input_name", "INPUT_UNITS"]

#: a record whose input has more than this fraction of its energy outside the model's band is outside it
OUTSIDE_BAND_FRACTION = 0.5
#: an input RMS (or peak) more than this factor beyond the identified range is outside it (extrapolated)
AMPLITUDE_MARGIN = 1.1
#: units of the channels that drive a model
INPUT_UNITS = {"spindle_accel": "m/s²", "force": "N"}


def _num(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _pair(x) -> tuple[float, float]:
    return (float(x[0]), float(x[1]))


@dataclass(frozen=True)
class Offsets:
    """The static part of a model (module docstring).

    Attributes
    ----------
    force : float or None
        The force the model's dynamics are about [N] (None: each record's own mean).
    output : float
        Added to the predicted deviation [unit of the output].
    output_name : {'body_accel', 'body_disp'}
        The output it is in.
    how : str
        What was done, in words.
    """

    force: float | None = None
    output: float = 0.0
    output_name: str = "body_accel"
    how: str = ""

    def to_dict(self) -> dict:
        return {"force": _num(self.force), "output": float(self.output), "output_name": self.output_name,
                "how": self.how}

    @classmethod
    def from_dict(cls, d: Mapping) -> "Offsets":
        try:
            f = d.get("force")
            return cls(force=None if f is None else float(f), output=float(d.get("output") or 0.0),
                       output_name=str(d.get("output_name") or "body_accel"), how=str(d.get("how") or ""))
        except (TypeError, ValueError, AttributeError) as err:
            raise ConfigError(f"cannot read the model's offsets: {err}") from None


@dataclass(frozen=True)
class PredictionBand:
    """The band a model's prediction covers (module docstring).

    Attributes
    ----------
    policy : {'whole', 'band'}
    band_hz : (float, float)
        The band the model was identified on (what ``'band'`` limits to).
    reason : str
    held_out : mapping
        The held-out whole-signal NMSE [%] per policy it was chosen by.
    """

    policy: Literal["whole", "band"] = "whole"
    band_hz: tuple[float, float] = (0.0, 0.0)
    reason: str = ""
    held_out: Mapping = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.policy not in ("whole", "band"):
            raise ConfigError(f"prediction band policy {self.policy!r} must be 'whole' or 'band'")
        object.__setattr__(self, "band_hz", _pair(self.band_hz))

    @property
    def limited(self) -> bool:
        return self.policy == "band"

    def describe(self) -> str:
        lo, hi = self.band_hz
        return (f"limited to {lo:.4g}-{hi:.4g} Hz, the band the model was identified on" if self.limited
                else "every frequency (not limited)")

    def to_dict(self) -> dict:
        return {"policy": self.policy, "band_hz": list(self.band_hz), "reason": self.reason,
                "held_out": dict(self.held_out)}

    @classmethod
    def from_dict(cls, d: Mapping) -> "PredictionBand":
        try:
            return cls(policy=str(d["policy"]), band_hz=_pair(d["band_hz"]), reason=str(d.get("reason") or ""),
                       held_out=dict(d.get("held_out") or {}))
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise ConfigError(f"cannot read the model's prediction band: {err}") from None


@dataclass(frozen=True)
class PeriodicResponse:
    """What the prediction of a periodic input is (module docstring).

    Attributes
    ----------
    policy : {'periodic', 'simulated'}
    reason : str
    held_out : mapping
        The held-out whole-signal NMSE [%] per policy it was chosen by.
    distortion : {'model', 'linear'}
        On the lines the input did not excite, the model's period average (its predicted distortion) or its linear
        twin's (the model's distortion did not predict the identification records' better).
    """

    policy: Literal["periodic", "simulated"] = "simulated"
    reason: str = ""
    held_out: Mapping = field(default_factory=dict)
    distortion: Literal["model", "linear"] = "model"

    def __post_init__(self) -> None:
        if self.policy not in ("periodic", "simulated"):
            raise ConfigError(f"periodic response policy {self.policy!r} must be 'periodic' or 'simulated'")
        if self.distortion not in ("model", "linear"):
            raise ConfigError(f"periodic response distortion {self.distortion!r} must be 'model' or 'linear'")

    @property
    def periodic(self) -> bool:
        return self.policy == "periodic"

    def describe(self) -> str:
        if not self.periodic:
            return "for a periodic input, the simulation as it comes"
        return ("for a periodic input, the model's periodic response (its period average" +
                (", on the lines the input did not excite the linear model's" if self.distortion == "linear" else "")
                + ", and the part of the linear model's response that is not periodic)")

    def to_dict(self) -> dict:
        return {"policy": self.policy, "reason": self.reason, "held_out": dict(self.held_out),
                "distortion": self.distortion}

    @classmethod
    def from_dict(cls, d: Mapping) -> "PeriodicResponse":
        try:
            return cls(policy=str(d["policy"]), reason=str(d.get("reason") or ""),
                       held_out=dict(d.get("held_out") or {}), distortion=str(d.get("distortion") or "model"))
        except (KeyError, TypeError, ValueError) as err:
            raise ConfigError(f"cannot read the model's periodic response: {err}") from None


@dataclass(frozen=True)
class RecordValidity:
    """How another record's input lies against a model's :class:`Validity`.

    Attributes
    ----------
    outside_fraction : float
        Fraction of the input's energy (about its mean) outside the model's band (0-1).
    rms_ratio, peak_ratio : float
        The input's RMS and peak (about its mean) over the highest identified ones.
    outside : bool
        Mostly outside the band, or beyond the identified amplitudes: the prediction is not validated there.
    message : str
        One line saying so ('' when inside).
    notes : tuple of str
        Milder departures (partly outside the band, peaks beyond the range, below the range).
    """

    outside_fraction: float
    rms_ratio: float
    peak_ratio: float
    outside: bool
    message: str = ""
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        return {"outside": self.outside, "message": self.message, "notes": list(self.notes),
                "outside_band_fraction": self.outside_fraction, "rms_ratio": self.rms_ratio,
                "peak_ratio": self.peak_ratio}


@dataclass(frozen=True)
class Validity:
    """Where a model holds: the band and the input amplitudes it was identified on (module docstring).

    Attributes
    ----------
    band_hz : (float, float)
    input_name : {'spindle_accel', 'force'}
        The channel that drives the model.
    rms, peak : (float, float)
        Lowest and highest RMS / peak (about the mean) of that input over the identification records.
    outside_fraction : float
        The largest fraction of an identification record's input energy outside ``band_hz``.
    n_records : int
    strut_range : mapping, optional
        The relative motion the strut's force law was measured over (``deflection_m``, ``velocity_m_s``).
    """

    band_hz: tuple[float, float]
    input_name: str
    rms: tuple[float, float]
    peak: tuple[float, float]
    outside_fraction: float = 0.0
    n_records: int = 0
    strut_range: Mapping | None = None

    def __post_init__(self) -> None:
        for k in ("band_hz", "rms", "peak"):
            object.__setattr__(self, k, _pair(getattr(self, k)))

    @property
    def unit(self) -> str:
        return INPUT_UNITS.get(self.input_name, "")

    @classmethod
    def of_inputs(cls, inputs, fs_hz: float, band_hz: tuple[float, float], *, input_name: str,
                  strut_range: Mapping | None = None) -> "Validity":
        """From the identification records' driving inputs (after their transients)."""
        rms, peak, out = [], [], []
        for x, fs in zip(inputs, np.broadcast_to(fs_hz, len(inputs))):
            d = np.asarray(x, float) - np.mean(x)
            rms.append(float(np.sqrt(np.mean(d ** 2))))
            peak.append(float(np.max(np.abs(d))))
            out.append(fraction_outside(d, float(fs), band_hz))
        if not rms:
            raise ConfigError("no records to take the model's validity from")
        return cls(band_hz, input_name, (min(rms), max(rms)), (min(peak), max(peak)), max(out), len(rms),
                   dict(strut_range) if strut_range else None)

    def check(self, x: np.ndarray, fs_hz: float) -> RecordValidity:
        """Where the input ``x`` of another record lies against this range."""
        d = np.asarray(x, float) - np.mean(x)
        frac = fraction_outside(d, fs_hz, self.band_hz)
        rms, peak = float(np.sqrt(np.mean(d ** 2))), float(np.max(np.abs(d)))
        r_rms = rms / self.rms[1] if self.rms[1] > 0 else float("inf")
        r_peak = peak / self.peak[1] if self.peak[1] > 0 else float("inf")
        lo, hi = self.band_hz
        u = self.unit
        reasons, notes = [], []
        if frac > OUTSIDE_BAND_FRACTION:
            reasons.append(f"{100 * frac:.0f} % of its input's energy lies outside {lo:.4g}-{hi:.4g} Hz, the band "
                           f"the model was identified on")
        elif frac > max(0.1, 2 * self.outside_fraction):
            notes.append(f"{100 * frac:.0f} % of its input's energy lies outside {lo:.4g}-{hi:.4g} Hz (identified "
                         f"on records with at most {100 * self.outside_fraction:.0f} %)")
        if r_rms > AMPLITUDE_MARGIN:
            reasons.append(f"its input RMS {rms:.3g} {u} is {r_rms:.2f}× the highest identified ({self.rms[1]:.3g} {u})")
        elif r_peak > AMPLITUDE_MARGIN:
            notes.append(f"its input peaks at {peak:.3g} {u}, {r_peak:.2f}× the highest identified peak "
                         f"({self.peak[1]:.3g} {u}): those stretches are extrapolated")
        if self.rms[0] > 0 and rms < self.rms[0] / 2:
            notes.append(f"its input RMS {rms:.3g} {u} is below the lowest identified ({self.rms[0]:.3g} {u})")
        message = ("outside the model's range: " + "; ".join(reasons)) if reasons else ""
        return RecordValidity(frac, r_rms, r_peak, bool(reasons), message, tuple(notes))

    def to_dict(self) -> dict:
        d = {"band_hz": list(self.band_hz), "input": self.input_name, "unit": self.unit, "rms": list(self.rms),
             "peak": list(self.peak), "outside_band_fraction": self.outside_fraction, "n_records": self.n_records}
        if self.strut_range:
            d["strut_range"] = dict(self.strut_range)
        return d

    @classmethod
    def from_dict(cls, d: Mapping) -> "Validity":
        try:
            return cls(band_hz=_pair(d["band_hz"]), input_name=str(d["input"]), rms=_pair(d["rms"]),
                       peak=_pair(d["peak"]), outside_fraction=float(d.get("outside_band_fraction") or 0.0),
                       n_records=int(d.get("n_records") or 0), strut_range=d.get("strut_range"))
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise ConfigError(f"cannot read the model's validity: {err}") from None


def input_name(record, force_gain: float) -> str:
    """The channel that drives a model with ``force_gain`` in ``record``: the force for a fixed spindle, else the
    spindle acceleration."""
    return "force" if getattr(record, "spindle_fixed", False) and force_gain > 0 else "spindle_accel"
