"""What the excitation of a record is: periodic or not, its period and transient, the band it excites.

What a test engineer reads off the data before identifying (docs/method.md §8),
read off by the program:

- **Periodic excitation** (a multisine repeats exactly). The period P is the
  smallest lag at which the input's autocorrelation is within 5 % of its
  largest value over lags up to half the record (a multisine's correlation
  is ≈ 1 at P, 2P, 3P...; a random or swept signal has no such peak), and is
  confirmed only when every steady period of the input repeats to within
  ``max_period_change`` of its RMS on the lines it excites (a sweep, a chirp
  or a road repeat nowhere). At least ``min_periods`` periods are needed.
- **Transient** (periodic data): the response's consecutive periods are
  compared on the excited lines; the leading periods that differ from their
  successor by more than twice the median difference of the second half are
  transient (the period-to-period difference of the steady state is the
  noise level, for free). At least one period is dropped when four or more
  are recorded: a test starts from rest, and its first period always holds
  the start-up.
- **Excited band**: the input's power per line (periodic: the lines of the
  period average; random: its Welch spectrum) against its own floor (the
  10th percentile of all lines): lines more than 20 dB above the floor and
  no more than 30 dB below the strongest, and only where excited lines are
  dense (at least half of the lines within ±5 % in frequency) — isolated
  lines (mains hum, a harmonic of the drive) are not the excitation.

For random data the band is also required to be coherent (ordinary coherence
input→output ≥ 0.5): where the output is only noise, nothing can be
identified or predicted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from ..errors import InputError
from .frf import coherence
from .spectral import SpectralSettings, auto_spectrum, cross_spectra

__all__ = ["Excitation", "analyse_excitation", "combine_excitations", "detect_period"]

#: a steady period of a periodic input differs from the next by at most this fraction of its RMS (excited lines)
MAX_PERIOD_CHANGE = 0.2
#: excited lines: this far above the floor [dB] ...
ABOVE_FLOOR_DB = 20.0
#: ... and at most this far below the strongest line [dB]
BELOW_PEAK_DB = 30.0
#: random data: the band must be at least this coherent input → output
MIN_COHERENCE = 0.5


@dataclass(frozen=True)
class Excitation:
    """What the excitation of one record (or several, combined) is.

    Attributes
    ----------
    periodic : bool
    period_samples : int or None
        Samples per period (periodic data).
    n_periods : int
        Whole periods in the record (0 for random data).
    transient_periods : int
        Leading periods that hold the start-up transient (to drop).
    band_hz : (float, float)
        The excited band of the input [Hz].
    input_name : str
        Which channel was the input ("force" or "spindle acceleration").
    noise_rel : float or None
        Periodic data: the steady state's period-to-period difference of the response on the excited
        lines, relative to its RMS (the noise level).
    reasons : mapping
        One sentence per finding ("period", "transient", "band").
    sources : tuple of str
    """

    periodic: bool
    period_samples: int | None
    n_periods: int
    transient_periods: int
    band_hz: tuple[float, float]
    input_name: str
    noise_rel: float | None = None
    reasons: Mapping[str, str] = field(default_factory=dict)
    sources: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        return {"periodic": self.periodic, "period_samples": self.period_samples, "n_periods": self.n_periods,
                "transient_periods": self.transient_periods, "band_hz": list(self.band_hz),
                "input": self.input_name, "noise_rel": self.noise_rel, "reasons": dict(self.reasons),
                "sources": list(self.sources)}


def _autocorrelation(x: np.ndarray) -> np.ndarray:
    """Unbiased normalised autocorrelation r(lag)/r(0)·n/(n - lag), lags 0..n-1 (one FFT pair)."""
    x = x - x.mean()
    n = x.size
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    spec = np.fft.rfft(x, nfft)
    r = np.fft.irfft(spec.real ** 2 + spec.imag ** 2, nfft)[:n]
    if not r[0] > 0:
        return np.zeros(n)
    return r / r[0] * n / (n - np.arange(n))


def _period_change(u: np.ndarray, p: int, lines: np.ndarray | None = None) -> np.ndarray:
    """Relative difference of each period to the next on ``lines`` (default: every line but DC)."""
    k = u.size // p
    spec = np.fft.rfft(u[: k * p].reshape(k, p), axis=1)
    if lines is None:
        lines = np.arange(1, spec.shape[1])
    s = spec[:, lines]
    ref = np.sqrt(np.mean(np.sum(np.abs(s[k // 2:]) ** 2, axis=1)))
    return np.sqrt(np.sum(np.abs(np.diff(s, axis=0)) ** 2, axis=1)) / max(ref, 1e-300)


def detect_period(u: np.ndarray, *, min_periods: int = 3, min_lag: int = 8) -> int | None:
    """The period of ``u`` in samples, or None when it is not periodic (module docstring)."""
    u = np.asarray(u, float)
    n = u.size
    top = n // min_periods
    if top <= min_lag or not np.any(u != u[0]):
        return None
    r = _autocorrelation(u)[: top + 1]
    seg = r[min_lag:]
    best = float(seg.max())
    if best < 0.5:
        return None
    above = np.flatnonzero(seg >= 0.95 * best)
    first = above[0]
    run = above[: np.searchsorted(above, first + max(2, first // 50)) + 0]   # the first peak's neighbourhood
    lag = int(run[np.argmax(seg[run])]) + min_lag
    for p in sorted({lag, lag - 1, lag + 1}, key=lambda q: -r[q] if 0 < q < r.size else 0):
        if p <= 0 or n // p < min_periods:
            continue
        k = n // p
        rms = np.sqrt(np.mean(u[: k * p].reshape(k, p) ** 2, axis=1))[1:]   # the first may hold a start-up
        if rms.size and not np.all(np.abs(rms / np.median(rms) - 1) <= 0.3):
            continue        # a periodic excitation puts the same energy in every period (a padded sweep does not)
        change = _period_change(u, p)
        if float(np.median(change)) <= MAX_PERIOD_CHANGE:
            return int(p)
    return None


def _dense(mask: np.ndarray, freq: np.ndarray, rel: float = 0.05) -> np.ndarray:
    """Lines of ``mask`` with at least half of the lines within ±``rel``·f (at least ±2 lines) also in it."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return mask
    c = np.concatenate([[0], np.cumsum(mask)])
    df = freq[1] - freq[0] if freq.size > 1 else 1.0
    out = np.zeros_like(mask)
    for i in idx:
        w = max(2, int(rel * freq[i] / df))
        lo, hi = max(i - w, 0), min(i + w + 1, mask.size)
        out[i] = (c[hi] - c[lo]) >= 0.5 * (hi - lo)
    return out


def _band_of(power: np.ndarray, freq: np.ndarray, extra: np.ndarray | None = None, *,
             below_peak_db: float | None = BELOW_PEAK_DB) -> tuple[int, int] | None:
    """(first, last) line index of the excited band (module docstring), None when nothing stands out."""
    pos = freq > 0
    p = np.where(pos, power, 0.0)
    if not np.any(p > 0):
        return None
    floor = float(np.quantile(p[pos], 0.1))
    thr = floor * 10 ** (ABOVE_FLOOR_DB / 10)
    if below_peak_db is not None:
        thr = max(thr, float(p.max()) * 10 ** (-below_peak_db / 10))
    mask = pos & (p >= thr)
    if extra is not None:
        mask &= extra
    mask = _dense(mask, freq)
    idx = np.flatnonzero(mask)
    if idx.size < 2:
        return None
    # the run of excited lines around the strongest one (gaps of a few lines bridged)
    level = 10 * np.log10(np.maximum(p, floor * 1e-3))
    smooth = np.convolve(level, np.ones(5) / 5, mode="same")
    peak = int(idx[np.argmax(smooth[idx])])
    gap = max(3, idx.size // 100)
    breaks = np.flatnonzero(np.diff(idx) > gap)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [idx.size - 1]])
    j = int(np.searchsorted(idx[ends], peak))
    lo, hi = int(idx[starts[j]]), int(idx[ends[j]])
    return _cliffs(level, lo, hi, peak, 10 * np.log10(thr) + 10.0)


#: a drop of the input's level by this much [dB] inside the run ends the excited band there (a multisine's edge;
#: beyond it the response's own harmonics and distortion, which a measured input such as an acceleration carries)
CLIFF_DB = 15.0


def _cliffs(level: np.ndarray, lo: int, hi: int, peak: int, weak: float) -> tuple[int, int]:
    """Cut the run [lo, hi] at the steepest edge on each side of ``peak`` where the level falls by ≥ CLIFF_DB to
    a weak level (median below ``weak`` [dB]): the edge of the excitation, not a mode's flank inside it."""
    w = max(4, (hi - lo) // 50)

    def step(i: int, up: bool) -> float:     # level inside the band minus outside, edge between i-1 and i
        a = level[max(i - w, lo):i]
        b = level[i:min(i + w, hi + 1)]
        if a.size == 0 or b.size == 0:
            return -np.inf
        inside, outside = (b, a) if up else (a, b)
        if np.median(outside) > weak:
            return -np.inf
        return float(np.median(inside) - np.median(outside))

    def exact(i: int, up: bool) -> int:
        """The edge's own line near i: the outermost line within ±w still above the midpoint of the two levels."""
        a = level[max(i - w, lo):i]
        b = level[i:min(i + w, hi + 1)]
        mid = 0.5 * (float(np.median(a)) + float(np.median(b)))
        near = np.arange(max(i - w, lo), min(i + w, hi + 1))
        inside = near[level[near] >= mid]
        if inside.size == 0:
            return i if up else i - 1
        return int(inside.min()) if up else int(inside.max())

    new_hi, new_lo = hi, lo
    best_hi = max(range(peak + 1, hi + 1), key=lambda i: step(i, False), default=None)
    if best_hi is not None and step(best_hi, False) >= CLIFF_DB:
        new_hi = max(exact(best_hi, False), peak)
    best_lo = max(range(lo + 1, peak + 1), key=lambda i: step(i, True), default=None)
    if best_lo is not None and step(best_lo, True) >= CLIFF_DB:
        new_lo = min(exact(best_lo, True), peak)
    return new_lo, new_hi


def analyse_excitation(u: np.ndarray, y: np.ndarray, fs_hz: float, *, period_samples: int | None = None,
                       input_name: str = "spindle acceleration", source: str = "",
                       random_settings: SpectralSettings | None = None) -> Excitation:
    """Periodicity, transient and excited band of one record (module docstring).

    Parameters
    ----------
    u, y : ndarray, shape (n,)
        The input (spindle acceleration, or the force when the spindle is fixed) and the output (body
        acceleration), whole from the start of the record.
    fs_hz : float
    period_samples : int, optional
        A known period (``--period-samples``): not detected, only used.
    random_settings : SpectralSettings, optional
        Blocks of the Welch spectra for random data (default Hann, 50 %, ≈ 8 s blocks).
    """
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    if u.shape != y.shape or u.size < 16:
        raise InputError("input and output must be two signals of the same length (at least 16 samples)",
                         source=source)
    reasons: dict[str, str] = {}
    p = int(period_samples) if period_samples else detect_period(u)
    if p and u.size // p >= 2:
        k = u.size // p
        spec_u = np.fft.rfft(u[: k * p].reshape(k, p), axis=1)
        f = np.fft.rfftfreq(p, 1.0 / fs_hz)
        mean_u = spec_u[k // 2:].mean(axis=0)
        band = _band_of(np.abs(mean_u) ** 2, f, below_peak_db=None)   # a periodic input's lines stand out
        if band is None:
            raise InputError("the input excites no line above its own floor", source=source,
                             hint="check the input channel (--columns)")
        lines = np.arange(band[0], band[1] + 1)
        lines = lines[np.abs(mean_u[lines]) ** 2 > 0]
        change = _period_change(y, p, lines)
        steady = change[change.size // 2:]
        noise = float(np.median(steady)) if steady.size else float("nan")
        lead = 0
        while lead < change.size // 2 and change[lead] > 2 * noise:
            lead += 1
        transient = max(lead, 1 if k >= 4 else 0)
        how = "given (--period-samples)" if period_samples else "detected (the input repeats)"
        reasons["period"] = (f"periodic excitation, period {p} samples ({p / fs_hz:.4g} s), {k} periods: {how}")
        reasons["transient"] = (f"first {transient} period(s) dropped as transient: "
                                + (f"the response's first {lead} period(s) differ from the next by more than twice "
                                   f"the steady state's {100 * noise:.2g} %" if lead else
                                   "the start-up from rest (the steady periods differ by "
                                   f"{100 * noise:.2g} %, the noise)" if transient else "none needed"))
        lo, hi = float(f[band[0]]), float(f[band[1]])
        reasons["band"] = (f"excited band {lo:.4g}-{hi:.4g} Hz: the lines of the {input_name}'s period average "
                           f"{ABOVE_FLOOR_DB:g} dB above its floor")
        return Excitation(True, p, k, transient, (lo, hi), input_name, noise, reasons, (source,) if source else ())
    settings = random_settings or SpectralSettings(block=_pow2(8.0 * fs_hz, u.size // 8), overlap=0.5,
                                                   window="hann")
    sp = cross_spectra(np.stack([u, y]), fs_hz, settings)
    f = sp.freq_hz
    coh = coherence(sp, 0, 1)
    coh_s = np.convolve(coh, np.ones(5) / 5, mode="same")
    band = _band_of(auto_spectrum(sp, 0), f, coh_s >= MIN_COHERENCE, below_peak_db=None)
    if band is None:
        raise InputError(f"the {input_name} excites no band coherent with the output (coherence ≥ "
                         f"{MIN_COHERENCE:g} and {ABOVE_FLOOR_DB:g} dB above the floor)", source=source,
                         hint="check the channels (--columns/--topics) and that the excitation was on")
    lo, hi = float(f[band[0]]), float(f[band[1]])
    reasons["period"] = "not periodic (random or swept excitation): windowed, overlapping blocks"
    reasons["band"] = (f"excited band {lo:.4g}-{hi:.4g} Hz: where the {input_name}'s spectrum is "
                       f"{ABOVE_FLOOR_DB:g} dB above its floor and coherent with the output (γ² ≥ {MIN_COHERENCE:g})")
    return Excitation(False, None, 0, 0, (lo, hi), input_name, None, reasons, (source,) if source else ())


def _pow2(target: float, most: int) -> int:
    """The power of two nearest ``target`` samples, at most ``most`` (at least 64)."""
    b = 1 << int(round(np.log2(max(target, 64))))
    while b > most and b > 64:
        b //= 2
    return b


def combine_excitations(parts: Sequence[Excitation]) -> Excitation:
    """One description of several records of one test: periodic only when all are with one period; the union of
    the excited bands; the most transient periods any record needs."""
    if not parts:
        raise InputError("no records to describe")
    periods = {e.period_samples for e in parts}
    periodic = all(e.periodic for e in parts) and len(periods) == 1
    lo = min(e.band_hz[0] for e in parts)
    hi = max(e.band_hz[1] for e in parts)
    first = parts[0]
    sources = tuple(s for e in parts for s in e.sources)
    reasons = dict(first.reasons)
    if len(parts) > 1:
        reasons["band"] = (f"excited band {lo:.4g}-{hi:.4g} Hz over {len(parts)} records (per record: "
                           + ", ".join(f"{e.band_hz[0]:.4g}-{e.band_hz[1]:.4g}" for e in parts) + " Hz)")
        if periodic:
            t = max(e.transient_periods for e in parts)
            reasons["transient"] = (f"first {t} period(s) dropped as transient (the most any record needs: "
                                    + ", ".join(str(e.transient_periods) for e in parts) + ")")
        elif any(e.periodic for e in parts):
            reasons["period"] = ("not every record is periodic with one period ("
                                 + ", ".join(str(e.period_samples) for e in parts) + "): treated as random")
    if not periodic:
        return Excitation(False, None, 0, 0, (lo, hi), first.input_name, None, reasons, sources)
    noise = [e.noise_rel for e in parts if e.noise_rel is not None]
    return Excitation(True, first.period_samples, min(e.n_periods for e in parts),
                      max(e.transient_periods for e in parts), (lo, hi), first.input_name,
                      float(np.median(noise)) if noise else None, reasons, sources)
