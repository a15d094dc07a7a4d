"""Band-limited integration: accuracy in band, zero phase, streaming equals batch."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from nifo_core.errors import ConfigError
from nifo_core.signal.integrate import (IntegrationBand, integrator_taps, StreamingIntegrator, default_band, integrate,
                                 integrator_response)

FS = 600.0


@pytest.mark.parametrize("f0", [1.0, 1.3, 5.0, 20.0, 150.0])
def test_sine_integrates_to_its_displacement_and_velocity_without_phase_error(f0):
    t = np.arange(int(120 * FS)) / FS
    x = 1e-3 * np.sin(2 * np.pi * f0 * t)
    v = 1e-3 * 2 * np.pi * f0 * np.cos(2 * np.pi * f0 * t)
    a = -(2 * np.pi * f0) ** 2 * x
    r = integrate(a, FS, band=IntegrationBand(0.5, 200.0))
    s = r.valid
    assert np.max(np.abs(r.displacement[s] - x[s])) < 0.004 * 1e-3
    assert np.max(np.abs(r.velocity[s] - v[s])) < 0.002 * np.max(v)


def test_response_is_real_positive_in_band_and_zero_outside():
    band = IntegrationBand(0.5, 200.0)
    f = np.array([0.1, 0.2, 1.5, 10, 100, 200, 260, 299])
    hv, hd = integrator_response(f, FS, band)
    gv, gd = hv * 2j * np.pi * f, hd * (2j * np.pi * f) ** 2
    np.testing.assert_allclose(np.abs(gv[2:6]), 1, atol=2e-3)
    np.testing.assert_allclose(np.abs(gd[2:6]), 1, atol=2e-3)
    assert np.all(np.abs(np.angle(gd[2:6], deg=True)) < 0.01)
    assert np.all(np.abs(gd[[0, 1, 6, 7]]) < 0.05)


@settings(max_examples=15, deadline=None)
@given(st.lists(st.integers(1, 3000), min_size=1, max_size=12), st.integers(0, 2**31 - 1))
def test_streaming_integrator_equals_batch_for_any_chunking(chunks, seed):
    a = np.random.default_rng(seed).standard_normal(12000)
    band = IntegrationBand(2.0, 200.0)
    ref = integrate(a, FS, band=band)
    si = StreamingIntegrator(FS, band)
    parts, i, k = [], 0, 0
    while i < a.size:
        n = chunks[k % len(chunks)]
        parts.append(si.push(a[i:i + n]))
        i += n
        k += 1
    parts.append(si.flush())
    v = np.concatenate([p[0] for p in parts])
    x = np.concatenate([p[1] for p in parts])
    np.testing.assert_allclose(v, ref.velocity, atol=1e-12 * np.abs(ref.velocity).max())
    np.testing.assert_allclose(x, ref.displacement, atol=1e-12 * np.abs(ref.displacement).max())


def test_integrate_does_not_mutate_its_input():
    a = np.random.default_rng(1).standard_normal(20000)
    a0 = a.copy()
    integrate(a, FS, band=IntegrationBand(1.0, 100.0))
    np.testing.assert_array_equal(a, a0)


def test_default_band_contains_body_bounce_and_respects_nyquist():
    b = default_band(600.0, 300.0)
    assert b.f_lo_hz <= 0.8 and b.f_hi_hz == 200.0
    assert default_band(400.0, 300.0).f_hi_hz == 160.0


def test_bad_band_and_short_record_are_explained():
    with pytest.raises(ConfigError, match="too close to Nyquist"):
        integrate(np.zeros(100000), FS, band=IntegrationBand(0.5, 290.0))
    with pytest.raises(ConfigError, match=r"the lowest edge this record length can resolve is 9\.61 Hz"):
        integrate(np.zeros(1000), FS, band=IntegrationBand(0.5, 200.0))


@pytest.mark.parametrize("f_lo", [1e-300, 1e-9, 1e-6, 1e-4, 1e-3, 0.1])
def test_a_tiny_lower_edge_is_refused_before_anything_is_allocated_with_the_lowest_resolvable_edge(f_lo):
    """Issue 26: 1e-300 Hz raised a TypeError in log2, 1e-9 / 1e-6 Hz tried to allocate 512 TiB / 512 GiB."""
    import re
    import time
    import tracemalloc

    a = np.random.default_rng(0).standard_normal(36_000)   # 60 s at 600 Hz
    band = IntegrationBand(f_lo, 200.0)
    tracemalloc.start()
    t = time.perf_counter()
    with pytest.raises(ConfigError) as info:
        integrate(a, FS, band=band)
    took, peak = time.perf_counter() - t, tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert took < 0.5 and peak < 1 << 20, (took, peak)
    text = str(info.value)
    assert "the lowest edge this record length can resolve is 0.267 Hz" in text and "Fix: raise the band's lower edge" in text
    lo = float(re.search(r"at least ([0-9.e+-]+) Hz", text)[1])
    integrate(a, FS, band=IntegrationBand(lo, 200.0))        # the edge it names works on this record
    with pytest.raises(ConfigError, match="can resolve"):
        integrate(a, FS, band=IntegrationBand(0.99 * 16 * FS / 35_999, 200.0))
    with pytest.raises(ConfigError, match=r"nifo designs at most \d+"):   # a stream (no length): the design limit
        integrator_taps(FS, band if f_lo < 1e-2 else IntegrationBand(1e-3, 200.0))
