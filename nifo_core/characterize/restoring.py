"""Restoring-force data from two accelerations, and its slices (paper §2.1, §3.2; docs/method.md §2).

From the body equation (paper Eq. 2, signs of :mod:`nifo_core.simulate.vehicle`)::

    -ẍ2 = (K2/M2)·z + (C2/M2)·ż + (K3/M2)·x2 + Σ (c_i/M2)·g_i(z, ż)

so the body acceleration, negated, is the strut's restoring force per unit
sprung mass; plotted against the relative velocity ż it shows damping
nonlinearities, against the relative displacement z stiffness nonlinearities
(paper Figs. 3, 4, 7). Only the two accelerations are needed.

Processing (docs/method.md §2-3):

1. Subtract first, then integrate: r̈ = ẍ2 - ẍ1 → ż, z with the band-limited,
   zero-phase FIR of :mod:`nifo_core.signal.integrate`.
2. Band-pass ẍ2 with *the same* band (:func:`bandpass`: the velocity
   integrator's taps times jω), so force and motion are filtered alike.
3. Drop the integrator's edge samples (``Integrated.valid``).

Slicing: chirp data by windows of the instantaneous frequency, estimated from
the spindle signal (:func:`instantaneous_frequency`, paper Fig. 3); random
data by amplitude bins of the local motion amplitude (Fig. 4), or by records
taken at several levels.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal, Mapping, Sequence

import numpy as np
from scipy import fft as sfft
from scipy import signal, stats

from ..errors import ConfigError, InputError, NifoError, RecordTooShortError
from ..signal.integrate import IntegrationBand, default_band, integrate, integrator_taps
from ..signal.memo import ArrayMemo
from ..signal.record import Record

__all__ = ["RestoringForce", "restoring_force", "bandpass", "bandpass_settle_samples", "suggest_band",
           "BandSuggestion", "FrequencyTrack", "track_frequency", "instantaneous_frequency", "Slice", "frequency_slices", "amplitude_slices",
           "local_amplitude"]


# --------------------------------------------------------------------------------------------
# band-pass matched to the integrator
# --------------------------------------------------------------------------------------------
@lru_cache(maxsize=16)
def _bandpass_response(fs_hz: float, f_lo: float, f_hi: float, nfft: int) -> np.ndarray:
    """rfft-domain response of the band-pass that matches the velocity integrator.

    The velocity taps ``hv`` approximate W(f)/(jω); times jω (at the DFT bins,
    where W is zero well below Nyquist) they give W(f): the band-pass whose
    output is the derivative of the integrator's velocity. Zero phase: the
    taps' delay is removed here.
    """
    hv, _ = integrator_taps(fs_hz, IntegrationBand(f_lo, f_hi))
    d = (hv.size - 1) // 2
    f = np.fft.rfftfreq(nfft, 1 / fs_hz)
    h = sfft.rfft(hv, nfft) * np.exp(2j * np.pi * f * d / fs_hz) * (2j * np.pi * f)
    h.flags.writeable = False
    return h


def _bp_nfft(n: int, fs_hz: float, band: IntegrationBand) -> int:
    hv, _ = integrator_taps(fs_hz, band)
    return sfft.next_fast_len(n + hv.size, real=True)


def bandpass(x: np.ndarray, fs_hz: float, band: IntegrationBand) -> np.ndarray:
    """Zero-phase band-pass of ``x`` (along the last axis) with the integrator's band.

    ``bandpass(a) == d/dt integrate(a).velocity`` (to rounding): apply it to
    the body acceleration and to every describing function g(z, ż) so they are
    band-limited exactly as z and ż are (docs/method.md §5 step 3). Like
    :func:`~nifo_core.signal.integrate.integrate` the ends see zero padding; see
    :func:`bandpass_settle_samples`. The result is read-only: an equal array
    band-passed again is looked up, not recomputed (:data:`_BANDPASSED`).
    """
    band.validate(fs_hz)
    return _BANDPASSED(np.asarray(x, dtype=float), float(fs_hz), float(band.f_lo_hz), float(band.f_hi_hz))


def _bandpassed(x: np.ndarray, fs_hz: float, f_lo: float, f_hi: float) -> np.ndarray:
    n = x.shape[-1]
    nfft = _bp_nfft(n, fs_hz, IntegrationBand(f_lo, f_hi))
    h = _bandpass_response(fs_hz, f_lo, f_hi, nfft)
    return np.ascontiguousarray(sfft.irfft(sfft.rfft(x, nfft, axis=-1) * h, nfft, axis=-1)[..., :n])


#: band-passed arrays, looked up by content (:class:`~nifo_core.signal.memo.ArrayMemo`: read-only results). The loop
#: band-passes the same g(z, ż) again and again (the design matrices of its rounds, candidates and bounds): measured
#: in ``nifo loop`` on ``benchmarks/bench_loop.py``'s 4 x 300 s, 1141 of 2864 calls repeat an earlier one, 725 of them
#: within the last 64 distinct arrays, 654 within the last 32; at 1-5 MB a result, 32 kept (at most 64 MB)
_BANDPASSED = ArrayMemo(_bandpassed, size=32, max_bytes=2 ** 26)


@lru_cache(maxsize=16)
def _settle(fs_hz: float, f_lo: float, f_hi: float, tol: float) -> int:
    hv, _ = integrator_taps(fs_hz, IntegrationBand(f_lo, f_hi))
    nfft = sfft.next_fast_len(4 * hv.size, real=True)
    hb = np.fft.fftshift(sfft.irfft(_bandpass_response(fs_hz, f_lo, f_hi, nfft), nfft))
    c = nfft // 2
    a = np.abs(hb)
    tail = np.cumsum(a[::-1])[::-1]  # tail[k] = Σ_{i>=k} |hb_i|
    # L1 mass of the impulse response farther than k samples from its centre (both sides)
    k = np.arange(c - 1)
    outside = tail[c + k + 1] + (tail[0] - tail[c - k])
    ok = np.nonzero(outside <= tol * a.sum())[0]
    return int(ok[0]) if ok.size else c


def bandpass_settle_samples(fs_hz: float, band: IntegrationBand, *, tol: float = 0.005) -> int:
    """Samples at each end of a band-passed segment disturbed by the segment's edges.

    Beyond this many samples from the centre the band-pass's impulse response
    holds less than ``tol`` of its L1 mass, so a step at a segment's edge
    changes the output there by less than ``tol`` of the step.
    """
    band.validate(fs_hz)
    return _settle(float(fs_hz), float(band.f_lo_hz), float(band.f_hi_hz), float(tol))


# --------------------------------------------------------------------------------------------
# restoring-force data
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RestoringForce:
    """Restoring force per unit sprung mass against relative motion, edges trimmed.

    Attributes
    ----------
    force : ndarray, shape (n,)
        -ẍ2, band-passed like z and ż [m/s² = N/kg]. Times M2 it is the strut force [N].
    z, zdot : ndarray, shape (n,)
        Relative displacement x2 - x1 [m] and velocity [m/s], band-limited integrals of ẍ2 - ẍ1.
    spindle_accel : ndarray, shape (n,)
        The raw spindle acceleration over the same samples [m/s²] (for frequency tracking).
    time_s : ndarray, shape (n,)
        Time of each sample from the record's first sample [s].
    fs_hz : float
    band : IntegrationBand
        Integration (and band-pass) band.
    start : int
        Index of the first kept sample in the record (the integrator's edge).
    source : str
    x2 : ndarray, shape (n,), optional
        Body displacement [m] integrated from ẍ2 alone (only when asked for: fitting K3·x2).
    applied : ndarray, shape (n,), optional
        The record's measured force on the body [N], band-passed like ``force``
        (then -ẍ2 = k·z + c·ż + Σ γ_i·g_i - F/M2: one more linear column).
    """

    force: np.ndarray
    z: np.ndarray
    zdot: np.ndarray
    spindle_accel: np.ndarray
    time_s: np.ndarray
    fs_hz: float
    band: IntegrationBand
    start: int
    source: str = ""
    x2: np.ndarray | None = None
    applied: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.z.size)

    def select(self, index) -> "RestoringForce":
        """The samples ``index`` (a mask or index array; order kept) as a new object."""
        return RestoringForce(self.force[index], self.z[index], self.zdot[index], self.spindle_accel[index],
                              self.time_s[index], self.fs_hz, self.band, self.start, self.source,
                              None if self.x2 is None else self.x2[index],
                              None if self.applied is None else self.applied[index])

    def linear_fit(self) -> tuple[float, float, float]:
        """Least squares ``force ≈ k·z + c·ż``: (k = K2/M2 [1/s²], c = C2/M2 [1/s], R²).

        A linear strut gives a planar surface: R² near 1.
        """
        a = np.column_stack([self.z, self.zdot])
        coef, *_ = np.linalg.lstsq(a, self.force, rcond=None)
        res = self.force - a @ coef
        r2 = 1.0 - float(res @ res) / float(self.force @ self.force)
        return float(coef[0]), float(coef[1]), r2


def restoring_force(record: Record, *, band: IntegrationBand | None = None,
                    body_displacement: bool = False) -> RestoringForce:
    """Restoring-force data of a record (paper Eq. 2; docs/method.md §2).

    Parameters
    ----------
    record : Record
        Spindle (ẍ1) and body (ẍ2) accelerations [m/s²].
    band : IntegrationBand, optional
        Integration band; default :func:`~nifo_core.signal.integrate.default_band`
        for the record's rate and length (see also :func:`suggest_band`).
    body_displacement : bool
        Also integrate ẍ2 alone to x2 (for a K3·x2 term).

    Returns
    -------
    RestoringForce
        -ẍ2 (band-passed), z and ż, with the integrator's edge samples dropped.
    """
    fs = float(record.fs_hz)
    try:
        band = (band or default_band(fs, record.duration_s)).validate(fs, n_samples=record.n)
    except NifoError as err:
        raise err.with_context(source=record.source) from None
    rel = np.asarray(record.body_accel) - np.asarray(record.spindle_accel)  # subtract first
    try:
        it = integrate(rel, fs, band=band)
    except RecordTooShortError as err:
        raise err.with_context(source=record.source) from None
    v = it.valid
    if v.stop - v.start < max(16, int(4 * fs / band.f_lo_hz)):
        raise RecordTooShortError(
            f"{record.duration_s:.1f} s leaves {max(v.stop - v.start, 0)} samples once the integrator's edges "
            f"({it.edge_samples} samples each) are dropped", source=record.source or "record",
            hint="record longer or raise the band's lower edge (--integration-band)")
    force = -bandpass(record.body_accel, fs, band)
    t = np.arange(record.n) / fs
    x2 = integrate(record.body_accel, fs, band=band).displacement[v] if body_displacement else None
    applied = bandpass(record.force, fs, band)[v] if record.force is not None else None
    return RestoringForce(force[v], it.displacement[v], it.velocity[v], np.asarray(record.spindle_accel)[v],
                          t[v], fs, band, v.start, record.source, x2, applied)


# --------------------------------------------------------------------------------------------
# band choice from the data
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BandSuggestion:
    """A data-driven integration band and why (docs/method.md §3).

    ``snr_db_at_hz`` maps a few frequencies (0.5, 1, 1.5, 2, 3 Hz) to the
    signal-to-noise ratio of ẍ2 - ẍ1 there: the SNR of z, ż at that frequency.
    """

    band: IntegrationBand
    noise_floor_m2_s4_hz: float
    snr_db_at_hz: Mapping[float, float]
    reason: str

    def to_dict(self) -> dict:
        return {**self.band.to_dict(), "noise_floor_m2_s4_hz": self.noise_floor_m2_s4_hz,
                "snr_db_at_hz": {f"{k:g}": v for k, v in self.snr_db_at_hz.items()}, "reason": self.reason}


def suggest_band(record: Record | Sequence[Record], *, min_snr_db: float = 10.0, check_to_hz: float = 5.0,
                 f_hi_hz: float | None = None) -> BandSuggestion:
    """Choose the band's lower edge where the relative motion rises out of the noise (docs/method.md §3).

    White accelerometer noise integrated twice grows as 1/ω⁴, so below some
    frequency z is mostly noise; noisy z makes every stiffness candidate
    blur (a 0.43 mm backlash is invisible under 0.25 mm of integrated noise)
    and attenuates the fitted stiffness. The SNR of z at f equals that of
    r̈ = ẍ2 - ẍ1 at f: its Welch spectrum over its 10th-percentile level in the top
    octave below ``f_hi`` (where a vehicle has little motion; the noise floor).
    ``f_lo`` is the lowest frequency from which the SNR stays ≥ ``min_snr_db``
    up to ``check_to_hz`` (above that the 1/ω⁴ growth no longer matters), and
    at least :func:`~nifo_core.signal.integrate.default_band`'s (of the shortest
    record). Noise-free data gets the default band.

    Several records (levels of one vehicle, one band for all: characterize and the loop stack them in one
    regression) are judged together: the spectra summed, the regression's SNR, the same whichever order the
    records come in. Measured (``benchmarks/bench_loop.py``'s four levels, 1-6 mm road, a hidden Coulomb friction of
    100 N beside the declared knee, 2 % noise): the first record alone, the 1 mm one where the friction nearly
    locks the strut, put the edge at 3.96 Hz; ż then missed 4-26 mm/s of its motion below it (against the
    truth), a friction's sign(ż) was blurred over it, and the loop added the cubic but not the friction (the
    knee absorbed it: -4900 N·s/m beyond 0.026 m/s). Pooled, the edge fell to 1.61 Hz and the loop added
    both, and nothing else (held-out equation error 2.23 → 0.62 %).

    Body bounce (≈1-1.5 Hz) then often lies in the integrator's transition
    band ``f_lo/2..f_lo`` and is passed only in part: fine for characterizing
    (y, z and every candidate see the same band), worth knowing for NIFO's T21
    (docs/method.md §3), for which a lower edge may be chosen knowingly.
    """
    recs = [record] if isinstance(record, Record) else list(record)
    if not recs:
        raise InputError("no records to suggest an integration band for")
    fs = float(recs[0].fs_hz)
    shortest = min(recs, key=lambda r: r.duration_s)
    try:
        base = default_band(fs, shortest.duration_s)
    except NifoError as err:
        raise err.with_context(source=shortest.source) from None
    f_hi = float(f_hi_hz) if f_hi_hz is not None else base.f_hi_hz
    nper = int(min(2 ** np.ceil(np.log2(fs / 0.05)), max(256, min(r.n for r in recs) // 4)))
    p = 0.0
    for r in recs:
        if float(r.fs_hz) != fs:
            raise InputError(f"records at {fs:g} and {float(r.fs_hz):g} Hz cannot share one integration band",
                             source=r.source, hint="resample them to one rate")
        rel = np.asarray(r.body_accel) - np.asarray(r.spindle_accel)
        f, pr = signal.welch(rel, fs, nperseg=nper)
        p = p + pr
    top = (f >= 0.5 * f_hi) & (f <= f_hi)
    floor = float(np.quantile(p[top], 0.1)) if top.any() else 0.0  # low quantile: harmonics, impacts are not noise
    if not floor > 0:
        return BandSuggestion(IntegrationBand(base.f_lo_hz, f_hi).validate(fs), 0.0, {},
                              "no noise floor found: default band")
    snr = 10 * np.log10(np.maximum(p, 1e-300) / floor)
    snr = np.convolve(snr, np.ones(3) / 3, mode="same")  # ±1 bin: one noisy bin must not decide
    at = {fr: round(float(np.interp(fr, f, snr)), 1) for fr in (0.5, 1.0, 1.5, 2.0, 3.0) if fr < f[-1]}
    check = (f > 0) & (f <= check_to_hz)
    bad = np.nonzero(check & (snr < min_snr_db))[0]
    if bad.size == 0:
        f_lo, why = base.f_lo_hz, f"z is {min_snr_db:g} dB above the noise down to {f[1]:.2g} Hz"
    elif bad[-1] + 1 < f.size and f[bad[-1] + 1] <= check_to_hz:
        f_snr = float(f[bad[-1] + 1])
        f_lo = max(base.f_lo_hz, f_snr)
        why = f"z rises {min_snr_db:g} dB above the integrated accelerometer noise at {f_snr:.2f} Hz"
    else:
        f_lo = max(base.f_lo_hz, check_to_hz)
        why = f"z never rises {min_snr_db:g} dB above the noise below {check_to_hz:g} Hz"
    if len(recs) > 1:
        why += f" (the {len(recs)} records' spectra summed)"
    if f_lo == base.f_lo_hz and bad.size:
        why += f" (the {'shortest ' if len(recs) > 1 else ''}record's length sets f_lo = {base.f_lo_hz:g} Hz)"
    return BandSuggestion(IntegrationBand(round(f_lo, 2), f_hi).validate(fs), floor, at, why)


# --------------------------------------------------------------------------------------------
# slicing
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FrequencyTrack:
    """The frequency of the dominant sine at every sample, and how much to trust it.

    Attributes
    ----------
    freq_hz : ndarray, shape (n,)
        Instantaneous frequency [Hz].
    reliable_fraction : float
        Fraction of STFT frames with a clear peak (4× the frame's median).
    trend : float
        Rank correlation of the reliable frames' frequency with time (±1: a monotone sweep).
    sweep_law : tuple of float, optional
        For a sweep, the coefficients (highest power first, time in s) of the
        quadratic fitted to the peak frequencies; ``freq_hz`` then follows it.
    """

    freq_hz: np.ndarray
    reliable_fraction: float
    trend: float
    sweep_law: tuple[float, ...] | None = None

    @property
    def is_sweep(self) -> bool:
        """A slow chirp or sine sweep: a clear peak most of the time, moving monotonically."""
        return self.reliable_fraction >= 0.7 and abs(self.trend) >= 0.9

    @property
    def range_hz(self) -> tuple[float, float]:
        lo, hi = np.quantile(self.freq_hz, [0.01, 0.99])
        return float(lo), float(hi)


def track_frequency(x: np.ndarray, fs_hz: float, *, window_s: float = 4.0,
                    f_range_hz: tuple[float, float] | None = None,
                    weight: Literal["velocity", "acceleration"] = "velocity",
                    fit_sweep: bool = True) -> FrequencyTrack:
    """Frequency [Hz] of the dominant sine in ``x`` at every sample (slow chirps, sine sweeps).

    A short-time Fourier transform's peak (magnitudes divided by f when ``x``
    is an acceleration and ``weight="velocity"``, so harmonics weigh less),
    refined by parabolic interpolation, median-smoothed over 5 frames and
    interpolated to the samples. Frames whose peak is not 4× the frame's
    median are unreliable (no dominant sine) and are interpolated over.

    With ``fit_sweep``, a sweep's track is replaced by a quadratic in time
    fitted with outlier rejection: just after a lightly damped mode the
    response rings at the mode's frequency for a while and the peak lingers
    there, though the excitation has moved on (the F-16 at 7.3 Hz); the
    sweep law gives the excitation's frequency.
    """
    x = np.asarray(x, dtype=float)
    fs = float(fs_hz)
    nper = int(min(max(64, round(window_s * fs)), x.size))
    hop = max(1, nper // 4)
    nfft = sfft.next_fast_len(4 * nper)
    f, t, s = signal.stft(x, fs, window="hann", nperseg=nper, noverlap=nper - hop, nfft=nfft,
                          boundary=None, padded=False)
    mag = np.abs(s)
    if weight == "velocity":
        mag = mag / np.where(f > 0, f, np.inf)[:, None]
    lo, hi = f_range_hz if f_range_hz is not None else (2.0 * fs / nper, fs / 2)
    m = (f >= lo) & (f <= hi)
    if not m.any():
        raise ConfigError(f"frequency range {lo:g}-{hi:g} Hz holds no STFT bin at fs={fs:g} Hz")
    sub = mag[m]
    i = np.argmax(sub, axis=0)
    k = np.clip(np.nonzero(m)[0][i], 1, f.size - 2)
    cols = np.arange(mag.shape[1])
    a, b, c = (np.log(mag[k + d, cols] + 1e-300) for d in (-1, 0, 1))
    den = a - 2 * b + c
    delta = np.where(den != 0, 0.5 * (a - c) / np.where(den == 0, 1, den), 0.0)
    fp = f[k] + np.clip(delta, -1, 1) * (f[1] - f[0])
    good = sub[i, cols] >= 4 * np.median(sub, axis=0)
    if fp.size >= 5:
        fp = signal.medfilt(fp, 5)
    if good.sum() >= 2:
        fp = np.interp(t, t[good], fp[good])
        trend = float(stats.spearmanr(t[good], fp[good])[0]) if np.ptp(fp[good]) > 0 else 0.0
    else:
        trend = 0.0
    trend = trend if np.isfinite(trend) else 0.0
    rel = float(good.mean()) if good.size else 0.0
    ts = np.arange(x.size) / fs
    law = _sweep_law(t[good], fp[good]) if fit_sweep and rel >= 0.7 and abs(trend) >= 0.9 else None
    if law is not None:
        return FrequencyTrack(np.polyval(law, ts), rel, trend, tuple(float(c) for c in law))
    return FrequencyTrack(np.interp(ts, t, fp), rel, trend)


def _sweep_law(t: np.ndarray, f: np.ndarray) -> np.ndarray | None:
    """Quadratic f(t) through the peak track, refitted without points off by > 3 robust sigmas."""
    keep = np.ones(t.size, bool)
    coef = None
    for _ in range(5):
        if keep.sum() < 8:
            return None
        coef = np.polyfit(t[keep], f[keep], 2)
        res = f - np.polyval(coef, t)
        mad = 1.4826 * np.median(np.abs(res[keep] - np.median(res[keep])))
        new = np.abs(res) <= max(3 * mad, 1e-3 * np.ptp(f))
        if np.array_equal(new, keep):
            break
        keep = new
    return coef


def instantaneous_frequency(x: np.ndarray, fs_hz: float, **kw) -> np.ndarray:
    """``track_frequency(x, fs_hz, **kw).freq_hz``."""
    return track_frequency(x, fs_hz, **kw).freq_hz


@dataclass(frozen=True)
class Slice:
    """A subset of restoring-force samples: a frequency window or an amplitude bin."""

    by: Literal["frequency", "amplitude", "record"]
    label: str
    centre: float          # Hz for frequency slices; amplitude [m] for amplitude slices
    index: np.ndarray      # sample indices into the RestoringForce (sorted)

    @property
    def n(self) -> int:
        return int(self.index.size)


def frequency_slices(rf: RestoringForce, centres_hz: Sequence[float], *, inst_freq_hz: np.ndarray | None = None,
                     cycles: float | None = 8.0, half_width_hz: float | None = None) -> list[Slice]:
    """Windows of a chirp's instantaneous frequency around each centre (paper Fig. 3).

    ``inst_freq_hz`` (per sample of ``rf``) defaults to
    :func:`instantaneous_frequency` of the spindle acceleration. The sweep's
    pass through ``centre ± half_width_hz`` (default 2 % of the centre) is
    found; the slice is ``cycles`` periods centred where the frequency is
    closest to the centre (a few clean loops, as in the paper's figures), or
    the whole pass with ``cycles=None``. Centres the record never reaches give
    no slice.
    """
    fi = instantaneous_frequency(rf.spindle_accel, rf.fs_hz) if inst_freq_hz is None else np.asarray(inst_freq_hz)
    if fi.size != rf.n:
        raise InputError(f"inst_freq_hz has {fi.size} samples, restoring-force data {rf.n}")
    out = []
    for fc in centres_hz:
        fc = float(fc)
        if fc <= 0:
            raise ConfigError(f"slice frequency {fc:g} Hz must be positive")
        hw = half_width_hz if half_width_hz is not None else 0.02 * fc
        idx = np.nonzero(np.abs(fi - fc) <= hw)[0]
        if idx.size == 0:
            continue
        runs = np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1)
        run = max(runs, key=len)  # the sweep's (longest) pass
        if cycles is not None:
            n = max(int(round(cycles * rf.fs_hz / fc)), 2)
            c = int(run[np.argmin(np.abs(fi[run] - fc))])
            lo = int(np.clip(c - n // 2, 0, max(rf.n - n, 0)))
            run = np.arange(lo, min(lo + n, rf.n))
        out.append(Slice("frequency", f"{fc:g} Hz", fc, run))
    return out


def local_amplitude(x: np.ndarray, fs_hz: float, *, window_s: float = 1.0) -> np.ndarray:
    """Moving RMS of ``x`` over ``window_s`` times √2 (the amplitude of a sine with that RMS)."""
    n = max(1, int(round(window_s * fs_hz)))
    w = np.ones(n) / n
    return np.sqrt(2 * np.maximum(signal.oaconvolve(np.asarray(x, float) ** 2, w, mode="same"), 0))


def amplitude_slices(rf: RestoringForce, n_bins: int = 4, *, variable: Literal["z", "zdot"] = "z",
                     window_s: float | None = None) -> list[Slice]:
    """Bins of the local amplitude of z (or ż) with equal sample counts (paper Fig. 4 for random data)."""
    if n_bins < 1:
        raise ConfigError(f"n_bins={n_bins} must be at least 1")
    x = rf.z if variable == "z" else rf.zdot
    win = window_s if window_s is not None else max(1.0, 2.0 / rf.band.f_lo_hz)
    amp = local_amplitude(x, rf.fs_hz, window_s=win)
    edges = np.quantile(amp, np.linspace(0, 1, n_bins + 1))
    unit = "mm" if variable == "z" else "mm/s"
    out = []
    for i in range(n_bins):
        m = (amp >= edges[i]) & ((amp < edges[i + 1]) if i < n_bins - 1 else (amp <= edges[i + 1]))
        idx = np.nonzero(m)[0]
        if idx.size:
            centre = float(np.median(amp[idx]))
            out.append(Slice("amplitude", f"{variable} amplitude {1e3 * edges[i]:.3g}-{1e3 * edges[i + 1]:.3g} {unit}",
                             centre, idx))
    return out
