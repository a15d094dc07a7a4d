"""Compiled strut forces by kind code: the one numba evaluation of the describing functions.

:mod:`nifo_core.kinds.describing` defines each kind in numpy (for whole signals);
the two time-stepping codes — the simulator (:mod:`nifo_core.simulate.quarter_car`) and the
prediction engine (:mod:`nifo_core.predict.timesim`) — need the same functions one
sample at a time inside numba loops. They are written here once, term by term
as ``describing.py`` computes them (same rounding), with each term reduced to
``(code, p0, p1)``; the backlash play state ``y`` is carried by the caller
and committed once per step (as :func:`describing.play_operator` does per sample).

``tests/test_describing.py`` / ``tests/test_simulate.py`` check the two
definitions agree.

``g_one`` and ``strut_force`` are inlined where they are called (``inline="always"``): called, each step
passed five arrays through two levels of calls, and their reference counting cost 72 ns of a 306 ns step;
inlined on the prediction engine's hot path, the step takes 68 ns, with the same arithmetic (bit for bit).
Each inlined copy is compiled anew, so the rare paths call one compiled copy (``timesim._fb_called``). numba's
on-disk cache keys a compiled loop on its own file only (a documented limitation, as it was before the
inlining): after a change to this file, clear the callers' caches (``find . -name '*.nb[ic]' -delete``).
"""

from __future__ import annotations

from typing import Sequence

import numba
import numpy as np

from .describing import CODES, Term
from ..errors import ConfigError

__all__ = ["PLAY", "kind_code", "strut_arrays", "g_one", "g_partials", "strut_force", "lipschitz", "slopes_within"]

# kind codes, from the kind registry (numba reads these module globals as constants)
_CUBIC, _CLEAR, _SAT, _BUMP_C, _BUMP_R, _PLAY, _VDZ, _VSAT, _COUL, _QUAD, _ASYM_R, _ASYM_C, _QSTIFF = (
    CODES["cubic"], CODES["clearance"], CODES["saturation"], CODES["bump_compression"], CODES["bump_rebound"],
    CODES["play"], CODES["velocity_deadzone"], CODES["velocity_saturation"], CODES["coulomb"],
    CODES["quadratic_damping"], CODES["asymmetric_rebound"], CODES["asymmetric_compression"],
    CODES["quadratic_stiffness"])
#: code of the hysteretic backlash (play operator), whose state the caller keeps
PLAY = _PLAY


def kind_code(t: Term) -> tuple[int, float, float]:
    """(code, p0, p1) of a term for the compiled force evaluation (``Kind.compiled`` of the registry)."""
    compiled = t.spec.compiled
    if compiled is None:  # pragma: no cover - every kind of the registry has one
        raise ConfigError(f"no compiled code for nonlinearity kind {t.kind!r}")
    code, p0, p1 = compiled(t.params)
    return code, float(p0), float(p1)


def strut_arrays(terms: Sequence[Term], coefficients: Sequence[float]):
    """``(codes, coef, p0, p1)`` arrays of terms with their coefficients, for :func:`strut_force`."""
    rows = [kind_code(t) for t in terms]
    codes = np.array([r[0] for r in rows], dtype=np.int64)
    p0 = np.array([r[1] for r in rows], dtype=np.float64)
    p1 = np.array([r[2] for r in rows], dtype=np.float64)
    coef = np.asarray(coefficients, dtype=np.float64).reshape(codes.size)
    return codes, coef, p0, p1


def lipschitz(t: Term) -> tuple[float, float]:
    """Global Lipschitz constants (L_z, L_ż) of g, or inf where g has none (cubic, quadratic).

    |g(z, ż) - g(z', ż')| ≤ L_z·|z - z'| + L_ż·|ż - ż'| for every pair of
    points (the play operator: in the sup norm along a path, constant 1). ``Kind.lipschitz`` of the registry;
    1 in the kind's variable where it has none.
    """
    if t.spec.lipschitz is not None:
        return t.spec.lipschitz(t.params)
    return (1.0, 0.0) if t.variable == "z" else (0.0, 1.0)


def slopes_within(t: Term, z_max: float, zdot_max: float) -> tuple[float, float]:
    """Upper bounds of |dg/dz| and |dg/dż| for motions up to |z| ≤ ``z_max`` [m] and |ż| ≤ ``zdot_max`` [m/s]: the
    Lipschitz constants (:func:`lipschitz`), or ``Kind.slopes_within`` for a g without one (cubic, quadratic)."""
    if t.spec.slopes_within is not None:
        return t.spec.slopes_within(t.params, z_max, zdot_max)
    return lipschitz(t)


@numba.njit(cache=True, inline="always")
def g_one(code, p0, p1, z, zd, y):  # pragma: no cover - compiled
    """One basis function, written as describing.py computes it (same rounding)."""
    if code == _CUBIC:
        return z**3
    if code == _QSTIFF:
        return z**2
    if code == _CLEAR or code == _VDZ:
        x = z if code == _CLEAR else zd
        return np.sign(x) * max(abs(x) - p0, 0.0)
    if code == _SAT or code == _VSAT:
        x = z if code == _SAT else zd
        return min(max(x, -p0), p0)
    if code == _BUMP_C:
        return min(z - p1 + p0, 0.0)
    if code == _BUMP_R:
        return max(z - p1 - p0, 0.0)
    if code == _PLAY:
        if y < z - p0:
            return z - p0
        if y > z + p0:
            return z + p0
        return y
    if code == _COUL:
        return np.tanh(zd / p0)
    if code == _QUAD:
        return zd * abs(zd)
    if code == _ASYM_R:
        return max(zd, 0.0)
    return min(zd, 0.0)  # _ASYM_C


@numba.njit(cache=True, inline="always")
def strut_force(z, zd, codes, coef, p0, p1, play, commit):  # pragma: no cover - compiled
    """N = Σ c_i·g_i(z, ż) (paper Eq. 1-2); commits the play states when ``commit``."""
    n1 = 0.0
    for i in range(codes.size):
        g = g_one(codes[i], p0[i], p1[i], z, zd, play[i])
        if commit and codes[i] == _PLAY:
            play[i] = g
        n1 += coef[i] * g
    return n1


@numba.njit(cache=True, inline="always")
def g_partials(code, p0, p1, z, zd, y):  # pragma: no cover - compiled
    """(∂g/∂z, ∂g/∂ż, ∂g/∂p0) of one basis function at (z, ż), :func:`g_one`'s forms differentiated (the output-error
    refinement's sensitivities, :mod:`nifo_core.predict.sensitivity`). Almost everywhere: at a kink, the side the
    point lies on. A play at committed state y: moving with z (∂g/∂z = 1, ∓1 in its half-width p0) or stuck (0, 0,
    0: its state carries the derivative)."""
    if code == _CUBIC:
        return 3.0 * z * z, 0.0, 0.0
    if code == _QSTIFF:
        return 2.0 * z, 0.0, 0.0
    if code == _CLEAR or code == _VDZ:
        x = z if code == _CLEAR else zd
        d = 1.0 if abs(x) > p0 else 0.0
        if code == _CLEAR:
            return d, 0.0, -np.sign(x) * d
        return 0.0, d, -np.sign(x) * d
    if code == _SAT or code == _VSAT:
        x = z if code == _SAT else zd
        inside = abs(x) < p0
        d = 1.0 if inside else 0.0
        dp = 0.0 if inside else np.sign(x)
        if code == _SAT:
            return d, 0.0, dp
        return 0.0, d, dp
    if code == _BUMP_C:
        if z - p1 + p0 < 0.0:
            return 1.0, 0.0, 1.0
        return 0.0, 0.0, 0.0
    if code == _BUMP_R:
        if z - p1 - p0 > 0.0:
            return 1.0, 0.0, -1.0
        return 0.0, 0.0, 0.0
    if code == _PLAY:
        if y < z - p0:
            return 1.0, 0.0, -1.0
        if y > z + p0:
            return 1.0, 0.0, 1.0
        return 0.0, 0.0, 0.0
    if code == _COUL:
        t = np.tanh(zd / p0)
        s = 1.0 - t * t
        return 0.0, s / p0, -s * zd / (p0 * p0)
    if code == _QUAD:
        return 0.0, 2.0 * abs(zd), 0.0
    if code == _ASYM_R:
        return 0.0, 1.0 if zd > 0.0 else 0.0, 0.0
    return 0.0, 1.0 if zd < 0.0 else 0.0, 0.0  # _ASYM_C
