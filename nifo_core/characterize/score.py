"""Scoring one candidate at full length: ERR, cross-validated ERR, F-test, coefficient stability
(the thresholds of :mod:`nifo_core.characterize.automatic`), and its reported form."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np
from scipy import stats

from .data import RegressionData
from .result import Candidate, Thresholds
from ..kinds.describing import Term
from ..signal.least_squares import lstsq
from ..signal.uncertainty import effective_samples

__all__ = ["score_candidate", "lstsq", "base_fit", "BaseFit", "detection_limit", "smallest_visible"]


# --------------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------------
def _n_eff(res: np.ndarray, rec: np.ndarray, fs: Sequence[float]) -> float:
    """Effective sample count of coloured residuals: Σ_records n·mean(S)²/mean(S²) (the one spectral engine)."""
    total = 0.0
    for i, f in enumerate(fs):
        r = res[rec == i]
        total += effective_samples(r, f, block=int(min(4096, max(64, r.size // 8))))
    return total


def _half_width(q0: np.ndarray, g: np.ndarray, res: np.ndarray, data: RegressionData, *, level: float = 0.95,
                block_s: float = 2.0) -> float:
    """Half-width of the ``level`` bound of the last coefficient θ of the fit [a0, g] with residual ``res``, ``q0``
    an orthonormal basis of a0's columns (:attr:`BaseFit.basis`).

    Batch means (a heteroscedasticity- and autocorrelation-consistent sandwich): with g⊥ = g
    orthogonalised against ``a0``, θ - θ_true = Σ g⊥·e / Σ g⊥², so over blocks b of ``block_s``
    (≥ 2 periods of the band's lower edge; the residual's correlation is far shorter)

        Var θ ≈ Σ_b (Σ_{i∈b} g⊥_i·e_i)² / (Σ g⊥²)²,   t quantile with (blocks - 1) degrees of freedom.

    The N_eff count of the F-test (N·mean(S)²/mean(S²)) treats the residual as if g⊥ were white;
    g⊥ is band-limited too, and that bound came out 5.6× too wide (20-seed check, quadratic damping).
    """
    gp = g - q0 @ (q0.T @ g)
    info = float(gp @ gp)
    if not info > 0:
        return float("nan")
    scores, covered = [], 0
    for i, rf in enumerate(data.rfs):
        m = data.rec == i
        blk = max(int(block_s * rf.fs_hz), int(2 * rf.fs_hz / rf.band.f_lo_hz))
        u = gp[m] * res[m]
        nb = u.size // blk
        if nb >= 1:
            scores.append(u[: nb * blk].reshape(nb, blk).sum(axis=1))
            covered += nb * blk
    sc = np.concatenate(scores) if scores else np.empty(0)
    if sc.size < 4:
        return float("nan")
    var = float(sc @ sc) * (gp.size / covered) / info ** 2   # rows past the last whole block: same density
    return float(stats.t.ppf(0.5 + level / 2, sc.size - 1)) * float(np.sqrt(var))


def _cv_rss(a: np.ndarray, y: np.ndarray, fold: np.ndarray) -> float:
    rss = 0.0
    for f in (0, 1):
        tr, te = fold == f, fold != f
        e = y[te] - a[te] @ lstsq(a[tr], y[tr])
        rss += float(e @ e)
    return rss


@dataclass(frozen=True)
class _Group:
    """One data group of a :class:`BaseFit`: its rows, an orthonormal basis of the base's columns there and -ẍ2 there
    orthogonalised against them (what every candidate's coefficient in the group is fitted from)."""

    rows: np.ndarray
    basis: np.ndarray
    y_perp: np.ndarray


def _groups(a0: np.ndarray, y: np.ndarray, group: np.ndarray) -> tuple[_Group, ...]:
    out = []
    for gi in np.unique(group):
        rows = group == gi
        q, _ = np.linalg.qr(a0[rows])
        ym = y[rows]
        out.append(_Group(rows, q, ym - q @ (q.T @ ym)))
    return tuple(out)


def _group_thetas(groups: Sequence[_Group], g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The coefficient of the column ``g`` fitted on each group alone (given the base's columns), and its information
    there; groups where the term is barely exercised (motion within a play, say) are left out: they say nothing."""
    gth, w = [], []
    for grp in groups:
        gm = g[grp.rows]
        q = grp.basis
        gp = gm - q @ (q.T @ gm)
        info = float(gp @ gp)
        if info <= 1e-12 * float(gm @ gm) or info == 0:
            continue  # the term is not exercised in this group
        gth.append(float(gp @ grp.y_perp / info))
        w.append(info)
    gth_a, w_a = np.array(gth), np.array(w)
    if w_a.size:
        big = w_a >= 1e-3 * w_a.max()
        gth_a, w_a = gth_a[big], w_a[big]
    return gth_a, w_a


def _quarters(data: RegressionData) -> np.ndarray:
    """Groups for the stability of a term exercised in one record only: consecutive quarters (``n_groups``) of
    each record, numbered apart."""
    out = np.empty(data.rec.size, dtype=np.int64)
    for i in np.unique(data.rec):
        idx = np.nonzero(data.rec == i)[0]
        out[idx] = i * data.n_groups + np.minimum(np.arange(idx.size) * data.n_groups // idx.size,
                                                  data.n_groups - 1)
    return out


def score_candidate(data: RegressionData, base: list[np.ndarray], term: Term, *, thresholds: Thresholds, n_grid: int,
           m2: float | None, names: tuple[str, ...], offsets: Sequence[float] | None = None,
           fit: BaseFit | None = None) -> Candidate:
    """Full-length fit of ``term`` on top of the linear columns and the ``base`` regressors.

    ``fit``: :func:`base_fit` of ``data`` and ``base``, when several terms are scored against the same base (a
    round's kinds side by side): what they share is computed once (the same numbers; the per-group coefficients'
    stability to rounding, 1e-15: :attr:`BaseFit.groups`)."""
    y = data.y
    fit = base_fit(data, base) if fit is None else fit
    a0 = fit.columns
    a1 = np.column_stack([a0, data.regressor(term, offsets=offsets)])
    c1 = lstsq(a1, y)
    r1 = y - a1 @ c1
    rss0, rss1, tss = fit.rss, float(r1 @ r1), fit.tss
    err = max(0.0, 1.0 - rss1 / rss0) if rss0 > 0 else 0.0
    neff = _n_eff(r1, data.rec, [rf.fs_hz for rf in data.rfs])
    dof = max(neff - a1.shape[1], 1.0)
    fstat = max(rss0 - rss1, 0.0) / max(rss1 / dof, 1e-300)
    p = float(min(1.0, stats.f.sf(fstat, 1, dof) * max(n_grid, 1)))  # Bonferroni over the grid
    cv0 = fit.cv_rss
    err_cv = 1.0 - _cv_rss(a1, y, data.fold) / cv0 if cv0 > 0 else 0.0
    theta = float(c1[-1])
    half = _half_width(fit.basis, a1[:, -1], r1, data)
    gth_a, w_a = _group_thetas(fit.groups, a1[:, -1])
    if w_a.size < 2 and len(data.rfs) > 1:
        # several records, and only one exercises the term (a stop reached at the highest level alone): its
        # stability across consecutive quarters of the records where it acts, as for a single record
        gth_a, w_a = _group_thetas(fit.quarters, a1[:, -1])
    if w_a.size >= 2 and theta != 0:
        spread = float(np.sqrt(np.sum(w_a * (gth_a - theta) ** 2) / np.sum(w_a)) / abs(theta))
    else:
        spread = float("nan")
    failed = []
    if err < thresholds.min_err:
        failed.append(f"ERR {err:.3f} < {thresholds.min_err:g}")
    if err_cv < thresholds.min_err_cv:
        failed.append(f"cross-validated ERR {err_cv:.3f} < {thresholds.min_err_cv:g}")
    if not p < thresholds.alpha:
        failed.append(f"p {p:.2g} ≥ {thresholds.alpha:g}")
    if not np.isfinite(spread):
        failed.append("coefficient stability unknown: the term acts in only one data group")
    elif spread > thresholds.max_spread:
        failed.append(f"coefficient spread {spread:.2f} > {thresholds.max_spread:g}")
    elif np.any((np.sign(gth_a) != np.sign(theta)) & (w_a >= 0.1 * w_a.max())):
        failed.append("the coefficient changes sign across the data groups: " + ", ".join(f"{g:.3g}" for g in gth_a))
    dr2 = max(rss0 - rss1, 0.0) / tss if tss > 0 else 0.0
    if dr2 < thresholds.min_delta_r2:
        failed.append(f"ΔR² {dr2:.1e} < {thresholds.min_delta_r2:g}")
    if term.spec.positive and theta <= 0:
        failed.append(f"coefficient {theta:.3g} has the unphysical sign")
    term, sign, equiv = term.spec.canonical(term, theta)
    return Candidate(term=term, theta=sign * theta, coefficient=None if m2 is None else sign * theta * m2,
                     theta_half_width=half,
                     err=err, delta_r2=dr2, err_cv=float(err_cv),
                     p_value=p, n_eff=float(neff), spread=spread, group_theta=tuple(sign * gth_a),
                     present=not failed, conditional_on=names, equivalent=equiv, failed=tuple(failed),
                     relative_param=_relative(term, data), offsets=() if offsets is None else tuple(offsets))


def _relative(term: Term, data: RegressionData) -> float | None:
    kp = term.spec.key_param
    if kp is None:
        return None
    peak = term.spec.reach(term, z_max=data.zmax, zdot_max=data.vmax, z_neg=data.zneg, z_pos=data.zpos)
    return None if peak is None else float(term.params[kp]) / peak


@dataclass(frozen=True)
class BaseFit:
    """The fit [z, ż, base] that candidates are scored and detection limits measured against: its ``columns``, an
    orthonormal ``basis`` of them, its residual sum of squares ``rss``, the total sum of squares ``tss`` of -ẍ2 (what
    ΔR² is a fraction of) and, each computed when first read (a score and a limit need different ones), its two-fold
    cross-validated residual :attr:`cv_rss`, its degrees of freedom :attr:`dof` and its data groups (:attr:`groups`,
    :attr:`quarters`)."""

    columns: np.ndarray
    basis: np.ndarray
    residual: np.ndarray
    rss: float
    tss: float
    data: RegressionData = field(repr=False, compare=False)

    @cached_property
    def cv_rss(self) -> float:
        """The residual sum of squares of the two-fold cross-validated fit (the folds of ``data.fold``)."""
        return _cv_rss(self.columns, self.data.y, self.data.fold)

    @cached_property
    def groups(self) -> tuple[_Group, ...]:
        """The data groups (``data.group``), each with the base's basis there: a candidate's coefficient per group."""
        return _groups(self.columns, self.data.y, self.data.group)

    @cached_property
    def quarters(self) -> tuple[_Group, ...]:
        """The same for consecutive quarters of each record (:func:`_quarters`)."""
        return _groups(self.columns, self.data.y, _quarters(self.data))

    @cached_property
    def dof(self) -> float:
        """N_eff - q - 1: the residual's effective samples less the columns and the term a limit adds (a candidate's
        score counts its own, with the term in)."""
        d = self.data
        return max(_n_eff(self.residual, d.rec, [rf.fs_hz for rf in d.rfs]) - self.columns.shape[1] - 1, 1.0)


def base_fit(data: RegressionData, base: list[np.ndarray]) -> BaseFit:
    """The :class:`BaseFit` of ``data`` and ``base``: computed once for every candidate scored or every detection
    limit measured beside the same ``base``."""
    a0 = np.column_stack([data.x, *base]) if base else data.x
    res = data.y - a0 @ lstsq(a0, data.y)
    q, _ = np.linalg.qr(a0)
    return BaseFit(columns=a0, basis=q, residual=res, rss=float(res @ res), tss=float(data.y @ data.y), data=data)


def detection_limit(data: RegressionData, base: list[np.ndarray], term: Term, *, thresholds: Thresholds,
                    n_grid: int, fit: BaseFit | None = None) -> tuple[float, float]:
    """Smallest coefficient θ [per kg] of ``term`` that these data would have shown beside ``base``, and its peak g.

    Adding θ·g to the truth lowers the residual sum of squares of the fit [z, ż, base] by
    θ²·Σg⊥² (g⊥: g band-limited and orthogonalised against those columns), so the smallest θ
    that passes the F-test at α/n_grid (N_eff effective samples, as :func:`score_candidate`),
    explains ``min_err`` of the residual and ``min_delta_r2`` of the total variance TSS of -ẍ2 is
    (the loop's detection limit, docs/method.md §5)

        θ_min = sqrt( max(F_crit·RSS/dof, min_err·RSS, min_delta_r2·TSS) / Σg⊥² ),
        F_crit = F⁻¹(1 - α/n_grid; 1, dof).

    ``fit``: :func:`base_fit` of ``data`` and ``base``, when several terms are measured against the same base.
    Returns ``(θ_min, |g|₉₉.₅)`` (the 99.5 % quantile of |g| on the measured motion: θ_min times it
    is the peak force per kg of M2 of the smallest visible effect); θ_min is inf when g lies in
    the span of the other columns.
    """
    fit = base_fit(data, base) if fit is None else fit
    q, rss, dof = fit.basis, fit.rss, fit.dof
    g = data.regressor(term)
    gp = g - q @ (q.T @ g)
    info = float(gp @ gp)
    peak = float(np.quantile(np.abs(np.concatenate([term.evaluate(rf.z, rf.zdot) for rf in data.rfs])), 0.995))
    if not info > 1e-12 * float(g @ g):
        return float("inf"), peak
    return smallest_visible(rss, info, dof, tss=fit.tss, thresholds=thresholds, n_grid=n_grid), peak


def smallest_visible(rss: float, info: float, dof: float, *, tss: float, thresholds: Thresholds, n_grid: int
                     ) -> float:
    """θ_min = sqrt( max(F_crit·RSS/dof, min_err·RSS, min_delta_r2·TSS) / Σg⊥² ), F_crit = F⁻¹(1 - α/n_grid;
    1, dof): the smallest coefficient of a column with Σg⊥² = ``info`` beyond the fit's residual ``rss`` that passes
    the F-test, explains ``min_err`` of the residual and ``min_delta_r2`` of the total sum of squares ``tss`` — every
    threshold of :func:`score_candidate` a coefficient's size decides (:func:`detection_limit`; the loop's
    :mod:`nifo_core.loop.detection`). On records with little noise the last one binds: the residual is small, the
    F-test passes at a tiny θ, and a limit without it names effects the selection refuses."""
    f_crit = float(stats.f.isf(min(thresholds.alpha / max(n_grid, 1), 0.5), 1, dof))
    return float(np.sqrt(max(f_crit * rss / dof, thresholds.min_err * rss, thresholds.min_delta_r2 * tss) / info))
