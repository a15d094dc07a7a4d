"""A bias correction whose second step turns back past the first brackets its fixed point
(nifo_core.signal.bias_correction).

The fixed-point iteration θ ← θ + (θ₀ - F(θ)) (F: the mean synthetic refit) oscillates when the refit moves more
than its truth (F's slope above 1), as the output-error refinement of fleet case #198 did: a bump stop 3.46e5 N/m
refined from records with 2.2 % spindle noise, its synthetic refits -11.8 % at θ₀ and -1.5 % at the first corrected
θ, the second step -0.87 × the first. The fixed point then lies between the two iterates, and the secant through
them reaches it; the correction was refused before (the refined stop stayed 12.7 % low). A slow contraction in one
direction (the steps shrinking by more than 0.6 each) is still refused: there the secant extrapolates.

The output-error refinement's correction asks for it (``bracket``); the loop's equation-error correction does not,
and there such a step is refused as before.

What must hold, on an errors-in-variables problem whose F is affine in θ for fixed noise draws (a static gain fitted
by least squares on a noisy input, mapped by a known affine law): the oscillating correction lands on the fixed
point θ* = (θ₀ - b)/(a·λ), λ = Σx²/(Σx² + Σ n·σ²) the attenuation the added noise makes; without ``bracket`` it is
refused; the slow one is refused either way.
"""

from __future__ import annotations

import numpy as np
import pytest

from nifo_core.signal.bias_correction import simulated_correction
from nifo_core.signal.noise import ChannelNoise, NoiseEstimate
from nifo_core.signal.record import Record

FS = 200.0
GAIN = 0.8


def _problem(noise_fraction: float, a: float, n: int = 20000, seed: int = 3):
    """Three noise-free records of ẍ2 = GAIN·ẍ1, noise estimates ``noise_fraction`` of each channel's RMS, and a fit
    a·(least-squares gain) + b with b such that the fit of the data is GAIN."""
    rng = np.random.default_rng(seed)
    b = GAIN * (1.0 - a)
    recs, noise = [], []
    for k in range(3):
        x = rng.standard_normal(n) * (1 + k)
        recs.append(Record(fs_hz=FS, spindle_accel=x, body_accel=GAIN * x))
        s1, s2 = noise_fraction * float(np.std(x)), noise_fraction * GAIN * float(np.std(x))
        noise.append(NoiseEstimate(f"r{k}", (ChannelNoise("spindle_accel", s1, 2 * s1 ** 2 / FS, 0.1, (1.0, 2.0)),
                                             ChannelNoise("body_accel", s2, 2 * s2 ** 2 / FS, 0.1, (1.0, 2.0)))))

    def fit(rs):
        x = np.concatenate([np.asarray(r.spindle_accel, float) for r in rs])
        y = np.concatenate([np.asarray(r.body_accel, float) for r in rs])
        return np.array([a * float(x @ y / (x @ x)) + b])

    def simulate(theta, rec):
        return theta[0] * np.asarray(rec.spindle_accel, float)

    power = sum(float(np.sum(np.square(r.spindle_accel))) for r in recs)
    lam = power / (power + sum(r.n * e.stds[0] ** 2 for r, e in zip(recs, noise)))
    return fit, simulate, recs, noise, b, lam


def test_an_oscillating_correction_lands_on_its_fixed_point():
    fit, simulate, recs, noise, b, lam = _problem(0.3, 2.0)
    theta0 = fit(recs)
    assert theta0[0] == pytest.approx(GAIN)
    kw = dict(seed=1, scale=np.ones(1), noise_only=True)
    assert simulated_correction(fit, simulate, recs, noise, theta0, **kw) is None      # not asked: refused
    cor = simulated_correction(fit, simulate, recs, noise, theta0, bracket=True, **kw)
    assert cor is not None, "an oscillating correction brackets its fixed point: it is not refused"
    assert cor.bracketed
    star = (theta0[0] - b) / (2.0 * lam)
    # the plain clipped tail (q at -0.6) would stop 1 % short of it; the secant reaches it to the draws' scatter
    assert cor.theta[0] == pytest.approx(star, rel=2e-3)
    assert theta0[0] < cor.theta[0] < theta0[0] + (theta0[0] - (2.0 * lam * theta0[0] + b))   # inside the first step


def test_a_slow_contraction_in_one_direction_is_still_refused():
    fit, simulate, recs, noise, _, _ = _problem(0.6, 0.2)
    theta0 = fit(recs)
    assert simulated_correction(fit, simulate, recs, noise, theta0, seed=1, scale=np.ones(1), noise_only=True,
                                bracket=True) is None
