"""Time-domain simulation of an identified model: the prediction engine (docs/method.md §4).

The model (:mod:`nifo_core.predict.linear_part`) is a linear part Hz = Z/U with the
nonlinear strut force fed back into its input::

    ẋ = A·x + b·u,   z = c·x,   ż = c·A·x   (c·b = 0),
    u = v + n,       v = ẍ1 [+ k3·x1] [- F/M2] (external, measured),
    n = Σ γ_i·g_i(z, ż) - a·z - b·ż     ((a, b): the strut terms' linear part the linear part absorbed)

How it runs, and why it cannot diverge numerically for a stable linear part:

1. v is interpolated band-limited to ``fs·oversample`` (zero-phase polyphase
   FIR, the simulator's anti-aliasing taps) and taken piecewise linear between
   the fine samples (first-order hold).
2. The linear part is discretised EXACTLY for that input (matrix exponential of
   the FOH-augmented system): x_{k+1} = Φ·x_k + Γ0·u_k + Γ1·u_{k+1}. Its
   poles are e^{p·h}: inside the unit circle for every step h when Hz is stable.
3. The feedback is implicit: n_{k+1} solves the scalar equation
   n = N(z* + α·n, ż* + β·n) with α = c·Γ1, β = c·A·Γ1 (fixed-point iteration,
   bisection on a bracket when it does not contract), so stiff and non-smooth
   forces (friction, bump stops) are taken at the end of the step, like an
   implicit integrator. The play state of a backlash is committed once per step.
4. Body acceleration ẍ2 = ẍ1 + z̈ at the fine rate is anti-aliased and
   decimated back to ``fs`` (as the simulator records); z, ż are the exact
   states at the record's instants.

With feedback paths (``LinearPart.paths``, :mod:`nifo_core.predict.feedback_paths`) the
linear part has two inputs sharing its poles, ``ẋ = A·x + b·v + Σ e_i·n_i``,
n_i = g_i(z) - α_i·z each term's bounded remainder through its own path; the
step is the same (exact FOH for both inputs, the n_i implicit by fixed point).

A state that leaves every bound (|z| above ``z_limit``, or not finite) means
the identified model itself is unstable at this level: reported, never hidden.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numba
import numpy as np
import scipy.linalg

from ..kinds.describing import Term, path_slopes
from ..errors import ConfigError
from .linear_part import LinearPart
from ..simulate.quarter_car import antialias_taps, decimate, interpolate
from ..kinds.strut_forces import PLAY, g_one, strut_arrays, strut_force
from ..signal.memo import ArrayMemo

__all__ = ["TimeResponse", "discretise", "simulate_response", "lookahead_samples"]


@dataclass(frozen=True, eq=False)
class TimeResponse:
    """Response of a model to an external input, at the input's rate.

    Attributes
    ----------
    z, zdot : ndarray
        Relative displacement [m] and velocity [m/s] (exact states at the samples).
    zddot : ndarray
        Relative acceleration body_accel - ẍ1 [m/s²].
    body_accel : ndarray
        ẍ1 + z̈ [m/s²] (anti-aliased at the fine rate, decimated).
    force : ndarray
        Feedback per unit body mass n = Σ γ_i·g_i - a·z - b·ż [m/s²] at the samples
        ((a, b) = ``linear.absorbed``).
    diverged_at : int
        Sample where the state left its bounds, -1 when it did not.
    oversample : int
    """

    z: np.ndarray
    zdot: np.ndarray
    zddot: np.ndarray
    body_accel: np.ndarray
    force: np.ndarray
    diverged_at: int
    oversample: int


@lru_cache(maxsize=32)
def _discretise_cached(key: bytes, n: int, h: float):
    abc = np.frombuffer(key, dtype=np.float64)
    a = abc[: n * n].reshape(n, n)
    b = abc[n * n: n * n + n]
    m = np.zeros((n + 2, n + 2))
    m[:n, :n] = a * h
    m[:n, n] = b * h
    m[n, n + 1] = 1.0
    e = scipy.linalg.expm(m)
    phi, p1, p2 = e[:n, :n], e[:n, n], e[:n, n + 1]
    return phi, p1 - p2, p2


def discretise(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact first-order-hold discretisation: x_{k+1} = Φ·x_k + Γ0·u_k + Γ1·u_{k+1} for step ``h`` [s]."""
    a = np.ascontiguousarray(a, float)
    b = np.ascontiguousarray(b, float)
    return _discretise_cached(np.concatenate([a.ravel(), b]).tobytes(), a.shape[0], float(h))


@numba.njit(cache=True, inline="always")
def _fb(z, zd, codes, coef, p0, p1, play, commit, la, lb):  # pragma: no cover - compiled
    """Feedback n = Σ γ_i·g_i(z, ż) - a·z - b·ż (the absorbed linear part taken out)."""
    return strut_force(z, zd, codes, coef, p0, p1, play, commit) - la * z - lb * zd


@numba.njit(cache=True)
def _fb_called(z, zd, codes, coef, p0, p1, play, commit, la, lb):  # pragma: no cover - compiled
    """:func:`_fb` as a call, for the rare paths: each inlined copy of the force is compiled anew (measured: the
    step with every path inlined took 12.5 s to compile, against 1.8 s before the inlining)."""
    return _fb(z, zd, codes, coef, p0, p1, play, commit, la, lb)


#: fixed-point iterations of the implicit feedback solve before the bracketed bisection takes over
FIXED_POINT_ITERATIONS = 40


@numba.njit(cache=True, inline="always")
def _settled(nn, n, atol):  # pragma: no cover - compiled
    """The fixed-point iteration n → nn has converged: the change below 1e-13 relative or ``atol`` [m/s²] (rounding
    of the input's scale). One test for the single march and the lanes (:mod:`.timesim_lanes`): the same bits."""
    return abs(nn - n) <= 1e-13 * max(abs(nn), abs(n)) + atol


@numba.njit(cache=True, inline="always")
def _solve(z0, zd0, alpha, beta, guess, codes, coef, p0, p1, play, la, lb, atol):  # pragma: no cover - compiled
    """n = N(z0 + α·n, ż0 + β·n): fixed point (:func:`_settled`), then bisection on a bracket (:func:`_bracketed`).
    Returns (n, ok)."""
    n = guess
    for _ in range(FIXED_POINT_ITERATIONS):
        nn = _fb(z0 + alpha * n, zd0 + beta * n, codes, coef, p0, p1, play, False, la, lb)
        if _settled(nn, n, atol):
            return nn, True
        n = nn
    return _bracketed(z0, zd0, alpha, beta, guess, codes, coef, p0, p1, play, la, lb, atol)


@numba.njit(cache=True)
def _bracketed(z0, zd0, alpha, beta, guess, codes, coef, p0, p1, play, la, lb, atol):  # pragma: no cover
    """The fixed point did not contract: bisection on a bracket (a call: rare, and compiled once)."""
    # not contracting: bracket a sign change of f(n) = n - N(n) around the guess and bisect; each half of the
    # bracket on its own (a force that is not monotone in z, e.g. an even quadratic spring, can give f the same
    # sign at both ends of a symmetric bracket with its root, the one next to the guess, inside)
    fg = guess - _fb_called(z0 + alpha * guess, zd0 + beta * guess, codes, coef, p0, p1, play, False, la, lb)
    if fg == 0.0:
        return guess, True
    d = max(abs(guess), 1e-6)
    lo, hi = guess - d, guess + d
    flo = lo - _fb_called(z0 + alpha * lo, zd0 + beta * lo, codes, coef, p0, p1, play, False, la, lb)
    fhi = hi - _fb_called(z0 + alpha * hi, zd0 + beta * hi, codes, coef, p0, p1, play, False, la, lb)
    k = 0
    while flo * fg > 0 and fhi * fg > 0 and k < 200:
        d *= 2.0
        lo, hi = guess - d, guess + d
        flo = lo - _fb_called(z0 + alpha * lo, zd0 + beta * lo, codes, coef, p0, p1, play, False, la, lb)
        fhi = hi - _fb_called(z0 + alpha * hi, zd0 + beta * hi, codes, coef, p0, p1, play, False, la, lb)
        k += 1
    if not (np.isfinite(flo) and np.isfinite(fhi) and np.isfinite(fg)):
        return guess, False
    if flo * fg <= 0:
        hi = guess
    elif fhi * fg <= 0:
        lo, flo = guess, fg
    else:
        return guess, False
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        fm = mid - _fb_called(z0 + alpha * mid, zd0 + beta * mid, codes, coef, p0, p1, play, False, la, lb)
        if (fm > 0) == (flo > 0):
            lo, flo = mid, fm
        else:
            hi = mid
        if hi - lo <= 1e-14 * max(abs(lo), abs(hi)) + atol:
            break
    return 0.5 * (lo + hi), True


@numba.njit(cache=True, inline="always")
def paired_prediction(x, xs, lo, c1, pa, pb, g0, g1, uk, un, cz, cd):  # pragma: no cover - compiled
    """xs = Φ·x + Γ0·uk + Γ1·un for Φ's rows as two fixed products (:func:`_rows`); returns (c·xs, c·A·xs). The
    step's state prediction, and its sensitivities' (:mod:`nifo_core.predict.sensitivity`)."""
    z0 = 0.0
    zd0 = 0.0
    for i in range(xs.size):
        acc = g0[i] * uk + g1[i] * un
        acc += pa[i] * x[lo[i]]
        acc += pb[i] * x[c1[i]]
        xs[i] = acc
        z0 += cz[i] * acc
        zd0 += cd[i] * acc
    return z0, zd0


@numba.njit(cache=True, inline="always")
def march_start(codes, coef, p0, p1, play, cz, cd, g1, la, lb):  # pragma: no cover - compiled
    """What a march fixes before its first step: (α = c·Γ1, β = c·A·Γ1, whether a play is there, whether any
    feedback acts, the feedback at rest with the play states committed)."""
    alpha = 0.0
    beta = 0.0
    for i in range(g1.size):
        alpha += cz[i] * g1[i]
        beta += cd[i] * g1[i]
    plays = False           # only a play has a state to commit after the step
    for i in range(codes.size):
        if codes[i] == PLAY:
            plays = True
    active = codes.size > 0 or la != 0.0 or lb != 0.0
    nk = _fb_called(0.0, 0.0, codes, coef, p0, p1, play, True, la, lb) if active else 0.0
    return alpha, beta, plays, active, nk


def _step_kernels(paired: bool):
    """The single-input step kernel (the feedback paths': :func:`_path_kernel`), for Φ's rows as two fixed products
    (``paired``) or as loops over their bands (:func:`_rows`). ``paired`` is a constant of the compiled code, not
    a branch in the step: with it as an argument (or the row in an inlined helper) the step ran no faster, or
    8× slower, than the band's loop (measured on the kernel with paths, F-16 level 7: 55 and 480 ms against 61;
    compiled with it as a constant, 49 ms)."""

    @numba.njit(cache=True, nogil=True)   # nogil: simulations side by side (nifo_core.signal.parallel)
    def run(phi, lo, hi, c1, pa, pb, g0, g1, cz, cd, ca, dd, v, codes, coef, p0, p1, la, lb, z_limit, atol, q,
             out_z, out_zd, out_zdd, out_n):  # pragma: no cover - compiled
        """March the FOH-discretised linear part with the implicit strut feedback; returns the failing step or -1.
        Row i of Φ is nonzero only in columns lo[i]..hi[i]-1 (:func:`_rows`). z̈ is written at every fine step
        (it is decimated), z, ż and n at every ``q``-th (the record's instants): ``out_z[k]`` is fine step k·q."""
        ns = phi.shape[0]
        x = np.zeros(ns)
        xs = np.zeros(ns)
        play = np.zeros(codes.size)
        alpha, beta, plays, active, nk = march_start(codes, coef, p0, p1, play, cz, cd, g1, la, lb)
        nprev = nk
        out_z[0], out_zd[0], out_zdd[0], out_n[0] = 0.0, 0.0, dd * (v[0] + nk), nk
        ph = 0
        k = 0
        for j in range(v.size - 1):
            uk = v[j] + nk
            un = v[j + 1]
            if paired:
                z0, zd0 = paired_prediction(x, xs, lo, c1, pa, pb, g0, g1, uk, un, cz, cd)
            else:
                z0 = 0.0
                zd0 = 0.0
                for i in range(ns):
                    acc = g0[i] * uk + g1[i] * un
                    for l in range(lo[i], hi[i]):
                        acc += phi[i, l] * x[l]
                    xs[i] = acc
                    z0 += cz[i] * acc
                    zd0 += cd[i] * acc
            n = 0.0
            if active:
                n, ok = _solve(z0, zd0, alpha, beta, 2.0 * nk - nprev, codes, coef, p0, p1, play, la, lb, atol)
                nprev = nk
                if not ok:
                    return j + 1
            zdd = dd * (un + n)
            for i in range(ns):
                x[i] = xs[i] + g1[i] * n
                zdd += ca[i] * x[i]
            z = z0 + alpha * n
            zd = zd0 + beta * n
            if plays:
                strut_force(z, zd, codes, coef, p0, p1, play, True)   # commit the play states
            nk = n
            out_zdd[j + 1] = zdd
            ph += 1
            if ph == q:
                ph = 0
                k += 1
                out_z[k], out_zd[k], out_n[k] = z, zd, n
            if not (abs(z) <= z_limit):
                return j + 1
        return -1

    return run


#: term counts whose feedback-path kernel has the count compiled in (:func:`_path_kernel`); more terms: one kernel
MAX_UNROLLED_TERMS = 3


@lru_cache(maxsize=None)
def _path_kernel(paired: bool, terms: int):
    """The feedback-path step kernel for Φ's rows as two fixed products (``paired``) or their band's loop, with the
    number of terms a constant of the compiled code (``terms`` ≥ 1; 0: read from ``codes``), as ``paired`` is.
    The loops over the terms inside the loops over the states are then unrolled, the sums in the same order: every
    output the same to the last bit. Measured: on 17 path simulations that ``nifo run`` on F-16 1/3/5/7 ran (kept by
    a scratch script; 22 states, one or two plays, 196 608 fine steps each) 0.50-0.63 s → 0.33-0.38 s in all;
    ``benchmarks/bench_predict.py`` prints the ratio on a three-play model of rational order 30 (1.50 on 60 s).
    Made at first use: each count compiles (or loads from numba's cache) only where it runs."""

    @numba.njit(cache=True, nogil=True)
    def run_paths(phi, lo, hi, c1, pa, pb, g0b, g1b, g0e, g1e, cz, cd, ca, ddb, dde, v, codes, p0, p1, alpha, z_limit,
                   out_z, out_zd, out_zdd, out_n):  # pragma: no cover - compiled
        """March the two-input linear part (measured input v, each term's remainder through its path); Φ's rows
        banded as in :func:`_run`; returns the failing step or -1."""
        ns = phi.shape[0]
        m = codes.size if terms == 0 else terms    # a constant: the loops over the terms unrolled
        x = np.zeros(ns)
        xs = np.zeros(ns)
        play = np.zeros(m)
        n = np.zeros(m)
        nn = np.zeros(m)
        az = np.zeros(m)      # z_{k+1} = z0 + Σ az_i·n_i
        ad = np.zeros(m)
        zmax = 0.0
        for i in range(m):
            for l in range(ns):
                az[i] += cz[l] * g1e[l, i]
                ad[i] += cd[l] * g1e[l, i]
        for j in range(v.size - 1):
            z0 = 0.0
            zd0 = 0.0
            for l in range(ns):
                acc = g0b[l] * v[j] + g1b[l] * v[j + 1]
                for i in range(m):
                    acc += g0e[l, i] * n[i]
                if paired:
                    acc += pa[l] * x[lo[l]]
                    acc += pb[l] * x[c1[l]]
                else:
                    for k in range(lo[l], hi[l]):
                        acc += phi[l, k] * x[k]
                xs[l] = acc
                z0 += cz[l] * acc
                zd0 += cd[l] * acc
            for i in range(m):
                nn[i] = n[i]
            ok = False
            for _ in range(100):        # contraction: |az_i| ~ h², the remainders 1-Lipschitz in z
                z = z0
                for i in range(m):
                    z += az[i] * nn[i]
                change = 0.0
                for i in range(m):
                    new = g_one(codes[i], p0[i], p1[i], z, 0.0, play[i]) - alpha[i] * z
                    change = max(change, abs(new - nn[i]))
                    nn[i] = new
                if change <= 1e-13 * (abs(z) + zmax) or change == 0.0:
                    ok = True
                    break
            if not ok:
                return j + 1
            z = z0
            zd = zd0
            zdd = ddb * v[j + 1]
            for i in range(m):
                z += az[i] * nn[i]
                zd += ad[i] * nn[i]
                zdd += dde[i] * nn[i]
            for i in range(m):
                play[i] = g_one(codes[i], p0[i], p1[i], z, 0.0, play[i])
                n[i] = play[i] - alpha[i] * z
            for l in range(ns):
                val = xs[l]
                for i in range(m):
                    val += g1e[l, i] * n[i]
                x[l] = val
                zdd += ca[l] * val
            tot = 0.0
            for i in range(m):
                tot += n[i]
            out_z[j + 1], out_zd[j + 1], out_zdd[j + 1], out_n[j + 1] = z, zd, zdd, tot
            zmax = max(zmax, abs(z))
            if not (abs(z) <= z_limit):
                return j + 1
        return -1

    return run_paths


#: the kernels of a block-diagonal Φ (every linear part nifo builds), and of any other (the band's loop)
_run_paired = _step_kernels(True)
_run_band = _step_kernels(False)


def _run(phi, lo, hi, c1, pa, pb, paired, *args):
    """:func:`_step_kernels`' single-input kernel for ``_rows(phi)``; returns the failing step or -1."""
    return (_run_paired if paired else _run_band)(phi, lo, hi, c1, pa, pb, *args)


def _run_paths(phi, lo, hi, c1, pa, pb, paired, *args, terms: int):
    """:func:`_path_kernel`'s kernel for ``_rows(phi)`` and ``terms`` terms; returns the failing step or -1."""
    kernel = _path_kernel(bool(paired), terms if 1 <= terms <= MAX_UNROLLED_TERMS else 0)
    return kernel(phi, lo, hi, c1, pa, pb, *args)


def _simulate_paths(linear: LinearPart, terms, v: np.ndarray, h: float, z_limit: float):
    alpha = path_slopes(terms)
    if len(terms) != linear.paths.shape[0]:
        raise ConfigError(f"{len(terms)} terms but {linear.paths.shape[0]} feedback paths")
    a, b, e, c = linear.path_state_space()
    phi, g0b, g1b = discretise(a, b, h)
    g0e, g1e = np.zeros_like(e), np.zeros_like(e)
    for i in range(e.shape[1]):
        _, g0e[:, i], g1e[:, i] = discretise(a, e[:, i], h)
    cd = c @ a
    ca = cd @ a
    codes, _, p0, p1 = strut_arrays(list(terms), [1.0] * len(terms))
    nf = v.size
    z, zd, zdd, nn = (np.zeros(nf) for _ in range(4))
    zdd[0] = float(cd @ b) * v[0]
    fail = _run_paths(*_rows(phi), g0b, g1b, g0e, g1e, c, cd, ca, float(cd @ b),
                      e.T @ cd, v,
                      codes, p0, p1, alpha, float(z_limit), z, zd, zdd, nn, terms=len(terms))
    return z, zd, zdd, nn, fail


def _rows(phi: np.ndarray) -> tuple:
    """Φ for the step kernels: ``(Φ, lo, hi, c1, pa, pb, paired)``, row i of Φ zero outside columns lo[i]..hi[i]-1.

    A rational linear part is in real modal form (one 2×2 block per conjugate pair, one 1×1 per real pole,
    :meth:`LinearPart.state_space`), so Φ = e^{A·h} is block diagonal with exact zeros, and every row has at most
    two nonzeros: then (``paired``) row i is the two fixed products pa[i]·x[lo[i]] + pb[i]·x[c1[i]] (pb = 0 for a
    1×1 block), otherwise a loop over lo[i]..hi[i]-1. Either way the products are summed in column order, and
    those with an exact zero are skipped (or add +0): every sum is the same to the last bit as the full product.
    Measured on the F-16's flexible body (22 states, level 5, 73 728 samples): the band instead of the full row
    took a prediction 0.20 → 0.10 s (0.22 → 0.12 s with feedback paths); the two fixed products instead of the
    band's loop took the path kernel on level 7 (442 368 fine steps, one play) 61 → 49 ms, the same to the last
    bit (``benchmarks/bench_predict.py`` prints both forms, same run)."""
    phi = np.ascontiguousarray(phi, float)
    nz = phi != 0.0
    n = phi.shape[0]
    lo = np.array([int(np.argmax(r)) if r.any() else 0 for r in nz], dtype=np.int64)
    hi = np.array([n - int(np.argmax(r[::-1])) if r.any() else 0 for r in nz], dtype=np.int64)
    width = hi - lo
    paired = bool(n == 0 or width.max() <= 2)
    rows = np.arange(n)
    c1 = np.where(width == 2, lo + 1, lo)
    pa = np.where(width >= 1, phi[rows, lo], 0.0)
    pb = np.where(width == 2, phi[rows, c1], 0.0)
    return phi, lo, hi, c1, pa, pb, paired


def lookahead_samples(q: int) -> int:
    """How many samples of later input a simulated sample depends on, at ``q`` fine steps per sample.

    The march itself is causal; the interpolation of the input to the fine rate and the decimation of z̈ back are
    zero-phase FIR filters (:func:`~nifo_core.simulate.quarter_car.antialias_taps`), each reaching half its length
    ahead. So the first k samples of a response are the same (to rounding: the filters' FFT blocks differ) whether
    the input stops at sample k + ``lookahead_samples(q)`` or goes on."""
    if q <= 1:
        return 0
    half = antialias_taps(q).size // 2
    return 2 * (-(-half // q)) + 1


def _up(x: np.ndarray, q: int) -> np.ndarray:
    return interpolate(x, q)


def _down(x: np.ndarray, q: int) -> np.ndarray:
    return decimate(x, q)


def _down_up(x: np.ndarray, q: int) -> np.ndarray:
    return _down(_UP(x, q), q)     # the fine-rate input the simulation has just interpolated: not again


#: the measured input at the fine rate, and the spindle signal there decimated back: the same for every
#: simulation of a record (the refinement's and the bias correction's dozens), computed once per record
_UP = ArrayMemo(_up, size=8)
_DOWN_UP = ArrayMemo(_down_up, size=8)


def simulate_response(linear: LinearPart, terms: Sequence[Term], gammas: Sequence[float], external: np.ndarray,
                      fs_hz: float, *, spindle_accel: np.ndarray | None = None, oversample: int = 8,
                      z_limit: float = np.inf) -> TimeResponse:
    """Simulate the model for a measured external input (module docstring).

    Parameters
    ----------
    linear : LinearPart
        Stable linear part Hz = Z/U.
    terms, gammas : sequences
        Describing functions and their coefficients per unit body mass γ_i = c_i/M2
        (not used with feedback paths: the paths carry them).
    external : ndarray, shape (n,)
        v = ẍ1 [+ k3·x1] [- F/M2] [m/s²] at ``fs_hz``.
    fs_hz : float
        Sample rate [Hz].
    spindle_accel : ndarray, optional
        ẍ1 [m/s²] for the body acceleration ẍ2 = ẍ1 + z̈ (zero when None: a fixed spindle).
    oversample : int
        Fine steps per sample.
    z_limit : float
        Bound of |z| [m] beyond which the response counts as diverged.

    Returns
    -------
    TimeResponse
    """
    q = _fine_steps(oversample)
    if not linear.stable:
        raise ConfigError(f"the linear part is not stable (poles {np.round(linear.all_poles(), 4).tolist()} 1/s)",
                          hint="refit it (select_linear_part flips unstable poles)")
    h = 1.0 / (fs_hz * q)
    v = _UP(np.asarray(external, float), q)
    if linear.paths is not None:     # each term through its own path; ``gammas`` are in the paths
        z, zd, zdd, nn, fail = _simulate_paths(linear, terms, v, h, z_limit)
        z, zd, nn = z[::q], zd[::q], nn[::q]
    else:
        march = march_arrays(linear, terms, gammas, h)
        z, zd, zdd, nn = march_outputs(v.size, q)
        fail = _run(*march.rows, *march.kernel_args(v, float(z_limit), q), z, zd, zdd, nn)
    return response(z, zd, zdd, nn, fail, external, spindle_accel, q)


def _fine_steps(oversample) -> int:
    q = int(oversample)
    if q < 1:
        raise ConfigError(f"oversample={oversample!r} must be a whole number ≥ 1")
    return q


@dataclass(frozen=True, eq=False)
class MarchArrays:
    """What the single-input step kernel needs of one model at one fine step h (:func:`march_arrays`)."""

    rows: tuple          # :func:`_rows` of Φ: (Φ, lo, hi, c1, pa, pb, paired)
    g0: np.ndarray
    g1: np.ndarray
    c: np.ndarray
    cd: np.ndarray
    ca: np.ndarray
    dd: float
    codes: np.ndarray
    coef: np.ndarray
    p0: np.ndarray
    p1: np.ndarray
    la: float
    lb: float

    def kernel_args(self, v: np.ndarray, z_limit: float, q: int) -> tuple:
        """The kernel's arguments after Φ's rows and before the outputs, for input ``v`` at the fine rate."""
        return (self.g0, self.g1, self.c, self.cd, self.ca, self.dd, v, self.codes, self.coef, self.p0, self.p1,
                self.la, self.lb, z_limit, solve_tolerance(v), q)


def solve_tolerance(v: np.ndarray) -> float:
    """Absolute tolerance [m/s²] of the implicit feedback solve for fine-rate input ``v``: rounding of its scale."""
    return 1e-13 * float(np.max(np.abs(v))) if v.size else 0.0


def march_arrays(linear: LinearPart, terms: Sequence[Term], gammas: Sequence[float], h: float) -> MarchArrays:
    """The FOH-discretised linear part (no feedback paths) and the strut terms as the step kernels take them."""
    a, b, c = linear.state_space()
    phi, g0, g1 = discretise(a, b, h)
    cd = c @ a
    codes, coef, p0, p1 = strut_arrays(list(terms), list(gammas))
    la, lb = linear.absorbed
    return MarchArrays(_rows(phi), g0, g1, c, cd, cd @ a, float(cd @ b), codes, coef, p0, p1, la, lb)


def march_outputs(nf: int, q: int, lanes: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(z, ż, z̈, n) for a march of ``nf`` fine steps: z, ż and n only at the record's instants, z̈ at every step
    (measured on an hour at 600 Hz, 4 fine steps per sample: traced peak 664 → 508 MB against four fine-rate
    arrays, the time the same, every output the same bits); with ``lanes``, a row per lane."""
    rows = () if lanes is None else (int(lanes),)
    z, zd, nn = (np.zeros((*rows, (nf + q - 1) // q)) for _ in range(3))
    return z, zd, np.zeros((*rows, nf)), nn


def response(z, zd, zdd, nn, fail: int, external: np.ndarray, spindle_accel: np.ndarray | None,
             q: int) -> TimeResponse:
    """The response at the record's rate from a march's outputs (z̈ decimated, the spindle's part added)."""
    ext = np.asarray(external, float)
    n = ext.size
    if spindle_accel is None:
        a2 = _down(zdd, q)[:n]
        a1 = 0.0
    else:           # ẍ2 = ẍ1 + z̈ at the fine rate, decimated: the decimation is linear, ẍ1's part is the record's
        a1 = np.asarray(spindle_accel, float)
        a2 = (_DOWN_UP(a1, q) + _down(zdd, q))[:n]
    return TimeResponse(z=z[:n], zdot=zd[:n], zddot=a2 - a1, body_accel=a2, force=nn[:n],
                        diverged_at=-1 if fail < 0 else int(fail // q), oversample=q)
