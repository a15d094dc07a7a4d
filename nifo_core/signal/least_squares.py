"""Least squares for tall, thin regressions: the restoring-force fits of characterize and the loop's equation error.

numpy's ``lstsq`` (LAPACK ``gelsd``, an SVD of the unscaled matrix) is both the slow part of these fits and
the less accurate where the columns' scales differ by orders of magnitude (z in metres, ż in m/s, z³ in m³):
:func:`lstsq` solves the normal equations on unit-norm columns with one refinement step, and falls back to the
SVD where they would be ill-conditioned.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

__all__ = ["GRAM_COND", "FixedColumns", "lstsq"]


#: the scaled Gram matrix's condition number up to which :func:`lstsq` solves the normal equations (their error,
#: ~cond·1e-16 before the refinement step, is then far below the noise); beyond it LAPACK's SVD solution
GRAM_COND = 1e8


def lstsq(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares coefficients of ``y`` on the columns of ``a``.

    The equation-error fits of characterize and the loop are tall and thin (10⁵ rows, 3-8 columns, a dozen per
    candidate, hundreds in the loop's bias correction): normal equations on unit-norm columns, Cholesky-solved,
    plus one step of iterative refinement from the residual (four passes over ``a``; 2.2× faster than numpy's).
    It is also the more accurate: LAPACK's ``gelsd`` as numpy calls it does not scale the columns, and a cubic's
    z³ (10⁻⁹ m³) beside ż (0.1 m/s) cost it ~1e-8 relative, against ~1e-12 here (measured against the SVD
    solution on unit-norm columns, 120 000-180 000 rows: tests/test_lstsq.py).
    Where the scaled Gram matrix's condition is :data:`GRAM_COND` or more (nearly collinear columns) the SVD
    solution on unit-norm columns; with an empty column, a short ``a`` or a 2-D ``y``, :func:`numpy.linalg.lstsq`."""
    a = np.asarray(a, float)
    y = np.asarray(y, float)
    if a.ndim != 2 or y.ndim != 1 or a.shape[1] == 0 or a.shape[0] < 8 * a.shape[1]:
        return np.linalg.lstsq(a, y, rcond=None)[0]
    gram = a.T @ a
    scale = np.sqrt(np.diag(gram))
    if not np.all((scale > 0) & np.isfinite(scale)):
        return np.linalg.lstsq(a, y, rcond=None)[0]
    gram = gram / np.outer(scale, scale)
    if not np.linalg.cond(gram) < GRAM_COND:
        return np.linalg.lstsq(a / scale, y, rcond=None)[0] / scale
    factor = scipy.linalg.cho_factor(gram, check_finite=False)
    x = scipy.linalg.cho_solve(factor, (a.T @ y) / scale, check_finite=False) / scale
    r = y - a @ x
    return x + scipy.linalg.cho_solve(factor, (a.T @ r) / scale, check_finite=False) / scale


class FixedColumns:
    """:func:`lstsq` of ``y`` on the columns ``[F, V]`` for many ``V`` beside one fixed ``F``: F's part of the Gram
    matrix and of the right side computed once (a search over one term's parameter refits the same other columns
    at every trial point; :func:`nifo_core.characterize.static.static_bump_stops`). The same normal equations on
    unit-norm columns with one refinement step, so the same coefficients to rounding; beyond :data:`GRAM_COND`,
    or short, :func:`lstsq` of the stacked matrix."""

    def __init__(self, f: np.ndarray, y: np.ndarray):
        self.f = np.ascontiguousarray(f, float)
        self.y = np.asarray(y, float)
        self.gff = self.f.T @ self.f
        self.fy = self.f.T @ self.y

    def fit(self, v: np.ndarray) -> tuple[np.ndarray, float]:
        """(coefficients of [F, V], residual sum of squares) for the varying columns ``v`` (rows × q)."""
        f, y = self.f, self.y
        v = np.asarray(v, float).reshape(y.size, -1)
        p = f.shape[1]
        gfv = f.T @ v
        gram = np.block([[self.gff, gfv], [gfv.T, v.T @ v]])
        scale = np.sqrt(np.diag(gram))
        ok = y.size >= 8 * gram.shape[0] and np.all((scale > 0) & np.isfinite(scale))
        if ok:
            gram = gram / np.outer(scale, scale)
            ok = np.linalg.cond(gram) < GRAM_COND
        if not ok:
            a = np.column_stack([f, v])
            x = lstsq(a, y)
            r = y - a @ x
            return x, float(r @ r)
        factor = scipy.linalg.cho_factor(gram, check_finite=False)
        x = scipy.linalg.cho_solve(factor, np.concatenate([self.fy, v.T @ y]) / scale, check_finite=False) / scale
        r = y - f @ x[:p] - v @ x[p:]
        x = x + scipy.linalg.cho_solve(factor, np.concatenate([f.T @ r, v.T @ r]) / scale, check_finite=False) / scale
        r = y - f @ x[:p] - v @ x[p:]
        return x, float(r @ r)
