"""The one spectral engine: scipy-equal densities, analytic FRFs, streaming == batch, exact merges."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import signal

from nifo_core.errors import ConfigError, InputError, RecordTooShortError
from nifo_core.signal.frf import (bound_factor, coherence, condition_number, h1, h2, mimo_fit, mimo_h1, multiple_coherence,
                            partial_coherence, white_noise_floor)
from nifo_core.signal.spectral import CrossSpectralAccumulator, SpectralSettings, auto_spectrum, cross_spectra

FS = 600.0
SMALL = SpectralSettings(block=256, overlap=0.5, window="hann")


def _noise(n_ch, n, seed=0):
    return np.random.default_rng(seed).standard_normal((n_ch, n))


# -- conventions ---------------------------------------------------------------------------
@pytest.mark.parametrize("window,detrend", [("flattop", "constant"), ("hann", "none"), ("boxcar", "constant")])
def test_every_entry_equals_scipy_csd(window, detrend):
    x = _noise(3, 20000, 1)
    x[1] += 0.7 * x[0] + 2.0
    s = SpectralSettings(block=1024, overlap=0.52, window=window, detrend=detrend)
    spec = cross_spectra(x, FS, s)
    for a in range(3):
        for b in range(3):
            f, ref = signal.csd(x[a], x[b], fs=FS, window=window, nperseg=s.block, noverlap=s.noverlap,
                                detrend=detrend if detrend != "none" else False)
            np.testing.assert_allclose(spec.G[:, a, b], ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
    np.testing.assert_allclose(spec.freq_hz, f)


def test_paper_defaults_give_59_blocks_of_6144_on_180000_samples():
    s = SpectralSettings()
    assert (s.block, s.window, s.noverlap, s.step) == (6144, "flattop", 3195, 2949)
    assert s.n_blocks(180_000) == 59


# -- analytic cases ---------------------------------------------------------------------------
def test_scaled_copy_gives_h1_equal_to_the_gain_and_unit_coherence():
    x = _noise(1, 8000, 2)[0]
    spec = cross_spectra(np.stack([x, -3.5 * x]), FS, SMALL)
    np.testing.assert_allclose(h1(spec, 0, 1), -3.5, rtol=1e-12)
    np.testing.assert_allclose(h2(spec, 0, 1), -3.5, rtol=1e-12)
    np.testing.assert_allclose(coherence(spec, 0, 1), 1.0, rtol=1e-12)


def test_two_input_system_is_recovered_with_unit_multiple_coherence():
    u = _noise(2, 30000, 3)
    b, a = signal.butter(2, 0.2)
    y = 2.0 * u[0] + signal.lfilter(b, a, u[1])
    spec = cross_spectra(np.stack([u[0], u[1], y]), FS, SpectralSettings(block=512, window="hann"))
    h = mimo_h1(spec, [0, 1], 2)
    f = spec.freq_hz
    ok = f < 0.8 * f[-1]
    np.testing.assert_allclose(h[0][ok], 2.0, rtol=2e-2)
    _, ref = signal.freqz(b, a, worN=f, fs=FS)
    assert np.median(np.abs(h[1][ok] / ref[ok] - 1)) < 0.02
    assert np.median(multiple_coherence(spec, 2, [0, 1])[ok]) > 0.999
    pc = partial_coherence(spec, 2, [0, 1])
    assert np.median(pc[:, ok]) > 0.99
    assert np.median(condition_number(spec, [0, 1])) < 1.2   # independent inputs


def test_mimo_fit_partial_coherence_equals_the_inverse_matrix_formula():
    # mimo_fit takes it from its own solve (conditioned spectra); partial_coherence from the inverse of the
    # full [inputs, output] matrix: two routes, one answer, on correlated inputs and a noisy output
    rng = np.random.default_rng(7)
    u = _noise(3, 40000, 5)
    u[1] += 0.8 * u[0]
    u[2] += 0.5 * signal.lfilter(*signal.butter(2, 0.1), u[1])
    y = u[0] - 0.7 * u[1] + signal.lfilter(*signal.butter(2, 0.3), u[2]) + 0.6 * rng.standard_normal(40000)
    spec = cross_spectra(np.stack([*u, y]), FS, SpectralSettings(block=512, window="hann"))
    fit = mimo_fit(spec, [0, 1, 2], 3)
    ref = partial_coherence(spec, 3, [0, 1, 2])
    assert 0.05 < np.median(ref) < 0.95
    np.testing.assert_allclose(fit.partial_coherence, ref, rtol=1e-8, atol=1e-12)


def test_noise_on_the_output_lowers_coherence_and_random_error_tracks_it():
    rng = np.random.default_rng(4)
    x = rng.standard_normal(60000)
    y = 0.5 * x + 0.5 * rng.standard_normal(60000)      # γ² = 0.5
    spec = cross_spectra(np.stack([x, y]), FS, SpectralSettings(block=512, overlap=0.0, window="boxcar"))
    fit = mimo_fit(spec, [0], 1)
    assert abs(np.median(fit.multiple_coherence) - 0.5) < 0.03
    eps = np.median(fit.random_error[0])
    assert abs(eps - np.sqrt(0.5 / (2 * (spec.n_avg - 1) * 0.5))) < 0.2 * eps
    err = np.abs(fit.h[0] / 0.5 - 1)
    assert 0.5 < np.std(err) / eps < 1.5                   # the bound is calibrated, not decorative


def test_correlated_inputs_have_a_large_condition_number():
    x = _noise(2, 20000, 5)
    spec = cross_spectra(np.stack([x[0], x[0] + 1e-3 * x[1]]), FS, SMALL)
    assert np.median(condition_number(spec, [0, 1])) > 1e3


def test_input_noise_correction_removes_the_h1_bias():
    rng = np.random.default_rng(6)
    x = rng.standard_normal(80000)
    xm = x + rng.standard_normal(80000)                  # input noise as strong as the signal
    spec = cross_spectra(np.stack([xm, 2 * x]), FS, SMALL)
    n_psd = white_noise_floor(cross_spectra(rng.standard_normal((1, 80000)), FS, SMALL), 0, (10, 290))
    plain = mimo_fit(spec, [0], 1).h[0]
    fixed = mimo_fit(spec, [0], 1, input_noise_psd=[n_psd]).h[0]
    assert abs(np.median(plain.real) - 1.0) < 0.05       # biased by 1/(1 + N/S)
    assert abs(np.median(fixed.real) - 2.0) < 0.05


# -- properties ---------------------------------------------------------------------------------
@settings(max_examples=20, deadline=None)
@given(st.sampled_from(["hann", "boxcar", "flattop", "blackman"]), st.integers(16, 300),
       st.floats(0.0, 0.8), st.integers(0, 2**31 - 1))
def test_parseval_integral_of_the_density_is_the_windowed_mean_square(window, block, overlap, seed):
    s = SpectralSettings(block=block, overlap=overlap, window=window, detrend="none")
    x = _noise(2, 5 * block + 7, seed)
    spec = cross_spectra(x, FS, s)
    w = s.window_array()
    nb = s.n_blocks(x.shape[1])
    blocks = [x[:, k * s.step:k * s.step + block] * w for k in range(nb)]
    ms = np.mean([(b[0] * b[1]).sum() for b in blocks]) / np.sum(w * w)
    df = FS / block
    assert np.isclose(np.sum(spec.G[:, 0, 1].real) * df, ms, rtol=1e-9, atol=1e-12)
    assert np.isclose(np.sum(auto_spectrum(spec, 0)) * df,
                      np.mean([(b[0] ** 2).sum() for b in blocks]) / np.sum(w * w), rtol=1e-9)


@settings(max_examples=20, deadline=None)
@given(st.floats(-50, 50).filter(lambda v: abs(v) > 1e-3), st.floats(-50, 50).filter(lambda v: abs(v) > 1e-3),
       st.integers(0, 2**31 - 1))
def test_spectra_scale_with_the_product_of_channel_gains_and_inputs_are_not_mutated(a, b, seed):
    x = _noise(2, 3000, seed)
    x0 = x.copy()
    base = cross_spectra(x, FS, SMALL).G
    scaled = cross_spectra(x * np.array([[a], [b]]), FS, SMALL).G
    np.testing.assert_allclose(scaled[:, 0, 1], a * b * base[:, 0, 1], rtol=1e-9, atol=1e-12 * abs(a * b))
    np.testing.assert_allclose(scaled[:, 1, 1], b * b * base[:, 1, 1], rtol=1e-9, atol=1e-12 * b * b)
    np.testing.assert_array_equal(x, x0)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 700), min_size=1, max_size=10), st.integers(0, 2**31 - 1))
def test_streaming_in_any_chunk_sizes_equals_batch(chunks, seed):
    x = _noise(3, 4000, seed)
    ref = cross_spectra(x, FS, SMALL)
    acc = CrossSpectralAccumulator(3, FS, SMALL)
    i, k = 0, 0
    while i < x.shape[1]:
        n = chunks[k % len(chunks)]
        acc.push(x[:, i:i + n])
        i, k = i + n, k + 1
    out = acc.spectra()
    assert out.n_avg == ref.n_avg
    np.testing.assert_allclose(out.G, ref.G, rtol=1e-10, atol=1e-14)


@settings(max_examples=15, deadline=None)
@given(st.integers(2, 12), st.integers(0, 2**31 - 1))
def test_merging_two_halves_split_at_a_block_boundary_equals_the_whole(k, seed):
    s = SMALL
    x = _noise(2, 20 * s.step + s.block, seed)
    cut = k * s.step
    first = CrossSpectralAccumulator(2, FS, s)
    first.push(x[:, :cut + s.noverlap])                  # blocks 0..k-1 exactly
    second = CrossSpectralAccumulator(2, FS, s)
    second.push(x[:, cut:])                               # blocks k..
    merged = first.merge(second)
    whole = cross_spectra(x, FS, s)
    assert merged.n_blocks == whole.n_avg
    np.testing.assert_allclose(merged.spectra().G, whole.G, rtol=1e-10, atol=1e-14)
    # merge is a pure function of its operands, and commutes
    np.testing.assert_allclose(second.merge(first).spectra().G, merged.spectra().G, rtol=1e-12)
    assert first.n_blocks == k


def test_merge_of_records_weights_each_by_its_block_count():
    a, b = _noise(2, 3000, 7), _noise(2, 9000, 8)
    sa, sb = cross_spectra(a, FS, SMALL), cross_spectra(b, FS, SMALL)
    acc_a, acc_b = CrossSpectralAccumulator(2, FS, SMALL), CrossSpectralAccumulator(2, FS, SMALL)
    acc_a.push(a)
    acc_b.push(b)
    m = acc_a.merge(acc_b).spectra()
    np.testing.assert_allclose(m.G, (sa.n_avg * sa.G + sb.n_avg * sb.G) / (sa.n_avg + sb.n_avg), rtol=1e-12)


def test_state_round_trip_continues_the_stream_exactly():
    x = _noise(2, 5000, 9)
    acc = CrossSpectralAccumulator(2, FS, SMALL, names=["a", "b"])
    acc.push(x[:, :1234])
    state = {k: np.array(v) for k, v in acc.state_dict().items()}   # plain arrays (np.savez-able)
    again = CrossSpectralAccumulator.from_state(state)
    again.push(x[:, 1234:])
    np.testing.assert_allclose(again.spectra().G, cross_spectra(x, FS, SMALL).G, rtol=1e-12)
    assert again.spectra().names == ("a", "b")


def test_combine_gives_the_spectra_of_channel_combinations():
    x = _noise(2, 6000, 10)
    spec = cross_spectra(x, FS, SMALL)
    direct = cross_spectra(np.stack([x[0] - 2 * x[1], x[1]]), FS, SMALL)
    comb = spec.combine(np.array([[1.0, -2.0], [0.0, 1.0]]))
    np.testing.assert_allclose(comb.G, direct.G, rtol=1e-10, atol=1e-14)


# -- errors ---------------------------------------------------------------------------------------
def test_too_short_record_raises_naming_the_block():
    with pytest.raises(RecordTooShortError, match="block=6144"):
        cross_spectra(np.zeros((2, 6000)), FS)
    with pytest.raises(RecordTooShortError, match="no complete spectral block"):
        CrossSpectralAccumulator(2, FS).spectra()


@pytest.mark.parametrize("kw,match", [({"block": 4}, "block=4"), ({"overlap": 1.0}, "overlap=1.0"),
                                      ({"window": "kaiser"}, "window='kaiser'"), ({"detrend": "linear"}, "detrend")])
def test_bad_settings_raise_config_error_naming_the_value(kw, match):
    with pytest.raises(ConfigError, match=match):
        SpectralSettings(**kw)


def test_merging_accumulators_with_different_settings_is_refused():
    a = CrossSpectralAccumulator(2, FS, SMALL)
    b = CrossSpectralAccumulator(2, FS, SpectralSettings(block=512))
    with pytest.raises(ConfigError, match="different set-ups"):
        a.merge(b)


def test_wrong_channel_count_and_non_finite_samples_are_input_errors():
    acc = CrossSpectralAccumulator(2, FS, SMALL)
    with pytest.raises(InputError, match="expected 2 channels"):
        acc.push(np.zeros((3, 10)))
    bad = np.zeros((2, 10))
    bad[0, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        acc.push(bad)


def test_bound_factor_is_students_t_of_the_fits_degrees_of_freedom():
    """k of the 95 % random-error bounds: t quantile of 2(n_avg - inputs) real dof, never below the normal one."""
    assert bound_factor(5, 1) == pytest.approx(2.306, abs=1e-3)      # t(0.975, 8)
    assert bound_factor(5, 2) == pytest.approx(2.447, abs=1e-3)      # t(0.975, 6)
    assert bound_factor(20, 1) > bound_factor(40, 1) > bound_factor(4000, 1) > 1.959
    assert bound_factor(4000, 1) == pytest.approx(1.960, abs=1e-3)
    assert bound_factor(1, 3) > 4      # fewer blocks than inputs: one dof, very wide, never undefined
    with pytest.raises(ConfigError, match="level"):
        bound_factor(5, 1, level=1.0)


def test_two_input_solve_in_closed_form_equals_the_eigendecomposition_on_full_singular_and_zero_lines():
    from nifo_core.signal import frf

    rng = np.random.default_rng(0)
    x = rng.normal(size=(300, 2, 8)) + 1j * rng.normal(size=(300, 2, 8))
    x[100:200, 1] = x[100:200, 0] * (0.3 - 0.2j)                  # rank one: the minimum-norm answer
    g = x @ np.swapaxes(x, 1, 2).conj()
    g[200:210] = 0.0
    g[210:220] = np.diag([2.0, 2.0])                               # equal eigenvalues
    y = rng.normal(size=(300, 2)) + 1j * rng.normal(size=(300, 2))
    s = frf._diag_scale(g)
    a = g * s[:, :, None] * s[:, None, :]
    lam, proj = frf._eig2(a)
    lam_ref, v = np.linalg.eigh(a)
    np.testing.assert_allclose(lam, lam_ref, atol=1e-12)
    np.testing.assert_allclose(np.einsum("fk,fkij->fij", lam, proj), a, atol=1e-12)
    h, ainv, _, cond = frf._solve(g, y)
    keep = np.abs(lam_ref) > 1e-13 * np.abs(lam_ref).max(axis=1, keepdims=True)
    inv = np.where(keep, 1 / np.where(keep, lam_ref, 1), 0)
    ref = (v * inv[:, None, :]) @ np.swapaxes(v, 1, 2).conj()
    np.testing.assert_allclose(ainv, ref, atol=1e-10)
    assert np.all(np.isinf(cond[100:210]) | (cond[100:210] > 1e13)) and np.all(cond[210:220] == 1.0)
