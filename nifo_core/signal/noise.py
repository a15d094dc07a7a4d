"""Sensor noise on each accelerometer, estimated from the data, and noise of the same level to add (docs/method.md §9).

Both accelerometers are noisy. Least squares on regressors built from them — z, ż
integrated from ẍ2 - ẍ1, any g(z, ż) — is biased (errors in variables: the noise
integrated into z pulls a cubic coefficient towards zero, it blurs a friction's
sign(ż)); an output-error fit driven by the noisy spindle signal is biased too
(:mod:`nifo_core.predict.refine`). Removing the bias needs the noise level of each sensor.

How it is estimated here (white noise, the usual model of an accelerometer's
electronic and quantisation noise above its 1/f corner): the Welch spectrum of each
channel and of the relative acceleration ẍ2 - ẍ1, averaged over octave bands from
the lowest that holds :data:`MIN_LINES` lines up to :data:`TOP_FRACTION` of the sample
rate; a channel's noise floor is the lowest octave of its *conditioned* spectrum G_ii·(1 - γ²₁₂),
the part not coherent with the other channel (a friction's or a stop's harmonics reach both masses
and are coherent; the sensors' noises are not). A vehicle's motion leaves a floor
at both ends of the spectrum — below the body mode (the strut hardly moves there, so
ẍ2 - ẍ1 is noise alone) and above the wheel-hop and the road's band — and the lower of
the two is the less contaminated. The floor of ẍ2 - ẍ1 is the noise that reaches z
and ż (the two sensors' noises add, they are independent); the channels' own floors
split it between the sensors (scaled down to it when they sum to more).

The estimate is an upper bound where signal fills every octave of a channel (then
the correction over-corrects; the report names the octave each level was read in).
A record whose spindle does not move (a force-driven rig) has no spindle noise and
its output channel may be a differentiated displacement: no estimate
(:attr:`NoiseEstimate.available` False, with why).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from .record import Record
from .spectral import SpectralSettings, auto_spectrum, cross_spectra

__all__ = ["ChannelNoise", "NoiseEstimate", "estimate_noise", "renoised", "noise_draw", "MIN_LINES",
           "TOP_FRACTION"]

#: an octave band counts once it holds this many spectral lines
MIN_LINES = 8
#: octave bands end at this fraction of the sample rate (below a data logger's anti-aliasing roll-off)
TOP_FRACTION = 0.4
#: the lowest octave starts no lower than this [Hz] (an accelerometer's 1/f noise and drift below)
LOWEST_HZ = 0.05


@dataclass(frozen=True)
class ChannelNoise:
    """White noise on one channel.

    Attributes
    ----------
    channel : str
        ``'spindle_accel'`` or ``'body_accel'``.
    std : float
        Standard deviation per sample [m/s²] (white over 0..fs/2).
    psd : float
        One-sided power spectral density [(m/s²)²/Hz].
    relative : float
        ``std`` over the channel's RMS (0.02: 2 % noise).
    octave_hz : (float, float)
        The octave band the level was read in.
    """

    channel: str
    std: float
    psd: float
    relative: float
    octave_hz: tuple[float, float]

    def to_dict(self) -> dict:
        return {"channel": self.channel, "std": self.std, "psd": self.psd, "relative": self.relative,
                "percent_of_rms": 100.0 * self.relative, "octave_hz": list(self.octave_hz)}


@dataclass(frozen=True)
class NoiseEstimate:
    """The noise on a record's two accelerometers (module docstring), or why there is none.

    Attributes
    ----------
    source : str
        The record.
    channels : tuple of ChannelNoise
        Spindle, then body (empty when not available).
    relative_psd : float
        Floor of ẍ2 - ẍ1 [(m/s²)²/Hz]: the noise that reaches z and ż.
    relative_octave_hz : (float, float)
    unavailable : str or None
        Why there is no estimate.
    """

    source: str
    channels: tuple[ChannelNoise, ...] = ()
    relative_psd: float = 0.0
    relative_octave_hz: tuple[float, float] = (0.0, 0.0)
    unavailable: str | None = None

    @property
    def available(self) -> bool:
        return self.unavailable is None and len(self.channels) == 2

    def channel(self, name: str) -> ChannelNoise:
        return next(c for c in self.channels if c.channel == name)

    @property
    def stds(self) -> tuple[float, float]:
        """(spindle, body) standard deviations per sample [m/s²]; zeros when not available."""
        if not self.available:
            return 0.0, 0.0
        return self.channel("spindle_accel").std, self.channel("body_accel").std

    def text(self) -> str:
        if not self.available:
            return f"{self.source}: no noise estimate ({self.unavailable})"
        # the channels by their symbols (ẍ1 input side — a vehicle's spindle —, ẍ2 output side): the core does not
        # know whether the data are a vehicle's
        parts = [f"{'ẍ1' if c.channel.startswith('spindle') else 'ẍ2'} {100 * c.relative:.2g} % of its RMS "
                 f"({c.std:.3g} m/s², "
                 f"floor at {c.octave_hz[0]:.3g}-{c.octave_hz[1]:.3g} Hz)" for c in self.channels]
        return f"{self.source}: sensor noise " + ", ".join(parts)

    def to_dict(self) -> dict:
        return {"source": self.source, "available": self.available, "unavailable": self.unavailable,
                "method": "lowest octave of each channel's spectrum conditioned on the other (white noise)",
                "channels": [c.to_dict() for c in self.channels],
                "relative_accel_psd": self.relative_psd, "relative_accel_octave_hz": list(self.relative_octave_hz),
                "text": self.text()}


def _octave_floors(psd: np.ndarray, f: np.ndarray, edges: np.ndarray) -> tuple[float, tuple[float, float]]:
    """The lowest octave-band mean of ``psd`` and its band."""
    best, where = np.inf, (0.0, 0.0)
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (f >= lo) & (f < hi)
        if m.sum() >= MIN_LINES:
            v = float(np.mean(psd[m]))
            if v < best:
                best, where = v, (float(lo), float(hi))
    return best, where


def estimate_noise(record: Record) -> NoiseEstimate:
    """The white-noise level of a record's spindle and body accelerometers (module docstring)."""
    src = record.source or "record"
    if record.spindle_fixed:
        return NoiseEstimate(src, unavailable="the spindle does not move (a force-driven rig): the noise model of "
                                              "two accelerometers does not apply")
    fs, n = float(record.fs_hz), int(record.n)
    block = int(2 ** np.floor(np.log2(max(n // 2, 16))))
    if block < 256:
        return NoiseEstimate(src, unavailable=f"{n} samples are too few for a noise floor")
    a1, a2 = np.asarray(record.spindle_accel, float), np.asarray(record.body_accel, float)
    sp = cross_spectra(np.stack([a1, a2, a2 - a1]), fs, SpectralSettings(block=block, overlap=0.5, window="hann"))
    f = sp.freq_hz
    df = fs / block
    lo = max(LOWEST_HZ, MIN_LINES * df / 2 ** 0.5)
    top = TOP_FRACTION * fs
    if not top > 2 * lo:
        return NoiseEstimate(src, unavailable=f"the record ({n / fs:.3g} s) resolves no octave band below "
                                              f"{top:.3g} Hz")
    edges = lo * 2.0 ** np.arange(0, np.floor(np.log2(top / lo)) + 1)
    n_avg = max(int(sp.n_avg), 2)
    g11, g22 = auto_spectrum(sp, 0), auto_spectrum(sp, 1)
    g12 = np.abs(sp.G[:, 0, 1]) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        coh = np.where(g11 * g22 > 0, g12 / (g11 * g22), 0.0)
    # conditioned spectra: the part of each channel not coherent with the other (noise is never coherent; a strut
    # force's harmonics reach both masses and are); n/(n-1) undoes the estimated coherence's bias
    unc = np.clip(1.0 - coh, 0.0, 1.0) * n_avg / (n_avg - 1)
    floors = [_octave_floors(g, f, edges) for g in (g11 * unc, g22 * unc, auto_spectrum(sp, 2))]
    (s1, w1), (s2, w2), (sr, wr) = floors
    if not (np.isfinite(s1) and np.isfinite(s2) and np.isfinite(sr)) or s1 <= 0 or s2 <= 0:
        return NoiseEstimate(src, unavailable="no octave band with enough lines, or a channel without noise "
                                              "(exactly zero floor)")
    if s1 + s2 > sr > 0:          # the relative channel's floor is the cleaner measure of what reaches z
        s1, s2 = s1 * sr / (s1 + s2), s2 * sr / (s1 + s2)
    sr = min(sr, s1 + s2)
    out = []
    for name, s, w, x in (("spindle_accel", s1, w1, a1), ("body_accel", s2, w2, a2)):
        std = float(np.sqrt(s * fs / 2))
        rms = float(np.sqrt(np.mean(x ** 2)))
        out.append(ChannelNoise(name, std, float(s), std / rms if rms > 0 else float("inf"), w))
    return NoiseEstimate(src, tuple(out), float(sr), wr)


def noise_draw(n: int, rng: np.random.Generator) -> np.ndarray:
    """One realisation of unit white noise for both channels, shape (2, n) (spindle, body)."""
    return rng.standard_normal((2, int(n)))


def renoised(record: Record, estimate: NoiseEstimate, draw: np.ndarray, scale: float) -> Record:
    """``record`` with ``scale`` × the estimated noise added to each accelerometer (``draw``: :func:`noise_draw`,
    or its negative for the antithetic copy). The result has the noise of the data plus ``scale²`` times as much
    again in variance."""
    s1, s2 = estimate.stds
    a1 = np.asarray(record.spindle_accel, float) + scale * s1 * draw[0, :record.n]
    a2 = np.asarray(record.body_accel, float) + scale * s2 * draw[1, :record.n]
    return replace(record, spindle_accel=a1, body_accel=a2)


def pooled(estimates: Sequence[NoiseEstimate]) -> str:
    """One line naming every record's estimate."""
    return "; ".join(e.text() for e in estimates)
