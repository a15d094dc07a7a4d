"""The equation-error fits' least squares (nifo_core.signal.least_squares.lstsq): the normal equations on unit-norm
columns with a refinement step agree with the SVD solution of the same column-scaled problem, are more accurate
than numpy's unscaled one where the columns' scales differ by 10^4 and more, and fall back to the SVD where the
columns are nearly collinear or one is empty."""

from __future__ import annotations

import numpy as np
import pytest

from nifo_core.signal.least_squares import GRAM_COND, lstsq


def _strut_columns(n: int = 120_000, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """z [m], ż [m/s], a knee's and a Coulomb friction's describing functions, z³: scales from 1e-9 to 1."""
    rng = np.random.default_rng(seed)
    z = np.cumsum(rng.standard_normal(n)) * 1e-4
    v = np.gradient(z) * 500
    a = np.column_stack([z, v, np.maximum(np.abs(v) - 0.01, 0) * np.sign(v), np.tanh(v / 1e-3), z ** 3])
    y = a @ np.array([1e4, 50, 30, 20, 1e9]) + rng.standard_normal(n)
    return a, y


def _reference(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    s = np.linalg.norm(a, axis=0)
    return np.linalg.lstsq(a / s, y, rcond=None)[0] / s


@pytest.mark.parametrize("k", [2, 3, 4, 5])
def test_agrees_with_the_scaled_svd_solution(k):
    a, y = _strut_columns()
    a = a[:, :k]
    ref = _reference(a, y)
    got = lstsq(a, y)
    assert np.max(np.abs(got - ref) / np.abs(ref)) < 1e-11


def test_more_accurate_than_the_unscaled_svd_where_scales_differ():
    a, y = _strut_columns()
    ref = _reference(a, y)
    ours = np.max(np.abs(lstsq(a, y) - ref) / np.abs(ref))
    unscaled = np.max(np.abs(np.linalg.lstsq(a, y, rcond=None)[0] - ref) / np.abs(ref))
    print(f"\nrelative error against the scaled SVD: ours {ours:.1e}, numpy's unscaled {unscaled:.1e}")
    assert ours < 1e-11 and ours < unscaled


def test_nearly_collinear_columns_take_the_svd():
    a, y = _strut_columns()
    twin = a[:, 1] * (1 + 1e-9 * np.sin(np.arange(a.shape[0])))
    b = np.column_stack([a[:, :2], twin])
    s = np.linalg.norm(b, axis=0)
    assert np.linalg.cond((b.T @ b) / np.outer(s, s)) >= GRAM_COND
    got, ref = lstsq(b, y), np.linalg.lstsq(b / s, y, rcond=None)[0] / s     # the coefficients ill-determined
    r_got, r_ref = y - b @ got, y - b @ ref
    assert r_got @ r_got <= (1 + 1e-9) * (r_ref @ r_ref)          # a least-squares solution all the same
    assert np.all(np.isfinite(got))


def test_an_empty_column_takes_numpys_minimum_norm_solution():
    a, y = _strut_columns()
    b = np.column_stack([a[:, :2], np.zeros(a.shape[0])])     # a clearance never reached
    got = lstsq(b, y)
    np.testing.assert_array_equal(got, np.linalg.lstsq(b, y, rcond=None)[0])
    assert got[2] == 0


def test_fixed_columns_refit_gives_lstsqs_coefficients_and_residual():
    """FixedColumns: F's Gram part once, many V beside it; the same solution as lstsq of [F, V] to rounding."""
    from nifo_core.signal.least_squares import FixedColumns

    rng = np.random.default_rng(4)
    n = 20000
    f = np.column_stack([rng.standard_normal(n) * 1e-3, rng.standard_normal(n) * 0.1])
    solver = FixedColumns(f, y := f @ [50.0, 2.0] + 0.01 * rng.standard_normal(n))
    for scale in (1e-9, 1.0):
        v = np.column_stack([np.maximum(f[:, 0], 0.0) * scale, f[:, 1] ** 3])
        yy = y + v @ [1.0 / scale, 3.0]
        solver = FixedColumns(f, yy)
        x, rss = solver.fit(v)
        a = np.column_stack([f, v])
        ref = lstsq(a, yy)
        np.testing.assert_allclose(x, ref, rtol=1e-9)
        assert rss == pytest.approx(float(np.sum((yy - a @ ref) ** 2)), rel=1e-9)
    collinear = np.column_stack([f[:, 0], f[:, 0] * (1 + 1e-12)])    # beyond GRAM_COND: lstsq of the whole
    x, _ = FixedColumns(f, y).fit(collinear)
    assert np.all(np.isfinite(x))
