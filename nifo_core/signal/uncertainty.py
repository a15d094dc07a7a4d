"""Bounds on least-squares coefficients fitted to coloured residuals (the loop's equation-error fit).

The equation-error regression y = X·θ + e (paper Eq. 2 per unit sprung mass,
every column band-passed) has residuals that are far from white: band-passed,
with the body-mode peak. Counting samples as independent would make the
bounds far too narrow. With N_eff = N·mean(S)²/mean(S²) the effective number
of independent samples of a residual with spectrum S (the count
:mod:`nifo_core.characterize.automatic` uses for its F-test), the covariance of θ is

    Cov θ ≈ σ²·(XᵀX)⁻¹·N/N_eff,     σ² = RSS/(N_eff - q)

(Bendat & Piersol's random error of a least-squares estimate with
N_eff degrees of freedom), and the two-sided bound at ``level`` is
t_{(1+level)/2, N_eff - q}·sqrt(diag Cov θ). Random error only: bias from
noise reaching the regressors through z (paper §2.2) is not in it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from .spectral import SpectralSettings, auto_spectrum, cross_spectra

__all__ = ["CoefficientBounds", "coefficient_bounds", "effective_samples"]


@dataclass(frozen=True)
class CoefficientBounds:
    """θ and the half-width of its two-sided bound at ``level`` (same units as θ)."""

    theta: np.ndarray
    half_width: np.ndarray
    level: float
    n_eff: float

    def to_list(self, names) -> list[dict]:
        return [{"name": n, "value": float(t), "half_width": float(h), "level": self.level}
                for n, t, h in zip(names, self.theta, self.half_width)]


def effective_samples(residual: np.ndarray, fs_hz: float, *, block: int | None = None) -> float:
    """N·mean(S)²/mean(S²) of a residual with spectrum S (from the one spectral engine)."""
    r = np.asarray(residual, float)
    nb = int(block or min(4096, max(64, 2 ** int(np.log2(max(r.size // 8, 64))))))
    sp = cross_spectra(r[None, :], fs_hz, SpectralSettings(block=nb, overlap=0.5, window="hann"))
    s = auto_spectrum(sp, 0)[1:]
    return float(r.size * np.mean(s) ** 2 / max(float(np.mean(s ** 2)), 1e-300))


def coefficient_bounds(x: np.ndarray, y: np.ndarray, fs_hz: float, *, level: float = 0.95,
                       segments: list[int] | None = None) -> CoefficientBounds:
    """Least-squares θ of y ≈ X·θ with bounds that count the residual's effective samples.

    Parameters
    ----------
    x : ndarray, shape (n, q)
    y : ndarray, shape (n,)
    fs_hz : float
        Sample rate of the rows [Hz] (for the residual's spectrum).
    level : float
        Two-sided confidence level.
    segments : list of int, optional
        Lengths of the contiguous records the rows were stacked from (N_eff summed over them).
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    theta = np.linalg.lstsq(x, y, rcond=None)[0]
    e = y - x @ theta
    bounds = np.cumsum([0, *(segments or [y.size])])
    n_eff = sum(effective_samples(e[a:b], fs_hz) for a, b in zip(bounds[:-1], bounds[1:]) if b - a >= 128)
    n_eff = max(min(n_eff, float(y.size)), x.shape[1] + 2.0)
    dof = n_eff - x.shape[1]
    sigma2 = float(e @ e) / y.size * (n_eff / dof)           # per-row variance, q parameters off N_eff
    cov = sigma2 * np.linalg.pinv(x.T @ x) * (y.size / n_eff)
    t = float(stats.t.ppf(0.5 + level / 2, dof))
    return CoefficientBounds(theta=theta, half_width=t * np.sqrt(np.maximum(np.diag(cov), 0)), level=level,
                             n_eff=n_eff)
