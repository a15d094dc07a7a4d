"""Automatic characterization: which describing function explains the restoring force (METHOD.md §5).

Equation error of the body equation (paper Eq. 2) per unit sprung mass::

    y = -ẍ2 = a·z + b·ż [+ k3·x2] + Σ θ_i·g_i(z, ż) + e,    a = K2/M2, b = C2/M2, θ_i = c_i/M2

For every kind of the describing-function library (:mod:`nifo_core.describing`,
the one place the forms live) over a grid of its parameters scaled to the
observed motion, the candidate g is evaluated on the measured z, ż and then
band-passed with the integrator's band (METHOD.md §5 step 3). Candidates are
scored by the error reduction ratio (Billings) — the fraction of the variance
the linear fit leaves that the candidate explains:

    ERR = (g⊥ᵀ r)² / (g⊥ᵀ g⊥ · rᵀ r),   g⊥ = g orthogonalised against [z, ż],  r = linear residual

vectorised over the grid (one QR of the linear regressors, then one dot
product per grid point on a row subsample), refined around each kind's best
grid point and refitted at full length. A forward orthogonal selection (FROLS)
builds the suggested model one term at a time; kinds that explain the same
thing as a chosen term are listed as its alternatives, not suggested beside it.

One filter for every column. ``y``, ``z``, ``ż`` (and ``x2``) are band-passed
once more with the same filter that band-limits each g, so every column of the
regression carries the same final band shape. This matters for the negative
control: with 2 % accelerometer noise, z holds integrated noise that peaks in
the integrator's low transition band; if g saw the filter one more time than
y and z, a static g(z) weighted that noise differently from z and "explained"
10-20 % of a linear strut's residual (small-gap clearance, tiny backlash).
With the same final filter, a static g of jointly Gaussian data is
uncorrelated with the linear residual (Bussgang), as it should be.

A candidate counts as *present* only if all of (:class:`Thresholds`):

- ERR ≥ 2 % of what the linear fit leaves (for later terms: of what the terms
  chosen before leave),
- cross-validated ERR ≥ 1 % (fitted on alternate blocks, scored on the others),
- F-test p < 0.001 with effective degrees of freedom for coloured residuals
  (N_eff = N·mean(S)²/mean(S²) from the residual spectrum S), Bonferroni-corrected
  for the grid points searched,
- coefficient stable across data groups (records, or quarters of one record):
  information-weighted relative spread ≤ 0.5,
- explains at least 0.001 % of the total variance of -ẍ2 (ΔR² ≥ 1e-5: on
  noise-free data the linear residual is rounding, and any ERR means nothing),
- ``coulomb`` only with c > 0 (friction that feeds energy in is an artefact).

``backlash`` with c < 0 is physical: a·z + c·play(z) with c = -a is a spring in
series with dry friction (Jenkins element, stick-slip; its force saturates at
|c|·deadband/2, paper §3.3 after Ferri), the loops with flat tops of paper Fig. 7b.

Exact equivalences once z and ż are in the fit: ``saturation(limit=x) =
z - clearance(gap=x)`` and ``velocity_saturation(limit=x) = ż -
velocity_deadzone(knee=x)`` explain the data identically; the
clearance/deadzone form is reported (its linear part is then the small-motion
behaviour, METHOD.md §3) and the other is named as its equivalent.
``asymmetric_damping`` rebound and compression differ by a linear term: the
side with the positive (added-damping) coefficient is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Mapping, Sequence

import numpy as np
from scipy import signal, stats

from .describing import Term, kind as lookup_kind
from .errors import ConfigError, InputError
from .integrate import IntegrationBand
from .record import Record
from .restoring import (RestoringForce, bandpass, bandpass_settle_samples, instantaneous_frequency, restoring_force,
                        suggest_band)

__all__ = ["Thresholds", "Candidate", "FittedModel", "Characterization", "RecordSummary", "characterize",
           "characterize_restoring", "DEFAULT_KINDS", "POSITIVE_KINDS", "candidate_grid"]

#: kinds searched by default (saturation/velocity_saturation are exact equivalents, named as such)
DEFAULT_KINDS = ("cubic_stiffness", "clearance", "bump_stop", "backlash", "velocity_deadzone", "coulomb",
                 "quadratic_damping", "asymmetric_damping")
#: kinds whose coefficient must be positive to be physical
POSITIVE_KINDS = frozenset({"coulomb"})

_EQUIVALENT = {"clearance": ("saturation", "gap", "limit"),
               "velocity_deadzone": ("velocity_saturation", "knee", "limit")}

#: rows used for the grid search (after band-passing at full length)
_SEARCH_ROWS = 40_000
#: kinds re-scored at full length per selection step (the best ones on the subsample)
_FULL_PER_STEP = 3


@dataclass(frozen=True)
class Thresholds:
    """When a candidate counts as present (module docstring). All must hold."""

    min_err: float = 0.02
    min_err_cv: float = 0.01
    alpha: float = 1e-3
    max_spread: float = 0.5
    min_delta_r2: float = 1e-5

    def __post_init__(self) -> None:
        for name in ("min_err", "min_err_cv", "alpha", "max_spread", "min_delta_r2"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"threshold {name}={v!r} must be finite and non-negative")

    def to_dict(self) -> dict:
        return {"min_err": self.min_err, "min_err_cv": self.min_err_cv, "alpha": self.alpha,
                "max_spread": self.max_spread, "min_delta_r2": self.min_delta_r2}


@dataclass(frozen=True)
class Candidate:
    """One describing function with its best parameters, its fit and the confidence in it.

    Attributes
    ----------
    term : Term
        Kind and parameters (what a model file lists).
    theta : float
        Coefficient per unit sprung mass, c/M2 (the kind's ``coef_unit`` per kg).
    coefficient : float or None
        c = θ·M2 in the kind's ``coef_unit`` (N/m, N·s/m, N, ...) when M2 is known.
    err : float
        Error reduction ratio: the fraction of the variance left by the linear fit
        (by the linear fit and ``conditional_on`` for later suggested terms) that the term explains.
    delta_r2 : float
        Variance explained beyond that, as a fraction of the total variance of -ẍ2.
    err_cv : float
        Cross-validated ERR (coefficients fitted on alternate blocks, error scored on the others).
    p_value : float
        F-test p-value with effective degrees of freedom, Bonferroni-corrected for the grid.
    n_eff : float
        Effective number of independent residual samples used by the F-test.
    spread, group_theta :
        Information-weighted relative spread of θ across data groups, and θ per group.
    present : bool
        All thresholds met (on its own, on top of the linear fit; suggested terms: on top of the earlier ones).
    status : str
        ``suggested`` (in the suggested model), ``alternative`` (explains the same as
        ``alternative_to``, nearly as well), ``redundant`` (explained by ``alternative_to``),
        ``unselected`` (present, but the suggestion was full), ``weak`` (a threshold not met).
    failed : tuple of str
        The thresholds not met.
    relative_param : float or None
        The key parameter relative to the observed range (|z| or |ż| peak).
    """

    term: Term
    theta: float
    coefficient: float | None
    err: float
    delta_r2: float
    err_cv: float
    p_value: float
    n_eff: float
    spread: float
    group_theta: tuple[float, ...]
    present: bool
    status: str = "weak"
    alternative_to: str | None = None
    conditional_on: tuple[str, ...] = ()
    equivalent: str | None = None
    failed: tuple[str, ...] = ()
    relative_param: float | None = None

    @property
    def kind(self) -> str:
        return self.term.kind

    @property
    def key_param(self) -> tuple[str, float] | None:
        """(name, value) of the kind's key parameter (gap, knee, deadband, ...), if it has one."""
        k = self.term.spec.key_param
        return (k, float(self.term.params[k])) if k else None

    def describe(self) -> str:
        """One line: what the term means physically."""
        return _describe(self)

    def to_dict(self) -> dict:
        kp = self.key_param
        return {"kind": self.kind, "params": dict(self.term.params), "label": self.term.label,
                "key_param": None if kp is None else {"name": kp[0], "value": kp[1],
                                                       "relative_to_range": self.relative_param},
                "theta_per_kg": self.theta, "coefficient": self.coefficient,
                "coefficient_unit": self.term.spec.coef_unit,
                "err": self.err, "delta_r2": self.delta_r2, "err_cv": self.err_cv, "p_value": self.p_value,
                "n_eff": self.n_eff, "spread": _finite(self.spread), "group_theta": list(self.group_theta),
                "present": self.present, "status": self.status, "alternative_to": self.alternative_to,
                "conditional_on": list(self.conditional_on), "equivalent": self.equivalent,
                "failed": list(self.failed), "meaning": self.describe()}


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


@dataclass(frozen=True)
class RecordSummary:
    """Per-record facts: length, motion ranges, the linear fit on this record alone."""

    source: str
    fs_hz: float
    duration_s: float
    seconds_used: float
    z_rms_m: float
    z_peak_m: float
    zdot_rms_m_s: float
    zdot_peak_m_s: float
    k_per_kg: float
    c_per_kg: float
    linear_r2: float

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass(frozen=True)
class FittedModel:
    """The suggested model fitted jointly: -ẍ2 ≈ k·z + c·ż + Σ θ_i·g_i (per unit sprung mass)."""

    k_per_kg: float
    c_per_kg: float
    terms: tuple[tuple[Term, float], ...]
    r2: float

    def contributions(self, z: np.ndarray, zdot: np.ndarray, *, fs_hz: float,
                      band: IntegrationBand) -> tuple[np.ndarray, np.ndarray]:
        """Along a motion: the linear part k·z + c·ż, shape (n,), and each θ_i·g_i band-passed
        like the data, shape (n_terms, n) [m/s²]."""
        z, zdot = np.asarray(z, float), np.asarray(zdot, float)
        lin = self.k_per_kg * z + self.c_per_kg * zdot
        per = np.zeros((len(self.terms), z.size))
        for i, (t, th) in enumerate(self.terms):
            per[i] = th * bandpass(t.evaluate(z, zdot), fs_hz, band)
        return lin, per

    def force(self, z: np.ndarray, zdot: np.ndarray, *, fs_hz: float, band: IntegrationBand) -> np.ndarray:
        """Model restoring force per unit mass [m/s²] along a motion (each g band-passed like the data)."""
        lin, per = self.contributions(z, zdot, fs_hz=fs_hz, band=band)
        return lin + per.sum(axis=0)

    def to_dict(self) -> dict:
        return {"k_per_kg": self.k_per_kg, "c_per_kg": self.c_per_kg, "r2": self.r2,
                "terms": [{**t.to_dict(), "theta_per_kg": th} for t, th in self.terms]}


@dataclass(frozen=True)
class Characterization:
    """Result of :func:`characterize`.

    ``candidates`` holds each kind's best form: the suggested terms first, in
    selection order (with their statistics given the terms before them), then
    the others ranked by the variance they explain beyond linear on their own;
    ``suggested`` the terms of the suggested model (empty: nothing nonlinear found).
    """

    candidates: tuple[Candidate, ...]
    suggested: tuple[Candidate, ...]
    band: IntegrationBand
    thresholds: Thresholds
    records: tuple[RecordSummary, ...]
    linear: Mapping[str, float]
    model: FittedModel | None = None
    m2_kg: float | None = None
    z_range_m: float = 0.0
    zdot_range_m_s: float = 0.0
    notes: tuple[str, ...] = ()

    @property
    def nothing_found(self) -> bool:
        """True when no candidate met the thresholds."""
        return not self.suggested

    @property
    def suggested_terms(self) -> tuple[Term, ...]:
        return tuple(c.term for c in self.suggested)

    def candidate(self, kind_name: str) -> Candidate:
        """The ranked candidate of one kind."""
        name = lookup_kind(kind_name).name
        for c in self.candidates:
            if c.kind == name:
                return c
        raise KeyError(name)

    def to_dict(self) -> dict:
        return {"band": self.band.to_dict(), "thresholds": self.thresholds.to_dict(), "m2_kg": self.m2_kg,
                "linear": dict(self.linear), "model": None if self.model is None else self.model.to_dict(),
                "z_range_m": self.z_range_m, "zdot_range_m_s": self.zdot_range_m_s,
                "nothing_found": self.nothing_found,
                "suggested": [c.to_dict() for c in self.suggested],
                "candidates": [c.to_dict() for c in self.candidates],
                "records": [r.to_dict() for r in self.records], "notes": list(self.notes)}


# --------------------------------------------------------------------------------------------
# data assembly
# --------------------------------------------------------------------------------------------
class _Data:
    """The regression's rows: every column band-passed once more with the one filter."""

    def __init__(self, rfs: Sequence[RestoringForce], *, n_groups: int, body_stiffness: bool,
                 masks: Sequence[np.ndarray | None] | None = None) -> None:
        self.rfs = list(rfs)
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

    def regressor(self, term: Term) -> np.ndarray:
        """g(z, ż) band-passed per record like every other column; kept rows, stacked."""
        key = (term.kind, tuple(sorted(term.params.items())))
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        parts = []
        for rf, k in zip(self.rfs, self.keep):
            parts.append(bandpass(term.evaluate(rf.z, rf.zdot), rf.fs_hz, rf.band)[k])
        out = np.concatenate(parts)
        if len(self._cache) < 48:
            self._cache[key] = out
        return out


# --------------------------------------------------------------------------------------------
# candidate grids
# --------------------------------------------------------------------------------------------
def candidate_grid(kind_name: str, *, z_range: float, zdot_range: float, z_neg: float | None = None,
                   z_pos: float | None = None, points: int = 24) -> list[Term]:
    """Terms of one kind over a parameter grid scaled to the observed motion.

    ``z_range``/``zdot_range`` are robust peaks of |z| [m] and |ż| [m/s];
    ``z_neg``/``z_pos`` the peaks in compression/rebound (bump stops; the
    threshold is measured from the mean position, static offsets being lost).
    Scale parameters get geometric grids (equal relative steps):

    ========================  ==================================
    clearance ``gap``          3-90 % of the |z| peak
    bump_stop ``gap``          0-92 % of the peak on each side
    backlash ``deadband``      1-70 % of the |z| peak
    velocity_deadzone ``knee`` 2-90 % of the |ż| peak
    coulomb ``eps``            0.1-30 % of the |ż| peak
    ========================  ==================================
    """
    k = lookup_kind(kind_name)
    name = k.name
    zr, vr = float(z_range), float(zdot_range)
    if not (zr > 0 and vr > 0):
        raise InputError(f"motion range z={zr:g} m, ż={vr:g} m/s must be positive to build a grid",
                         hint="the record holds no relative motion in the band")
    if points < 2:
        raise ConfigError(f"grid points={points} must be at least 2")

    def geo(lo, hi):
        return np.geomspace(lo, hi, points)

    if name in ("cubic_stiffness", "quadratic_damping"):
        return [Term(name)]
    if name == "asymmetric_damping":
        return [Term(name, {"side": "rebound"})]
    if name in ("clearance", "saturation"):
        key = "gap" if name == "clearance" else "limit"
        return [Term(name, {key: g}) for g in geo(0.03, 0.9) * zr]
    if name == "bump_stop":
        out = []
        for side, peak in (("compression", z_neg or zr), ("rebound", z_pos or zr)):
            out += [Term(name, {"gap": g, "side": side}) for g in np.linspace(0.0, 0.92, points) * peak]
        return out
    if name == "backlash":
        return [Term(name, {"deadband": d}) for d in geo(0.01, 0.7) * zr]
    if name in ("velocity_deadzone", "velocity_saturation"):
        key = "knee" if name == "velocity_deadzone" else "limit"
        return [Term(name, {key: g}) for g in geo(0.02, 0.9) * vr]
    if name == "coulomb":
        return [Term(name, {"eps": e}) for e in geo(0.001, 0.3) * vr]
    raise ConfigError(f"no parameter grid for kind {name!r}")  # pragma: no cover - every kind has one


def _refine(term: Term, grid: list[Term], points: int = 7) -> list[Term]:
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
            if not np.isclose(x, v) and (x > 0 or term.kind == "bump_stop")]


# --------------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------------
def _n_eff(res: np.ndarray, rec: np.ndarray, fs: Sequence[float]) -> float:
    """Effective sample count of coloured residuals: Σ_records n·mean(S)²/mean(S²)."""
    total = 0.0
    for i, f in enumerate(fs):
        r = res[rec == i]
        nper = int(min(4096, max(64, r.size // 8)))
        _, s = signal.welch(r, f, nperseg=nper)
        s = s[1:]
        total += r.size * float(np.mean(s)) ** 2 / max(float(np.mean(s ** 2)), 1e-300)
    return total


def _lstsq(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.linalg.lstsq(a, y, rcond=None)[0]


def _cv_rss(a: np.ndarray, y: np.ndarray, fold: np.ndarray) -> float:
    rss = 0.0
    for f in (0, 1):
        tr, te = fold == f, fold != f
        e = y[te] - a[te] @ _lstsq(a[tr], y[tr])
        rss += float(e @ e)
    return rss


def _score(data: _Data, base: list[np.ndarray], term: Term, *, thresholds: Thresholds, n_grid: int,
           m2: float | None, names: tuple[str, ...]) -> Candidate:
    """Full-length fit of ``term`` on top of the linear columns and the ``base`` regressors."""
    y = data.y
    a0 = np.column_stack([data.x, *base]) if base else data.x
    a1 = np.column_stack([a0, data.regressor(term)])
    c1 = _lstsq(a1, y)
    r0 = y - a0 @ _lstsq(a0, y)
    r1 = y - a1 @ c1
    rss0, rss1, tss = float(r0 @ r0), float(r1 @ r1), float(y @ y)
    err = max(0.0, 1.0 - rss1 / rss0) if rss0 > 0 else 0.0
    neff = _n_eff(r1, data.rec, [rf.fs_hz for rf in data.rfs])
    dof = max(neff - a1.shape[1], 1.0)
    fstat = max(rss0 - rss1, 0.0) / max(rss1 / dof, 1e-300)
    p = float(min(1.0, stats.f.sf(fstat, 1, dof) * max(n_grid, 1)))  # Bonferroni over the grid
    cv0 = _cv_rss(a0, y, data.fold)
    err_cv = 1.0 - _cv_rss(a1, y, data.fold) / cv0 if cv0 > 0 else 0.0
    theta = float(c1[-1])
    gth, w = [], []
    for gi in np.unique(data.group):
        am, ym = a1[data.group == gi], y[data.group == gi]
        q, rr = np.linalg.qr(am[:, :-1])
        gp = am[:, -1] - q @ (q.T @ am[:, -1])
        info = float(gp @ gp)
        if info <= 1e-12 * float(am[:, -1] @ am[:, -1]) or info == 0:
            continue  # the term is not exercised in this group
        gth.append(float(gp @ (ym - q @ (q.T @ ym)) / info))
        w.append(info)
    gth_a, w_a = np.array(gth), np.array(w)
    if w_a.size:  # groups where the term is barely exercised (motion within a play, say) say nothing
        big = w_a >= 1e-3 * w_a.max()
        gth_a, w_a = gth_a[big], w_a[big]
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
    if term.kind in POSITIVE_KINDS and theta <= 0:
        failed.append(f"coefficient {theta:.3g} has the unphysical sign")
    term, sign, equiv = _canonical(term, theta)
    return Candidate(term=term, theta=sign * theta, coefficient=None if m2 is None else sign * theta * m2,
                     err=err, delta_r2=dr2, err_cv=float(err_cv),
                     p_value=p, n_eff=float(neff), spread=spread, group_theta=tuple(sign * gth_a),
                     present=not failed, conditional_on=names, equivalent=equiv, failed=tuple(failed),
                     relative_param=_relative(term, data))


def _relative(term: Term, data: _Data) -> float | None:
    kp = term.spec.key_param
    if kp is None:
        return None
    v = float(term.params[kp])
    if term.spec.variable == "zdot":
        return v / data.vmax
    if term.kind == "bump_stop":
        peak = data.zneg if term.params["side"] == "compression" else data.zpos
        return v / peak if peak > 0 else None
    return v / data.zmax


def _canonical(term: Term, theta: float) -> tuple[Term, float, str | None]:
    """(reported term, sign to apply to θ, equivalent form)."""
    if term.kind == "asymmetric_damping" and theta < 0:
        # c·max(ż,0) = c·ż - c·min(ż,0): the other side with -c, plus a linear term
        other = "compression" if term.params["side"] == "rebound" else "rebound"
        return Term("asymmetric_damping", {"side": other}), -1.0, None
    if term.kind in _EQUIVALENT:
        name, kp, kq = _EQUIVALENT[term.kind]
        return term, 1.0, f"{name}({kq}={float(term.params[kp]):.4g}) with the opposite coefficient"
    return term, 1.0, None


# --------------------------------------------------------------------------------------------
# the search
# --------------------------------------------------------------------------------------------
class _Search:
    """Grid columns on the row subsample, orthogonalised against the linear columns (one QR)."""

    def __init__(self, data: _Data, kinds: Sequence[str], grid_points: int,
                 progress: Callable[[float], None] | None) -> None:
        self.data = data
        rows = data.rows
        self.q, _ = np.linalg.qr(data.x[rows])
        ys = data.y[rows]
        self.r0 = ys - self.q @ (self.q.T @ ys)
        self.grids = {k: candidate_grid(k, z_range=data.zmax, zdot_range=data.vmax, z_neg=data.zneg,
                                        z_pos=data.zpos, points=grid_points) for k in kinds}
        self.terms: list[Term] = []
        self.cols: list[np.ndarray] = []
        self._total = sum(len(g) for g in self.grids.values()) + 7 * len(kinds)
        self._progress = progress
        for k in kinds:
            self._add(self.grids[k])
        self._refresh()
        err, th = self.err(np.empty((rows.size, 0)), self.r0)
        for k in kinds:  # refine each kind's best
            j = self.best_of(k, err, th)
            if j is not None:
                self._add(_refine(self.terms[j], self.grids[k]))
        self._refresh()

    def _add(self, terms: list[Term]) -> None:
        for t in terms:
            self.terms.append(t)
            self.cols.append(self.data.regressor(t)[self.data.rows])
            if self._progress:
                self._progress(min(len(self.terms) / self._total, 1.0))

    def _refresh(self) -> None:
        g = np.column_stack(self.cols)
        self.norm2 = np.einsum("ij,ij->j", g, g)
        self.gp = g - self.q @ (self.q.T @ g)
        self.kind_of = np.array([t.kind for t in self.terms])

    def err(self, extra: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ERR of every column given further orthonormal basis vectors ``extra`` and residual ``r``; and sign of θ."""
        g = self.gp - extra @ (extra.T @ self.gp) if extra.shape[1] else self.gp
        d = np.einsum("ij,ij->j", g, g)
        num = g.T @ r
        ok = d > 1e-9 * self.norm2  # not (numerically) in the span of the linear columns
        e = np.where(ok, num ** 2 / np.maximum(d, 1e-300) / max(float(r @ r), 1e-300), 0.0)
        return e, np.sign(num)

    def best_of(self, kind_name: str, err: np.ndarray, sign: np.ndarray) -> int | None:
        ok = self.kind_of == kind_name
        if kind_name in POSITIVE_KINDS:
            ok &= sign > 0
        idx = np.nonzero(ok)[0]
        return int(idx[np.argmax(err[idx])]) if idx.size else None

    def unit(self, j: int, extra: np.ndarray) -> np.ndarray:
        g = self.gp[:, j]
        if extra.shape[1]:
            g = g - extra @ (extra.T @ g)
        return g / np.linalg.norm(g)


def characterize_restoring(rfs: Sequence[RestoringForce], *, m2_kg: float | None = None,
                           kinds: Sequence[str] = DEFAULT_KINDS, thresholds: Thresholds = Thresholds(),
                           grid_points: int = 24, max_terms: int = 3, n_groups: int = 4,
                           body_stiffness: bool = False, masks: Sequence[np.ndarray | None] | None = None,
                           progress: Callable[[float], None] | None = None) -> Characterization:
    """Characterize restoring-force data (the work behind :func:`characterize`; same parameters).

    ``rfs`` must share one integration band. ``masks`` (one per ``rf``, or
    None) select the samples to fit, e.g. a frequency window of a sweep; the
    candidates are still evaluated and band-passed over the whole record.
    ``n_groups``: parts of a single record (consecutive) for the
    coefficient-stability check; several records are one group each.
    """
    if not rfs:
        raise InputError("no restoring-force data to characterize")
    bands = {(rf.band.f_lo_hz, rf.band.f_hi_hz) for rf in rfs}
    if len(bands) > 1:
        raise ConfigError(f"records were integrated in different bands {sorted(bands)}",
                          hint="characterize records integrated with one band")
    if m2_kg is not None and not (np.isfinite(m2_kg) and m2_kg > 0):
        raise ConfigError(f"m2_kg={m2_kg!r} must be a positive mass [kg]")
    if max_terms < 1:
        raise ConfigError(f"max_terms={max_terms} must be at least 1")
    if masks is not None and len(masks) != len(rfs):
        raise InputError(f"{len(masks)} masks for {len(rfs)} records")
    kinds = tuple(dict.fromkeys(lookup_kind(k).name for k in kinds))
    data = _Data(rfs, n_groups=n_groups, body_stiffness=body_stiffness, masks=masks)
    search = _Search(data, kinds, grid_points, progress)
    n_grid = {k: len(search.grids[k]) for k in kinds}

    def score(j: int, base: list[np.ndarray], names: tuple[str, ...]) -> Candidate:
        t = search.terms[j]
        return _score(data, base, t, thresholds=thresholds, n_grid=n_grid[t.kind], m2=m2_kg, names=names)

    # --- each kind's best on its own, refitted at full length: the ranked table ------------
    none = np.empty((data.rows.size, 0))
    e1, s1 = search.err(none, search.r0)
    best1 = {}
    for k in kinds:  # a kind with only unphysical signs keeps its best, to show why it fails
        j = search.best_of(k, e1, s1)
        best1[k] = j if j is not None else search.best_of(k, e1, np.ones_like(s1))
    table = {k: score(best1[k], [], ()) for k in kinds}
    # --- forward selection: each step re-scores the best few kinds at full length ----------
    chosen: list[Candidate] = []
    chosen_j: list[int] = []
    base: list[np.ndarray] = []
    extra, r = none, search.r0
    for _ in range(max_terms):
        e, sg = search.err(extra, r)
        js = {k: search.best_of(k, e, sg) for k in kinds if k not in {c.kind for c in chosen}}
        js = {k: j for k, j in js.items() if j is not None and e[j] > 0}
        top = sorted(js, key=lambda k: -e[js[k]])[:_FULL_PER_STEP]
        if not chosen:  # step 1 is the ranked table itself
            scored = [(table[k], best1[k]) for k in sorted(kinds, key=lambda k: -table[k].err)[:_FULL_PER_STEP]]
        else:
            names = tuple(c.term.label for c in chosen)
            scored = [(score(js[k], base, names), js[k]) for k in top]
        scored = [(c, j) for c, j in scored if c.present]
        if not scored:
            break
        cand, j = max(scored, key=lambda cj: cj[0].err)
        chosen.append(replace(cand, status="suggested"))
        chosen_j.append(j)
        base.append(data.regressor(search.terms[j]))
        v = search.unit(j, extra)
        extra = np.column_stack([extra, v])
        r = r - v * (v @ r)
    # --- what the suggestion explains of the other kinds ----------------------------------------
    out = []
    chosen_kinds = [c.kind for c in chosen]
    names = tuple(c.term.label for c in chosen)
    for k in sorted(kinds, key=lambda k: -table[k].err):
        c = table[k]
        mine = [ch for ch in chosen if ch.kind == k]
        if mine:  # its statistics given the terms chosen before it
            out.append(mine[0])
            continue
        if not c.present:
            out.append(replace(c, status="weak"))
            continue
        by = None
        ex, rr = none, search.r0
        for cj, jj in zip(chosen, chosen_j):  # the first suggested term after which it adds < min_err
            v = search.unit(jj, ex)
            ex = np.column_stack([ex, v])
            rr = rr - v * (v @ rr)
            e, sg = search.err(ex, rr)
            j = search.best_of(k, e, sg)
            if j is None or e[j] < thresholds.min_err:
                by = cj
                break
        if by is not None:
            status = "alternative" if c.err >= 0.5 * table[by.kind].err else "redundant"
            out.append(replace(c, status=status, alternative_to=by.term.label))
        else:  # still adds something given the suggestion: say why it was not taken
            e, sg = search.err(extra, r)
            cond = score(search.best_of(k, e, sg) if search.best_of(k, e, sg) is not None else best1[k], base, names)
            why = cond.failed or (f"the suggestion holds max_terms={max_terms} terms",)
            out.append(replace(c, status="unselected", failed=tuple(f"given the suggestion: {w}" for w in why)))
    out = sorted(out, key=lambda c: (c.status != "suggested",
                                     chosen_kinds.index(c.kind) if c.status == "suggested" else 0))
    model = _joint(data, [c.term for c in chosen])
    lin = _linear(data, m2_kg, body_stiffness)
    notes = []
    if not chosen:
        notes.append("no nonlinear candidate met the thresholds: no form of the library explains what the "
                     "linear fit leaves")
    if lin["r2"] < 0.9:
        notes.append(f"the linear fit explains only {100 * lin['r2']:.0f} % of the force: the rest is noise or "
                     f"dynamics outside the one-mass equation of the output side (another mode, a second load "
                     f"path), which no nonlinearity of the element models")
    if rfs[0].band.f_lo_hz > 1.0:
        notes.append(f"the integration band starts at {rfs[0].band.f_lo_hz:g} Hz: motion below it is only partly "
                     f"in z, ż: the lowest mode of interest must lie above it")
    return Characterization(candidates=tuple(out), suggested=tuple(chosen), band=rfs[0].band,
                            thresholds=thresholds, records=tuple(_summary(rf, data, i) for i, rf in enumerate(rfs)),
                            linear=lin, model=model, m2_kg=m2_kg,
                            z_range_m=data.zmax, zdot_range_m_s=data.vmax, notes=tuple(notes))


def rank_beyond(rfs: Sequence[RestoringForce], declared: Sequence[Term], *, m2_kg: float | None = None,
                kinds: Sequence[str] = DEFAULT_KINDS, thresholds: Thresholds = Thresholds(),
                grid_points: int = 24, n_groups: int = 4,
                progress: Callable[[float], None] | None = None) -> tuple[Candidate, ...]:
    """Each kind's best candidate on top of a linear strut AND the ``declared`` terms, ranked by ERR.

    What a model holding ``declared`` still lacks (the tracing step of the
    loop, METHOD.md §5): the same grids, band-limiting and QR-orthogonalised
    scoring as :func:`characterize_restoring`, with the declared terms' regressors
    (coefficients refitted) in the base. ERR is then the fraction of what the
    linear + declared fit leaves that the candidate explains; every statistic of
    :class:`Candidate` is given the declared terms (``conditional_on``).
    A candidate identical to a declared term is not listed.
    """
    if not rfs:
        raise InputError("no restoring-force data to rank candidates on")
    kinds = tuple(dict.fromkeys(lookup_kind(k).name for k in kinds))
    declared = tuple(declared)
    data = _Data(rfs, n_groups=n_groups, body_stiffness=False)
    search = _Search(data, kinds, grid_points, progress)
    base = [data.regressor(t) for t in declared]
    extra, r = np.empty((data.rows.size, 0)), search.r0
    for b in base:  # orthonormal basis of the declared columns beyond the linear ones (subsample rows)
        v = b[data.rows] - search.q @ (search.q.T @ b[data.rows])
        if extra.shape[1]:
            v = v - extra @ (extra.T @ v)
        nv = float(np.linalg.norm(v))
        if nv > 1e-9 * max(float(np.linalg.norm(b[data.rows])), 1e-300):
            v = v / nv
            extra = np.column_stack([extra, v])
            r = r - v * (v @ r)
    e, sg = search.err(extra, r)
    n_grid = {k: len(search.grids[k]) for k in kinds}
    names = tuple(t.label for t in declared)
    out = []
    for k in kinds:
        ok = np.array([t not in declared for t in search.terms])
        j = search.best_of(k, np.where(ok, e, -1.0), sg)
        if j is None:  # only the unphysical sign: keep its best, to show why it fails
            j = search.best_of(k, np.where(ok, e, -1.0), np.ones_like(sg))
        if j is None or not ok[j]:
            continue
        out.append(_score(data, base, search.terms[j], thresholds=thresholds, n_grid=n_grid[k], m2=m2_kg,
                          names=names))
    return tuple(sorted(out, key=lambda c: -c.err))


def _joint(data: _Data, terms: list[Term]) -> "FittedModel":
    lin = data.x[:, data.lin]
    a = np.column_stack([lin, *[data.regressor(t) for t in terms]]) if terms else lin
    c = _lstsq(a, data.y)
    res = data.y - a @ c
    tss = float(data.y @ data.y)
    return FittedModel(k_per_kg=float(c[0]), c_per_kg=float(c[1]),
                       terms=tuple((t, float(th)) for t, th in zip(terms, c[len(data.lin):])),
                       r2=1.0 - float(res @ res) / tss if tss > 0 else 0.0)


def _linear(data: _Data, m2: float | None, body_stiffness: bool) -> dict:
    c = _lstsq(data.x, data.y)
    r = data.y - data.x @ c
    tss = float(data.y @ data.y)
    out = {"k_per_kg": float(c[0]), "c_per_kg": float(c[1]), "r2": 1.0 - float(r @ r) / tss if tss > 0 else 0.0}
    if body_stiffness:
        out["k3_per_kg"] = float(c[2])
    if data.forced and c[-1] < 0:                 # -ẍ2 = ... - F/M2
        out["m2_from_force_kg"] = -1.0 / float(c[-1])
    if m2 is not None:
        out.update(k2_n_per_m=float(c[0]) * m2, c2_n_s_per_m=float(c[1]) * m2)
        if body_stiffness:
            out["k3_n_per_m"] = float(c[2]) * m2
    return out


def _summary(rf: RestoringForce, data: _Data, i: int) -> RecordSummary:
    m = data.rec == i
    x, y = data.x[m][:, data.lin], data.y[m]
    coef = _lstsq(x, y)
    res = y - x @ coef
    return RecordSummary(source=rf.source, fs_hz=rf.fs_hz, duration_s=(rf.n + 2 * rf.start) / rf.fs_hz,
                         seconds_used=float(m.sum()) / rf.fs_hz,
                         z_rms_m=float(np.std(x[:, 0])), z_peak_m=float(np.max(np.abs(x[:, 0]))),
                         zdot_rms_m_s=float(np.std(x[:, 1])), zdot_peak_m_s=float(np.max(np.abs(x[:, 1]))),
                         k_per_kg=float(coef[0]), c_per_kg=float(coef[1]),
                         linear_r2=1.0 - float(res @ res) / float(y @ y))


def characterize(records: Record | Sequence[Record], *, band: IntegrationBand | None = None,
                 m2_kg: float | None = None, kinds: Sequence[str] = DEFAULT_KINDS,
                 thresholds: Thresholds = Thresholds(), grid_points: int = 24, max_terms: int = 3,
                 freq_window_hz: tuple[float, float] | None = None, body_stiffness: bool = False,
                 progress: Callable[[float], None] | None = None) -> Characterization:
    """Rank describing functions by how much of the restoring force they explain beyond linear.

    Parameters
    ----------
    records : Record or sequence of Record
        One record, or several at different excitation levels (same vehicle).
    band : IntegrationBand, optional
        Integration band for z, ż and the band-pass of every column; default
        :func:`~nifo_core.restoring.suggest_band` of the first record.
    m2_kg : float, optional
        Sprung mass [kg]: coefficients are then also given in N/m, N·s/m, N, ...
    kinds : sequence of str
        Kinds of :mod:`nifo_core.describing` to try (default :data:`DEFAULT_KINDS`).
    thresholds : Thresholds
        When a candidate counts as present.
    grid_points : int
        Grid points per parameter (then refined around each kind's best).
    max_terms : int
        Most terms in the suggested model.
    freq_window_hz : (float, float), optional
        Fit only the samples whose instantaneous frequency (tracked on the
        spindle signal, :func:`~nifo_core.restoring.track_frequency`) lies in
        this window: sweeps of multi-mode structures, where one linear k, c
        holds only near one mode.
    body_stiffness : bool
        Also fit K3·x2 (a rig restraint from body to ground), x2 integrated from
        ẍ2 alone. Off by default: x2 is a low-passed copy of the very signal
        being explained (y = -ẍ2), so the fit can lean on it; use it only when
        K3 ≠ 0 is known.
    progress : callable, optional
        Called with the fraction of the grid evaluated.

    Returns
    -------
    Characterization
    """
    recs = [records] if isinstance(records, Record) else list(records)
    if not recs:
        raise InputError("no records to characterize")
    if band is None:
        band = suggest_band(recs[0]).band
    rfs = [restoring_force(r, band=band, body_displacement=body_stiffness) for r in recs]
    masks = None
    if freq_window_hz is not None:
        lo, hi = (float(v) for v in freq_window_hz)
        if not 0 < lo < hi:
            raise ConfigError(f"frequency window {lo:g}-{hi:g} Hz must satisfy 0 < lo < hi")
        masks = [(f >= lo) & (f <= hi) for f in (instantaneous_frequency(rf.spindle_accel, rf.fs_hz) for rf in rfs)]
    return characterize_restoring(rfs, m2_kg=m2_kg, kinds=kinds, thresholds=thresholds,
                                  grid_points=grid_points, max_terms=max_terms, body_stiffness=body_stiffness,
                                  masks=masks, progress=progress)


def _describe(c: Candidate) -> str:
    t, th = c.term, c.theta
    p = t.params
    if t.kind == "cubic_stiffness":
        return f"{'hardening' if th > 0 else 'softening'} cubic stiffness"
    if t.kind == "clearance":
        how = "stiffens (clearance/contact)" if th > 0 else "softens (saturation)"
        return f"stiffness {how} beyond ±{1e3 * p['gap']:.3g} mm"
    if t.kind == "saturation":
        return f"stiffness saturates beyond ±{1e3 * p['limit']:.3g} mm"
    if t.kind == "bump_stop":
        return (f"one-sided {'stiffening' if th > 0 else 'softening'} beyond {1e3 * p['gap']:.3g} mm "
                f"of {p['side']} (from the mean position)")
    if t.kind == "backlash":
        if th < 0:
            return (f"spring in series with dry friction (stick-slip, Jenkins element): slips after "
                    f"{1e3 * p['deadband']:.3g} mm of reversal")
        return f"hysteretic stiffness through a play of {1e3 * p['deadband']:.3g} mm"
    if t.kind == "velocity_deadzone":
        how = "rises (progressive)" if th > 0 else "drops (digressive, blow-off)"
        return f"damping {how} beyond ±{p['knee']:.3g} m/s"
    if t.kind == "velocity_saturation":
        return f"damping force saturates beyond ±{p['limit']:.3g} m/s"
    if t.kind == "coulomb":
        return "dry friction"
    if t.kind == "quadratic_damping":
        return f"velocity-squared damping ({'adds' if th > 0 else 'removes'} damping at speed)"
    if t.kind == "asymmetric_damping":
        return f"extra damping in {p['side']}"
    return t.spec.description  # pragma: no cover
