"""The fast spectral engine (issue 29) gives the textbook answer: every shape, exactly Hermitian, offsets cost no digits."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import signal

from nifo_core.signal.spectral import CrossSpectralAccumulator, SpectralSettings, block_ffts, cross_spectra

FS = 600.0


def _textbook_sums(x: np.ndarray, s: SpectralSettings) -> np.ndarray:
    """Σ_k conj(X_a,k)·X_b,k the slow, obvious way: a loop over blocks, scipy's detrend, every pair."""
    w = signal.get_window(s.window, s.block, fftbins=True)
    total = np.zeros((s.n_freq, x.shape[0], x.shape[0]), complex)
    for k in range(s.n_blocks(x.shape[1])):
        seg = x[:, k * s.step:k * s.step + s.block]
        if s.detrend == "constant":
            seg = signal.detrend(seg, axis=-1, type="constant")
        spec = np.fft.rfft(seg * w, axis=-1)
        total += np.einsum("af,bf->fab", spec.conj(), spec)
    return total


def _line_relative_error(g: np.ndarray, ref: np.ndarray) -> float:
    """max |G - ref| per line relative to sqrt(ref_aa·ref_bb), the scale of every entry on that line.

    Lines with no power (DC after a detrend) are judged against 1e-9 of the record's largest auto-spectrum.
    """
    d = np.abs(np.einsum("faa->fa", ref))
    d = np.maximum(d, 1e-9 * d.max())
    return float(np.max(np.abs(g - ref) / np.sqrt(d[:, :, None] * d[:, None, :])))


@pytest.mark.parametrize("n_ch,block,overlap,n,window,detrend", [
    (1, 256, 0.5, 3000, "hann", "constant"),           # one channel
    (4, 6144, 0.52, 180_000, "flattop", "constant"),    # the paper's record: 59 blocks (odd), 3073 lines
    (3, 1000, 0.25, 8000, "blackman", "none"),          # 10 blocks (even), 501 lines: not a multiple of the chunk
    (9, 511, 0.6, 6000, "nuttall", "constant"),          # odd block length (no Nyquist line), more channels
    (2, 512, 0.5, 512, "boxcar", "constant"),            # a single block
])
def test_engine_equals_the_textbook_loop_over_blocks(n_ch, block, overlap, n, window, detrend):
    x = np.random.default_rng(n_ch).standard_normal((n_ch, n))
    x[-1] += 0.5 * x[0] + 1.5
    s = SpectralSettings(block=block, overlap=overlap, window=window, detrend=detrend)
    acc = CrossSpectralAccumulator(n_ch, FS, s)
    acc.push(x)
    assert _line_relative_error(acc.state_dict()["sum"], _textbook_sums(x, s)) < 1e-12


def test_cross_spectral_matrix_is_exactly_hermitian_with_a_real_diagonal():
    x = np.random.default_rng(5).standard_normal((5, 12_000))
    g = cross_spectra(x, FS, SpectralSettings(block=1024, overlap=0.5)).G
    np.testing.assert_array_equal(g, np.conj(np.swapaxes(g, 1, 2)))
    np.testing.assert_array_equal(np.einsum("faa->fa", g).imag, 0.0)


def test_a_large_offset_beside_a_small_vibration_costs_no_digits():
    # gravity on an accelerometer: the mean is removed before the window and the FFT, as scipy does
    rng = np.random.default_rng(3)
    x = 1e-3 * rng.standard_normal((2, 20_000))
    x[0] += 9.81
    x[1] -= 4.0
    s = SpectralSettings(block=1024, overlap=0.52)
    g = cross_spectra(x, FS, s).G
    ref = np.stack([np.stack([signal.csd(x[a], x[b], fs=FS, window=s.window, nperseg=s.block,
                                         noverlap=s.noverlap)[1] for b in range(2)], axis=-1) for a in range(2)], axis=1)
    assert _line_relative_error(g, ref) < 1e-12


def test_block_ffts_detrend_then_window_each_block_and_leave_the_input_alone():
    x = np.random.default_rng(1).standard_normal((2, 3000)) + 7.0
    before = x.copy()
    s = SpectralSettings(block=400, overlap=0.5, window="hann")
    spec = block_ffts(x, s)
    w = s.window_array()
    for k in range(s.n_blocks(x.shape[1])):
        seg = signal.detrend(x[:, k * s.step:k * s.step + s.block], axis=-1, type="constant")
        np.testing.assert_allclose(spec[:, k], np.fft.rfft(seg * w, axis=-1), rtol=0, atol=1e-12 * np.abs(spec).max())
    np.testing.assert_array_equal(x, before)


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 6), st.integers(16, 700), st.floats(0.0, 0.9), st.integers(0, 2**31 - 1))
def test_any_shape_equals_the_textbook_loop(n_ch, block, overlap, seed):
    s = SpectralSettings(block=block, overlap=overlap, window="hann")
    x = np.random.default_rng(seed).standard_normal((n_ch, block * 3 + seed % 97))
    acc = CrossSpectralAccumulator(n_ch, FS, s)
    acc.push(x)
    assert _line_relative_error(acc.state_dict()["sum"], _textbook_sums(x, s)) < 1e-12
