"""Where the static position lies in each record: bump stops measured from it (docs/method.md §5).

z and ż are band-limited integrals of accelerations: their mean is lost, so z is
measured from each record's *mean* position. A one-sided force (a bump stop)
pushes the mean away from it, the more the harder the excitation. A gap
measured from the mean is therefore the true gap from the static position plus
that shift, and it differs from level to level (a stop 8 mm from static at 7 mm
road RMS reads 9.9 mm from the mean; at 5 mm RMS 8.5 mm).

The static position is recovered from the mean of the body equation (paper
Eq. 2 averaged over the record): the body does not accelerate on average and
ż has zero mean, so with m the mean position measured from static (z_static = z + m)

    0 = k·m + Σ θ_i·mean g_i(z + m, ż)

a scalar root per record (a stiffening stop makes the right side monotone in m).
The gap s from the static position is then fitted with, on each record, the
regressor g(z + m_i; s) — the term with ``offset = -m_i`` — and m_i recomputed
from the refitted k, θ.

An even stiffness (``quadratic_stiffness``, z²) moves the mean too (its mean force
θ·mean z² > 0), and unlike a symmetric term it is not the same function of z
measured from the mean: (z + m)² = z² + 2m·z + m², a stiffness 2θ·m that differs from
level to level (m grows with the motion) and that one linear k cannot hold; left
so, a level-dependent term (a wide play, say) takes it up. Its regressor is
evaluated on z + m_i too (``offset = -m_i``, the same balance, no gap to search):
:func:`shifted_offsets` during the selection, :func:`static_bump_stops` with a stop.
"""

from __future__ import annotations

from math import comb
from typing import Sequence

import numpy as np
from scipy import optimize

from .data import RegressionData
from ..kinds.describing import Term
from ..signal.least_squares import FixedColumns, lstsq
from ..signal.parallel import thread_map

__all__ = ["RecordMeans", "record_means", "mean_shift", "static_bump_stops", "shifted_offsets", "static_frame",
           "equation_fit", "balance_offsets", "Refits"]


def _threshold_from_static(t: Term) -> bool:
    """A one-sided kind whose threshold counts from the static position (``Kind.static_frame``: a bump stop)."""
    return t.spec.static_frame == "threshold"


def _shifted(t: Term) -> bool:
    """An even kind without a threshold evaluated on z from the static position (a quadratic stiffness)."""
    return t.spec.static_frame == "position"


class RecordMeans:
    """One record's z and ż for its mean balance (:func:`mean_shift`): the mean of a term at any shift m of z.

    A search over a stop's gap solves the balance hundreds of times on the same record (the loop benchmark's
    records: 724 roots, 6 500 evaluations of every term over 120 000 samples). So the record's z is sorted once with
    the running sums of its powers 0-3: a kind of z given as pieces of a polynomial (``Kind.pieces``: a cubic, a
    bump stop, a clearance) then averages at any m from two binary searches, the powers of (z + m) expanded about m;
    a form of ż, which does not move with m, is averaged once per term; any other kind (a play) is evaluated sample by
    sample. The same means as evaluating the samples, summed in another order."""

    def __init__(self, z: np.ndarray, zdot: np.ndarray):
        self.z, self.zdot = np.asarray(z, float), np.asarray(zdot, float)
        self.order = np.sort(self.z)
        powers = np.vstack([np.ones_like(self.order), self.order, self.order ** 2, self.order ** 3])
        self.sums = np.zeros((4, self.order.size + 1))
        np.cumsum(powers, axis=1, out=self.sums[:, 1:])
        self._fixed: dict = {}

    def mean(self, term: Term, m: float) -> float:
        """mean g(z + m, ż) over the record."""
        spec = term.spec
        if spec.variable != "z":
            key = (term.kind, tuple(sorted(term.params.items())))
            if key not in self._fixed:
                self._fixed[key] = float(np.mean(term.evaluate(self.z, self.zdot)))
            return self._fixed[key]
        pieces = None if spec.pieces is None else spec.pieces(term.params)
        if pieces is None or any(len(a) > self.sums.shape[0] for _, _, a in pieces):
            return float(np.mean(term.evaluate(self.z + m, self.zdot)))
        total = 0.0
        for lo, hi, a in pieces:
            i0, i1 = np.searchsorted(self.order, (lo - m, hi - m))
            if i1 <= i0:
                continue
            s = self.sums[:, i1] - self.sums[:, i0]      # Σ z^k over the samples of this piece
            for j, aj in enumerate(a):                   # Σ (z + m)^j = Σ_k C(j, k)·m^(j-k)·Σ z^k
                if aj:
                    total += aj * sum(comb(j, k) * m ** (j - k) * s[k] for k in range(j + 1))
        return total / self.order.size


def record_means(data: RegressionData) -> list[RecordMeans]:
    """:class:`RecordMeans` of every record of ``data``, made once for these rows."""
    return data.remembered("record means", lambda: [RecordMeans(rf.z, rf.zdot) for rf in data.rfs])


def mean_shift(z: np.ndarray, zdot: np.ndarray, k_per_kg: float, terms: Sequence[tuple[Term, float]], *,
               near: float | None = None, means: RecordMeans | None = None) -> float:
    """Mean position m [m] of a record measured from the static position (module docstring).

    Parameters
    ----------
    z, zdot : ndarray
        Relative displacement [m] (zero-mean: measured from the record's mean) and velocity [m/s].
    k_per_kg : float
        Linear stiffness per unit sprung mass K2/M2 [1/s²].
    terms : sequence of (Term, θ)
        The nonlinear terms with their coefficients per unit sprung mass; a bump stop's own
        ``offset`` is ignored (it is what m replaces).

    near : float, optional
        Where the root is expected (the last step of a fixed point): bracketed around it first, widening to the
        motion's range (the same root to the solver's tolerance, from fewer evaluations of the balance).
    means : RecordMeans, optional
        The same record's :class:`RecordMeans` (:func:`record_means`), kept from one call to the next.

    Returns
    -------
    float
        m such that k·m + Σ θ·mean g(z + m, ż) = 0; 0.0 when no root lies within the motion's range.
    """
    rec = means if means is not None else RecordMeans(z, zdot)
    terms = [(Term(t.kind, {**t.params, "offset": 0.0}) if _threshold_from_static(t) else t, th) for t, th in terms]

    def balance(m: float) -> float:
        return k_per_kg * m + sum(th * rec.mean(t, m) for t, th in terms)

    a = 2.0 * float(np.max(np.abs(rec.order[[0, -1]]))) if rec.order.size else 0.0
    if not (a > 0 and np.isfinite(k_per_kg)):
        return 0.0
    if near is not None and abs(near) < a:
        d = 1e-3 * a
        while True:      # a bracket around ``near``, widened until it holds the sign change or spans the range
            lo_m, hi_m = max(near - d, -a), min(near + d, a)
            lo, hi = balance(lo_m), balance(hi_m)
            if not (np.isfinite(lo) and np.isfinite(hi)):
                break
            if lo * hi <= 0:
                return float(optimize.brentq(balance, lo_m, hi_m, xtol=1e-9 * a))
            if lo_m == -a and hi_m == a:
                return 0.0
            d *= 10.0
    lo, hi = balance(-a), balance(a)
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo * hi > 0:
        return 0.0
    return float(optimize.brentq(balance, -a, a, xtol=1e-9 * a))


def shifted_offsets(data: RegressionData, terms: Sequence[Term], *,
                    iterations: int = 4) -> list[tuple[float, ...] | None]:
    """Per term, the offsets -m_i of every record for the shifted terms (``Kind.static_frame`` "position"), else
    None (module docstring).

    A fixed point: fit k, θ with the current offsets, solve the mean balance of every record
    (:func:`mean_shift`, with the terms other than bump stops, whose gap is still from the mean),
    repeat. All None when ``terms`` hold no shifted kind.
    """
    terms = list(terms)
    which = [_shifted(t) for t in terms]
    if not any(which):
        return [None] * len(terms)
    nl = len(data.lin)
    off = [0.0] * len(data.rfs)
    for _ in range(iterations):
        c, _ = equation_fit(data, terms, [tuple(off) if w else None for w in which])
        pairs = [(t, float(c[nl + i])) for i, t in enumerate(terms) if not _threshold_from_static(t)]
        off = [-mean_shift(rf.z, rf.zdot, float(c[0]), pairs, means=r)
               for rf, r in zip(data.rfs, record_means(data))]
    return [tuple(off) if w else None for w in which]


def equation_fit(data: RegressionData, terms: Sequence[Term],
                 offsets: Sequence[Sequence[float] | None]) -> tuple[np.ndarray, float]:
    """The equation error's least squares of ``terms`` at their per-record ``offsets`` (None: the data's own frame):
    (coefficients [linear columns, θ_i], residual sum of squares)."""
    a = np.column_stack([data.x[:, data.lin], *[data.regressor(t, offsets=o) for t, o in zip(terms, offsets)]])
    c = lstsq(a, data.y)
    r = data.y - a @ c
    return c, float(r @ r)


def balance_offsets(data: RegressionData, terms: Sequence[Term], c: np.ndarray,
                    near: Sequence[float] | None = None) -> list[float]:
    """offset = -m per record: each record's mean balance (:func:`mean_shift`) with ``terms`` at the coefficients of
    the fit ``c`` (:func:`equation_fit`; a bump stop's gap counts from the static position). ``near``: the offsets of
    a fixed point's step before, where the roots are sought first."""
    nl = len(data.lin)
    pairs = [(t, float(c[nl + i])) for i, t in enumerate(terms)]
    return [-mean_shift(rf.z, rf.zdot, float(c[0]), pairs, near=None if near is None else -float(near[r]), means=m)
            for r, (rf, m) in enumerate(zip(data.rfs, record_means(data)))]


class Refits:
    """The fit of ``terms`` with term ``j`` and the ``shifted`` terms' columns varying from trial to trial, the others
    fixed (:class:`~nifo_core.signal.least_squares.FixedColumns`: their Gram part computed once). The same
    coefficients as :func:`equation_fit` to rounding, in its order."""

    def __init__(self, data: RegressionData, terms: list[Term], offsets: list, j: int, shifted: list[bool]):
        self.data, self.nl = data, len(data.lin)
        self.vary = [i for i in range(len(terms)) if i == j or shifted[i]]
        self.fixed = [i for i in range(len(terms)) if i not in self.vary]
        cols = [data.x[:, data.lin], *[data.regressor(terms[i], offsets=offsets[i])[:, None] for i in self.fixed]]
        self.solver = FixedColumns(np.hstack(cols), data.y)

    def fit(self, terms: list[Term], offsets: list) -> tuple[np.ndarray, float]:
        v = np.column_stack([self.data.regressor(terms[i], offsets=offsets[i]) for i in self.vary])
        x, rss = self.solver.fit(v)
        nl, nf = self.nl, len(self.fixed)
        c = np.empty(nl + len(terms))
        c[:nl] = x[:nl]
        c[[nl + i for i in self.fixed]] = x[nl:nl + nf]
        c[[nl + i for i in self.vary]] = x[nl + nf:]
        return c, rss


def static_bump_stops(data: RegressionData, terms: Sequence[Term], *,
                      points: int = 25) -> tuple[list[Term], list[tuple[float, ...] | None]]:
    """Each bump stop of ``terms`` with its gap from the static position and per-record offsets.

    Parameters
    ----------
    data : RegressionData
    terms : sequence of Term
        The suggested terms; bump stops among them carry the gap from the mean position.
    points : int
        Static gaps tried between 30 % and 105 % of the gap from the mean.

    Returns
    -------
    terms : list of Term
        The terms, bump stops with ``gap`` from the static position and ``offset`` = -m of the
        record with the largest motion (the one a single-record model is identified on).
    offsets : list
        Per term: the offset -m_i [m] of every record (bump stops), else None.
    """
    terms = list(terms)
    offsets: list = list(shifted_offsets(data, terms))
    shifted = [_shifted(t) for t in terms]
    for j, t in enumerate(terms):
        if not _threshold_from_static(t):
            continue
        key = t.spec.key_param       # the gap, counted from the static position
        g_mean = float(t.params[key])
        c, _ = equation_fit(data, terms, offsets)
        best = (np.inf, g_mean, [0.0] * len(data.rfs))
        refits = Refits(data, terms, offsets, j, shifted)

        def trial(s: float, c0: np.ndarray) -> tuple[float, float, list[float]]:
            cc, off = c0, None
            trial_terms = terms[:j] + [Term(t.kind, {**t.params, key: s})] + terms[j + 1:]
            for _ in range(3):  # m depends on k and θ, which depend on the offsets: a few fixed-point steps
                off = balance_offsets(data, trial_terms, cc, near=off)
                trial_off = [off if (i == j or shifted[i]) else o for i, o in enumerate(offsets)]
                cc, rss = refits.fit(trial_terms, trial_off)
            return rss, s, off

        # the trials of a grid are independent: side by side on threads, then taken in grid order (the same
        # choice as one after the other)
        def tried(gaps) -> None:
            nonlocal best
            for got in thread_map(lambda s: trial(float(s), c), gaps):
                best = min(best, got, key=lambda b: b[0])

        grid = np.linspace(0.3, 1.05, points) * g_mean
        tried(grid)
        step = grid[1] - grid[0]
        tried([s for s in np.linspace(best[1] - step, best[1] + step, 9) if s > 0])
        _, s, off = best
        main = int(np.argmax([float(np.std(rf.z)) for rf in data.rfs]))
        terms[j] = Term(t.kind, {**t.params, key: float(s), "offset": float(off[main])})
        offsets = [off if (i == j or shifted[i]) else o for i, o in enumerate(offsets)]
    return terms, [None if o is None else tuple(float(v) for v in o) for o in offsets]


def static_frame(data: RegressionData, terms: Sequence[Term],
                 offsets: Sequence[Sequence[float] | None]) -> tuple[float, ...]:
    """One offset -m [m] per record: where the static position lies given ``terms`` (module docstring).

    Any term with a mean force moves the mean position, not only a stop or an even spring: a damper stiffer in
    rebound than in compression pushes it by -θ·mean g(ż)/k, the more the harder the excitation. A symmetric form
    of z (a clearance, a cubic) acts about the static position, so measured from the mean it is another function
    at every level. ``terms`` are fitted with their ``offsets`` (None: the data's own frame), then each record's
    mean balance is solved with all of them (:func:`mean_shift`; a bump stop's gap counts from the static
    position).
    """
    terms = list(terms)
    c, _ = equation_fit(data, terms, list(offsets))
    return tuple(balance_offsets(data, terms, c))

