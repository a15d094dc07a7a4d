"""The output-error refinement's Jacobian from one march: forward sensitivities beside the state (issue 58).

The refinement (:mod:`nifo_core.predict.refine`) minimises the band-limited prediction error over θ: the terms'
coefficients, their key parameters (log factors), a one-mass body's k and c (log factors) and a measured
force's gain (log factor). Forward differences cost one simulation of every record per parameter. The step of
the prediction engine (:mod:`nifo_core.predict.timesim`) is differentiable almost everywhere, and its
derivative is a linear recursion marched beside the state, for every parameter at once::

    x_{k+1} = Φ·x_k + Γ0·(v_k + m_k) + Γ1·(v_{k+1} + m_{k+1}),   z = c·x,  ż = c·A·x,
    m_{k+1} = N(z0 + α·m_{k+1}, ż0 + β·m_{k+1})                              (the implicit feedback)

    ∂m = (N_z·∂z0 + N_ż·∂ż0 + N_θ) / (1 - α·N_z - β·N_ż),   ∂x_{k+1} = ∂xs + Γ1·∂m,
    ∂z̈ = d·(∂v + ∂m) + c·A²·∂x

N_z, N_ż are the strut force's slopes at the solved point (each kind's,
:func:`~nifo_core.kinds.strut_forces.g_partials`); N_θ is the force's own dependence on θ: g_i times the
coefficient's scale (less its absorbed slope where the linear part tracks it), γ_i·∂g_i/∂p·p for a key
parameter, and for the body's k and c the feedback k·z and c·ż that scaling them adds (z̈ = -k·z - c·ż - u: the
rescaled exact discretisation to O((ωh)²)). A play's committed state carries its own derivative; a measured
force's gain moves the input v. The body acceleration's derivative is decimated and taken to the scored lines as
the prediction is (both maps are linear): one march gives the residual and its Jacobian.

Measured (``tests/test_sensitivity.py``): the columns agree with central differences to their truncation error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from ..errors import ConfigError
from ..kinds.strut_forces import PLAY, g_one, g_partials, strut_force
from ..simulate.quarter_car import decimate
from .prediction_error import band_spectra
from .time_prediction import _static_frame, engine_input, record_inputs
from .timesim import _UP, _solve, _up, march_arrays, march_start, paired_prediction, solve_tolerance

__all__ = ["GAMMA", "SHAPE", "BODY_K", "BODY_C", "FORCE_GAIN", "Parameters", "sensitivity_march", "residual_jacobian"]

#: what a parameter of the march is: a term's coefficient, a term's key parameter (log factor), the body's k or
#: c (log factors), the measured force's gain (log factor)
GAMMA, SHAPE, BODY_K, BODY_C, FORCE_GAIN = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class Parameters:
    """The march's parameters: per parameter its kind (:data:`GAMMA` …), the term it belongs to (-1: none) and its
    scale (dγ/dθ for a coefficient; the body's k or c for theirs); per term its absorbed slopes (α, β) where the
    linear part tracks them (zeros otherwise)."""

    kind: np.ndarray
    term: np.ndarray
    scale: np.ndarray
    absorbed_a: np.ndarray
    absorbed_b: np.ndarray


@numba.njit(cache=True, nogil=True)
def _march(lo, c1, pa, pb, g0, g1, cz, cd, ca, dd, v, dv, kv, codes, coef, p0, p1, la, lb, z_limit, atol,
           pkind, pterm, pscale, aa, ab, out_dzdd):  # pragma: no cover - compiled
    """``timesim``'s single-input step (the same arithmetic for the state) with the sensitivities of every parameter
    marched beside it; returns the failing step or -1. ``dv``: ∂v/∂θ of parameter ``kv`` (a force's gain; -1:
    none, the input moves with no parameter)."""
    ns = pa.size
    nt = codes.size
    npar = pkind.size
    x = np.zeros(ns)
    xs = np.zeros(ns)
    dx = np.zeros((npar, ns))
    dxs = np.zeros((npar, ns))
    play = np.zeros(nt)
    dplay = np.zeros((npar, nt))
    dm_prev = np.zeros(npar)
    gz = np.zeros(nt)
    gzd = np.zeros(nt)
    gp = np.zeros(nt)
    gv = np.zeros(nt)
    alpha, beta, plays, active, nk = march_start(codes, coef, p0, p1, play, cz, cd, g1, la, lb)
    nprev = nk
    if kv >= 0:
        out_dzdd[kv, 0] = dd * dv[0]
    for j in range(v.size - 1):
        uk = v[j] + nk
        un = v[j + 1]
        z0, zd0 = paired_prediction(x, xs, lo, c1, pa, pb, g0, g1, uk, un, cz, cd)
        guess = 2.0 * nk - nprev
        nprev = nk
        n, ok = _solve(z0, zd0, alpha, beta, guess, codes, coef, p0, p1, play, la, lb, atol) if active else (0.0, True)
        if not ok:
            return j + 1
        z = z0 + alpha * n
        zd = zd0 + beta * n
        # the force's slopes at the solved point, before the play states are committed
        nz = -la
        nzd = -lb
        for i in range(nt):
            gv[i] = g_one(codes[i], p0[i], p1[i], z, zd, play[i])
            a, b, c = g_partials(codes[i], p0[i], p1[i], z, zd, play[i])
            gz[i], gzd[i], gp[i] = a, b, c
            nz += coef[i] * a
            nzd += coef[i] * b
        denom = 1.0 - alpha * nz - beta * nzd
        for k in range(npar):
            dvj = 0.0
            dvn = 0.0
            if k == kv:
                dvj = dv[j]
                dvn = dv[j + 1]
            dz0, dzd0 = paired_prediction(dx[k], dxs[k], lo, c1, pa, pb, g0, g1, dvj + dm_prev[k], dvn, cz, cd)
            kind = pkind[k]
            t = pterm[k]
            nth = 0.0
            if kind == 0:
                nth = pscale[k] * (gv[t] - aa[t] * z - ab[t] * zd)
            elif kind == 1:
                nth = coef[t] * gp[t] * p0[t]
            elif kind == 2:
                nth = pscale[k] * z
            elif kind == 3:
                nth = pscale[k] * zd
            if plays:
                for i in range(nt):     # a stuck play's force is its state: the state's derivative
                    if codes[i] == PLAY and gz[i] == 0.0:
                        nth += coef[i] * dplay[k, i]
            dm = (nz * dz0 + nzd * dzd0 + nth) / denom
            dzk = dz0 + alpha * dm
            zdd_k = dd * (dvn + dm)
            for i in range(ns):
                dx[k, i] = dxs[k, i] + g1[i] * dm
                zdd_k += ca[i] * dx[k, i]
            out_dzdd[k, j + 1] = zdd_k
            dm_prev[k] = dm
            for i in range(nt if plays else 0):
                if codes[i] == PLAY and gz[i] != 0.0:
                    dplay[k, i] = dzk + (gp[i] * p0[i] if (kind == 1 and t == i) else 0.0)
        for i in range(ns):
            x[i] = xs[i] + g1[i] * n
        if plays:
            strut_force(z, zd, codes, coef, p0, p1, play, True)
        nk = n
        if not (abs(z) <= z_limit):
            return j + 1
    return -1


def sensitivity_march(linear, terms, gammas, v: np.ndarray, dv: np.ndarray | None, h: float, q: int,
                      z_limit: float, params: Parameters) -> tuple[np.ndarray, int]:
    """(∂z̈/∂θ per parameter at the record's rate, failing fine step or -1) for fine-rate input ``v`` and ``dv`` its
    derivative by the force's gain (None: no parameter moves the input)."""
    ma = march_arrays(linear, terms, gammas, h)
    phi, lo, _, c1, pa, pb, paired = ma.rows
    if not paired:      # every linear part nifo builds is block diagonal in 2×2 and 1×1 blocks (timesim._rows)
        raise ConfigError("the sensitivity march needs a block-diagonal linear part", hint="refine by differences")
    dzdd = np.zeros((params.kind.size, v.size))
    kv = -1 if dv is None else int(np.flatnonzero(params.kind == FORCE_GAIN)[0])
    fail = _march(lo, c1, pa, pb, ma.g0, ma.g1, ma.c, ma.cd, ma.ca, ma.dd, v, np.zeros(1) if dv is None else dv, kv,
                  ma.codes, ma.coef, ma.p0, ma.p1, ma.la, ma.lb, float(z_limit), solve_tolerance(v), params.kind,
                  params.term, params.scale, params.absorbed_a, params.absorbed_b, dzdd)
    return (decimate(dzdd, q) if dzdd.size else dzdd), fail


def residual_jacobian(model, record, params: Parameters, *, band_hz: tuple[float, float],
                      period_samples: int | None = None, skip_samples: int = 0,
                      oversample: int | None = None) -> np.ndarray | None:
    """∂[(Ŷ - Y)/‖Y‖]/∂θ on the band's lines of ``record`` (complex, lines × parameters): the derivative of
    :func:`~nifo_core.predict.refine.prediction_residual` from one march, or None where the simulation diverges
    (model without feedback paths, time-domain engine)."""
    a1, force = record_inputs(record, model)
    lin = model.linear
    got = engine_input(model, a1, force, record.fs_hz, oversample)
    v, q, limit = got.v, got.oversample, got.z_limit
    vf = _UP(v, q)
    dv = _up(-model.force_gain * force, q) if np.any(params.kind == FORCE_GAIN) else None  # v is linear in it
    d, fail = sensitivity_march(lin, _static_frame(model.terms), model.c_over_m2, vf, dv,
                                1.0 / (record.fs_hz * q), q, limit, params)
    if fail >= 0:
        return None
    n = record.body_accel.size
    kw = dict(band_hz=band_hz, period_samples=period_samples, skip_samples=skip_samples)
    y = band_spectra(record.body_accel, record.body_accel, record.fs_hz, **kw)[0]
    norm = np.sqrt(np.sum(np.abs(y) ** 2))
    return np.stack([band_spectra(record.body_accel, row[:n], record.fs_hz, **kw)[1] / norm for row in d], axis=1)
