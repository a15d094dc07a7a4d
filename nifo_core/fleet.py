"""The fleet's pure parts: tree reduction of partial accumulations, and strut health.

A fleet is many records of many vehicles. Each record (bag) gives a partial
spectral accumulation (a :class:`~nifo_core.nifo.identify.StreamingNifo` state); the
partials of one group (vehicle, corner) merge exactly (sums of block
cross-spectra, paper Eq. 8's G matrices) in any order, so they are reduced as
a tree: ⌈log_f n⌉ levels of f-way merges instead of one long chain, which a
scheduler runs in parallel. :func:`reduction_plan` gives the tree,
:func:`tree_reduce` runs it in-process (the Dask shell submits the same plan).

Strut health compares every group's identified coefficients with the rest of
the fleet. For one coefficient x (e.g. C2/M2) over the groups with enough data:

    m = median(x),   s = max(1.4826·MAD(x), rel_floor·|m|),   z = (x - m)/s

(the robust z-score: median and scaled median absolute deviation are not
dragged by the outliers they are meant to find; then m and s are re-estimated
on the values within 2.5 s of m, see :func:`robust_z`). A group is flagged on that
coefficient when |z| > ``z_limit`` AND its deviation exceeds ``se_factor``
times its own standard error (the spread of its per-record estimates over
√n): a deviation the group's own data cannot resolve is not a finding. Never
from too little data: a group with fewer than ``min_records`` records or
``min_duration_s`` seconds is "not assessed", and with fewer than
``min_groups`` assessable groups nobody is flagged (there is no fleet to
compare with).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Hashable, Mapping, Sequence, TypeVar

import numpy as np

from .errors import ConfigError

__all__ = ["batch_plan", "reduction_plan", "tree_reduce", "standard_error", "interval_halfwidth", "Estimate", "HealthSettings", "CoefficientHealth",
           "GroupHealth", "robust_z", "assess_health", "MAD_TO_SIGMA"]

T = TypeVar("T")

#: 1/Φ⁻¹(3/4): the MAD of a normal sample times this estimates σ
MAD_TO_SIGMA = 1.482602218505602


# ---------------------------------------------------------------------------------------------
# tree reduction
# ---------------------------------------------------------------------------------------------
def batch_plan(group_sizes: Sequence[int], *, n_workers: int, batch: int | None = None,
               tasks_per_worker: int = 8, max_batch: int = 32) -> list[list[tuple[int, range, bool]]]:
    """Cut items that come in groups into tasks of several items each.

    Each task is a list of (group number, range of that group's items, whole:
    the range is the whole group). Tasks hold about ``target`` items: ``batch``
    when given, else ``ceil(n / (tasks_per_worker * n_workers))`` at most
    ``max_batch`` (a few tasks per worker, enough to balance the load at the end
    of a run, each carrying many items, so the scheduler's cost per task is spread
    over them). Small groups are packed whole into one task up to ``target``; a
    group of up to ``max_batch`` items (``batch`` when given) is never split (its
    task may then exceed ``target``); a larger one is cut into ranges of ``target``.

    Examples
    --------
    >>> batch_plan([2, 2, 5], n_workers=1, batch=4)
    [[(0, range(0, 2), True), (1, range(0, 2), True)], [(2, range(0, 4), False)], [(2, range(4, 5), False)]]
    >>> [sum(len(r) for _, r, _ in t) for t in batch_plan([10] * 20, n_workers=2)]   # a vehicle per task
    [10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10]
    """
    sizes = [int(m) for m in group_sizes]
    if any(m < 0 for m in sizes):
        raise ConfigError(f"group sizes {sizes!r} must be whole numbers >= 0")
    if isinstance(n_workers, bool) or int(n_workers) != n_workers or n_workers < 1:
        raise ConfigError(f"n_workers={n_workers!r} must be a whole number >= 1")
    if batch is not None and (isinstance(batch, bool) or int(batch) != batch or batch < 1):
        raise ConfigError(f"batch={batch!r} must be a whole number of items per task >= 1")
    n = sum(sizes)
    target = int(batch) if batch else min(max(1, -(-n // (tasks_per_worker * int(n_workers)))), max_batch)
    limit = int(batch) if batch else max(max_batch, target)
    tasks: list[list[tuple[int, range, bool]]] = []
    cur: list[tuple[int, range, bool]] = []
    filled = 0
    for g, m in enumerate(sizes):
        if m == 0:
            continue
        if m > limit:                       # too large for one task: cut (the group's set-up is fixed later)
            if cur:
                tasks.append(cur)
                cur, filled = [], 0
            tasks.extend([[(g, range(i, min(i + target, m)), False)] for i in range(0, m, target)])
            continue
        if cur and filled + m > target:
            tasks.append(cur)
            cur, filled = [], 0
        cur.append((g, range(m), True))
        filled += m
    if cur:
        tasks.append(cur)
    return tasks


def reduction_plan(n: int, *, fanout: int = 2) -> list[list[tuple[int, ...]]]:
    """The levels of a ``fanout``-way tree merging ``n`` items into one.

    Level ``k`` is a list of index tuples into the items of level ``k - 1``
    (level 0: the inputs); each tuple is merged into one item of level ``k``.
    A tuple of one index passes an item up unchanged. ``n == 1`` gives no level.

    Examples
    --------
    >>> reduction_plan(5)
    [[(0, 1), (2, 3), (4,)], [(0, 1), (2,)], [(0, 1)]]
    """
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise ConfigError(f"n={n!r} must be a whole number of items >= 1")
    if isinstance(fanout, bool) or int(fanout) != fanout or fanout < 2:
        raise ConfigError(f"fanout={fanout!r} must be a whole number >= 2")
    levels, width = [], int(n)
    while width > 1:
        level = [tuple(range(i, min(i + fanout, width))) for i in range(0, width, fanout)]
        levels.append(level)
        width = len(level)
    return levels


def tree_reduce(items: Sequence[T], merge: Callable[[T, T], T], *, fanout: int = 2) -> T:
    """Merge ``items`` pairwise along :func:`reduction_plan` (``merge(a, b)`` must be associative)."""
    cur = list(items)
    if not cur:
        raise ConfigError("nothing to reduce: no items", hint="give at least one partial")
    for level in reduction_plan(len(cur), fanout=fanout):
        nxt = []
        for idx in level:
            acc = cur[idx[0]]
            for i in idx[1:]:
                acc = merge(acc, cur[i])
            nxt.append(acc)
        cur = nxt
    return cur[0]


# ---------------------------------------------------------------------------------------------
# uncertainty of a group's coefficient
# ---------------------------------------------------------------------------------------------
def standard_error(per_record: Sequence[float]) -> float:
    """Standard error of a mean from per-record estimates: std(ddof=1)/√n; NaN below 2 finite values."""
    x = np.asarray(per_record, float)
    x = x[np.isfinite(x)]
    if x.size < 2:
        return float("nan")
    return float(np.std(x, ddof=1) / np.sqrt(x.size))


def interval_halfwidth(se: float, n: int, *, level: float = 0.95) -> float:
    """Half-width of the ``level`` confidence interval of a mean of ``n`` values: t_{n-1}·SE (NaN below n = 2).

    Student's t, not 2·SE: with the few records of one vehicle (n = 2: t = 12.7)
    the normal quantile would claim far too much.
    """
    from scipy.stats import t

    if n < 2 or not np.isfinite(se):
        return float("nan")
    return float(t.ppf(0.5 + level / 2, n - 1) * se)


@dataclass(frozen=True)
class Estimate:
    """One coefficient of one group: the value from all its data, its standard error, how much data.

    Parameters
    ----------
    value : float
        Estimate from the group's merged spectra [unit of the coefficient].
    se : float
        Standard error (NaN when unknown, e.g. from one record).
    n_records : int
        Records (bags) that entered the estimate.
    duration_s : float
        Seconds of data used [s].
    """

    value: float
    se: float
    n_records: int
    duration_s: float


@dataclass(frozen=True)
class HealthSettings:
    """When a group counts as deviating from the fleet (module docstring).

    Parameters
    ----------
    z_limit : float
        |robust z| above which a coefficient deviates (3.5: Iglewicz & Hoaglin's outlier rule).
    se_factor : float
        The deviation from the fleet median must also exceed this many of the group's own standard errors.
    min_records : int
        Fewest records (bags) a group needs to be assessed (2: a standard error needs two).
    min_duration_s : float
        Fewest seconds of data a group needs to be assessed [s].
    min_groups : int
        Fewest assessable groups that make a fleet to compare with.
    rel_floor : float
        Floor of the robust scale as a fraction of |median|, so a fleet of near-identical
        struts does not flag a 1 % difference.
    """

    z_limit: float = 3.5
    se_factor: float = 2.0
    min_records: int = 2
    min_duration_s: float = 60.0
    min_groups: int = 5
    rel_floor: float = 0.02

    def __post_init__(self) -> None:
        for name in ("z_limit", "se_factor", "min_duration_s", "rel_floor"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"{name}={getattr(self, name)!r} must be a finite number >= 0")
        if self.z_limit <= 0:
            raise ConfigError(f"z_limit={self.z_limit!r} must be > 0", hint="e.g. 3.5")
        if int(self.min_records) < 2:
            raise ConfigError(f"min_records={self.min_records!r} must be at least 2 (a standard error needs two)")
        if int(self.min_groups) < 3:
            raise ConfigError(f"min_groups={self.min_groups!r} must be at least 3 (a median of fewer is no fleet)")

    def to_dict(self) -> dict:
        return {"z_limit": self.z_limit, "se_factor": self.se_factor, "min_records": int(self.min_records),
                "min_duration_s": self.min_duration_s, "min_groups": int(self.min_groups),
                "rel_floor": self.rel_floor}


@dataclass(frozen=True)
class CoefficientHealth:
    """One coefficient of one group against the fleet.

    ``z`` is NaN and ``flagged`` False when the group or the fleet could not be
    assessed (``note`` says why).
    """

    name: str
    value: float
    se: float
    fleet_median: float
    fleet_scale: float
    z: float
    flagged: bool
    note: str = ""

    @property
    def deviation(self) -> float:
        """Relative deviation from the fleet median (x/m - 1)."""
        return float(self.value / self.fleet_median - 1) if self.fleet_median else float("nan")

    def to_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "se": self.se, "fleet_median": self.fleet_median,
                "fleet_scale": self.fleet_scale, "z": self.z, "flagged": self.flagged, "note": self.note,
                "deviation": self.deviation}


@dataclass(frozen=True)
class GroupHealth:
    """All coefficients of one group; ``assessed`` False with ``reason`` when there was too little data."""

    group: Hashable
    assessed: bool
    reason: str
    coefficients: tuple[CoefficientHealth, ...] = field(default_factory=tuple)

    @property
    def flagged(self) -> bool:
        return any(c.flagged for c in self.coefficients)

    @property
    def evidence(self) -> tuple[str, ...]:
        """One sentence per flagged coefficient."""
        return tuple(c.note for c in self.coefficients if c.flagged)

    def to_dict(self) -> dict:
        return {"assessed": self.assessed, "reason": self.reason, "flagged": self.flagged,
                "evidence": list(self.evidence), "coefficients": [c.to_dict() for c in self.coefficients]}


def _truncated_sd_ratio(a: float) -> float:
    """σ of a standard normal truncated at ±a (scipy-free: erf from math)."""
    from math import erf, exp, pi, sqrt

    phi = exp(-a * a / 2) / sqrt(2 * pi)
    return sqrt(1 - 2 * a * phi / erf(a / sqrt(2)))


def robust_z(values: Sequence[float], *, rel_floor: float = 0.0, clip: float | None = 2.5,
             min_inliers: int = 3) -> tuple[float, float, np.ndarray]:
    """Centre, scale and z-scores of ``values``, robust to the outliers they are meant to find.

    Step 1: centre = median, scale = 1.4826·MAD. Step 2 (``clip``): values
    within ``clip`` step-1 scales of the median are the inliers; centre =
    their median, scale = their standard deviation over the σ-ratio of a
    normal truncated at ±clip (0.955 at 2.5), so the scale is consistent for
    normal data. Step 2 matters for small fleets: with 3 outliers among 10
    values the MAD alone is inflated ~1.5× and hides a 30 % fault. The scale
    is floored at ``rel_floor·|centre|``. NaN values are left out and get
    z = NaN; a zero scale gives z = 0 for values at the centre, ±inf otherwise.
    """
    x = np.asarray(values, float)
    ok = np.isfinite(x)
    if not ok.any():
        return float("nan"), float("nan"), np.full(x.shape, np.nan)
    med = float(np.median(x[ok]))
    scale = MAD_TO_SIGMA * float(np.median(np.abs(x[ok] - med)))
    if clip is not None and scale > 0:
        inl = x[ok][np.abs(x[ok] - med) <= clip * scale]
        if inl.size >= max(min_inliers, 2):
            med = float(np.median(inl))
            scale = float(np.std(inl, ddof=1)) / _truncated_sd_ratio(clip)
    scale = max(scale, float(rel_floor) * abs(med))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(ok, (x - med) / scale, np.nan) if scale > 0 else np.where(ok, np.sign(x - med) * np.inf, np.nan)
        z = np.where(ok & (x == med), 0.0, z)
    return med, scale, z


def _too_little(e: Sequence[Estimate], s: HealthSettings) -> str:
    n = max((x.n_records for x in e), default=0)
    dur = max((x.duration_s for x in e), default=0.0)
    if n < s.min_records:
        return f"{n} record(s) (at least {s.min_records} are needed to assess a strut)"
    if dur < s.min_duration_s:
        return f"{dur:.0f} s of data (at least {s.min_duration_s:g} s are needed to assess a strut)"
    return ""


def assess_health(estimates: Mapping[Hashable, Mapping[str, Estimate]], *,
                  settings: HealthSettings = HealthSettings(),
                  units: Mapping[str, str] | None = None) -> dict[Hashable, GroupHealth]:
    """Robust z-score of every coefficient of every group against the fleet (module docstring).

    Parameters
    ----------
    estimates : mapping group -> (mapping coefficient name -> Estimate)
        Groups may lack coefficients (e.g. a different model file): each
        coefficient is compared over the groups that have it.
    settings : HealthSettings
    units : mapping coefficient name -> unit text, optional
        For the evidence sentences.

    Returns
    -------
    dict group -> GroupHealth
        In the order of ``estimates``.
    """
    units = dict(units or {})
    s = settings
    reasons = {g: _too_little(list(e.values()), s) for g, e in estimates.items()}
    assessable = [g for g, r in reasons.items() if not r]
    names = list(dict.fromkeys(n for e in estimates.values() for n in e))
    per_coef: dict[str, tuple[float, float, dict]] = {}
    for name in names:
        gs = [g for g in assessable if name in estimates[g] and np.isfinite(estimates[g][name].value)]
        if len(gs) < s.min_groups:
            per_coef[name] = (float("nan"), float("nan"), {})
            continue
        med, scale, z = robust_z([estimates[g][name].value for g in gs], rel_floor=s.rel_floor)
        per_coef[name] = (med, scale, dict(zip(gs, z)))
    out: dict[Hashable, GroupHealth] = {}
    for g, est in estimates.items():
        coefs = []
        for name, e in est.items():
            med, scale, zs = per_coef[name]
            u = units.get(name, "")
            if reasons[g]:
                coefs.append(CoefficientHealth(name, e.value, e.se, med, scale, float("nan"), False,
                                               f"not assessed: {reasons[g]}"))
                continue
            if g not in zs:
                n_ok = sum(1 for gg in assessable if name in estimates[gg] and np.isfinite(estimates[gg][name].value))
                why = ("its value is not finite" if not np.isfinite(e.value)
                       else f"only {n_ok} group(s) with enough data have it (at least {s.min_groups} make a fleet)")
                coefs.append(CoefficientHealth(name, e.value, e.se, med, scale, float("nan"), False,
                                               f"not assessed: {why}"))
                continue
            z = float(zs[g])
            resolved = np.isfinite(e.se) and abs(e.value - med) > s.se_factor * e.se
            flagged = bool(abs(z) > s.z_limit and resolved)
            ratio = e.value / med if med else float("nan")
            note = (f"{name} = {e.value:.4g} {u} is {ratio:.2f}× the fleet median {med:.4g} {u} "
                    f"(robust z {z:+.1f}, limit ±{s.z_limit:g}; ±{s.se_factor:g} SE of this group "
                    f"±{s.se_factor * e.se:.2g} {u}; {e.n_records} records, {e.duration_s:.0f} s)")
            if abs(z) > s.z_limit and not resolved:
                note += "; not flagged: the group's own uncertainty covers the deviation"
            coefs.append(CoefficientHealth(name, e.value, e.se, med, scale, z, flagged, note.replace("  ", " ")))
        out[g] = GroupHealth(g, not reasons[g], reasons[g], tuple(coefs))
    return out
