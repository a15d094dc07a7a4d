"""A band of frequencies as a zero-phase filter: where a model holds, what a prediction is limited to.

:func:`band_taper` is 1 inside ``[lo, hi]``, 0 below ``lo - width`` and above ``hi + width``, a raised cosine
between (the same edges the non-parametric prediction fades with, :mod:`nifo_core.predict.model`).
:func:`band_limit` applies it to a signal in the frequency domain, zero-phase, the record padded with zeros so
that the filter's response does not wrap around from one end to the other (a record of whole periods of a
periodic excitation is filtered exactly as it is: it is periodic).
"""

from __future__ import annotations

import numpy as np
import scipy.fft

from ..errors import ConfigError

__all__ = ["band_taper", "band_limit", "edge_width_hz", "fraction_outside"]


def edge_width_hz(band_hz: tuple[float, float]) -> float:
    """Width [Hz] of each raised-cosine edge of ``band_hz``: 0.5 Hz, at most a quarter of the band."""
    lo, hi = float(band_hz[0]), float(band_hz[1])
    return min(0.5, 0.25 * (hi - lo))


def band_taper(freq_hz: np.ndarray, band_hz: tuple[float, float], width_hz: float | None = None) -> np.ndarray:
    """1 inside ``band_hz``, 0 outside ``[lo - width, hi + width]``, a raised cosine between (module docstring)."""
    lo, hi = float(band_hz[0]), float(band_hz[1])
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi):
        raise ConfigError(f"band {lo:g}-{hi:g} Hz must satisfy 0 <= lo < hi")
    w = edge_width_hz(band_hz) if width_hz is None else float(width_hz)
    f = np.asarray(freq_hz, float)
    if w <= 0:
        return ((f >= lo) & (f <= hi)).astype(float)
    x = np.clip(np.minimum(f - (lo - w), (hi + w) - f) / w, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def band_limit(x: np.ndarray, fs_hz: float, band_hz: tuple[float, float], *, period_samples: int | None = None
               ) -> np.ndarray:
    """``x`` with its content outside ``band_hz`` removed (zero-phase; module docstring); its mean goes with the
    band's lower edge (a band from above 0 Hz removes it).

    ``period_samples``: a record of whole periods is filtered as periodic (no padding); otherwise it is padded by
    four times the edge's time scale (1/width), at most its own length.
    """
    x = np.asarray(x, float)
    n = x.size
    if n == 0:
        return x.copy()
    w = edge_width_hz(band_hz)
    periodic = bool(period_samples) and n % int(period_samples) == 0
    pad = 0 if periodic else min(n, int(np.ceil(4.0 / max(w, 1e-9) * fs_hz)))
    nfft = n if periodic else scipy.fft.next_fast_len(n + pad, real=True)
    f = np.fft.rfftfreq(nfft, 1.0 / fs_hz)
    return scipy.fft.irfft(scipy.fft.rfft(x, nfft) * band_taper(f, band_hz, w), nfft)[:n]


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
