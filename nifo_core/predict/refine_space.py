"""The output-error refinement's parameter space: θ ↔ model, its bounds, the names and values it reports, and the
covariance stored with a refined model and rebuilt from it (:func:`parameter_space`, for prediction bounds and the
bias correction). Split from :mod:`nifo_core.predict.refine` (issue 58), which runs the least squares over it.

θ: the terms' coefficients relative to their start's scale, then log factors of the refined key parameters (a gap,
a knee), of a one-mass body's k and c and of a measured force's gain 1/M2, then a rational linear part's residue
changes (re, im per pole pair, in units of |r|).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Callable, Mapping

import numpy as np

from ..kinds.describing import KINDS, Term
from .linear_part import BodyModel, absorbed_rates
from .model import IdentifiedModel
from .sensitivity import BODY_C, BODY_K, FORCE_GAIN, GAMMA, SHAPE, Parameters

__all__ = ["Space", "space_for", "terms_on", "reported_values", "half_widths", "stored_covariance", "ParameterSpace",
           "parameter_space", "moved_refinement"]

#: range of a key parameter around its start (factor)
_SHAPE_RANGE = 4.0


def _blocks(a: np.ndarray) -> bool:
    """A is block diagonal in 2×2 and 1×1 blocks (so is e^{A·h}): what the sensitivity march takes."""
    nz = a != 0
    cols = np.arange(a.shape[1])
    return all(not row.any() or np.ptp(cols[row]) <= 1 for row in nz)


@dataclass(frozen=True)
class Space:
    """θ ↔ model for one starting model."""

    base: IdentifiedModel
    gamma_scale: np.ndarray
    shape_idx: tuple[int, ...]        # terms whose key parameter is refined
    body: bool                        # refine k, c of a one-mass body
    track_absorbed: bool = False      # absorbed = absorbed_rates(terms, γ) as γ moves (bounded feedback)
    residues: bool = False            # refine a rational linear part's residues (poles kept)
    force: bool = False               # refine a measured force's gain 1/M2 (log scale)

    @functools.cached_property
    def _pairs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(upper members of the conjugate pairs, their partners, real poles, |r| of the upper ones: the scale)."""
        if not self.residues:
            return (np.zeros(0, int),) * 3 + (np.zeros(0),)
        p, r = self.base.linear.poles, self.base.linear.residues
        up = np.flatnonzero(p.imag > 0)
        lo = np.array([int(np.argmin(np.abs(p - np.conj(p[k])))) for k in up], int)
        real = np.flatnonzero(p.imag == 0)
        scale = np.abs(r[up])
        return up, lo, real, np.where(scale > 0, scale, max(float(scale.max(initial=0.0)), 1e-12))

    @property
    def n_residues(self) -> int:
        return 2 * self._pairs[0].size

    @functools.cached_property
    def hz(self) -> np.ndarray:
        """(1 - T21)/ω² on the model's lines: B_i = γ_i·hz (paper Eq. 8 with constant coefficients)."""
        w = 2 * np.pi * self.base.freq_hz
        with np.errstate(divide="ignore", invalid="ignore"):
            return (1 - self.base.t21) / np.where(w > 0, w, np.nan) ** 2

    @property
    def n_linear(self) -> int:
        """Log factors of the linear part's physical parameters: a one-mass body's k and c, a force's 1/M2."""
        return (2 if self.body else 0) + (1 if self.force else 0)

    @property
    def size(self) -> int:
        return self.gamma_scale.size + len(self.shape_idx) + self.n_linear + self.n_residues

    def x0(self, gammas: np.ndarray) -> np.ndarray:
        return np.concatenate([gammas / self.gamma_scale,
                               np.zeros(len(self.shape_idx) + self.n_linear + self.n_residues)])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        nt, ns, nr = self.gamma_scale.size, len(self.shape_idx), self.n_residues
        lo = np.concatenate([np.full(nt, -np.inf), np.full(ns, -np.log(_SHAPE_RANGE)),
                             np.full(self.n_linear, -2.0), np.full(nr, -np.inf)])
        hi = np.concatenate([np.full(nt, np.inf), np.full(ns, np.log(_SHAPE_RANGE)),
                             np.full(self.n_linear, 2.0), np.full(nr, np.inf)])
        return lo, hi

    def _linear(self, lin, dx: np.ndarray):
        """The rational linear part with residues r + Δr (Δr = dx·|r| per pair, re then im), Σ r kept at 0
        (relative degree 2: z and ż stay states) by one shift of the pairs' real parts; the poles kept."""
        up, lo, real, scale = self._pairs
        k = up.size
        r = np.array(self.base.linear.residues, complex)
        r[up] = r[up] + (dx[:k] + 1j * dx[k:]) * scale
        total = 2 * float(np.sum(r[up]).real) + float(np.sum(r[real]).real)
        r[up] -= total / (2 * k)
        r[lo] = np.conj(r[up])
        return replace(lin, residues=r)

    def march_parameters(self, model: IdentifiedModel) -> Parameters | None:
        """θ as the sensitivity march takes it (:mod:`nifo_core.predict.sensitivity`) for ``model`` = self.model(θ),
        or None where the march cannot give its Jacobian (the linear part's residues move, feedback paths)."""
        if self.residues or model.linear.paths is not None or not _blocks(model.linear.state_space()[0]):
            return None
        nt, sh = self.gamma_scale.size, list(self.shape_idx)
        kind = [GAMMA] * nt + [SHAPE] * len(sh)
        term = list(range(nt)) + sh
        scale = list(self.gamma_scale) + [0.0] * len(sh)
        if self.body:
            kind += [BODY_K, BODY_C]
            term += [-1, -1]
            scale += [model.linear.body.k, model.linear.body.c]
        if self.force:
            kind.append(FORCE_GAIN)
            term.append(-1)
            scale.append(0.0)
        ab = np.array([KINDS[t.kind].absorb if self.track_absorbed else (0.0, 0.0) for t in model.terms], float)
        ab = ab.reshape(len(model.terms), 2)
        return Parameters(np.array(kind, np.int64), np.array(term, np.int64), np.array(scale, float),
                          np.ascontiguousarray(ab[:, 0]), np.ascontiguousarray(ab[:, 1]))

    def names(self) -> list[tuple[str, str]]:
        """(name, unit) of every reported value (:func:`reported_values`)."""
        out = [(f"c/M2 of {t.kind}", f"{KINDS[t.kind].coef_unit}/kg") for t in self.base.terms]
        for i in self.shape_idx:
            t = self.base.terms[i]
            key = KINDS[t.kind].shape_param
            out.append((f"{t.kind}.{key}", KINDS[t.kind].params[key][1]))
        if self.body:
            out += [("k = K2/M2 (nominal body)", "1/s²"), ("c = C2/M2 (nominal body)", "1/s")]
        if self.force:
            out.append(("1/M2 (gain of the measured force)", "1/kg"))
        return out

    def model(self, x: np.ndarray) -> IdentifiedModel:
        m = self.base
        nt = self.gamma_scale.size
        gam = x[:nt] * self.gamma_scale
        terms = list(m.terms)
        for j, i in enumerate(self.shape_idx):
            t = terms[i]
            key = KINDS[t.kind].shape_param
            terms[i] = Term(t.kind, {**dict(t.params), key: float(t.params[key]) * float(np.exp(x[nt + j]))})
        lin, body = m.linear, m.body
        if self.residues:
            lin = self._linear(lin, x[self.size - self.n_residues:])
        k0 = nt + len(self.shape_idx)
        if self.body:
            kb, cb = x[k0:k0 + 2]
            bm = lin.body
            lin = replace(lin, body=BodyModel(bm.k * float(np.exp(kb)), bm.c * float(np.exp(cb)), bm.k3, bm.fit_rms))
        force_gain = m.force_gain * float(np.exp(x[k0 + (2 if self.body else 0)])) if self.force else m.force_gain
        if self.track_absorbed:       # the realised linear part stays; the terms' linear part moves with γ
            lin = replace(lin, absorbed=absorbed_rates(terms, gam))
        if lin.kind == "body":        # the nominal body: the realised one without the absorbed strut part
            bm, (ka, ca) = lin.body, lin.absorbed
            body = BodyModel(bm.k - ka, bm.c - ca, bm.k3, bm.fit_rms)
        b = gam[:, None] * self.hz[None, :]
        return replace(m, terms=tuple(terms), c_over_m2=gam, b=b, linear=lin, body=body, force_gain=force_gain)


def space_for(start: IdentifiedModel, scale_from: IdentifiedModel, *, shape: bool, linear_params: bool,
           track_absorbed: bool, residues: bool = False) -> Space:
    g = np.abs(np.asarray(scale_from.c_over_m2, float))
    scale = np.where((g > 0) & np.isfinite(g), g, 1.0)
    shaped = [(i, t.params.get(KINDS[t.kind].shape_param)) for i, t in enumerate(start.terms)]
    idx = tuple(i for i, v in shaped if shape and isinstance(v, float) and v > 0)
    body = bool(linear_params and start.linear.kind == "body" and start.linear.body.k > 0 and start.linear.body.c > 0)
    res = bool(residues and start.linear.kind == "rational" and np.any(start.linear.poles.imag > 0))
    # a measured force's gain 1/M2 comes from NIFO's force path; refined with the body, it is what sets the static
    # gain of the output: the Silverbox at 150 mV refined with it predicts 50 and 100 mV at 0.77 and 0.78 mV
    # against 0.92 and 0.97 mV with NIFO's gain held (1/M2 +0.34 %)
    force = bool(linear_params and start.force_gain > 0)
    return Space(start, scale, idx, body, track_absorbed, res, force)


def terms_on(linear: IdentifiedModel, model: IdentifiedModel, gammas: np.ndarray) -> IdentifiedModel:
    """``model``'s terms at coefficients ``gammas`` on ``linear``'s linear part, taken as the realised one: the
    terms' slope absorbed into it, so that each adds only its bounded remainder."""
    return replace(linear, terms=model.terms, c_over_m2=gammas, source=model.source,
                   provenance=dict(model.provenance), b=np.zeros((len(model.terms), linear.freq_hz.size), complex),
                   linear=replace(linear.linear, absorbed=absorbed_rates(model.terms, gammas)))


def reported_values(sp: Space, x: np.ndarray) -> list[float]:
    m = sp.model(x)
    vals = [float(g) for g in m.c_over_m2]
    for i in sp.shape_idx:
        t = m.terms[i]
        vals.append(float(t.params[KINDS[t.kind].shape_param]))
    if sp.body:      # the nominal body: the realised one without the terms' absorbed linear part
        vals += [m.body.k, m.body.c]
    if sp.force:
        vals.append(m.force_gain)
    return vals


def half_widths(sp: Space, x: np.ndarray, cov: np.ndarray | None) -> list[float | None]:
    """95 % half-widths of the reported values (:func:`reported_values`), cov(θ) carried by their derivatives in θ."""
    if cov is None:
        return [None] * len(sp.names())
    p = x.size
    v0 = np.asarray(reported_values(sp, x))
    d = np.zeros((v0.size, p))
    for j in range(p):
        step = 1e-6 * max(1.0, abs(x[j]))
        xx = np.array(x, float)
        xx[j] += step
        d[:, j] = (np.asarray(reported_values(sp, xx)) - v0) / step
    var = np.einsum("ij,jk,ik->i", d, cov, d)
    return [float(1.96 * np.sqrt(v)) if np.isfinite(v) and v >= 0 else None for v in var]


def stored_covariance(sp: Space, x: np.ndarray, cov: np.ndarray | None) -> dict | None:
    """cov(θ) in coordinates of the refined model itself (what :func:`parameter_space` rebuilds).

    θ' = (γ_i/γ_i*, log of each refined key parameter's factor, log k, log c of a one-mass body): the
    coefficients relative to their refined values (1 where a value is 0), the rest log offsets, which
    carry over unchanged.
    """
    if cov is None:
        return None
    nt = sp.gamma_scale.size
    gam = x[:nt] * sp.gamma_scale
    scale = np.where(gam != 0, gam, 1.0)
    d = np.concatenate([sp.gamma_scale / scale, np.ones(x.size - nt - sp.n_residues)])
    if sp.residues:              # residue changes in units of the refined |r| (what parameter_space rebuilds)
        start_scale = sp._pairs[3]
        ref = Space(sp.model(x), np.ones(nt), (), False, residues=True)._pairs[3]
        d = np.concatenate([d, np.tile(start_scale / ref, 2)])
    return {"coordinates": "coefficients relative to the refined ones, then log factors of the key parameters, "
                           "of a one-mass body's k and c and of a force's 1/M2, then the rational linear part's residue changes "
                           "(re, im per pole pair, in units of |r|)",
            "shape_terms": list(sp.shape_idx), "body": bool(sp.body), "track_absorbed": bool(sp.track_absorbed),
            "residues": bool(sp.residues), "force": bool(sp.force), "matrix": (d[:, None] * cov * d[None, :]).tolist()}


def _stored_space(model: IdentifiedModel) -> tuple[Space, np.ndarray] | None:
    """The refined model's own space θ' and cov(θ') from its stored covariance, or None."""
    c = (model.provenance.get("refined") or {}).get("covariance")
    if not c:
        return None
    gam = np.asarray(model.c_over_m2, float)
    scale = np.where(gam != 0, gam, 1.0)
    sp = Space(model, scale, tuple(int(i) for i in c["shape_terms"]), bool(c["body"]), bool(c["track_absorbed"]),
                bool(c.get("residues", False)), bool(c.get("force", False)))
    cov = np.asarray(c["matrix"], float)
    if cov.shape != (sp.size, sp.size) or not np.all(np.isfinite(cov)):
        return None
    return sp, cov


@dataclass(frozen=True)
class ParameterSpace:
    """A refined model's parameters θ' (relative coefficients and log factors, the covariance's own coordinates).

    Parameters
    ----------
    to_model : callable θ' → IdentifiedModel
        The model at θ'; ``to_model(theta)`` is the refined model itself.
    theta : ndarray, shape (p,)
        θ'* of the refined model.
    cov : ndarray, shape (p, p)
        cov(θ') stored with the refinement.
    """

    to_model: Callable[[np.ndarray], IdentifiedModel]
    theta: np.ndarray
    cov: np.ndarray
    #: the model's θ' as the sensitivity march takes them (:meth:`Space.march_parameters`; None: it cannot)
    march: Callable[[IdentifiedModel], Parameters | None] = lambda m: None


def parameter_space(model: IdentifiedModel) -> ParameterSpace | None:
    """The :class:`ParameterSpace` of a refined model's stored covariance, or None.

    For propagating the refinement's parameter uncertainty to predictions
    (:mod:`nifo_core.predict.prediction_bounds`): ``space.to_model(space.theta)`` is ``model``.
    """
    got = _stored_space(model)
    if got is None:
        return None
    sp, cov = got
    return ParameterSpace(to_model=sp.model, theta=sp.x0(np.asarray(model.c_over_m2, float)), cov=cov,
                          march=sp.march_parameters)


def moved_refinement(model: IdentifiedModel, x: np.ndarray, cov: np.ndarray,
                     note: Mapping) -> tuple[IdentifiedModel, list[dict]]:
    """A refined ``model`` moved to θ' = ``x`` of its :func:`parameter_space` with covariance ``cov`` (there):
    the moved model (its stored covariance re-expressed around it, ``note`` stored as the refinement's
    ``bias_correction``) and its reported parameters (before as in ``model``, after, 95 % half-widths)."""
    sp, _ = _stored_space(model)
    moved = sp.model(x)
    old = model.provenance["refined"]
    params = [{**p, "after": float(v), "half_width_95": h}
              for p, v, h in zip(old["parameters"], reported_values(sp, x), half_widths(sp, x, cov))]
    prov = {**dict(model.provenance), "refined": {**old, "parameters": params, "bias_correction": dict(note),
                                                  "covariance": stored_covariance(sp, x, cov)}}
    return replace(moved, provenance=prov), params
