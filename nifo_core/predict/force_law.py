"""The strut's force law: its force against deflection and against velocity, each term and the total.

A model's strut force per unit body mass (docs/method.md §2, paper Eq. 1-2 / M2) is::

    F/M2 = k·z + c·ż + Σ γ_i·g_i(z, ż)        (k = K2/M2, c = C2/M2, γ_i = c_i/M2)

The **stiffness characteristic** is that force against the deflection z with ż = 0 (the linear
spring k·z and the terms in z), the **damping characteristic** against the velocity ż with z = 0
(the linear damper c·ż and the terms in ż): the two curves in which springs and dampers are exchanged
between test and simulation groups. A hysteretic term (the play) has no single curve: it is traced
over one steady cycle of the grid (down from its top, then up), so its table has a decreasing and an
increasing branch. A rational (flexible) linear part has no k, c: its curves hold the terms alone
(the linear part is a transfer function; :meth:`~nifo_core.predict.linear_part.LinearPart.state_space`).

Forces are per kg of the body mass M2 unless the mass is known (``scale=M2``: newtons).
:func:`force_law_bounds` carries a refined model's parameter covariance
(:func:`~nifo_core.predict.refine_space.parameter_space`) to 95 % bounds of each curve's total.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Mapping, Sequence

import numpy as np

from ..errors import ConfigError
from ..kinds.describing import Term, make_term
from ..signal.integrate import IntegrationBand, integrate
from ..signal.record import Record
from .model import IdentifiedModel
from .refine_space import parameter_space

__all__ = ["StrutLaw", "Characteristic", "strut_law", "characteristic", "force_law_bounds", "truth_law",
           "motion_range", "Variable", "Branch"]

Variable = Literal["z", "zdot"]
Branch = Literal["decreasing", "increasing", "any"]


@dataclass(frozen=True)
class StrutLaw:
    """The strut's force law per kg of M2: linear spring k [1/s²] and damper c [1/s] (None for a rational linear
    part), and the terms with their coefficients γ_i [unit of c_i per kg]."""

    terms: tuple[Term, ...]
    gammas: tuple[float, ...]
    k: float | None
    c: float | None

    def __post_init__(self) -> None:
        if len(self.terms) != len(self.gammas):
            raise ConfigError(f"{len(self.terms)} terms but {len(self.gammas)} coefficients")

    def hysteretic(self, variable: Variable) -> bool:
        return any(t.spec.hysteretic and t.variable == variable for t in self.terms)


@dataclass(frozen=True, eq=False)
class Characteristic:
    """Force against one variable (the other held at zero) on one branch of travel [force per kg, or N].

    Attributes
    ----------
    variable : {'z', 'zdot'}
    x : ndarray, shape (n,)
        The grid, ascending [m or m/s].
    branch : {'decreasing', 'increasing', 'any'}
        The direction of travel ('any': no hysteretic term acts in this variable).
    linear : ndarray, shape (n,) or None
        The linear spring k·z or damper c·ż (None: a rational linear part).
    terms : ndarray, shape (n_terms, n)
        Each term's γ_i·g_i (zero for a term in the other variable).
    """

    variable: Variable
    x: np.ndarray
    branch: Branch
    linear: np.ndarray | None
    terms: np.ndarray

    @property
    def total(self) -> np.ndarray:
        return self.terms.sum(axis=0) + (0.0 if self.linear is None else self.linear)


def strut_law(model: IdentifiedModel) -> StrutLaw:
    """The force law of an identified model: its nominal one-mass body's k, c (the terms carry their whole
    linear part), or none for a rational linear part."""
    body = model.body if model.linear.kind == "body" else None
    return StrutLaw(tuple(model.terms), tuple(float(g) for g in model.c_over_m2),
                    None if body is None else float(body.k), None if body is None else float(body.c))


def truth_law(vehicle: Mapping, strut: Sequence[Mapping]) -> StrutLaw:
    """The simulator's strut (a truth file's ``vehicle`` and ``strut``) as a force law per kg of its M2."""
    m2 = float(vehicle["m2"])
    return StrutLaw(tuple(make_term(s) for s in strut), tuple(float(s["coefficient"]) / m2 for s in strut),
                    float(vehicle["k2"]) / m2, float(vehicle["c2"]) / m2)


def _cycle(x: np.ndarray) -> tuple[np.ndarray, slice, slice]:
    """Two cycles over the grid (down from the top, then up; twice: the second is steady) and where its
    decreasing and increasing branches are (each in the grid's ascending order once reversed)."""
    down, up = x[::-1], x
    n = x.size
    return np.concatenate([down, up, down, up]), slice(2 * n, 3 * n), slice(3 * n, 4 * n)


def characteristic(law: StrutLaw, x, variable: Variable, *, scale: float = 1.0) -> tuple[Characteristic, ...]:
    """The force against ``x`` (z [m] or ż [m/s], ascending) with the other variable at zero: one curve, or a
    decreasing and an increasing branch when a hysteretic term acts in this variable. ``scale``: M2 [kg] for
    newtons (default per kg)."""
    if variable not in ("z", "zdot"):
        raise ConfigError(f"variable={variable!r} must be 'z' or 'zdot'")
    x = np.asarray(x, float)
    if x.ndim != 1 or x.size < 2 or not np.all(np.diff(x) > 0):
        raise ConfigError("the grid must be one ascending array of at least two values")
    lin_coef = law.k if variable == "z" else law.c
    linear = None if lin_coef is None else scale * lin_coef * x
    if not law.hysteretic(variable):
        path, branches = x, [("any", slice(0, x.size))]
    else:
        path, dec, inc = _cycle(x)
        branches = [("decreasing", dec), ("increasing", inc)]
    zero = np.zeros_like(path)
    arg = (path, zero) if variable == "z" else (zero, path)
    g = np.array([scale * gam * t.evaluate(*arg) if t.variable == variable else np.zeros_like(path)
                  for t, gam in zip(law.terms, law.gammas)]).reshape(len(law.terms), path.size)
    out = []
    for name, sl in branches:
        part = g[:, sl]
        if name == "decreasing":
            part = part[:, ::-1]
        out.append(Characteristic(variable, x, name, linear, part))
    return tuple(out)


def force_law_bounds(model: IdentifiedModel, x, variable: Variable, *, scale: float = 1.0,
                     step: float = 1e-4) -> tuple[np.ndarray, ...] | None:
    """95 % half-widths of each branch's total force (:func:`characteristic`'s order) from the refined model's
    parameter covariance, by first-order propagation (central differences in the covariance's own coordinates:
    relative coefficients and log factors); None when the model carries no covariance (not refined)."""
    space = parameter_space(model)
    if space is None:
        return None
    to_model, theta, cov = space.to_model, space.theta, space.cov

    def totals(th: np.ndarray) -> np.ndarray:
        return np.array([c.total for c in characteristic(strut_law(to_model(th)), x, variable, scale=scale)])

    base = totals(theta)
    jac = np.empty((theta.size,) + base.shape)
    for j in range(theta.size):
        d = np.zeros_like(theta)
        d[j] = step
        jac[j] = (totals(theta + d) - totals(theta - d)) / (2 * step)
    var = np.einsum("i...,ij,j...->...", jac, cov, jac)
    return tuple(1.96 * np.sqrt(np.maximum(v, 0.0)) for v in var)


def motion_range(records: Sequence[Record], band: IntegrationBand) -> dict:
    """The strut's measured range over ``records``: smallest and largest deflection z [m] and velocity ż [m/s],
    integrated from ẍ2 - ẍ1 with ``band`` as identification does, start-up edges left out."""
    zs, vs = [], []
    for rec in records:
        got = integrate(np.asarray(rec.body_accel) - np.asarray(rec.spindle_accel), rec.fs_hz, band=band)
        v = got.valid
        if v.stop - v.start < 2:
            continue
        zs.append((float(np.min(got.displacement[v])), float(np.max(got.displacement[v]))))
        vs.append((float(np.min(got.velocity[v])), float(np.max(got.velocity[v]))))
    if not zs:
        raise ConfigError("no record is longer than the integrator's start-up edges: no measured range")
    return {"deflection_m": [min(a for a, _ in zs), max(b for _, b in zs)],
            "velocity_m_s": [min(a for a, _ in vs), max(b for _, b in vs)],
            "how": f"smallest and largest z, ż over {len(zs)} record(s), integrated from ẍ2 - ẍ1 in "
                   f"{band.f_lo_hz:.3g}-{band.f_hi_hz:.4g} Hz, start-up edges left out"}
