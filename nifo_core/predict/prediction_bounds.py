"""Bounds on a prediction from the identified model's parameter uncertainty.

A refined model (:mod:`nifo_core.predict.refine`) carries the covariance of its
parameters θ (coefficients, key parameters, a one-mass body's k and c):
the asymptotic output-error covariance s²·(JᵀJ)⁻¹ at the solution. Carried
to a prediction of other data by symmetric sigma points — θ* ± the columns
of a square root S of the covariance (S·Sᵀ = cov θ), each one simulation of
the record —

    δŶ_k = (Ŷ(θ* + S_k) - Ŷ(θ* - S_k))/2,   var Ŷ_l ≈ Σ_k |δŶ_k,l|²   (every band line l)
    δN_k = (NMSE(θ* + S_k) - NMSE(θ* - S_k))/2,   95 % half-width of the NMSE = 1.96·sqrt(Σ_k δN_k²)

(the first-order propagation gᵀ·cov·g evaluated with central differences
along S, which also holds for the non-smooth terms, where a derivative at θ*
would not). The transmissibility's band is obtained the same way from each
sigma point's predicted body signal.

What it is: the random error of the prediction that comes from the
parameters being estimated from finite, noisy data. What it is not: the
model-class error (an effect the model lacks) — that is what the prediction
error itself shows, and what the loop looks for.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..signal.parallel import batch_map, thread_map
from .model import IdentifiedModel, PredictionDivergedError
from .refine_space import parameter_space

__all__ = ["PredictionSpread", "prediction_spread", "line_spread", "half_width", "Z95"]

#: two-sided 95 % of a normal variable
Z95 = 1.96


@dataclass(frozen=True)
class PredictionSpread:
    """Sigma-point predictions of one record (or why there are none).

    Attributes
    ----------
    plus, minus : list of ndarray
        Body acceleration predicted at θ* ± S_k (one per column k of S).
    n_parameters : int
        Size of θ.
    unavailable : str or None
        Why the spread could not be computed (then ``plus``/``minus`` are empty).
    """

    plus: list
    minus: list
    n_parameters: int
    unavailable: str | None = None

    @property
    def available(self) -> bool:
        return self.unavailable is None


def _sqrt_cov(cov: np.ndarray) -> np.ndarray:
    """Columns S_k with S·Sᵀ = cov (eigen-decomposition; directions of zero variance dropped)."""
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    keep = lam > 1e-12 * max(float(lam.max(initial=0.0)), 1e-300)
    return vec[:, keep] * np.sqrt(lam[keep])


def prediction_spread(model: IdentifiedModel, simulate: Callable[[IdentifiedModel], np.ndarray], *,
                      together: Callable[[list[IdentifiedModel]], list] | None = None) -> PredictionSpread:
    """The record's predictions at the sigma points of ``model``'s parameter covariance.

    ``simulate(m)`` returns the body acceleration model ``m`` predicts for the record (the caller's
    predictor, with the record's drive and options; pure: the sigma points run on threads,
    :mod:`nifo_core.signal.parallel`). ``together(models)``, where given, returns the same for several models at
    once (each a body acceleration, or the :class:`PredictionDivergedError` it raised): the sigma points are then
    marched together in a batch per thread (:mod:`nifo_core.predict.timesim_lanes`, the same bits; measured with
    ``nifo predict`` of the sample's loop model on its 3 records, 36 sigma points: CPU 0.93 of one by one). A model without a stored covariance (not refined,
    or refined without more residual lines than parameters), or one whose sigma point diverges, gives
    an unavailable spread that says why.
    """
    space = parameter_space(model)
    if space is None:
        return PredictionSpread([], [], 0, "the model carries no parameter covariance (refine it: "
                                           "nifo identify --refine)")
    to_model, x, cov = space.to_model, space.theta, space.cov
    s = _sqrt_cov(cov)
    points = [(k, sign) for k in range(s.shape[1]) for sign in (1.0, -1.0)]

    def at(point: tuple[int, float]) -> np.ndarray | tuple[int, float]:
        k, sign = point
        try:
            return np.asarray(simulate(to_model(x + sign * s[:, k])), float)
        except PredictionDivergedError:
            return point
    if together is None:
        got = thread_map(at, points)          # the sigma points side by side (simulate is pure)
    else:
        def batch(part: list[tuple[int, float]]) -> list:
            out = together([to_model(x + sign * s[:, k]) for k, sign in part])
            return [pt if isinstance(o, PredictionDivergedError) else np.asarray(o, float)
                    for pt, o in zip(part, out)]
        got = batch_map(batch, points)
    for (k, sign), g in zip(points, got):
        if isinstance(g, tuple):
            return PredictionSpread([], [], x.size, f"the model {'+' if sign > 0 else '-'}1σ along parameter "
                                                    f"direction {k + 1} diverges on this record")
    plus, minus = got[0::2], got[1::2]
    return PredictionSpread(plus, minus, x.size)


def line_spread(plus: list[np.ndarray], minus: list[np.ndarray]) -> np.ndarray:
    """Standard deviation of a complex (or real) quantity per line from its sigma-point values."""
    if not plus:
        raise ValueError("no sigma points")
    d = [(np.asarray(p) - np.asarray(m)) / 2 for p, m in zip(plus, minus)]
    return np.sqrt(np.sum([np.abs(v) ** 2 for v in d], axis=0))


def half_width(plus: list[float], minus: list[float]) -> float:
    """95 % half-width of a scalar from its sigma-point values: 1.96·sqrt(Σ_k ((f⁺_k - f⁻_k)/2)²)."""
    return float(Z95 * np.sqrt(np.sum([((p - m) / 2) ** 2 for p, m in zip(plus, minus)])))
