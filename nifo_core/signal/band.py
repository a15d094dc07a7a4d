"""A band of frequencies as a zero-phase filter: where a model holds, what a prediction is limited to.

:func:`band_taper` is 1 inside ``[lo, hi]``, 0 below ``lo - width`` and above ``hi + width``, a raised cosine
between (the edges the non-parametric prediction fades with, :mod:`nifo_core.predict.model`; a limited prediction's
are narrower, :func:`prediction_taper`).
:func:`band_limit` applies it to a signal in the frequency domain, zero-phase, the record padded with zeros so
that the filter's response does not wrap around from one end to the other (a record of whole periods of a
periodic excitation is filtered exactly as it is: it is periodic).
"""

from __future__ import annotations

import numpy as np
import scipy.fft

from ..errors import ConfigError

__all__ = ["band_taper", "band_limit", "edge_width_hz", "fraction_outside", "prediction_taper", "PREDICTION_EDGE"]


def edge_width_hz(band_hz: tuple[float, float]) -> float:
    """Width [Hz] of each raised-cosine edge of ``band_hz``: 0.5 Hz, at most a quarter of the band."""
    lo, hi = float(band_hz[0]), float(band_hz[1])
    return min(0.5, 0.25 * (hi - lo))


def band_taper(freq_hz: np.ndarray, band_hz: tuple[float, float], width_hz: float | tuple[float, float] | None = None
               ) -> np.ndarray:
    """1 inside ``band_hz``, 0 outside ``[lo - w_lo, hi + w_hi]``, a raised cosine between (module docstring);
    ``width_hz`` one width for both edges or (w_lo, w_hi); default :func:`edge_width_hz`."""
    lo, hi = float(band_hz[0]), float(band_hz[1])
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi):
        raise ConfigError(f"band {lo:g}-{hi:g} Hz must satisfy 0 <= lo < hi")
    w = edge_width_hz(band_hz) if width_hz is None else width_hz
    w_lo, w_hi = (float(w), float(w)) if np.ndim(w) == 0 else (float(w[0]), float(w[1]))
    f = np.asarray(freq_hz, float)
    return _edge(f - lo, w_lo) * _edge(hi - f, w_hi)


def _edge(d: np.ndarray, w: float) -> np.ndarray:
    """0 for d < -w, 1 for d >= 0, a raised cosine between (a step for w = 0)."""
    if w <= 0:
        return (d >= 0).astype(float)
    return 0.5 - 0.5 * np.cos(np.pi * np.clip((d + w) / w, 0.0, 1.0))


#: a prediction limited to a band falls off over this fraction of each edge's frequency outside it: narrow, because
#: outside the band the model's response is not identified (the F-16 3/5/7 model predicting level 1 put 0.0078 m/s²
#: RMS of its own into 1.5-2 Hz through a 0.5 Hz edge, against 0.0006 m/s² for its linear twin)
PREDICTION_EDGE = 0.025


def prediction_taper(freq_hz: np.ndarray, band_hz: tuple[float, float]) -> np.ndarray:
    """:func:`band_taper` with the edges of a limited prediction (:data:`PREDICTION_EDGE`)."""
    return band_taper(freq_hz, band_hz, (PREDICTION_EDGE * float(band_hz[0]), PREDICTION_EDGE * float(band_hz[1])))


def band_limit(x: np.ndarray, fs_hz: float, band_hz: tuple[float, float], *, period_samples: int | None = None
               ) -> np.ndarray:
    """``x`` with its content outside ``band_hz`` removed (zero-phase, the edges of :func:`prediction_taper`;
    module docstring); its mean goes with the band's lower edge (a band from above 0 Hz removes it).

    ``period_samples``: a record of whole periods is filtered as periodic (no padding); otherwise it is padded by
    four times the narrowest edge's time scale, at most its own length.
    """
    x = np.asarray(x, float)
    n = x.size
    if n == 0:
        return x.copy()
    w = PREDICTION_EDGE * max(float(band_hz[0]), 1e-3)
    periodic = bool(period_samples) and n % int(period_samples) == 0
    pad = 0 if periodic else min(n, int(np.ceil(4.0 / w * fs_hz)))
    nfft = n if periodic else scipy.fft.next_fast_len(n + pad, real=True)
    f = np.fft.rfftfreq(nfft, 1.0 / fs_hz)
    return scipy.fft.irfft(scipy.fft.rfft(x, nfft) * prediction_taper(f, band_hz), nfft)[:n]


def fraction_outside(x: np.ndarray, fs_hz: float, band_hz: tuple[float, float]) -> float:
    """The fraction of ``x``'s energy about its mean outside ``band_hz`` (0-1; the band's edges count as inside)."""
    x = np.asarray(x, float)
    spec = np.abs(scipy.fft.rfft(x - x.mean())) ** 2
    total = float(np.sum(spec))
    if total <= 0:
        return 0.0
    f = np.fft.rfftfreq(x.size, 1.0 / fs_hz)
    inside = (f >= band_hz[0]) & (f <= band_hz[1])
    return float(np.sum(spec[~inside]) / total)
