"""Road (tire-patch) inputs for the simulator: band-limited random roads and slow chirps.

A road is a frozen description; :func:`road_signal` turns it into the tire-patch
displacement xb [m] and velocity ẋb [m/s] on a uniform grid. The grid starts
``warmup_s`` before t = 0 (the first recorded sample); over the first part of
the warm-up the input fades in with a raised cosine, so the vehicle starts at
rest without a jolt and is settled when recording begins (docs/method.md §6).

- :class:`RandomRoad`: Gaussian, flat displacement spectrum in [f_lo, f_hi]
  with raised-cosine edges (f_lo/2..f_lo and f_hi..1.25·f_hi), made by shaping
  complex Gaussian Fourier coefficients; ẋb is the exact derivative of the same
  band-limited (periodic) signal. Scaled to ``rms_m`` over the whole grid.
- :class:`ChirpRoad`: the paper's characterization input (Table 1), a sine
  displacement of constant amplitude whose frequency sweeps linearly from f0
  at t = 0 at ``rate_hz_per_s``; before t = 0 it is a fading-in sine at f0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft as sfft

from ..errors import ConfigError

__all__ = ["RandomRoad", "ChirpRoad", "Road", "road_signal", "road_from_dict"]

#: raised-cosine edges of the random road's band: f_lo/2..f_lo and f_hi..EDGE_HI·f_hi
EDGE_HI = 1.25


def _check_positive(name: str, value: float, *, allow_zero: bool = False) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        need = "non-negative" if allow_zero else "positive"
        raise ConfigError(f"{name}={value!r} must be finite and {need}")
    return v


@dataclass(frozen=True)
class RandomRoad:
    """Gaussian band-limited road displacement.

    Parameters
    ----------
    rms_m : float
        RMS of the displacement xb [m]; 0.5-7 mm is typical (docs/method.md §6).
    f_lo_hz, f_hi_hz : float
        Band of the displacement spectrum [Hz].
    spectrum : {'flat', 'iso8608'}
        ``'flat'``: flat displacement spectrum in the band. ``'iso8608'``: displacement PSD
        ∝ f⁻² (amplitude ∝ 1/f, constant velocity spectrum) from ``corner_hz`` up, as real
        roads (ISO 8608 at constant speed; docs/method.md §6): a low RMS level then keeps ż small, so
        a play is seen apart from a damper knee (the paper's two-step procedure).
    corner_hz : float
        Where the ISO-like spectrum starts to fall [Hz] (flat below).
    """

    rms_m: float
    f_lo_hz: float = 0.5
    f_hi_hz: float = 40.0
    spectrum: str = "flat"
    corner_hz: float = 1.0

    def __post_init__(self) -> None:
        rms = float(self.rms_m)
        if not np.isfinite(rms) or rms <= 0:
            raise ConfigError(f"road RMS {self.rms_m!r} m must be finite and positive",
                              hint="give the RMS displacement in metres, e.g. 0.0025 for 2.5 mm")
        if rms > 0.1:
            raise ConfigError(f"road RMS {rms:g} m is more than 100 mm",
                              hint="the RMS is in metres: 2.5 mm is 0.0025")
        lo = _check_positive("road f_lo_hz", self.f_lo_hz)
        hi = _check_positive("road f_hi_hz", self.f_hi_hz)
        if lo >= hi:
            raise ConfigError(f"road band {lo:g}-{hi:g} Hz must satisfy f_lo < f_hi", hint="e.g. 0.5-40 Hz")
        if self.spectrum not in ("flat", "iso8608"):
            raise ConfigError(f"road spectrum {self.spectrum!r} must be 'flat' or 'iso8608'")
        _check_positive("road corner_hz", self.corner_hz)

    @property
    def top_hz(self) -> float:
        """Highest frequency with road energy [Hz]."""
        return EDGE_HI * self.f_hi_hz

    def to_dict(self) -> dict:
        d = {"kind": "random", "rms_m": float(self.rms_m), "f_lo_hz": float(self.f_lo_hz),
             "f_hi_hz": float(self.f_hi_hz)}
        if self.spectrum != "flat":
            d |= {"spectrum": self.spectrum, "corner_hz": float(self.corner_hz)}
        return d


@dataclass(frozen=True)
class ChirpRoad:
    """Slow linear sine sweep of the tire patch (paper Table 1: 0-15 Hz at 0.025 Hz/s).

    Parameters
    ----------
    amplitude_m : float
        Displacement amplitude [m].
    f0_hz, f1_hz : float
        Start and end frequency [Hz].
    rate_hz_per_s : float
        Sweep rate [Hz/s].

    ``sweep_s = (f1 - f0) / rate`` is the natural record duration (600 s for
    the defaults).
    """

    amplitude_m: float
    f0_hz: float = 0.0
    f1_hz: float = 15.0
    rate_hz_per_s: float = 0.025

    def __post_init__(self) -> None:
        a = float(self.amplitude_m)
        if not np.isfinite(a) or a <= 0:
            raise ConfigError(f"chirp amplitude {self.amplitude_m!r} m must be finite and positive",
                              hint="give the amplitude in metres, e.g. 0.001 for 1 mm")
        if a > 0.1:
            raise ConfigError(f"chirp amplitude {a:g} m is more than 100 mm", hint="the amplitude is in metres")
        f0 = _check_positive("chirp f0_hz", self.f0_hz, allow_zero=True)
        f1 = _check_positive("chirp f1_hz", self.f1_hz)
        _check_positive("chirp rate_hz_per_s", self.rate_hz_per_s)
        if f1 <= f0:
            raise ConfigError(f"chirp must sweep upwards, got f0={f0:g} Hz, f1={f1:g} Hz")

    @property
    def sweep_s(self) -> float:
        """Duration of the sweep from f0 to f1 [s]."""
        return (self.f1_hz - self.f0_hz) / self.rate_hz_per_s

    @property
    def top_hz(self) -> float:
        return float(self.f1_hz)

    def to_dict(self) -> dict:
        return {"kind": "chirp", "amplitude_m": float(self.amplitude_m), "f0_hz": float(self.f0_hz),
                "f1_hz": float(self.f1_hz), "rate_hz_per_s": float(self.rate_hz_per_s)}


Road = RandomRoad | ChirpRoad


def road_from_dict(d: dict) -> Road:
    """Inverse of ``road.to_dict()``."""
    d = dict(d)
    k = d.pop("kind", None)
    try:
        if k == "random":
            return RandomRoad(**d)
        if k == "chirp":
            return ChirpRoad(**d)
    except TypeError as err:
        raise ConfigError(f"cannot read road {d!r}: {err}") from None
    raise ConfigError(f"unknown road kind {k!r}", hint="use 'random' or 'chirp'")


def _band_gain(f: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Flat in [lo, hi], raised-cosine edges over lo/2..lo and hi..1.25·hi, zero outside."""
    g = ((f >= lo) & (f <= hi)).astype(float)
    m = (f > 0.5 * lo) & (f < lo)
    g[m] = 0.5 - 0.5 * np.cos(np.pi * (f[m] - 0.5 * lo) / (0.5 * lo))
    m = (f > hi) & (f < EDGE_HI * hi)
    g[m] = 0.5 + 0.5 * np.cos(np.pi * (f[m] - hi) / ((EDGE_HI - 1) * hi))
    return g


def _random(road: RandomRoad, fs_hz: float, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    nfft = sfft.next_fast_len(n, real=True)
    f = np.fft.rfftfreq(nfft, 1.0 / fs_hz)
    re, im = rng.standard_normal((2, f.size))
    spec = (re + 1j * im) * _band_gain(f, road.f_lo_hz, road.f_hi_hz)
    if road.spectrum == "iso8608":  # amplitude ∝ 1/f above the corner (displacement PSD ∝ f⁻²)
        spec = spec * np.minimum(1.0, road.corner_hz / np.maximum(f, 1e-12))
    xb = sfft.irfft(spec, nfft)
    scale = road.rms_m / np.sqrt(np.mean(xb**2))
    xbd = sfft.irfft(spec * (2j * np.pi * f), nfft)  # exact derivative of the band-limited signal
    return xb[:n] * scale, xbd[:n] * scale


def _chirp(road: ChirpRoad, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    tp = np.maximum(t, 0.0)
    phase = 2 * np.pi * (road.f0_hz * t + 0.5 * road.rate_hz_per_s * tp**2)
    freq = road.f0_hz + road.rate_hz_per_s * tp  # instantaneous frequency [Hz]
    a = road.amplitude_m
    return a * np.sin(phase), a * 2 * np.pi * freq * np.cos(phase)


def _fade_in(xb: np.ndarray, xbd: np.ndarray, fs_hz: float, n_fade: int) -> None:
    """xb·w and (xb·w)' = ẋb·w + xb·w' with a raised cosine w over the first n_fade samples (in place)."""
    if n_fade < 2:
        return
    k = np.arange(n_fade)
    w = 0.5 - 0.5 * np.cos(np.pi * k / n_fade)
    dw = 0.5 * np.pi * fs_hz / n_fade * np.sin(np.pi * k / n_fade)
    xbd[:n_fade] = xbd[:n_fade] * w + xb[:n_fade] * dw
    xb[:n_fade] *= w


def road_signal(road: Road, *, fs_hz: float, n: int, warmup_s: float, fade_s: float,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Tire-patch displacement xb [m] and velocity ẋb [m/s] on ``n`` samples at ``fs_hz``.

    Sample k is at time ``k/fs_hz - warmup_s`` [s]; the input fades in over the
    first ``fade_s`` seconds. ``rng`` is used only by random roads.
    """
    if isinstance(road, RandomRoad):
        xb, xbd = _random(road, fs_hz, n, rng)
    else:
        xb, xbd = _chirp(road, np.arange(n) / fs_hz - warmup_s)
    _fade_in(xb, xbd, fs_hz, min(n, int(round(fade_s * fs_hz))))
    return xb, xbd
