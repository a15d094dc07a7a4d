"""The one spectral engine: the whole cross-spectral matrix, batch and streaming.

Every spectral estimate in nifo (auto and cross spectra here; H1/H2, ordinary,
multiple and partial coherence and the MIMO fits in :mod:`nifo_core.signal.frf`; NIFO)
derives from one :class:`CrossSpectra` made by one segment-FFT path (docs/method.md §3: "one spectral engine"). The path is

1. cut each channel into blocks of ``block`` samples, hop ``block - noverlap``
   (a strided view, no copy, no Python loop over blocks);
2. remove each block's mean (``detrend='constant'``) and apply the window,
   writing into one array (the one copy the rfft needs), then rfft all blocks of
   all channels in one call;
3. accumulate the *sums* ``S[f, a, b] = Σ_k conj(X_a,k(f))·X_b,k(f)``, upper
   triangle only and mirrored (:mod:`._block_products`, in numba: why is
   measured there), and the block count.

On 4 channels of the paper's record this costs 1.15-1.4× the bare batched rfft
of the same blocks (``benchmarks/bench_spectral.py``).

Because sums (not means) are kept, accumulators of separate records merge
exactly, a stream pushed in any chunk sizes gives the batch answer, and the
state is a handful of plain arrays a node can checkpoint.

Conventions (those of :func:`scipy.signal.csd`, so a test can compare):

.. math::

    G_{ab}(f) = \\frac{c_f}{f_s \\sum_t w_t^2}\\,\\frac{1}{n_{avg}}
                \\sum_{k=1}^{n_{avg}} \\overline{X_{a,k}(f)}\\,X_{b,k}(f),

with c_f = 2 except at DC and (even blocks) Nyquist where c_f = 1: a one-sided
density in units²/Hz. ``G[f, a, b] = csd(x_a, x_b)``; ``G[f, a, a]`` is the
Welch PSD. Frequency response estimates use the usual H1 = G_xy / G_xx.

Paper Table 2 defaults: block 6144, 52 % overlap, flattop window, fs 600 Hz,
180 000 samples (59 blocks here; the paper quotes 60).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Mapping, Sequence, get_args

import numpy as np
import scipy.fft
from numpy.lib.stride_tricks import sliding_window_view
from scipy import signal

from ..errors import ConfigError, InputError, RecordTooShortError
from ._block_products import accumulate_block_products

__all__ = [
    "Window", "Detrend", "SpectralSettings", "CrossSpectra", "CrossSpectralAccumulator", "cross_spectra",
    "auto_spectrum", "cross_spectrum", "block_ffts", "MAX_BLOCK",
]

#: the largest spectral block accepted [samples] (2^22: 4.2 M, 2 h at 600 Hz; the paper uses 6144)
MAX_BLOCK = 1 << 22

Window = Literal["flattop", "hann", "hamming", "boxcar", "blackman", "blackmanharris", "nuttall"]
Detrend = Literal["constant", "none"]
_WINDOWS = get_args(Window)
_DETRENDS = get_args(Detrend)
Channel = int | str


@dataclass(frozen=True)
class SpectralSettings:
    """How records are cut into blocks and windowed (paper Table 2 defaults).

    Parameters
    ----------
    block : int
        Samples per block (FFT length). Frequency resolution is ``fs_hz / block``.
    overlap : float
        Fraction of a block shared with the next one, 0 <= overlap < 1. The
        overlap in samples is ``round(overlap * block)``.
    window : {'flattop', 'hann', 'hamming', 'boxcar', 'blackman', 'blackmanharris', 'nuttall'}
        Periodic window (as :func:`scipy.signal.get_window` gives for spectra).
    detrend : {'constant', 'none'}
        Remove each block's mean before windowing, or not.
    """

    block: int = 6144
    overlap: float = 0.52
    window: Window = "flattop"
    detrend: Detrend = "constant"

    def __post_init__(self) -> None:
        if isinstance(self.block, bool) or not isinstance(self.block, (int, np.integer)) or \
                not 8 <= self.block <= MAX_BLOCK:
            raise ConfigError(f"spectral block={self.block!r} must be an integer of 8 to {MAX_BLOCK} samples",
                              hint="e.g. --block 6144 (paper Table 2)")
        object.__setattr__(self, "block", int(self.block))
        try:
            ov = float(self.overlap)
        except (TypeError, ValueError):
            raise ConfigError(f"spectral overlap={self.overlap!r} is not a number", hint="e.g. 0.52") from None
        if not (0.0 <= ov < 1.0):
            raise ConfigError(f"spectral overlap={self.overlap!r} must satisfy 0 <= overlap < 1",
                              hint="give a fraction of the block, e.g. 0.52 for 52 %")
        object.__setattr__(self, "overlap", ov)
        if self.noverlap >= self.block:
            raise ConfigError(f"overlap={ov} leaves no hop for block={self.block}", hint="lower the overlap")
        if self.window not in _WINDOWS:
            raise ConfigError(f"spectral window={self.window!r} is not supported",
                              hint=f"use one of {', '.join(_WINDOWS)}")
        if self.detrend not in _DETRENDS:
            raise ConfigError(f"spectral detrend={self.detrend!r} is not supported",
                              hint=f"use one of {', '.join(_DETRENDS)}")

    @property
    def noverlap(self) -> int:
        """Overlap in samples, ``round(overlap * block)``."""
        return int(round(self.overlap * self.block))

    @property
    def step(self) -> int:
        """Hop between block starts [samples]."""
        return self.block - self.noverlap

    @property
    def n_freq(self) -> int:
        return self.block // 2 + 1

    def window_array(self) -> np.ndarray:
        """The window, shape (block,), read-only."""
        return _window(self.window, self.block)

    def freq_hz(self, fs_hz: float) -> np.ndarray:
        """Frequency lines [Hz], shape (block // 2 + 1,)."""
        return np.fft.rfftfreq(self.block, 1.0 / fs_hz)

    def n_blocks(self, n_samples: int) -> int:
        """Number of complete blocks in ``n_samples`` samples."""
        return 0 if n_samples < self.block else (n_samples - self.block) // self.step + 1

    def to_dict(self) -> dict:
        return {"block": self.block, "overlap": self.overlap, "window": self.window, "detrend": self.detrend}

    @classmethod
    def from_dict(cls, d: Mapping) -> "SpectralSettings":
        unknown = set(d) - {"block", "overlap", "window", "detrend"}
        if unknown:
            raise ConfigError(f"spectral settings have unknown field(s) {sorted(unknown)}",
                              hint="use block, overlap, window, detrend")
        return cls(**dict(d))


_WIN_CACHE: dict[tuple[str, int], np.ndarray] = {}


def _window(name: str, block: int) -> np.ndarray:
    key = (name, block)
    if key not in _WIN_CACHE:
        w = signal.get_window(name, block, fftbins=True).astype(float)
        w.flags.writeable = False
        _WIN_CACHE[key] = w
    return _WIN_CACHE[key]


def _density_scale(settings: SpectralSettings, fs_hz: float) -> np.ndarray:
    """Per-line factor turning a raw sum/n into a one-sided density (scipy's 'density' scaling)."""
    w = _window(settings.window, settings.block)
    scale = np.full(settings.n_freq, 2.0 / (fs_hz * float(np.sum(w * w))))
    scale[0] /= 2
    if settings.block % 2 == 0:
        scale[-1] /= 2
    return scale


def block_ffts(x: np.ndarray, settings: SpectralSettings) -> np.ndarray:
    """rfft of every complete block of every channel: (n_ch, n) -> (n_ch, n_blocks, n_freq).

    Each block is detrended (as ``settings.detrend`` says) and windowed before
    its rfft, in that order, as :func:`scipy.signal.csd` does. ``x`` is not modified.
    """
    nb = settings.n_blocks(x.shape[1])
    blocks = sliding_window_view(x, settings.block, axis=-1)[:, ::settings.step][:, :nb]
    w = _window(settings.window, settings.block)
    if settings.detrend == "constant":   # in the time domain, before the window: a large offset (gravity) costs no digits
        windowed = np.subtract(blocks, blocks.mean(axis=-1, keepdims=True))
        windowed *= w
    else:
        windowed = np.multiply(blocks, w)
    return scipy.fft.rfft(windowed, axis=-1, overwrite_x=True)


def _as_channels(x, n_channels: int | None) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2:
        raise InputError(f"expected samples of shape (n_channels, n), got {np.shape(x)}",
                         hint="stack channels as rows")
    if n_channels is not None and arr.shape[0] != n_channels:
        raise InputError(f"expected {n_channels} channels, got {arr.shape[0]} (shape {arr.shape})",
                         hint="push all channels of the accumulator at once, one row each")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{int((~np.isfinite(arr)).sum())} samples are NaN or infinite",
                         hint="repair or cut the bad stretch before spectral analysis")
    return arr


@dataclass(frozen=True, eq=False)
class CrossSpectra:
    """The averaged cross-spectral density matrix of a set of channels.

    Attributes
    ----------
    freq_hz : ndarray, shape (nf,)
        Frequency lines [Hz].
    G : ndarray, complex, shape (nf, n_ch, n_ch)
        ``G[f, a, b]`` = E[conj(X_a)·X_b], one-sided density [unit_a·unit_b/Hz]
        (equal to ``scipy.signal.csd(x_a, x_b)``); Hermitian in (a, b).
    n_avg : int
        Number of blocks averaged (over all records merged).
    fs_hz : float
        Sample rate [Hz].
    settings : SpectralSettings
    names : tuple of str
        Channel names, for look-up by name.
    """

    freq_hz: np.ndarray
    G: np.ndarray
    n_avg: int
    fs_hz: float
    settings: SpectralSettings
    names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for a in (self.freq_hz, self.G):
            a.flags.writeable = False

    @property
    def n_channels(self) -> int:
        return int(self.G.shape[1])

    def index(self, ch: Channel) -> int:
        """Channel index from an index or a name."""
        if isinstance(ch, str):
            try:
                return self.names.index(ch)
            except ValueError:
                raise InputError(f"no channel named {ch!r}", hint=f"channels are {list(self.names)}") from None
        i = int(ch)
        if not -self.n_channels <= i < self.n_channels:
            raise InputError(f"channel index {i} out of range for {self.n_channels} channels")
        return i % self.n_channels

    def indices(self, chs: Channel | Sequence[Channel]) -> list[int]:
        if isinstance(chs, (str, int, np.integer)):
            return [self.index(chs)]
        return [self.index(c) for c in chs]

    def select(self, chs: Sequence[Channel]) -> "CrossSpectra":
        """The sub-matrix of channels ``chs`` (in that order)."""
        idx = self.indices(chs)
        names = tuple(self.names[i] for i in idx) if self.names else ()
        return CrossSpectra(self.freq_hz, self.G[:, idx][:, :, idx].copy(), self.n_avg, self.fs_hz,
                            self.settings, names)

    def combine(self, weights: np.ndarray, names: Sequence[str] = ()) -> "CrossSpectra":
        """Spectra of linear combinations of the channels, exactly.

        New channel p is ``Y_p(f) = Σ_a W[f, p, a]·X_a(f)`` in every block, so
        ``G'[f] = conj(W[f]) · G[f] · W[f]ᵀ``. ``weights`` has shape (m, n_ch)
        (constant) or (nf, m, n_ch) (per line). Used e.g. to subtract a known
        nonlinear contribution from an output (two-step NIFO).
        """
        w = np.asarray(weights)
        if w.ndim == 2:
            w = np.broadcast_to(w, (self.freq_hz.size, *w.shape))
        if w.ndim != 3 or w.shape[0] != self.freq_hz.size or w.shape[2] != self.n_channels:
            raise InputError(f"weights of shape {np.shape(weights)} do not fit {self.n_channels} channels "
                             f"on {self.freq_hz.size} lines", hint="use shape (m, n_ch) or (nf, m, n_ch)")
        g = (w.conj() @ self.G) @ np.swapaxes(w, 1, 2)        # batched products: einsum's path search cost more
        return CrossSpectra(self.freq_hz, g, self.n_avg, self.fs_hz, self.settings, tuple(names))


class CrossSpectralAccumulator:
    """Streaming cross-spectral matrix: push samples as they arrive, read spectra any time.

    Parameters
    ----------
    n_channels : int
        Number of channels pushed together.
    fs_hz : float
        Sample rate [Hz].
    settings : SpectralSettings, optional
        Block, overlap, window, detrend (paper Table 2 by default).
    names : sequence of str, optional
        Channel names carried into :class:`CrossSpectra`.

    Notes
    -----
    :meth:`push` keeps the samples that do not yet complete a block (the tail
    that later blocks overlap), so any chunking of a stream gives exactly the
    blocks, and the spectra, of one batch call on the whole stream.

    :meth:`merge` returns a **new** accumulator holding the sums of both
    (neither operand changes). The operands are separate records: the merged
    accumulator's stream starts empty, and a partial block pending in either
    operand is dropped, as it is at the end of a batch record.
    """

    def __init__(self, n_channels: int, fs_hz: float, settings: SpectralSettings | None = None, *,
                 names: Sequence[str] = ()) -> None:
        if int(n_channels) < 1:
            raise ConfigError(f"n_channels={n_channels!r} must be at least 1")
        if not (np.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError(f"fs_hz={fs_hz!r} must be a positive sample rate [Hz]")
        self.n_channels = int(n_channels)
        self.fs_hz = float(fs_hz)
        self.settings = settings or SpectralSettings()
        self.names = tuple(str(n) for n in names)
        if self.names and len(self.names) != self.n_channels:
            raise ConfigError(f"{len(self.names)} names {list(self.names)} for {self.n_channels} channels")
        self._sum = np.zeros((self.settings.n_freq, self.n_channels, self.n_channels), complex)
        self._n_blocks = 0
        self._tail = np.zeros((self.n_channels, 0))

    # -- streaming -------------------------------------------------------------
    def push(self, x: np.ndarray) -> int:
        """Add samples of all channels, shape (n_channels, k) (or (k,) for one channel).

        Returns the number of blocks completed by this push. ``x`` is not modified.
        """
        arr = _as_channels(x, self.n_channels)
        buf = np.concatenate([self._tail, arr], axis=1) if self._tail.shape[1] else arr
        nb = self.settings.n_blocks(buf.shape[1])
        if nb:
            accumulate_block_products(block_ffts(buf, self.settings), self._sum)
            self._n_blocks += nb
            buf = buf[:, nb * self.settings.step:]
        self._tail = buf.copy()
        return nb

    def drop_pending(self) -> None:
        """End the stream: drop the samples waiting for the next block (later pushes start a new record).

        The same as merging with an empty accumulator, without copying the sums.
        """
        self._tail = np.zeros((self.n_channels, 0))

    @property
    def n_blocks(self) -> int:
        """Blocks accumulated so far."""
        return self._n_blocks

    @property
    def pending_samples(self) -> int:
        """Samples held back waiting for the next block to complete."""
        return int(self._tail.shape[1])

    def spectra(self, band_hz: tuple[float, float] | None = None) -> CrossSpectra:
        """The averaged cross-spectral matrix of all blocks so far (only the lines in ``band_hz`` [Hz] when given).

        Raises
        ------
        RecordTooShortError
            When no complete block has been accumulated yet.
        """
        if self._n_blocks == 0:
            raise RecordTooShortError(
                f"no complete spectral block yet ({self.pending_samples} samples pushed, "
                f"block={self.settings.block} needs {self.settings.block})",
                hint="record longer or choose a smaller block")
        f = self.settings.freq_hz(self.fs_hz)
        scale = _density_scale(self.settings, self.fs_hz) / self._n_blocks
        keep = slice(None) if band_hz is None else (f >= band_hz[0]) & (f <= band_hz[1])
        return CrossSpectra(f[keep], self._sum[keep] * scale[keep, None, None], self._n_blocks, self.fs_hz,
                            self.settings, self.names)

    def merge(self, other: "CrossSpectralAccumulator") -> "CrossSpectralAccumulator":
        """A new accumulator with the blocks of both (separate records); operands unchanged."""
        if not isinstance(other, CrossSpectralAccumulator):
            raise ConfigError(f"cannot merge a cross-spectral accumulator with {type(other).__name__}")
        if (self.settings, self.n_channels, self.fs_hz) != (other.settings, other.n_channels, other.fs_hz):
            raise ConfigError(
                f"cannot merge accumulators with different set-ups: {self.settings}, {self.n_channels} channels, "
                f"{self.fs_hz:g} Hz vs {other.settings}, {other.n_channels} channels, {other.fs_hz:g} Hz",
                hint="accumulate all records with the same settings, channels and sample rate")
        if self.names and other.names and self.names != other.names:
            raise ConfigError(f"cannot merge accumulators of channels {list(self.names)} and {list(other.names)}")
        out = CrossSpectralAccumulator(self.n_channels, self.fs_hz, self.settings, names=self.names or other.names)
        out._sum = self._sum + other._sum
        out._n_blocks = self._n_blocks + other._n_blocks
        return out

    # -- checkpointing -----------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        """The complete state as plain numpy arrays (``np.savez``-able); see :meth:`from_state`."""
        s = self.settings
        return {
            "n_channels": np.array(self.n_channels), "fs_hz": np.array(self.fs_hz),
            "block": np.array(s.block), "overlap": np.array(s.overlap),
            "window": np.array(s.window), "detrend": np.array(s.detrend),
            "names": np.array(self.names, dtype=str), "sum": self._sum.copy(),
            "n_blocks": np.array(self._n_blocks), "tail": self._tail.copy(),
        }

    @classmethod
    def from_state(cls, state: Mapping[str, np.ndarray]) -> "CrossSpectralAccumulator":
        """Rebuild an accumulator from :meth:`state_dict` output."""
        try:
            settings = SpectralSettings(int(state["block"]), float(state["overlap"]), str(state["window"]),
                                        str(state["detrend"]))
            acc = cls(int(state["n_channels"]), float(state["fs_hz"]), settings,
                      names=[str(n) for n in np.atleast_1d(state["names"])] if np.size(state["names"]) else ())
            total = np.asarray(state["sum"], dtype=complex)
            tail = np.asarray(state["tail"], dtype=float)
            n_blocks = int(state["n_blocks"])
        except KeyError as err:
            raise ConfigError(f"cross-spectral state lacks {err.args[0]!r}",
                              hint="pass what state_dict() returned") from None
        if total.shape != acc._sum.shape or tail.ndim != 2 or tail.shape[0] != acc.n_channels or n_blocks < 0:
            raise ConfigError(f"cross-spectral state has inconsistent shapes: sum {total.shape}, tail {tail.shape}",
                              hint="pass what state_dict() returned")
        acc._sum, acc._tail, acc._n_blocks = total.copy(), tail.copy(), n_blocks
        return acc


def cross_spectra(x: np.ndarray, fs_hz: float, settings: SpectralSettings | None = None, *,
                  names: Sequence[str] = ()) -> CrossSpectra:
    """Cross-spectral matrix of a batch of channels (one push into an accumulator).

    Parameters
    ----------
    x : ndarray, shape (n_channels, n) or (n,)
        Samples, one row per channel.
    fs_hz : float
        Sample rate [Hz].
    settings : SpectralSettings, optional
    names : sequence of str, optional

    Raises
    ------
    RecordTooShortError
        When ``n`` is shorter than one block.
    """
    arr = _as_channels(x, None)
    settings = settings or SpectralSettings()
    if arr.shape[1] < settings.block:
        raise RecordTooShortError(
            f"{arr.shape[1]} samples ({arr.shape[1] / fs_hz:.1f} s) is shorter than one spectral block "
            f"(block={settings.block})", hint="record longer or choose a smaller block")
    acc = CrossSpectralAccumulator(arr.shape[0], fs_hz, settings, names=names)
    acc.push(arr)
    return acc.spectra()


# -- estimates derived from a CrossSpectra ------------------------------------------

def auto_spectrum(spec: CrossSpectra, a: Channel) -> np.ndarray:
    """One-sided PSD G_aa [unit²/Hz], shape (nf,), real."""
    i = spec.index(a)
    return spec.G[:, i, i].real.copy()


def cross_spectrum(spec: CrossSpectra, a: Channel, b: Channel) -> np.ndarray:
    """Cross spectrum G_ab = E[conj(A)·B], shape (nf,), complex."""
    return spec.G[:, spec.index(a), spec.index(b)].copy()
