"""Frequency-domain prediction: a fast path, used only where it provably converges (docs/method.md §4).

On the whole zero-padded record, the model's feedback reads (K3 = 0)

    Z = Hz·V + Σ Bz_i·G_i(z, ż),    Bz_i = γ_i·Hz (parametric) or the identified B_i(ω) (non-parametric),

and plain Picard iteration Z ← Hz·V + Σ Bz_i·G_i(z_prev) is a contraction when
every g_i is globally Lipschitz (|Δg_i| ≤ Lz_i·|Δz| + Lż_i·|Δż|,
:func:`nifo_core.kinds.strut_forces.lipschitz`) and

    ρ = min_λ max( λ·Σ_i S0_i·K_i , Σ_i S1_i·K_i ) < 1,
    K_i = Lz_i/λ + Lż_i,  S0_i = sup_ω |Bz_i(ω)|,  S1_i = sup_ω ω·|Bz_i(ω)|,

(Parseval: in the norm max(λ‖Δz‖₂, ‖Δż‖₂) one iteration shrinks the error by
ρ at least). Cubic and quadratic terms have no global Lipschitz constant and
a backlash is Lipschitz only in the sup norm: for them, and wherever ρ ≥ 1,
the time-domain engine (:mod:`nifo_core.predict.timesim`) is the one that runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.fft

from ..kinds.describing import Term, play_operator
from ..kinds.strut_forces import lipschitz

__all__ = ["contraction_bound", "fixed_point_solve", "FixedPoint"]


@dataclass(frozen=True)
class FixedPoint:
    """The Picard iteration's answer: the relative motion's spectrum ``z_spec`` [m·s on the FFT lines], the
    ``iterations`` taken and the ``change`` of the last one (RMS of the update over RMS of z, inside the record)."""

    z_spec: np.ndarray
    iterations: int
    change: float


def contraction_bound(terms: Sequence[Term], bz: np.ndarray, freq_hz: np.ndarray) -> float:
    """ρ of the module docstring (inf when a term has no usable Lipschitz constant)."""
    if not len(terms):
        return 0.0
    lips = np.array([lipschitz(t) for t in terms])
    if np.any(~np.isfinite(lips)) or any(t.spec.hysteretic for t in terms):
        return float("inf")
    w = 2 * np.pi * np.asarray(freq_hz, float)
    mag = np.abs(np.where(np.isfinite(bz), bz, 0))
    s0 = mag.max(axis=1)
    s1 = (w[None, :] * mag).max(axis=1)
    best = np.inf
    for lam in np.logspace(-2, 4, 241):
        k = lips[:, 0] / lam + lips[:, 1]
        best = min(best, max(lam * float(np.sum(s0 * k)), float(np.sum(s1 * k))))
    return float(best)


def _evaluate(terms: Sequence[Term], z: np.ndarray, zdot: np.ndarray) -> np.ndarray:
    out = np.empty((len(terms), z.size))
    for i, t in enumerate(terms):
        out[i] = play_operator(z, t.params[t.spec.key_param]) if t.spec.hysteretic else t.evaluate(z, zdot)
    return out


def fixed_point_solve(terms: Sequence[Term], hz: np.ndarray, bz: np.ndarray, v_spec: np.ndarray, nfft: int,
                      fs_hz: float, sl: slice, *, tol: float, max_iter: int) -> FixedPoint:
    """Picard iteration Z ← Hz·V + Σ Bz_i·G_i(z) on the FFT lines: :class:`FixedPoint` (Z, iterations, last
    change).

    ``sl`` selects the record inside the padding (the change is measured there).
    Call only where :func:`contraction_bound` < 1 (then it converges geometrically).
    """
    f = np.fft.rfftfreq(nfft, 1.0 / fs_hz)
    w = 2 * np.pi * f
    Z = hz * v_spec
    z = scipy.fft.irfft(Z, nfft)
    it, change = 0, 0.0
    if len(terms):
        for it in range(1, max_iter + 1):
            zd = scipy.fft.irfft(1j * w * Z, nfft)
            G = scipy.fft.rfft(_evaluate(terms, z, zd), axis=1)
            Z = hz * v_spec + np.sum(bz * G, axis=0)
            zn = scipy.fft.irfft(Z, nfft)
            change = float(np.sqrt(np.mean((zn[sl] - z[sl]) ** 2)) / max(np.sqrt(np.mean(zn[sl] ** 2)), 1e-300))
            z = zn
            if change < tol:
                break
    return FixedPoint(z_spec=Z, iterations=it, change=change)
