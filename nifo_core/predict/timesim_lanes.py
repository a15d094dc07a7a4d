"""Several simulations in one march: the lanes of the prediction engine (issue 29), several models on one record, or
one model on several records of one length (issue 58).

The step kernel of :mod:`nifo_core.predict.timesim` is latency-bound: each fine step waits for its implicit
feedback solve, a chain of fixed-point iterations, each waiting for the one before (54-98 ns per step with one to
three terms, against 23 ns without any). The output-error refinement's forward-difference Jacobian simulates the
same record once per parameter, with models that differ only in their numbers. Marched together — each step of
every lane before the next step, the lanes' fixed-point iterations interleaved — the processor overlaps their
chains. Every lane does exactly the arithmetic of its own march, in the same order, so each response is the
single simulation's to the last bit (``tests/test_predict_lanes.py``).

Measured on the loop's refinement models (bench_loop's records, 245 k fine steps, one to four terms; one
thread, best of 3): three lanes' marches took 0.56-0.66 of the time of three single ones, two lanes 0.65-0.83; a
model without terms gains nothing (its step has no chain to overlap). Whole predictions (interpolation, decimation
and all), three lanes: 0.71-0.81; ``benchmarks/bench_predict.py`` prints that ratio on the machine it runs on.
The F-16's 22-state modal body with one play: 0.91-0.94 (its step is mostly the linear update, not the solve).

Lanes share a rate, a length and the kernel's shape: the same term kinds in the same order and a linear part with
the same state size and block pattern (every model of a refinement). Each lane reads its own row of the inputs, or
all the one row (a refinement's models on one record). One model on several records
(:func:`~nifo_core.predict.time_prediction.predict_records`) is what the bias corrections simulate at every step (a
synthetic record per fit record, and each record again with ± a draw of drive noise) and what the loop's held-out
scores and the refinement's evaluations simulate: measured on four 30 s records at 1 kHz of the loop benchmark's
model (a knee, a cubic, a friction; one thread, best of 3), 0.45 of the time of four single simulations; the loop
benchmark's whole ``nifo loop``, paired against the code before: 0.94-0.95 of its CPU time, every output the same.
Where lanes cannot share a march — feedback paths, a linear part not block-diagonal, different kinds —
:func:`simulate_responses` simulates one after the other.
"""

from __future__ import annotations

from typing import Sequence

import numba
import numpy as np

from ..kinds.describing import Term
from ..kinds.strut_forces import PLAY, g_one
from .linear_part import LinearPart
from .timesim import (FIXED_POINT_ITERATIONS, TimeResponse, _UP, _bracketed, _fine_steps, _settled, march_arrays,
                      march_outputs, response, simulate_response, solve_tolerance)

__all__ = ["MAX_LANES", "simulate_responses"]

#: the most records :func:`~nifo_core.predict.time_prediction.predict_records` marches together: measured (one thread,
#: best of 3, a 30 s record at 1 kHz, the loop benchmark's model with a knee, a cubic and a friction), a lane cost 0.57
#: of a single simulation with 4 lanes and 0.57 with 8, while each lane holds its input and z̈ at the fine rate
MAX_LANES = 4


@numba.njit(cache=True, inline="always")
def _fb_lane(z, zd, codes, coef, p0, p1, play, lane, commit, la, lb):  # pragma: no cover - compiled
    """``timesim._fb`` for lane ``lane`` of the (lanes, terms) arrays: the same sum in the same order."""
    n1 = 0.0
    for i in range(codes.size):
        g = g_one(codes[i], p0[lane, i], p1[lane, i], z, zd, play[lane, i])
        if commit and codes[i] == PLAY:
            play[lane, i] = g
        n1 += coef[lane, i] * g
    return n1 - la * z - lb * zd


@numba.njit(cache=True, nogil=True)
def _run_lanes(lo, c1, pa, pb, g0, g1, cz, cd, ca, dd, v, row, codes, coef, p0, p1, la, lb, z_limit, atol, q,
               out_z, out_zd, out_zdd, out_n, fail):  # pragma: no cover - compiled
    """``timesim``'s paired single-input kernel for every lane (row l of each 2-D array), marched together; lane l's
    input is row ``row[l]`` of ``v`` and its solve's tolerance ``atol[l]``.

    Per step: each lane's prediction of the state, then the lanes' fixed-point iterations interleaved (a lane
    stops iterating when it has converged; after FIXED_POINT_ITERATIONS the bracketed bisection, lane by lane),
    then each lane's update. A lane that fails (no finite solve, or |z| beyond its bound) stops there with
    ``fail[l]`` the step, as the single kernel returns it; the others go on."""
    nl, ns = pa.shape
    nt = codes.size
    plays = False
    for i in range(nt):
        if codes[i] == PLAY:
            plays = True
    x = np.zeros((nl, ns))
    xs = np.zeros((nl, ns))
    play = np.zeros((nl, nt))
    alpha = np.zeros(nl)
    beta = np.zeros(nl)
    active = np.zeros(nl, np.bool_)
    nk = np.zeros(nl)
    nprev = np.zeros(nl)
    z0 = np.zeros(nl)
    zd0 = np.zeros(nl)
    cur = np.zeros(nl)
    res = np.zeros(nl)
    guess = np.zeros(nl)
    done = np.zeros(nl, np.bool_)
    for l in range(nl):
        fail[l] = -1
        for i in range(ns):
            alpha[l] += cz[l, i] * g1[l, i]
            beta[l] += cd[l, i] * g1[l, i]
        active[l] = nt > 0 or la[l] != 0.0 or lb[l] != 0.0
        if active[l]:
            nk[l] = _fb_lane(0.0, 0.0, codes, coef, p0, p1, play, l, True, la[l], lb[l])
        nprev[l] = nk[l]
        out_z[l, 0], out_zd[l, 0], out_zdd[l, 0], out_n[l, 0] = 0.0, 0.0, dd[l] * (v[row[l], 0] + nk[l]), nk[l]
    ph = 0
    k = 0
    for j in range(v.shape[1] - 1):
        for l in range(nl):
            if fail[l] >= 0:
                done[l] = True
                continue
            uk = v[row[l], j] + nk[l]
            un = v[row[l], j + 1]
            a = 0.0
            b = 0.0
            for i in range(ns):
                acc = g0[l, i] * uk + g1[l, i] * un
                acc += pa[l, i] * x[l, lo[i]]
                acc += pb[l, i] * x[l, c1[i]]
                xs[l, i] = acc
                a += cz[l, i] * acc
                b += cd[l, i] * acc
            z0[l] = a
            zd0[l] = b
            if active[l]:
                guess[l] = 2.0 * nk[l] - nprev[l]
                cur[l] = guess[l]
                done[l] = False
            else:
                res[l] = 0.0
                done[l] = True
        for _ in range(FIXED_POINT_ITERATIONS):
            left = False
            for l in range(nl):
                if done[l]:
                    continue
                n = cur[l]
                nn = _fb_lane(z0[l] + alpha[l] * n, zd0[l] + beta[l] * n, codes, coef, p0, p1, play, l, False,
                              la[l], lb[l])
                if _settled(nn, n, atol[l]):
                    res[l] = nn
                    done[l] = True
                else:
                    cur[l] = nn
                    left = True
            if not left:
                break
        for l in range(nl):
            if fail[l] >= 0:
                continue
            if not done[l]:
                n, ok = _bracketed(z0[l], zd0[l], alpha[l], beta[l], guess[l], codes, coef[l], p0[l], p1[l],
                                   play[l], la[l], lb[l], atol[l])
                if not ok:
                    fail[l] = j + 1
                    continue
                res[l] = n
            n = res[l]
            if active[l]:
                nprev[l] = nk[l]
            zdd = dd[l] * (v[row[l], j + 1] + n)
            for i in range(ns):
                x[l, i] = xs[l, i] + g1[l, i] * n
                zdd += ca[l, i] * x[l, i]
            z = z0[l] + alpha[l] * n
            zd = zd0[l] + beta[l] * n
            if plays:
                _fb_lane(z, zd, codes, coef, p0, p1, play, l, True, 0.0, 0.0)   # commit the play states
            nk[l] = n
            out_zdd[l, j + 1] = zdd
            if ph + 1 == q:
                out_z[l, k + 1], out_zd[l, k + 1], out_n[l, k + 1] = z, zd, n
            if not (abs(z) <= z_limit[l]):
                fail[l] = j + 1
        ph += 1
        if ph == q:
            ph = 0
            k += 1
    return fail


def _same_shape(marches) -> bool:
    """Whether the marches fit one lane kernel: paired rows with the same pattern, the same term kinds."""
    first = marches[0]
    _, lo, _, c1, _, _, paired = first.rows
    return paired and all(m.rows[6] and np.array_equal(m.rows[1], lo) and np.array_equal(m.rows[3], c1)
                          and np.array_equal(m.codes, first.codes) for m in marches)


def simulate_responses(linears: Sequence[LinearPart], terms: Sequence[Sequence[Term]],
                       gammas: Sequence[Sequence[float]], external: np.ndarray, fs_hz: float, *,
                       spindle_accel: np.ndarray | None = None, oversample: int = 8,
                       z_limits: Sequence[float] | None = None) -> list[TimeResponse]:
    """:func:`~nifo_core.predict.timesim.simulate_response` of each model (``linears[l]``, ``terms[l]``,
    ``gammas[l]``, bound ``z_limits[l]``) for one external input, or for lane l's own (``external`` and
    ``spindle_accel`` of shape (lanes, n): several records of one length): the same responses, bit for bit, marched
    together where the models share the kernel's shape (module docstring), else one after the other."""
    n_lanes = len(linears)
    limits = [np.inf] * n_lanes if z_limits is None else [float(b) for b in z_limits]
    if not (len(terms) == len(gammas) == len(limits) == n_lanes):
        raise ValueError("one linear part, term list, coefficient list and bound per lane")
    ext = np.asarray(external, float)
    own = ext.ndim == 2     # an input per lane
    if own and ext.shape[0] != n_lanes:
        raise ValueError("one input row per lane")

    def row(x, l: int):
        return x if x is None or not own else x[l]

    def one_by_one() -> list[TimeResponse]:
        return [simulate_response(lin, t, g, row(ext, l), fs_hz, spindle_accel=row(spindle_accel, l),
                                  oversample=oversample, z_limit=b)
                for l, (lin, t, g, b) in enumerate(zip(linears, terms, gammas, limits))]

    if n_lanes < 2 or any(lin.paths is not None or not lin.stable for lin in linears):
        return one_by_one()     # (an unstable linear part: the single simulation says so)
    q = _fine_steps(oversample)
    h = 1.0 / (fs_hz * q)
    marches = [march_arrays(lin, t, g, h) for lin, t, g in zip(linears, terms, gammas)]
    if not _same_shape(marches):
        return one_by_one()
    # the inputs at the fine rate, a row each (one row for all: no copy per lane); read-only as the memo's are, so
    # that the kernel has one signature
    ups = [_UP(x, q) for x in ext] if own else [_UP(ext, q)]
    v = np.stack(ups) if own else ups[0][None, :]
    v.flags.writeable = False
    rows = np.arange(n_lanes, dtype=np.int64) if own else np.zeros(n_lanes, dtype=np.int64)
    atol = np.array([solve_tolerance(u) for u in ups], dtype=float)[rows]     # each input's once

    def lanes(field: str) -> np.ndarray:
        return np.array([getattr(m, field) for m in marches], dtype=float)

    first = marches[0]
    outs = march_outputs(v.shape[1], q, lanes=n_lanes)
    fail = np.zeros(n_lanes, dtype=np.int64)
    _run_lanes(first.rows[1], first.rows[3], np.array([m.rows[4] for m in marches], dtype=float),
               np.array([m.rows[5] for m in marches], dtype=float),
               *(lanes(f) for f in ("g0", "g1", "c", "cd", "ca", "dd")), v, rows, first.codes,
               *(lanes(f) for f in ("coef", "p0", "p1", "la", "lb")), np.array(limits, dtype=float),
               atol, q, *outs, fail)
    z, zd, zdd, nn = outs
    return [response(z[l], zd[l], zdd[l], nn[l], int(fail[l]), row(ext, l), row(spindle_accel, l), q)
            for l in range(n_lanes)]
