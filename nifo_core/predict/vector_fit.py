"""Vector fitting of a rational transfer function to measured lines (Gustavsen & Semlyen 1999, relaxed:
Gustavsen 2006): the numerics behind :func:`nifo_core.predict.linear_part.fit_rational`, split from
:mod:`nifo_core.predict.linear_part` (issue 58), which builds the linear part from the poles and residues found here.

Poles and residues in conjugate pairs; unstable poles flipped into the left half plane and damped at least to a given
decay; residues constrained to Σ r = 0 (relative degree 2). :class:`RecordLines` carries one record's lines for a
refit of the residues on every record's own spectra.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

__all__ = ["RecordLines", "Refit", "conjugate_pairs", "fit_residues", "refit", "start_poles", "vector_fit"]


def _basis(s: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """Real-coefficient partial-fraction basis: 1/(s-p) for a real pole; for a pair
    1/(s-p) + 1/(s-p̄) and j/(s-p) - j/(s-p̄) (Gustavsen & Semlyen 1999, Eq. A.3)."""
    cols = []
    for p in poles:
        if p.imag == 0:
            cols.append(1 / (s - p.real))
        elif p.imag > 0:
            cols.append(1 / (s - p) + 1 / (s - np.conj(p)))
            cols.append(1j / (s - p) - 1j / (s - np.conj(p)))
    return np.stack(cols, axis=1)


def _real_block(poles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) with the basis above = (sI - A)⁻¹·b, columnwise (real modal form)."""
    kept = [p for p in poles if p.imag >= 0]
    n = sum(1 if p.imag == 0 else 2 for p in kept)
    a, b = np.zeros((n, n)), np.zeros(n)
    i = 0
    for p in kept:
        if p.imag == 0:
            a[i, i], b[i] = p.real, 1.0
            i += 1
        else:
            a[i:i + 2, i:i + 2] = [[p.real, p.imag], [-p.imag, p.real]]
            b[i] = 2.0
            i += 2
    return a, b


def _lstsq(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The relaxed system's least squares, whole (pivoted QR). Measured (2026-12-07, 120 systems of orders 2-40 from
    ``nifo loop`` on physics-fleet case 64, 2771 rows): the reduced system of the fast implementation (Deschrijver
    et al. 2008: the residue columns projected out, only σ's unknowns solved) 0.239 s against 0.244 s, no faster
    for one response; the normal equations 6x faster at 82 columns, but the column-scaled systems' condition numbers
    reach 5e7 (median 2e5 at order 40), so squared they would lose every digit. Nor would a convergence test stop the
    12 relocations early: after 11 the poles (sorted) differ from the 12th's by 1e-3 of themselves at order 8 and by
    more than their own size at orders 14-40. And 6 relocations instead of 12 cost accuracy: F-16 leave-one-level-out
    (``benchmarks/bench_hands_off.py --silverbox-levels``), 1/3/5 → 7 band NMSE 0.622 → 0.769 %, 3/5/7 → 1's sweep
    0.103 → 0.113 %."""
    return scipy.linalg.lstsq(a, y, lapack_driver="gelsy", check_finite=False)[0]


def _stack(a: np.ndarray) -> np.ndarray:
    return np.concatenate([a.real, a.imag])


def _flip(poles: np.ndarray, min_decay: float) -> np.ndarray:
    """Unstable poles mirrored into the left half plane; every pole decays at least at ``min_decay`` [1/s]."""
    return np.minimum(-np.abs(poles.real), -min_decay) + 1j * poles.imag


def conjugate_pairs(poles: np.ndarray) -> np.ndarray:
    """Keep one pole per conjugate pair (Im > 0) and real poles, then add the conjugates back."""
    up = [p for p in poles if p.imag > 1e-9 * max(abs(p), 1)]
    real = [complex(p.real, 0) for p in poles if abs(p.imag) <= 1e-9 * max(abs(p), 1)]
    return np.array(real + up + [np.conj(p) for p in up], complex)


def fit_residues(s, h, wgt, poles):
    """Residues for fixed poles, with Σ r = 0 (relative degree 2), weighted least squares."""
    phi = _basis(s, poles)
    a = _stack(phi * wgt[:, None])
    y = _stack(h * wgt)
    # constraint row: sum of complex residues = Σ_real c + Σ_pairs 2·c1 = 0
    con = np.concatenate([[1.0] if p.imag == 0 else [2.0, 0.0] for p in poles if p.imag >= 0])
    # Σ r = 0 by elimination: x = N·y with N a basis of the constraint's null space
    null = scipy.linalg.null_space(con[None, :])
    an = a @ null
    cn = np.linalg.norm(an, axis=0)
    cn[cn == 0] = 1.0
    x = null @ (_lstsq(an / cn, y) / cn)
    res, i = [], 0
    kept = [p for p in poles if p.imag >= 0]
    for p in kept:
        if p.imag == 0:
            res.append(complex(x[i]))
            i += 1
        else:
            res.append(complex(x[i], x[i + 1]))
            i += 2
    r = np.array(res)
    full_p = np.concatenate([np.array(kept), np.conj([p for p in kept if p.imag > 0])])
    full_r = np.concatenate([r, np.conj([rr for p, rr in zip(kept, r) if p.imag > 0])])
    return full_p, full_r


def vector_fit(s, h, wgt, poles, n_iter, min_decay):
    """Relaxed vector fitting pole relocation (Gustavsen 2006), unstable poles flipped each pass."""
    ns = s.size
    for _ in range(n_iter):
        phi = _basis(s, poles)
        m = phi.shape[1]
        # unknowns: c (m), d, c̃ (m), d̃ ;   Σ c φ + d - H·(Σ c̃ φ + d̃) = 0
        blk = np.concatenate([phi, np.ones((ns, 1)), -h[:, None] * phi, -h[:, None]], axis=1) * wgt[:, None]
        a = _stack(blk)
        # relaxation: Re Σ_k σ(s_k) = ns, scaled to the data
        norm_row = np.concatenate([np.zeros(m + 1), np.sum(phi, axis=0).real, [ns]])
        scale = np.linalg.norm(wgt * h) / ns
        a = np.vstack([a, scale * norm_row])
        y = np.zeros(a.shape[0])
        y[-1] = scale * ns
        cn = np.linalg.norm(a, axis=0)
        cn[cn == 0] = 1.0
        x = _lstsq(a / cn, y) / cn          # columns scaled: conditioning
        ct, dt = x[m + 1: 2 * m + 1], x[-1]
        if abs(dt) < 1e-8:
            dt = 1e-8
        ab, bb = _real_block(poles)
        new = np.linalg.eigvals(ab - np.outer(bb, ct) / dt)
        poles = conjugate_pairs(_flip(new, min_decay))
    return poles


def start_poles(n_pairs: int, band_hz: tuple[float, float]) -> np.ndarray:
    w = 2 * np.pi * np.linspace(max(band_hz[0], 0.05), band_hz[1], n_pairs)
    up = -w / 100 + 1j * w
    return np.concatenate([up, np.conj(up)])


@dataclass(frozen=True)
class RecordLines:
    """One record's measured transmissibility on its lines and what each line weighs in *predicting* that record.

    The prediction error of record r on line k is ω²·|A1_k|·|Hz_k - Ĥz_k| (A2 - A1 = s²·Hz·A1), and its NMSE
    divides by Σ|A2|²: ``weight`` = ω²·|A1_k| / √(Σ_k |A2_k|²), so that Σ weight²·|Hz - Ĥz|² is the record's
    band NMSE of a linear model (the metric of :mod:`nifo_core.predict.prediction_error`; records count by their relative
    error, as in :mod:`nifo_core.predict.refine`).
    """

    freq_hz: np.ndarray
    t21: np.ndarray
    weight: np.ndarray

    @classmethod
    def from_spectra(cls, freq_hz, g11, g12, g22, band_hz: tuple[float, float]) -> "RecordLines":
        """From one record's auto and cross spectra of A1, A2 (H1 = G12/G11) on the lines of ``band_hz``."""
        f = np.asarray(freq_hz, float)
        m = (f >= band_hz[0]) & (f <= band_hz[1]) & (f > 0) & (np.asarray(g11).real > 0)
        g11, g12, g22 = (np.asarray(x)[m] for x in (g11, g12, g22))
        w = 2 * np.pi * f[m]
        den = float(np.sqrt(np.sum(np.asarray(g22).real)))
        return cls(f[m], g12 / g11.real, w ** 2 * np.sqrt(g11.real) / max(den, 1e-300))


@dataclass(frozen=True)
class Refit:
    """Residues refitted on the records' own lines (:func:`refit`)."""

    poles: np.ndarray
    residues: np.ndarray
    #: mean band NMSE fraction of the records' linear prediction
    error: float


def refit(lines: "list[RecordLines]", poles: np.ndarray) -> Refit:
    """Residues on ``poles`` minimising the records' summed prediction error (RecordLines)."""
    s = np.concatenate([2j * np.pi * x.freq_hz for x in lines])
    w = np.concatenate([2 * np.pi * x.freq_hz for x in lines])
    h = np.concatenate([(1 - x.t21) / (2 * np.pi * x.freq_hz) ** 2 for x in lines])
    wgt = np.concatenate([x.weight for x in lines])
    ok = np.isfinite(h) & np.isfinite(wgt) & (w > 0)
    p, r = fit_residues(s[ok], h[ok], wgt[ok], poles)
    hh = np.sum(r[:, None] / (s[ok][None, :] - p[:, None]), axis=0)
    return Refit(p, r, float(np.sum(wgt[ok] ** 2 * np.abs(h[ok] - hh) ** 2) / len(lines)))
