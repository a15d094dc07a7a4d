"""Band-limited integration of accelerations (docs/method.md §2, pitfalls in §3).

One linear-phase FIR pair approximates 1/(jω) (velocity) and -1/ω²
(displacement) inside a band [f_lo, f_hi] with raised-cosine edges and is zero
outside it. The same taps serve the offline commands (:func:`integrate`,
zero-phase: the (n_taps-1)/2 delay is removed) and the live integrator node
(:class:`StreamingIntegrator`, which outputs the identical samples delayed by
``delay_samples``). Subtract first, then integrate: pass ẍ2 - ẍ1 to get z, ż.

Why FIR and not trapezoid + high-pass: a causal high-pass shifts phase and
distorts restoring-force loops; filtfilt cannot stream. A linear-phase FIR is
exactly zero-phase once its delay is removed, and streams.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import signal

from ..errors import ConfigError, RecordTooShortError

__all__ = ["IntegrationBand", "Integrated", "default_band", "lowest_edge_hz", "integrator_taps", "integrator_length",
           "integrate", "StreamingIntegrator", "integrator_response", "lowest_resolvable_hz", "band_for_records",
           "MAX_TAPS"]

#: the longest integrator designed [taps] (its design needs ~300 bytes per tap): 0.5 Hz up to fs = 65 kHz
MAX_TAPS = 1 << 21


@dataclass(frozen=True)
class IntegrationBand:
    """Pass band [Hz] of the integrator. Edges fall off over ``f_lo/2..f_lo`` and ``f_hi..1.25·f_hi``."""

    f_lo_hz: float
    f_hi_hz: float

    def validate(self, fs_hz: float, *, n_samples: int | None = None) -> "IntegrationBand":
        """``self`` if it can be integrated at ``fs_hz`` (and, given ``n_samples``, resolved by a record
        that long), else :class:`ConfigError` saying the lowest edge that can — before anything is allocated.

        The integrator spans 16 periods of ``f_lo`` (:func:`integrator_length`): it must fit in the record,
        and in :data:`MAX_TAPS`.
        """
        if not (0 < self.f_lo_hz < self.f_hi_hz):
            raise ConfigError(f"integration band {self.f_lo_hz}-{self.f_hi_hz} Hz must satisfy 0 < f_lo < f_hi",
                              hint="e.g. --integration-band 0.5 200")
        if self.f_hi_hz * 1.25 > fs_hz / 2 + 1e-9:
            raise ConfigError(f"integration band upper edge {self.f_hi_hz} Hz is too close to Nyquist "
                              f"({fs_hz / 2:g} Hz at fs={fs_hz:g} Hz)", hint=f"use f_hi <= {fs_hz / 2.5:g} Hz")
        taps = integrator_length(fs_hz, self.f_lo_hz)
        fix = "raise the band's lower edge to at least {lo} Hz (--integration-band {lo} {hi:g}, or settings.integration_band_hz in the model file)"
        if n_samples is not None and taps > n_samples:
            lo = lowest_resolvable_hz(fs_hz, n_samples)
            raise ConfigError(
                f"integration band lower edge {self.f_lo_hz:g} Hz is below what the record resolves: the integrator "
                f"spans 16 periods of it ({_TAPS_PER_CYCLE / self.f_lo_hz:.3g} s), the record is "
                f"{n_samples / fs_hz:.3g} s ({n_samples} samples at {fs_hz:g} Hz); the lowest edge this record "
                f"length can resolve is {_show(lo)} Hz", hint=fix.format(lo=_show(lo), hi=self.f_hi_hz))
        if taps > MAX_TAPS:
            lo = _TAPS_PER_CYCLE * fs_hz / (MAX_TAPS - 1)
            raise ConfigError(
                f"integration band lower edge {self.f_lo_hz:g} Hz needs an integrator of {taps:.3g} taps (16 periods "
                f"at fs={fs_hz:g} Hz); nifo designs at most {MAX_TAPS} (lowest edge {_show(lo)} Hz at this rate)",
                hint=fix.format(lo=_show(lo), hi=self.f_hi_hz))
        return self

    def to_dict(self) -> dict:
        return {"f_lo_hz": self.f_lo_hz, "f_hi_hz": self.f_hi_hz}


def band_for_records(band: IntegrationBand, records) -> IntegrationBand:
    """``band`` validated at the records' rate and against the shortest record (errors name that record)."""
    shortest = min(records, key=lambda r: r.n)
    try:
        return band.validate(min(r.fs_hz for r in records), n_samples=shortest.n)
    except ConfigError as err:
        raise err.with_context(source=shortest.source or None) from None


def default_band(fs_hz: float, duration_s: float | None = None) -> IntegrationBand:
    """A band that contains the body-bounce mode (≈1-1.5 Hz) and keeps integration honest.

    f_lo is 0.5 Hz (docs/method.md §3: the band must contain body bounce; 1.5 Hz
    biased T21 by 10 %, 0.8 Hz by 0.5 %), raised for short records so the
    integrator spans at most half of the record; f_hi = min(200 Hz, fs/2.5)
    (the paper's 200 Hz low-pass, Table 2).
    """
    f_lo = 0.5
    if duration_s is not None and duration_s > 0:
        f_lo = max(f_lo, 2 * _TAPS_PER_CYCLE / duration_s)
    f_hi = min(200.0, fs_hz / 2.5)
    if f_lo >= f_hi:
        raise RecordTooShortError(f"a {duration_s:.2f} s record is too short to integrate",
                                  hint="record at least 30 s")
    return IntegrationBand(f_lo, f_hi)


_TAPS_PER_CYCLE = 16.0  # taps = 16 periods of f_lo: |H| within 0.2 % of ideal from 1.5·f_lo


def lowest_edge_hz(duration_s: float) -> float:
    """The lowest lower edge [Hz] a record of ``duration_s`` can integrate: its integrator spans at most half of it."""
    return 2 * _TAPS_PER_CYCLE / float(duration_s)


def integrator_length(fs_hz: float, f_lo_hz: float) -> float:
    """Taps of the integrator for lower edge ``f_lo_hz`` at ``fs_hz`` (odd), computed without designing it
    (a float: ``inf`` for an edge so low that no integer holds it)."""
    n = _TAPS_PER_CYCLE * float(fs_hz) / float(f_lo_hz)
    if not np.isfinite(n) or n > 1e18:
        return float("inf")
    return float(int(np.ceil(n)) | 1)


def lowest_resolvable_hz(fs_hz: float, n_samples: int) -> float:
    """The lowest band edge whose integrator (16 periods, :func:`integrator_length`) fits ``n_samples``."""
    n = int(n_samples) if int(n_samples) % 2 else int(n_samples) - 1
    return _TAPS_PER_CYCLE * float(fs_hz) / max(n, 1)


def _show(f_hz: float) -> str:
    """``f_hz`` rounded up to 3 significant digits (an edge shown this way is resolvable)."""
    if not np.isfinite(f_hz) or f_hz <= 0:
        return f"{f_hz:g}"
    e = int(np.floor(np.log10(f_hz))) - 2
    return f"{np.ceil(f_hz / 10.0 ** e) * 10.0 ** e:.3g}"


def _window_gain(f: np.ndarray, band: IntegrationBand, fs_hz: float) -> np.ndarray:
    lo0, lo1 = 0.5 * band.f_lo_hz, band.f_lo_hz
    hi0, hi1 = band.f_hi_hz, min(1.25 * band.f_hi_hz, fs_hz / 2)
    w = np.zeros_like(f)
    w[(f >= lo1) & (f <= hi0)] = 1.0
    m = (f > lo0) & (f < lo1)
    w[m] = 0.5 - 0.5 * np.cos(np.pi * (f[m] - lo0) / (lo1 - lo0))
    m = (f > hi0) & (f < hi1)
    w[m] = 0.5 + 0.5 * np.cos(np.pi * (f[m] - hi0) / (hi1 - hi0))
    return w


@lru_cache(maxsize=32)
def _taps_cached(fs_hz: float, f_lo: float, f_hi: float) -> tuple[np.ndarray, np.ndarray]:
    band = IntegrationBand(f_lo, f_hi)
    n = int(integrator_length(fs_hz, band.f_lo_hz))  # odd: integer delay
    nfft = 1 << int(np.ceil(np.log2(8 * n)))
    f = np.fft.rfftfreq(nfft, 1 / fs_hz)
    w = _window_gain(f, band, fs_hz)
    with np.errstate(divide="ignore", invalid="ignore"):
        jw = 2j * np.pi * f
        hv = np.where(w > 0, w / jw, 0)
        hd = np.where(w > 0, w / jw**2, 0)
    d = (n - 1) // 2
    win = signal.windows.kaiser(n, 8.0)
    out = []
    for h in (hv, hd):
        imp = np.fft.irfft(h, nfft)  # DTFT of the taps = W(f)/(jω)^order, in s or s²
        imp = np.roll(imp, d)[:n] * win
        imp.flags.writeable = False
        out.append(imp)
    return out[0], out[1]


def integrator_taps(fs_hz: float, band: IntegrationBand) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and displacement FIR taps (odd length, delay ``(len-1)//2``), read-only."""
    band.validate(fs_hz)
    return _taps_cached(float(fs_hz), float(band.f_lo_hz), float(band.f_hi_hz))


def integrator_response(freq_hz: np.ndarray, fs_hz: float, band: IntegrationBand) -> tuple[np.ndarray, np.ndarray]:
    """Zero-phase frequency response of the velocity and displacement integrators at ``freq_hz``."""
    hv, hd = integrator_taps(fs_hz, band)
    d = (hv.size - 1) // 2
    w = 2 * np.pi * np.asarray(freq_hz) / fs_hz
    k = np.arange(hv.size) - d
    e = np.exp(-1j * np.outer(w, k))
    return e @ hv, e @ hd


@dataclass(frozen=True)
class Integrated:
    """Velocity [m/s] and displacement [m] of one acceleration signal, with how they were made.

    The first and last ``edge_samples`` are start-up transients (the filter ran
    over zero padding); ``valid`` selects the rest.
    """

    velocity: np.ndarray
    displacement: np.ndarray
    band: IntegrationBand
    edge_samples: int

    @property
    def valid(self) -> slice:
        return slice(self.edge_samples, self.velocity.size - self.edge_samples)


def integrate(accel: np.ndarray, fs_hz: float, *, band: IntegrationBand | None = None) -> Integrated:
    """Zero-phase band-limited integration of an acceleration [m/s²] to velocity and displacement.

    For relative motion pass the difference of the accelerations (ẍ2 - ẍ1).
    """
    a = np.asarray(accel, dtype=float)
    band = band or default_band(fs_hz, a.size / fs_hz)
    if a.size < integrator_length(fs_hz, band.f_lo_hz):   # before the taps are designed
        band.validate(fs_hz, n_samples=a.size)
    hv, hd = integrator_taps(fs_hz, band)
    v = signal.oaconvolve(a, hv, mode="same")
    x = signal.oaconvolve(a, hd, mode="same")
    return Integrated(v, x, band, (hv.size - 1) // 2)


class StreamingIntegrator:
    """Streaming form of :func:`integrate`: push samples as they arrive.

    Output sample k of :meth:`push` equals sample k of ``integrate`` on the
    whole stream (to FFT rounding); it becomes available ``delay_samples``
    later. :meth:`flush` returns the last ``delay_samples`` (zero-padded end,
    as the batch form does).
    """

    #: pushes of up to this many samples are convolved directly, longer ones by overlap-add FFT: the direct sum costs
    #: in proportion to the push, the FFT about the same whatever it is, and they cross between 256 and 512 samples
    #: for any length of taps (``benchmarks/bench_integrator.py``, CPU per push, the direct sum's gain: 4801 taps
    #: 43× at 1 sample, 4.5× at 60, 1.13× at 256, 0.99× at 512; 6401 and 11 429 taps alike). The integrator node's
    #: blocks (0.1 s: 60 samples at 600 Hz) take the direct sum; both agree with the batch form to 1e-15.
    DIRECT_MAX = 256

    def __init__(self, fs_hz: float, band: IntegrationBand) -> None:
        self.fs_hz = float(fs_hz)
        self.band = band
        self._hv, self._hd = integrator_taps(fs_hz, band)
        self.delay_samples = (self._hv.size - 1) // 2
        self._buf = np.zeros(self._hv.size - 1)
        self._skip = self.delay_samples  # full-convolution outputs before batch sample 0

    def push(self, accel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Feed samples; return the velocity and displacement samples now complete."""
        a = np.asarray(accel, dtype=float)
        if a.size == 0:
            return np.empty(0), np.empty(0)
        ext = np.concatenate([self._buf, a])
        if a.size <= self.DIRECT_MAX:     # the same outputs to rounding (1e-15 of the largest), sooner (above)
            v = np.convolve(ext, self._hv, mode="valid")
            x = np.convolve(ext, self._hd, mode="valid")
        else:
            v = signal.oaconvolve(ext, self._hv, mode="valid")
            x = signal.oaconvolve(ext, self._hd, mode="valid")
        self._buf = ext[-(self._hv.size - 1):]
        if self._skip:
            k = min(self._skip, v.size)
            v, x = v[k:], x[k:]
            self._skip -= k
        return v, x

    def flush(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the outputs still held back (the stream's end padded with zeros)."""
        return self.push(np.zeros(self.delay_samples))
