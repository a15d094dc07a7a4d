"""How the field scores a model: the raw predicted signal against the raw measured one (docs/method.md §10).

The ``nonlinear-benchmarks`` convention: the model simulated in free run from the measured input, compared
with the measured output over all frequencies, offset included, after a short initial window —

    RMS error = √(Σ_t (y_t - ŷ_t)²/N)   [unit of the output],   NMSE = 100·Σ_t (y_t - ŷ_t)²/Σ_t (y_t - ȳ)²   [%]

(:func:`whole_signal_error`). The band NMSE (:mod:`nifo_core.predict.prediction_error`) is a diagnosis beside it.

For a periodic excitation the lines that were not excited carry the nonlinear distortion: a nonlinear model
should predict it, a linear one cannot. :func:`distortion_error` scores the period-averaged prediction on those
lines against what was measured there, and against predicting none (100 %); beside it, how far each period of the
prediction and of the measurement differs from their period average (a structure driven periodically answers
periodically, up to its noise; a model may not: a play that slips on some cycles and not others).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft

from ..errors import InputError

__all__ = ["WholeSignalError", "whole_signal_error", "DistortionError", "distortion_error", "excited_lines",
           "NOT_PERIODIC"]

#: a line of a periodic input inside the excited band within this many dB of the band's median power is excited
EXCITED_DB = 30.0


@dataclass(frozen=True)
class WholeSignalError:
    """The error of a raw predicted signal (module docstring).

    Attributes
    ----------
    rms_error : float
        RMS of y - ŷ after ``after_samples`` [unit of the output], offset included.
    nmse_percent : float
        Its mean square over the output's variance [%].
    offset_error : float
        The mean of y - ŷ: the part of the error that is a constant offset.
    output_rms : float
        RMS of the measured output about its mean over the same samples.
    after_samples : int
        The initial window left out (the start-up from rest, and a transient the settings drop).
    """

    rms_error: float
    nmse_percent: float
    offset_error: float
    output_rms: float
    after_samples: int

    def to_dict(self) -> dict:
        return {"rms_error": self.rms_error, "nmse_percent": self.nmse_percent, "offset_error": self.offset_error,
                "output_rms": self.output_rms, "after_samples": self.after_samples}


def whole_signal_error(y: np.ndarray, yhat: np.ndarray, *, skip: int = 0) -> WholeSignalError:
    """:class:`WholeSignalError` of ``yhat`` against ``y`` after their first ``skip`` samples."""
    y = np.asarray(y, float)
    yhat = np.asarray(yhat, float)
    if y.shape != yhat.shape:
        raise InputError(f"measured ({y.size}) and predicted ({yhat.size}) signals differ in length")
    skip = max(int(skip), 0)
    e = y[skip:] - yhat[skip:]
    if e.size == 0:
        raise InputError(f"nothing is left to score after the first {skip} samples")
    dev = y[skip:] - np.mean(y[skip:])
    var = float(np.mean(dev ** 2))
    mse = float(np.mean(e ** 2))
    return WholeSignalError(rms_error=float(np.sqrt(mse)), nmse_percent=float(100 * mse / var) if var > 0 else np.inf,
                            offset_error=float(np.mean(e)), output_rms=float(np.sqrt(var)), after_samples=skip)


def _periods(x: np.ndarray, period: int, skip: int) -> np.ndarray:
    """The whole periods of ``x`` after ``skip`` samples, one per row."""
    x = np.asarray(x, float)[skip:]
    k = x.size // period
    if k < 1:
        raise InputError(f"{x.size} samples after the first {skip} hold no whole period of {period} samples")
    return x[: k * period].reshape(k, period)


def _variation(periods: np.ndarray) -> float:
    """RMS of each period about the period average (NaN from one period)."""
    if periods.shape[0] < 2:
        return float("nan")
    return float(np.sqrt(np.mean((periods - periods.mean(axis=0)) ** 2)))


def excited_lines(u_period: np.ndarray, fs_hz: float, band_hz: tuple[float, float]) -> np.ndarray:
    """The lines of one period of a periodic input that were excited: inside ``band_hz`` (the excited band the
    settings found), within :data:`EXCITED_DB` of the median power of the lines there. A measured response used as
    the input (a spindle or wing acceleration) carries the structure's own distortion outside the band, at times
    above its weakest excited lines (an antiresonance): the band, not a level, separates them."""
    p = np.abs(scipy.fft.rfft(np.asarray(u_period, float))) ** 2
    f = np.fft.rfftfreq(np.asarray(u_period).size, 1.0 / fs_hz)
    inside = (f >= band_hz[0]) & (f <= band_hz[1]) & (f > 0)
    if not inside.any():
        return inside
    return inside & (p > np.median(p[inside]) * 10 ** (-EXCITED_DB / 10))


@dataclass(frozen=True)
class DistortionError:
    """The prediction on the lines a periodic excitation did not excite (module docstring).

    Attributes
    ----------
    lines : int
        Non-excited lines scored (above DC).
    measured_rms : float
        RMS of the measured period-averaged output on them [unit of the output]: the distortion measured.
    error_rms : float
        RMS of the prediction's error on them.
    percent_of_none : float
        100·Σ|Y - Ŷ|²/Σ|Y|² on them: 100 % is what predicting no distortion scores.
    share_percent : float
        The distortion's share of the period-averaged output's energy about its mean [%].
    period_variation_rms, measured_period_variation_rms : float
        RMS of each period of the prediction (of the measured output) about its period average [unit of the
        output]; NaN from a single period.
    """

    lines: int
    measured_rms: float
    error_rms: float
    percent_of_none: float
    share_percent: float
    period_variation_rms: float = float("nan")
    measured_period_variation_rms: float = float("nan")

    def not_periodic(self, reference: "DistortionError | None" = None) -> bool:
        """The prediction varies from period to period more than :data:`NOT_PERIODIC` times the measured output
        does (and than ``reference``, another model's prediction of the same record, does)."""
        v, m = self.period_variation_rms, self.measured_period_variation_rms
        r = reference.period_variation_rms if reference is not None else 0.0
        return bool(np.isfinite(v) and np.isfinite(m) and v > NOT_PERIODIC * max(m, r if np.isfinite(r) else 0.0))

    def to_dict(self) -> dict:
        return {"lines": self.lines, "measured_rms": self.measured_rms, "error_rms": self.error_rms,
                "percent_of_none": self.percent_of_none, "share_percent": self.share_percent,
                "period_variation_rms": _finite(self.period_variation_rms),
                "measured_period_variation_rms": _finite(self.measured_period_variation_rms)}


#: a prediction varying from period to period by more than this many times what was measured is not periodic where
#: the structure was (F-16, `nifo run` on levels 3/5/7, its predicted signal at level 1: 0.0092 m/s² against 0.0028
#: measured and 0.0011 for its linear twin; at level 3, which it was identified on: 0.0087 against 0.0105 and 0.0086)
NOT_PERIODIC = 2.0


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def distortion_error(y: np.ndarray, yhat: np.ndarray, u: np.ndarray, fs_hz: float, *, period_samples: int,
                     band_hz: tuple[float, float], skip: int = 0) -> DistortionError:
    """:class:`DistortionError` of ``yhat`` on the lines the periodic input ``u`` did not excite in its excited band
    ``band_hz`` (:func:`excited_lines`), all periods after ``skip`` averaged."""
    p = int(period_samples)
    ys, yhs, us = (_periods(x, p, skip) for x in (y, yhat, u))
    yp, ypp, up = (x.mean(axis=0) for x in (ys, yhs, us))
    exc = excited_lines(up, fs_hz, band_hz)
    Y, Yh = scipy.fft.rfft(yp), scipy.fft.rfft(ypp)
    none = ~exc
    none[0] = False
    n = int(none.sum())
    total = float(np.sum(np.abs(Y[1:]) ** 2))
    d = float(np.sum(np.abs(Y[none]) ** 2))
    e = float(np.sum(np.abs(Y[none] - Yh[none]) ** 2))
    scale = np.sqrt(2.0) / p          # a line's amplitude as an RMS in the time domain
    return DistortionError(lines=n, measured_rms=float(scale * np.sqrt(d)), error_rms=float(scale * np.sqrt(e)),
                           percent_of_none=float(100 * e / d) if d > 0 else float("nan"),
                           share_percent=float(100 * d / total) if total > 0 else 0.0,
                           period_variation_rms=_variation(yhs), measured_period_variation_rms=_variation(ys))
