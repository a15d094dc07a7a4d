"""The characterization's regression data and grid search (:mod:`nifo_core.characterize.automatic`, docs/method.md §5).

:class:`RegressionData` band-passes every column once more with the one
filter (the module docstring of :mod:`nifo_core.characterize.automatic` says why);
:func:`candidate_grid` spans each kind's parameters over the observed motion;
:class:`GridSearch` scores every grid column by its error reduction ratio on
a row subsample (one QR of the linear columns).
"""

from __future__ import annotations

import copy
from typing import Callable, Sequence

import numpy as np

from ..kinds.describing import Term, kind as lookup_kind
from ..errors import ConfigError, InputError
from .restoring import RestoringForce, bandpass, bandpass_settle_samples
from ..signal.parallel import max_threads, thread_map

__all__ = ["RegressionData", "GridSearch", "candidate_grid", "refine_grid"]

#: rows used for the grid search (after band-passing at full length)
_SEARCH_ROWS = 40_000


class RegressionData:
    """The regression's rows: every column band-passed once more with the one filter."""

    def __init__(self, rfs: Sequence[RestoringForce], *, n_groups: int, body_stiffness: bool,
                 masks: Sequence[np.ndarray | None] | None = None) -> None:
        self.rfs = list(rfs)
        #: one offset [m] per record: every form of z is evaluated on z - offset, z from the static position
        #: (``offset`` = -m, m the record's mean position from it: :mod:`.static`); None: z from each mean
        self.frame: tuple[float, ...] | None = None
        self.n_groups = n_groups
        self.keep: list[np.ndarray] = []
        ys, xs, groups, folds, recs = [], [], [], [], []
        masks = list(masks) if masks is not None else [None] * len(self.rfs)
        for i, (rf, mask) in enumerate(zip(self.rfs, masks)):
            s = bandpass_settle_samples(rf.fs_hz, rf.band)
            need = int(4 * rf.fs_hz / rf.band.f_lo_hz)
            if rf.n - 2 * s < need:
                raise InputError(f"{rf.n / rf.fs_hz:.1f} s of restoring-force data is too short to characterize "
                                 f"(the band-pass settles over {s / rf.fs_hz:.1f} s at each end)",
                                 source=rf.source or f"record {i}",
                                 hint="record longer or raise the band's lower edge")
            ok = np.zeros(rf.n, bool)
            ok[s:rf.n - s] = True
            if mask is not None:
                ok &= np.asarray(mask, bool)
            k = np.nonzero(ok)[0]
            if k.size < max(64, int(2 * rf.fs_hz / rf.band.f_lo_hz)):
                raise InputError(f"only {k.size} samples ({k.size / rf.fs_hz:.1f} s) are selected for characterizing",
                                 source=rf.source or f"record {i}",
                                 hint="widen the frequency window or record longer")
            self.keep.append(k)
            n = k.size
            cols = [rf.z, rf.zdot]
            if body_stiffness:
                if rf.x2 is None:
                    raise ConfigError("body_stiffness needs x2: make the data with "
                                      "restoring_force(..., body_displacement=True)")
                cols.append(rf.x2)
            if rf.applied is not None:   # measured force on the body: coefficient -1/M2
                cols.append(rf.applied)
            both = bandpass(np.vstack([rf.force, *cols]), rf.fs_hz, rf.band)[:, k]
            ys.append(both[0])
            xs.append(both[1:].T)
            recs.append(np.full(n, i))
            # cross-validation folds: alternate blocks of 1/16 of the rows (≥ 2 periods of f_lo)
            blk = max(n // 16, int(2 * rf.fs_hz / rf.band.f_lo_hz))
            folds.append((np.arange(n) // blk) % 2)
            groups.append(np.full(n, i) if len(self.rfs) > 1
                          else np.minimum(np.arange(n) * n_groups // n, n_groups - 1))
        self.y = np.concatenate(ys)
        forced = {rf.applied is not None for rf in self.rfs}
        if len(forced) > 1:
            raise InputError("some records have a measured force and some not",
                             hint="characterize records of one kind together")
        self.forced = forced.pop()
        #: the linear columns of every fit: z, ż (and the measured force)
        self.lin = [0, 1] + ([len(xs[0][0]) - 1] if self.forced else [])
        self.x = np.concatenate(xs)
        self.group = np.concatenate(groups)
        self.fold = np.concatenate(folds)
        self.rec = np.concatenate(recs)
        z, v = self.x[:, 0], self.x[:, 1]
        self.rows = np.arange(0, z.size, max(1, int(np.ceil(z.size / _SEARCH_ROWS))))
        self.zmax = float(np.quantile(np.abs(z), 0.995))
        self.vmax = float(np.quantile(np.abs(v), 0.995))
        self.zneg = float(np.quantile(-z, 0.998))
        self.zpos = float(np.quantile(z, 0.998))
        self._cache: dict = {}

    def regressor(self, term: Term, *, offsets: Sequence[float] | None = None) -> np.ndarray:
        """g(z, ż) band-passed per record like every other column; kept rows, stacked.

        ``offsets``: one ``offset`` [m] per record replacing the term's own (a bump stop measured
        from the static position, which sits elsewhere in each record: :mod:`.static`); a kind
        without an ``offset`` parameter (quadratic stiffness) is evaluated on ``z - offset``. Without them a
        form of z takes :attr:`frame` when the data have one.
        """
        return self.regressors([term], offsets=offsets)[0]

    def regressors(self, terms: Sequence[Term], *, offsets: Sequence[float] | None = None) -> list[np.ndarray]:
        """:meth:`regressor` of each term; those not remembered computed side by side on threads
        (:func:`~nifo_core.signal.parallel.thread_map`: each is its term's own evaluation and FFTs, which release
        the GIL, so every column is what one thread gives; the first 48 remembered, in order)."""
        if offsets is not None and len(offsets) != len(self.rfs):
            raise ConfigError(f"{len(offsets)} offsets for {len(self.rfs)} records")
        off = None if offsets is None else tuple(float(o) for o in offsets)
        offs = [off if off is not None or not framed(t.spec) else self.frame for t in terms]
        keys = [(t.kind, tuple(sorted(t.params.items())), o) for t, o in zip(terms, offs)]
        out: list[np.ndarray | None] = [self._cache.get(k) for k in keys]
        todo = [i for i, got in enumerate(out) if got is None]
        for i, col in zip(todo, thread_map(lambda i: self._compute(terms[i], offs[i]), todo)):
            out[i] = col
            if len(self._cache) < 48:
                self._cache.setdefault(keys[i], col)
        return out

    def in_frame(self, frame: Sequence[float] | None) -> "RegressionData":
        """The same rows with every form of z evaluated from the static position (:attr:`frame`; None: from each
        record's mean); the band-passed force, z and ż are shared, the remembered columns are not."""
        if frame is not None and len(frame) != len(self.rfs):
            raise ConfigError(f"{len(frame)} frame offsets for {len(self.rfs)} records")
        out = copy.copy(self)
        out.frame = None if frame is None else tuple(float(o) for o in frame)
        out._cache = {}
        return out

    def remembered(self, key: str, make: Callable[[], object]) -> object:
        """What ``make()`` gives for these rows, made once (beside the remembered columns; :meth:`forget` drops it)."""
        got = self._cache.get(("made", key))
        if got is None:
            got = self._cache.setdefault(("made", key), make())
        return got

    def forget(self) -> None:
        """Drop the remembered full-length columns (:meth:`regressors`): for data kept while other work runs."""
        self._cache.clear()

    def _compute(self, term: Term, offsets: tuple[float, ...] | None) -> np.ndarray:
        parts = []
        own = "offset" in term.spec.params
        for i, (rf, k) in enumerate(zip(self.rfs, self.keep)):
            if offsets is None:
                g = term.evaluate(rf.z, rf.zdot)
            elif own:
                g = Term(term.kind, {**term.params, "offset": offsets[i]}).evaluate(rf.z, rf.zdot)
            else:  # a form without an offset of its own: evaluated on z measured from the static position
                g = term.evaluate(rf.z - offsets[i], rf.zdot)
            parts.append(bandpass(g, rf.fs_hz, rf.band)[k])
        return np.concatenate(parts)


def framed(spec) -> bool:
    """Whether a kind's columns are forms of z, evaluated in the data's frame (:attr:`RegressionData.frame`); the
    others (forms of ż) are the same in every frame."""
    return spec.variable == "z"


# --------------------------------------------------------------------------------------------
# candidate grids
# --------------------------------------------------------------------------------------------
def candidate_grid(kind_name: str, *, z_range: float, zdot_range: float, z_neg: float | None = None,
                   z_pos: float | None = None, points: int = 24) -> list[Term]:
    """Terms of one kind over a parameter grid scaled to the observed motion.

    ``z_range``/``zdot_range`` are robust peaks of |z| [m] and |ż| [m/s];
    ``z_neg``/``z_pos`` the peaks in compression/rebound (bump stops; the
    threshold is measured from the mean position, static offsets being lost).
    Each kind holds its own grid (``Kind.grid_spec``: which parameter, over what fraction of which peak, e.g. a
    clearance's gap over 3-90 % of the |z| peak, a bump stop's over 0-92 % of each side's); a kind without one
    gives one term.
    """
    k = lookup_kind(kind_name)
    zr, vr = float(z_range), float(zdot_range)
    if not (zr > 0 and vr > 0):
        raise InputError(f"motion range z={zr:g} m, ż={vr:g} m/s must be positive to build a grid",
                         hint="the record holds no relative motion in the band")
    if points < 2:
        raise ConfigError(f"grid points={points} must be at least 2")
    return k.grid(z_range=zr, zdot_range=vr, points=points, z_neg=z_neg, z_pos=z_pos)


def refine_grid(term: Term, grid: list[Term], points: int = 7) -> list[Term]:
    """Terms between the grid neighbours of ``term`` (same kind and side), on its varying parameter."""
    same = [t for t in grid if t.params.get("side") == term.params.get("side")]
    varying = [p for p in term.params if p != "side" and len({t.params[p] for t in same}) > 1]
    if not varying:
        return []
    kp = varying[0]
    vals = np.array(sorted(float(t.params[kp]) for t in same))
    v = float(term.params[kp])
    i = int(np.argmin(np.abs(vals - v)))
    lo, hi = vals[max(i - 1, 0)], vals[min(i + 1, vals.size - 1)]
    new = np.linspace(lo, hi, points + 2)[1:-1]
    return [Term(term.kind, {**term.params, kp: float(x)}) for x in new
            if not np.isclose(x, v) and term.spec.may_be(kp, x)]



# --------------------------------------------------------------------------------------------
# the search
# --------------------------------------------------------------------------------------------
class GridSearch:
    """Grid columns on the row subsample, orthogonalised against the linear columns (one QR).

    The projected columns are kept one per row of :attr:`gt` (contiguous), and :meth:`err` scores them all
    against a further orthonormal basis E without forming the projected matrix: for an orthonormal E and
    p = Eᵀg, ‖g - Ep‖² = ‖g‖² - ‖p‖² and (g - Ep)ᵀr = gᵀr - pᵀ(Eᵀr). Each call then reads the columns
    twice where forming them wrote and read a copy the size of the grid (hundreds of MB). Measured under
    cProfile, ``nifo characterize`` of the bundled sample on one thread: the scoring and the stacking 1.40 s ->
    0.08 s, the characterization 6.8 -> 4.4 s, characterize.json the same to the byte.
    """

    def __init__(self, data: RegressionData, kinds: Sequence[str], grid_points: int,
                 progress: Callable[[float], None] | None, prior: "GridSearch | None" = None) -> None:
        """``prior``: the search of the same rows in another frame (:meth:`RegressionData.in_frame`); its columns of
        the kinds that are not forms of z (:func:`framed`) are the same here and are taken from it, not computed
        again: the same arrays, every score the same to the bit."""
        self.data = data
        self.grid_points = grid_points
        rows = data.rows
        self.q, _ = np.linalg.qr(data.x[rows])
        ys = data.y[rows]
        self.r0 = ys - self.q @ (self.q.T @ ys)
        self.grids = {k: candidate_grid(k, z_range=data.zmax, zdot_range=data.vmax, z_neg=data.zneg,
                                        z_pos=data.zpos, points=grid_points) for k in kinds}
        self.terms: list[Term] = []
        self._blocks: list[np.ndarray] = []      # projected columns, one per row
        self._norms: list[np.ndarray] = []       # ‖column‖² before and after the projection
        self._total = sum(len(g) for g in self.grids.values()) + 7 * len(kinds)
        self._progress = progress
        same = (prior is not None and prior.data.x is data.x and prior.data.rows is rows
                and prior.grid_points == grid_points)
        kept = {k for k in kinds if same and k in prior.span and not framed(lookup_kind(k))}
        for k in kinds:
            if k in kept:       # the grid and its refinement, as this search would make them
                self._taken(prior, k)
            else:
                self._add(self.grids[k])
        self._refresh()
        err, th = self.err(np.empty((rows.size, 0)), self.r0)
        for k in kinds:  # refine each kind's best
            if k in kept:
                continue
            j = self.best_of(k, err, th)
            if j is not None:
                self._add(refine_grid(self.terms[j], self.grids[k]))
        self._refresh()

    def _add(self, terms: list[Term]) -> None:
        step = 4 * max_threads()    # a few columns per thread between two progress updates
        rows = self.data.rows
        for j in range(0, len(terms), step):
            chunk = terms[j:j + step]
            g = np.stack([col[rows] for col in self.data.regressors(chunk)])      # one column per row
            gp = g - (g @ self.q) @ self.q.T
            self._blocks.append(gp)
            self._norms.append(np.stack([np.einsum("ij,ij->i", g, g), np.einsum("ij,ij->i", gp, gp)]))
            self.terms.extend(chunk)
            self._progressed()

    def _taken(self, prior: "GridSearch", kind_name: str) -> None:
        """``prior``'s columns of ``kind_name`` (its grid, then its refinement), as :meth:`_add` would add them."""
        cols = prior.span[kind_name]
        self._blocks.append(prior.gt[cols])
        self._norms.append(np.stack([prior.norm2[cols], prior.gp2[cols]]))
        self.terms.extend(prior.terms[cols])
        self._progressed()

    def _progressed(self) -> None:
        if self._progress:
            self._progress(min(len(self.terms) / self._total, 1.0))

    def _refresh(self) -> None:
        """Stack the blocks with each kind's columns together, in the order added (:attr:`span`): :meth:`best_given`
        scores one kind's columns as a view. Ties within a kind fall as before (the same order)."""
        kinds = list(self.grids)
        kind_of = np.array([t.kind for t in self.terms])
        order = np.argsort([kinds.index(k) for k in kind_of], kind="stable")
        where = np.empty_like(order)
        where[order] = np.arange(order.size)          # each column's place in the stack
        self.gt = np.empty((order.size, self._blocks[0].shape[1]))
        start = 0
        for b in self._blocks:
            self.gt[where[start:start + len(b)]] = b
            start += len(b)
        self._blocks = [self.gt]
        norms = np.concatenate(self._norms, axis=1)[:, order]
        self._norms = [norms]
        self.norm2, self.gp2 = norms
        self.terms = [self.terms[i] for i in order]
        self.kind_of = kind_of[order]
        counts = [int(np.count_nonzero(kind_of == k)) for k in kinds]
        ends = np.cumsum(counts)
        self.span = {k: slice(int(e) - n, int(e)) for k, n, e in zip(kinds, counts, ends)}

    def err(self, extra: np.ndarray, r: np.ndarray, cols: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """ERR of every column (of ``cols``) given further orthonormal basis vectors ``extra`` and residual ``r``; and
        sign of θ."""
        gt = self.gt[cols]
        num = gt @ r
        d = self.gp2[cols]
        if extra.shape[1]:
            p = gt @ extra                    # (columns × basis): Eᵀg of every column
            d = d - np.einsum("ij,ij->i", p, p)
            num = num - p @ (extra.T @ r)
        ok = d > 1e-9 * self.norm2[cols]  # not (numerically) in the span of the linear columns
        e = np.where(ok, num ** 2 / np.maximum(d, 1e-300) / max(float(r @ r), 1e-300), 0.0)
        return e, np.sign(num)

    def best_given(self, kind_name: str, extra: np.ndarray, r: np.ndarray) -> int | None:
        """:meth:`best_of` ``kind_name`` given ``extra`` and ``r``, scoring its columns alone: a set search re-places
        one kind at a time, and scoring every kind's columns for it cost nine times as much (nine kinds)."""
        cols = self.span[kind_name]
        e, sign = self.err(extra, r, cols)
        ok = sign > 0 if lookup_kind(kind_name).positive else np.ones(e.size, bool)
        idx = np.nonzero(ok)[0]
        return cols.start + int(idx[np.argmax(e[idx])]) if idx.size else None

    def best_of(self, kind_name: str, err: np.ndarray, sign: np.ndarray) -> int | None:
        ok = self.kind_of == kind_name
        if lookup_kind(kind_name).positive:
            ok &= sign > 0
        idx = np.nonzero(ok)[0]
        return int(idx[np.argmax(err[idx])]) if idx.size else None

    def basis(self, base: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Orthonormal basis of the ``base`` columns beyond the linear ones (subsample rows), and the residual."""
        rows = self.data.rows
        extra, r = np.empty((rows.size, 0)), self.r0
        for b in base:
            v = b[rows] - self.q @ (self.q.T @ b[rows])
            if extra.shape[1]:
                v = v - extra @ (extra.T @ v)
            nv = float(np.linalg.norm(v))
            if nv > 1e-9 * max(float(np.linalg.norm(b[rows])), 1e-300):
                v = v / nv
                extra = np.column_stack([extra, v])
                r = r - v * (v @ r)
        return extra, r

    def unit(self, j: int, extra: np.ndarray) -> np.ndarray:
        g = self.gt[j]
        if extra.shape[1]:
            g = g - extra @ (extra.T @ g)
        return g / np.linalg.norm(g)
