"""Results of the automatic characterization (:mod:`nifo_core.characterize.automatic`): thresholds, candidates, the
suggested model and the per-record summary, with their JSON form and one-line meaning."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..kinds.describing import DEFAULT_KINDS, Term, kind as lookup_kind
from ..errors import ConfigError
from ..signal.integrate import IntegrationBand
from .restoring import bandpass

__all__ = ["Thresholds", "Candidate", "Equivalence", "FittedModel", "Characterization", "RecordSummary",
           "DEFAULT_KINDS"]


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
    theta_half_width : float
        Half-width of the 95 % bound of ``theta`` (random error, N_eff degrees of freedom as the F-test;
        :mod:`nifo_core.signal.uncertainty`); times M2 for ``coefficient``.
    offsets : tuple of float
        A bump stop's ``offset`` [m] on every record: where the static position lies in z measured
        from the record's mean (the gap is from the static position; :mod:`.characterize_static`).
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
    offsets: tuple[float, ...] = ()
    theta_half_width: float = float("nan")

    @property
    def m2_factor(self) -> float | None:
        """M2 [kg] (coefficient/θ) when the coefficient is known in physical units."""
        return None if self.coefficient is None or self.theta == 0 else self.coefficient / self.theta

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
        return describe(self)

    def to_dict(self) -> dict:
        kp = self.key_param
        return {"kind": self.kind, "params": dict(self.term.params), "label": self.term.label,
                "key_param": None if kp is None else {"name": kp[0], "value": kp[1],
                                                       "relative_to_range": self.relative_param},
                "theta_per_kg": self.theta, "coefficient": self.coefficient,
                "theta_half_width_per_kg": _finite(self.theta_half_width),
                "coefficient_half_width": None if self.coefficient is None or self.m2_factor is None
                else _finite(self.theta_half_width * self.m2_factor),
                "coefficient_unit": self.term.spec.coef_unit,
                "err": self.err, "delta_r2": self.delta_r2, "err_cv": self.err_cv, "p_value": self.p_value,
                "n_eff": self.n_eff, "spread": _finite(self.spread), "group_theta": list(self.group_theta),
                "present": self.present, "status": self.status, "alternative_to": self.alternative_to,
                "conditional_on": list(self.conditional_on), "equivalent": self.equivalent,
                "failed": list(self.failed), "meaning": self.describe(),
                "offset_per_record_m": list(self.offsets)}


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
class Equivalence:
    """A suggested term and the terms of other kinds these data cannot tell from it (an ambiguity, named).

    Each alternative, in the suggested term's place beside the other suggested terms, explains as much of what
    those leave: the F-test of the difference of their residuals does not reach the significance a term needs
    (``p_value`` ≥ the threshold's alpha). The suggested one explains most; both are named, neither is dropped
    silently.
    """

    suggested: Candidate
    alternatives: tuple[Candidate, ...]
    p_values: tuple[float, ...]

    @property
    def kinds(self) -> tuple[str, ...]:
        return (self.suggested.kind, *(a.kind for a in self.alternatives))

    def text(self) -> str:
        opts = [self.suggested, *self.alternatives]
        names = " or ".join(f"{describe(c)} ({c.term.label}{_coef_text(c)})" for c in opts)
        how = ", ".join(f"{100 * c.err:.3g} %" for c in opts)
        return (f"{names}: these data cannot tell them apart (each explains {how} of what the other terms leave; "
                f"p = {', '.join(f'{p:.2g}' for p in self.p_values)} for the difference); a record at higher "
                f"amplitude (or lower noise) would. The suggested model holds the first")

    def to_dict(self) -> dict:
        return {"kinds": list(self.kinds), "suggested": self.suggested.term.label,
                "options": [c.to_dict() for c in (self.suggested, *self.alternatives)],
                "p_values": list(self.p_values), "text": self.text()}


def _coef_text(c: Candidate) -> str:
    if c.coefficient is None:
        return f", {c.theta:.3g} {c.term.spec.coef_unit}/kg"
    return f", {c.coefficient:.3g} {c.term.spec.coef_unit}"


@dataclass(frozen=True)
class Characterization:
    """Result of :func:`characterize`.

    ``candidates`` holds each kind's best form: the suggested terms first, in
    selection order (with their statistics given the terms before them), then
    the others ranked by the variance they explain beyond linear on their own;
    ``suggested`` the terms of the suggested model (empty: nothing nonlinear found); ``ambiguities`` the
    suggested terms that other kinds explain as well (:class:`Equivalence`: named, not suggested beside them).
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
    ambiguities: tuple[Equivalence, ...] = ()
    #: each record's mean position from the static one [m] (rebound positive) when the forms of z were measured
    #: from the static position (the suggested terms' mean force moves it: :mod:`.static`); None: from the means
    mean_position_m: tuple[float, ...] | None = None

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
                "ambiguities": [a.to_dict() for a in self.ambiguities],
                "candidates": [c.to_dict() for c in self.candidates],
                "records": [r.to_dict() for r in self.records], "notes": list(self.notes),
                "mean_position_from_static_m": None if self.mean_position_m is None else list(self.mean_position_m)}


def describe(c: Candidate) -> str:
    """What a candidate means in a test engineer's words (``Kind.describe``)."""
    return c.term.spec.describe(c.term, c.theta, from_static=bool(c.offsets))
