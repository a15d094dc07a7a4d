"""Removing the bias of a fit by simulating it: what the fit does to data whose truth is known (docs/method.md §9).

The loop's equation-error fit (and characterize's) is biased in two ways that a random-error bound
does not hold: noise on both accelerometers reaches the regressors (z, ż integrated from ẍ2 - ẍ1 and
every g(z, ż) of them: errors in variables, paper §2.2 — a stiffness attenuated, a friction's sign(ż)
blurred), and the processing itself (z, ż integrated in a band lack their motion outside it, and a
sign(ż) or a stop's contact computed from them differs from the true one: measured −3.8 % on Coulomb
100 N with no noise at all). Both are properties of the estimator on *these* records, so they can be
measured on synthetic records that share everything but a known truth (parametric-bootstrap bias
correction, indirect inference; Gouriéroux & Monfort; Carroll et al., *Measurement Error in Nonlinear
Models*, ch. 5 for the measurement-error case):

1. θ₀ = the fit on the data.
2. Synthetic records: the measured spindle acceleration drives the model with θ (the one-mass body
   and the terms, :func:`nifo_core.predict.model.predict_body`); the estimated noise of each sensor
   (:mod:`nifo_core.signal.noise`) is added to both channels, one draw and its negative (antithetic).
3. θ_syn = the same fit on them; the bias b = θ_syn - θ; the corrected θ ← θ₀ - b.
   Repeated :data:`ITERATIONS` times (θ from the previous step: the fixed point is the θ whose
   synthetic fit reproduces θ₀), then the rest of the way to the fixed point extrapolated from the
   last two steps (geometric tail, Aitken: step × q/(1 - q), q their ratio per coefficient). Measured on
   a bump stop (2e5 N/m, 4 mm gap, 2.5 mm road, 2 % noise on both sensors), whose steps shrink only
   by q ≈ 0.4-0.5: θ₀ 1.28e5, two steps 1.78e5, with the tail 1.91e5, five steps and their tail 1.95e5.
   Where the steps do not contract (:data:`MAX_CONTRACTION`) or the first steps' correction exceeds
   half a coefficient (:data:`MAX_RELATIVE_BIAS`: terms that share their shape —
   a friction beside a damper knee — make the bias map ill-conditioned: measured, a knee's
   coefficient moved by -130 %) there is no correction (None): the caller says the fit may be biased.

Uncertainty (:meth:`Correction.extra_sd`): the draws' scatter (the correction's Monte-Carlo error) and
the noise level's own error (:data:`NOISE_LEVEL_RTOL`, measured: estimates 0.7-1.3 × the truth on
simulated records) times the part of the bias the noise makes (b minus the bias of a noise-free
synthetic fit), and :data:`TAIL_RTOL` of the extrapolated tail. The random error of θ₀ carries over,
times 1/(1 - r) with r the iteration's contraction (the bias's sensitivity to θ).
What it cannot remove is bias from a model outside the family (an effect the model lacks).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from .noise import NoiseEstimate, noise_draw
from .parallel import thread_map
from .record import Record

__all__ = ["ITERATIONS", "NOISE_LEVEL_RTOL", "Correction", "simulated_correction"]

#: bias-correction iterations (1: θ₀ - b(θ₀); 2: once more from the corrected θ)
ITERATIONS = 2
#: a correction whose last step exceeds MAX_CONTRACTION × the one before (plus CONVERGED_RTOL·|θ₀|) is refused;
#: measured: 0.05 on a friction or a cubic alone, 0.43 on a bump stop (its contact depends on the amplitude)
MAX_CONTRACTION = 0.6
#: a correction larger than this fraction of a coefficient is refused: the fit cannot tell the term apart
#: (measured: a friction beside a damper knee, the knee's coefficient moved by -130 %, the friction's +53 %)
MAX_RELATIVE_BIAS = 0.5
CONVERGED_RTOL = 0.01
#: relative error of an estimated noise variance (measured on simulated records: 0.7-1.3 × the truth)
NOISE_LEVEL_RTOL = 0.3
#: relative error of the extrapolated tail (measured on a bump stop: it fell 20-30 % short of the tail that
#: three more iterations give)
TAIL_RTOL = 0.5


@dataclass(frozen=True)
class Correction:
    """Coefficients with the fit's bias removed, and what the correction adds to their uncertainty.

    Attributes
    ----------
    theta : ndarray
        Corrected coefficients.
    theta_fit : ndarray
        The plain fit θ₀ on the data.
    noise_bias : ndarray
        The part of the bias the sensor noise makes (the rest is the processing's).
    draw_sd : ndarray
        Standard deviation of the correction from its noise draws.
    gain : float
        Factor on θ₀'s random error carried into θ: 1/(1 - r), r the iteration's contraction.
    tail : ndarray or None
        The extrapolated rest of the way to the fixed point (included in ``theta``).
    """

    theta: np.ndarray
    theta_fit: np.ndarray
    noise_bias: np.ndarray
    draw_sd: np.ndarray
    gain: float = 1.0
    tail: np.ndarray | None = None

    @property
    def bias(self) -> np.ndarray:
        """θ₀ - θ: the plain fit's estimated bias."""
        return self.theta_fit - self.theta

    def extra_sd(self) -> np.ndarray:
        """Standard deviation the correction adds beyond θ₀'s random error."""
        tail = 0.0 if self.tail is None else TAIL_RTOL * self.tail
        return np.sqrt(self.draw_sd ** 2 + (NOISE_LEVEL_RTOL * self.noise_bias) ** 2 + tail ** 2)


def _noisy(rec: Record, body: np.ndarray, est: NoiseEstimate, draw: np.ndarray | None) -> Record:
    """A synthetic record: the measured spindle signal and ``body``, plus ``draw`` × the estimated noise."""
    a1, a2 = np.asarray(rec.spindle_accel, float), np.asarray(body, float)
    if draw is not None and est.available:
        s1, s2 = est.stds
        a1, a2 = a1 + s1 * draw[0, :rec.n], a2 + s2 * draw[1, :rec.n]
    return replace(rec, spindle_accel=a1, body_accel=a2)


def simulated_correction(fit: Callable[[Sequence[Record]], np.ndarray],
                         simulate: Callable[[np.ndarray, Record], np.ndarray | None],
                         records: Sequence[Record], noise: Sequence[NoiseEstimate], theta0: np.ndarray, *,
                         seed: int = 0, iterations: int = ITERATIONS, scale: np.ndarray | None = None,
                         noise_only: bool = False, hold: np.ndarray | None = None,
                         side_by_side: bool = False) -> Correction | None:
    """``theta0`` (the fit ``fit`` on ``records``) with the fit's bias removed (module docstring).

    ``simulate(θ, record)`` is the body acceleration the model with θ gives for the record's spindle
    signal (None: it cannot: no correction). ``noise`` holds one estimate per record.
    ``scale``: the size each coordinate of θ is judged against (refusal, convergence; default |θ₀|:
    give it where a coordinate is a log factor that is 0 at θ₀). ``noise_only``: the fit is consistent
    on noise-free records of its own model (an output-error fit: no noise-free synthetic fit is run,
    the whole bias counts as the noise's). ``hold``: coordinates kept at θ₀, neither corrected nor judged
    (those the data do not determine: their synthetic refits scatter along a flat valley of the cost).
    ``side_by_side``: ``fit`` and ``simulate`` are safe on several threads at once; the records'
    simulations and the antithetic pair's two refits then run on threads (:mod:`nifo_core.signal.parallel`),
    the result the same to the last digit."""
    each = thread_map if side_by_side else (lambda fn, items: [fn(x) for x in items])
    rng = np.random.default_rng(seed)
    draws = [noise_draw(r.n, rng) for r in records]
    t0 = np.asarray(theta0, float)
    size = np.abs(t0) if scale is None else np.broadcast_to(np.abs(np.asarray(scale, float)), t0.shape)
    free = np.ones(t0.shape, bool) if hold is None else ~np.asarray(hold, bool)
    theta = t0.copy()
    noise_bias, draw_sd = np.zeros_like(t0), np.zeros_like(t0)
    steps = []
    for _ in range(max(int(iterations), 1)):
        bodies = each(lambda r: simulate(theta, r), records)
        if any(b is None or not np.all(np.isfinite(b)) for b in bodies):
            return None
        got = each(lambda s: np.asarray(fit([_noisy(r, b, e, s * d) for r, b, e, d in
                                             zip(records, bodies, noise, draws)]), float), (1.0, -1.0))
        syn = 0.5 * (got[0] + got[1])
        clean = theta if noise_only else np.asarray(fit([_noisy(r, b, e, None)
                                                         for r, b, e in zip(records, bodies, noise)]), float)
        noise_bias, draw_sd = free * (syn - clean), free * 0.5 * np.abs(got[0] - got[1])
        steps.append(free * (t0 - syn))
        theta = theta + steps[-1]
    if np.any(np.abs(theta - t0) > MAX_RELATIVE_BIAS * size):
        return None
    gain, tail = 1.0, None
    if len(steps) > 1:
        if np.any(np.abs(steps[-1]) > MAX_CONTRACTION * np.abs(steps[-2]) + CONVERGED_RTOL * size):
            return None     # the fixed point contracts slowly: the bias map is ill-conditioned (confounded terms)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(np.abs(steps[-2]) > 0, steps[-1] / steps[-2], 0.0)
        q = np.clip(q, -MAX_CONTRACTION, MAX_CONTRACTION)
        gain = float(1.0 / (1.0 - float(np.max(np.abs(q)))))
        tail = free * steps[-1] * q / (1.0 - q)      # the geometric rest of the way to the fixed point
        theta = theta + tail
    return Correction(theta, t0, noise_bias, draw_sd, gain, tail)
