"""Feedback paths: every nonlinear term's force reaches the response through its own linear path.

Every other model in nifo has the structure of the static NIFO fit
(:mod:`nifo_core.predict.linear_part`): the strut force enters the linear part where
the spindle's inertial force does, ``Z = Hz·(A1 + Σ γ_i·G_i)``. That is exact
for a body that is one rigid mass. On a flexible body — the F-16's payload
behind its wing interface, a subframe, a cab — the interface force reaches
the measured point through the body's own modes. For a body with receptance
Hp(s) from the interface to the measured point, joined by a linear spring-damper
K + C·s and the nonlinear force g (z = x2 - x1 at the interface)::

    X2 = -Hp·((K + C·s)·Z + G),  Z = X2 - X1
    ⇒ Z = -(1/s²)/(1 + Hp·(K + C·s))·A1 - Hp/(1 + Hp·(K + C·s))·G

The two paths share their poles (the zeros of 1 + Hp·(K + C·s)) and differ
in their residues; their ratio s²·Hp(s) is 1/M2 only for a rigid mass. This
is the structure of FNSI and of nonlinear state-space models (one A, an input
matrix B for the measured input and another, E, for the nonlinear feedback;
Noël & Kerschen 2013, Paduart et al. 2010). Here::

    Z = Hz(s)·A1 + Σ_i Hq_i(s)·N_i,     Hq_i(s) = Σ_n q_in/(s - p_n)   (the poles p_n of Hz)
    N_i = g_i(z) - α_i·z                (the term's bounded remainder: its slope α_i stays in Hz)

Hz is the linear model identified on the same data (its poles and residues
kept); the path residues q_in are fitted. With the poles fixed they enter
linearly, so the fit is one least-squares problem over the lines of the
analysis band of every identification record (equation error, as NIFO: z from
the measured accelerations), each record weighted by its relative error, the
residues constrained to Σ_n q_in = 0 (relative degree 2: no algebraic loop),
and a ridge λ·max|M| on the q_in (they are ~2 per mode and per term, and the
nonlinear remainders are small at low levels). λ is chosen on the
identification records alone, by their *simulation* error from rest (the
metric of :mod:`nifo_core.predict.refine`) over a fixed grid.

Only terms whose remainder is bounded whatever the motion are allowed
(backlash, clearance, saturation): then a stable Hz with any path residues
gives a bounded response — no q can destabilise the model at another level.
Bounded is not enough: each term is piecewise linear, and while a term sits in
its small-amplitude regime (a play stuck, z inside a clearance) its remainder
is a linear feedback (s_i - α_i)·z through Hq_i. A structure whose joint is
stuck is a stable linear structure, so every combination of regimes must be
a stable linear system (:func:`regimes_stable`); a fit where one is not would
self-oscillate at low amplitude (measured on the F-16: 53 % error on the
4.8 N sine sweep from a clearance path fitted on levels 3/5/7). Such a fit is
not eligible, whatever its score.

Measured on the F-16 ground-vibration test in ``docs/f16_predict.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from itertools import combinations
from typing import Callable, Sequence

import numba
import numpy as np

from ..kinds.describing import KINDS, Term, path_slopes
from ..errors import ConfigError
from ..signal.integrate import IntegrationBand, integrate
from .linear_part import LinearPart, pole_residue_response
from .refine import model_nmse
from ..signal.spectral import SpectralSettings, block_ffts
from ..kinds.strut_forces import g_one, strut_arrays

__all__ = ["PATH_KINDS", "SMALL_SLOPE", "JointFit", "PathFit", "PathResult", "check_terms", "choose_paths",
           "equivalent_gammas", "fit_joint", "fit_paths", "path_model", "path_remainders", "regimes_stable"]

#: kinds a feedback path may carry, with the slope α of z their remainder g - α·z leaves in Hz (their slope at
#: large amplitude: the fully active regime feeds nothing back linearly)
PATH_KINDS = {name: KINDS[name].path_slopes[0] for name in sorted(KINDS) if KINDS[name].path_slopes is not None}
#: their slope at small amplitude (a play stuck, inside a clearance, below a saturation's limit)
SMALL_SLOPE = {name: KINDS[name].path_slopes[1] for name in PATH_KINDS}

#: the default grid of ridge weights λ (relative to the largest entry of the regression matrix): from barely
#: regularised to paths shrunk almost to nothing (the linear model)
RIDGE_GRID = (0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0)


#: the slopes α_i of the terms; :class:`ConfigError` for a kind without a bounded remainder (the registry's)
check_terms = path_slopes


@numba.njit(cache=True)
def _remainders(z, zd, codes, p0, p1, alpha, out):  # pragma: no cover - compiled
    play = np.zeros(codes.size)
    for k in range(z.size):
        for i in range(codes.size):
            g = g_one(codes[i], p0[i], p1[i], z[k], zd[k], play[i])
            play[i] = g
            out[i, k] = g - alpha[i] * z[k]


def path_remainders(terms: Sequence[Term], z: np.ndarray, zdot: np.ndarray) -> np.ndarray:
    """N_i(t) = g_i(z) - α_i·z for every term, shape (n_terms, n) (plays start centred at z[0])."""
    alpha = check_terms(terms)
    codes, _, p0, p1 = strut_arrays(list(terms), [1.0] * len(terms))
    z = np.ascontiguousarray(z, float)
    out = np.zeros((len(terms), z.size))
    _remainders(z, np.ascontiguousarray(zdot, float), codes, p0, p1, alpha, out)
    return out


def _upper(poles: np.ndarray) -> np.ndarray:
    """Indices of the real poles and of the upper member of each conjugate pair."""
    return np.flatnonzero(poles.imag >= 0)


def _basis(poles: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Columns of Σ q/(s-p) in real parameters (Re q, Im q per pair; q per real pole) and Σ q's weights."""
    cols, wsum = [], []
    for k in _upper(poles):
        p = poles[k]
        a = 1 / (s - p)
        if p.imag == 0:
            cols.append(a)
            wsum.append(1.0)
        else:
            b = 1 / (s - np.conj(p))
            cols += [a + b, 1j * (a - b)]
            wsum += [2.0, 0.0]
    return np.column_stack(cols), np.asarray(wsum)


def _unpack(poles: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Real parameters → residues on every pole (conjugate pairs both listed)."""
    q = np.zeros(poles.size, complex)
    i = 0
    for k in _upper(poles):
        if poles[k].imag == 0:
            q[k] = x[i]
            i += 1
        else:
            q[k] = x[i] + 1j * x[i + 1]
            d = np.abs(poles - np.conj(poles[k]))
            d[k] = np.inf
            j = int(np.argmin(d))
            q[j] = np.conj(q[k])
            i += 2
    return q


def _record_rows(rec, terms, settings: SpectralSettings, band: IntegrationBand, lines: np.ndarray,
                 period_samples: int | None):
    """Spectra (A1, A2, N_i) of one record at ``lines``, per block (rows) — or, for periodic data, of the
    period average (one row): z integrated exactly at the band's lines, the remainders over the periodic z."""
    a1 = np.asarray(rec.spindle_accel, float)
    a2 = np.asarray(rec.body_accel, float)
    if period_samples:
        p = int(period_samples)
        k = a1.size // p
        if k < 1:
            raise ConfigError(f"{rec.source or 'a record'} is shorter than one period ({p} samples)")
        a1, a2 = (x[:k * p].reshape(k, p).mean(axis=0) for x in (a1, a2))
        f = np.fft.rfftfreq(p, 1.0 / rec.fs_hz)
        s = 2j * np.pi * f
        keep = (f >= band.f_lo_hz) & (f <= band.f_hi_hz)
        d = np.zeros(f.size, complex)
        d[keep] = np.fft.rfft(a2 - a1)[keep] / s[keep] ** 2
        z, zd = np.fft.irfft(d, p), np.fft.irfft(d * s, p)
        n = path_remainders(terms, np.tile(z, 3), np.tile(zd, 3))[:, 2 * p:]     # the plays settled
        spec = np.fft.rfft(np.vstack([a1, a2, n]), axis=1)[:, None, lines]        # block = period: same lines
    else:
        integ = integrate(a2 - a1, rec.fs_hz, band=band)
        n = path_remainders(terms, integ.displacement, integ.velocity)
        spec = block_ffts(np.vstack([a1, a2, n]), settings)[:, :, lines]          # (2 + m, blocks, lines)
    return spec[0], spec[1], spec[2:]


@dataclass(frozen=True)
class PathFit:
    """The fitted feedback paths of one ridge weight.

    Attributes
    ----------
    ridge : float
        λ of the ridge (relative to the largest regression entry).
    paths : ndarray, complex, shape (n_terms, n_poles)
        q_in on the poles of the linear part (conjugate pairs both listed).
    score : float
        Sum of the identification records' simulation NMSE [%] (nan before :func:`choose_paths` scores it).
    scores : tuple of float
        Per record.
    stable : bool
        Every regime of the terms (each in its small- or large-amplitude state) is a stable linear system.
    """

    ridge: float
    paths: np.ndarray
    score: float = float("nan")
    scores: tuple = ()
    stable: bool = True


def _design(records: Sequence, terms: Sequence[Term], linear: LinearPart, *, settings: SpectralSettings,
            band: IntegrationBand, analysis_band_hz: tuple[float, float], period_samples: int | None):
    """The least-squares problem of the path residues: (matrix, right-hand side, constraint rows, basis size)."""
    if period_samples and int(period_samples) != settings.block:
        raise ConfigError(f"periodic data: the block ({settings.block}) must be the period ({period_samples})",
                          hint="--block equal to --period-samples")
    if linear.kind != "rational":
        raise ConfigError("feedback paths need a rational linear part", hint="identify with the rational linear part")
    if any(linear.absorbed):
        raise ConfigError("feedback paths sit on a linear model's own linear part (nothing absorbed)",
                          hint="pass the linear model identified on the same data")
    check_terms(terms)
    if not records:
        raise ConfigError("no records to fit feedback paths on")
    fs = float(records[0].fs_hz)
    f = settings.freq_hz(fs)
    lines = np.flatnonzero((f >= analysis_band_hz[0]) & (f <= analysis_band_hz[1]))
    s = 2j * np.pi * f[lines]
    basis, wsum = _basis(linear.poles, s)
    hz = linear.hz_realised(f[lines])
    m, nb = len(terms), basis.shape[1]
    rows, rhs = [], []
    for rec in records:
        A1, A2, N = _record_rows(rec, terms, settings, band, lines, period_samples)
        y = (A2 - A1) - (s**2 * hz)[None, :] * A1                        # blocks × lines
        cols = [(s**2)[None, :, None] * basis[None, :, :] * N[i][:, :, None] for i in range(m)]
        mat = np.concatenate(cols, axis=2).reshape(-1, m * nb)
        scale = 1.0 / max(np.linalg.norm(A2), 1e-300)
        rows.append(np.vstack([mat.real, mat.imag]) * scale)
        rhs.append(np.concatenate([y.ravel().real, y.ravel().imag]) * scale)
    mat, y = np.vstack(rows), np.concatenate(rhs)
    big = float(np.abs(mat).max())
    if not np.isfinite(big) or big == 0:
        raise ConfigError("the terms' remainders are zero on these records: nothing to fit a path to",
                          hint="check the terms' widths against the motion z")
    cons = np.zeros((m, m * nb))
    for i in range(m):
        cons[i, i * nb:(i + 1) * nb] = wsum
    return mat, y, cons, nb, big


def _solve(mat, y, cons, big, lam, m, nb):
    a = np.vstack([mat, 1e3 * big * cons, lam * big * np.eye(m * nb)])
    b = np.concatenate([y, np.zeros(m + m * nb)])
    return np.linalg.lstsq(a, b, rcond=None)[0]


def fit_paths(records: Sequence, terms: Sequence[Term], linear: LinearPart, *, settings: SpectralSettings,
              band: IntegrationBand, analysis_band_hz: tuple[float, float], period_samples: int | None = None,
              ridges: Sequence[float] = RIDGE_GRID) -> list[PathFit]:
    """The path residues of ``terms`` on the poles of the rational ``linear`` part, one fit per ridge weight.

    ``records`` are the identification records without their start-up: their
    blocks (``settings``), z integrated in ``band`` as NIFO does; with
    ``period_samples`` (a periodic excitation whose period is the block) the
    period average, z integrated exactly on its lines.
    """
    mat, y, cons, nb, big = _design(records, terms, linear, settings=settings, band=band,
                                    analysis_band_hz=analysis_band_hz, period_samples=period_samples)
    m = len(terms)
    out = []
    for lam in ridges:
        x = _solve(mat, y, cons, big, lam, m, nb)
        out.append(PathFit(float(lam), np.array([_unpack(linear.poles, x[i * nb:(i + 1) * nb]) for i in range(m)])))
    return out


def _joint_design(records: Sequence, terms: Sequence[Term], linear: LinearPart, *, settings: SpectralSettings,
                  band: IntegrationBand, analysis_band_hz: tuple[float, float], period_samples: int | None):
    """The joint least squares of the linear part's residues and the terms' path residues on ``linear``'s poles:
    A2 - A1 = s²·Hz·A1 + Σ_i s²·Hq_i·N_i, every record weighted by 1/‖A2‖ (its relative error)."""
    if period_samples and int(period_samples) != settings.block:
        raise ConfigError(f"periodic data: the block ({settings.block}) must be the period ({period_samples})",
                          hint="--block equal to --period-samples")
    if linear.kind != "rational" or any(linear.absorbed):
        raise ConfigError("feedback paths need a linear model's own rational linear part",
                          hint="pass the linear model identified on the same data")
    check_terms(terms)
    fs = float(records[0].fs_hz)
    f = settings.freq_hz(fs)
    lines = np.flatnonzero((f >= analysis_band_hz[0]) & (f <= analysis_band_hz[1]))
    s = 2j * np.pi * f[lines]
    basis, wsum = _basis(linear.poles, s)
    m, nb = len(terms), basis.shape[1]
    rows, rhs = [], []
    for rec in records:
        A1, A2, N = _record_rows(rec, terms, settings, band, lines, period_samples)
        y = A2 - A1
        cols = [(s**2)[None, :, None] * basis[None, :, :] * A1[:, :, None]]
        cols += [(s**2)[None, :, None] * basis[None, :, :] * N[i][:, :, None] for i in range(m)]
        mat = np.concatenate(cols, axis=2).reshape(-1, (m + 1) * nb)
        scale = 1.0 / max(np.linalg.norm(A2), 1e-300)
        rows.append(np.vstack([mat.real, mat.imag]) * scale)
        rhs.append(np.concatenate([y.ravel().real, y.ravel().imag]) * scale)
    mat, y = np.vstack(rows), np.concatenate(rhs)
    big_lin = float(np.abs(mat[:, :nb]).max())
    big = float(np.abs(mat[:, nb:]).max())
    if not np.isfinite(big) or big == 0:
        raise ConfigError("the terms' remainders are zero on these records: nothing to fit a path to",
                          hint="check the terms' widths against the motion z")
    cons = np.zeros((m + 1, (m + 1) * nb))
    for i in range(m + 1):
        cons[i, i * nb:(i + 1) * nb] = wsum
    return mat, y, cons, nb, big_lin, big


def _joint_solve(design, lam: float, m: int) -> np.ndarray:
    mat, y, cons, nb, big_lin, big = design
    reg = np.zeros((m * nb, (m + 1) * nb))
    reg[:, nb:] = np.eye(m * nb)
    a = np.vstack([mat, 1e3 * max(big_lin, big) * cons, lam * big * reg])
    b = np.concatenate([y, np.zeros(m + 1 + m * nb)])
    return np.linalg.lstsq(a, b, rcond=None)[0]


@dataclass(frozen=True)
class JointFit:
    """The linear part's residues and the terms' path residues of one ridge weight (:func:`fit_joint`)."""

    ridge: float
    residues: np.ndarray        # of the linear part, on its poles
    paths: np.ndarray           # (n_terms, n_poles)


def fit_joint(records: Sequence, terms: Sequence[Term], linear: LinearPart, *, settings: SpectralSettings,
              band: IntegrationBand, analysis_band_hz: tuple[float, float], period_samples: int | None = None,
              ridges: Sequence[float] = RIDGE_GRID) -> list[JointFit]:
    """The linear part identified *jointly* with the terms' feedback paths, its poles kept (one fit per ridge).

    A2 - A1 = s²·Hz(s)·A1 + Σ_i s²·Hq_i(s)·N_i is linear in the residues of Hz and of every Hq_i once the poles
    are fixed: one least-squares problem over the analysis-band lines of every record (periodic data: the period
    average), each record by its relative error, Σ r = 0 and Σ q_i = 0 (relative degree 2), a ridge λ on the
    path residues alone (relative to the largest path column). Without terms it is the linear model that predicts
    the records best (:class:`~nifo_core.predict.vector_fit.RecordLines`); with them the linear part and the paths share
    what they explain, so the model nests its linear model on this metric.
    """
    m = len(terms)
    design = _joint_design(records, terms, linear, settings=settings, band=band, analysis_band_hz=analysis_band_hz,
                           period_samples=period_samples)
    nb = design[3]
    out = []
    for lam in ridges:
        x = _joint_solve(design, float(lam), m)
        out.append(JointFit(float(lam), _unpack(linear.poles, x[:nb]),
                            np.array([_unpack(linear.poles, x[(i + 1) * nb:(i + 2) * nb]) for i in range(m)])))
    return out


def equivalent_gammas(linear: LinearPart, paths: np.ndarray, analysis_band_hz: tuple[float, float]) -> np.ndarray:
    """γ_i that a constant-coefficient model would have: the band median of Re(Hq_i/Hz) (for reports)."""
    f = np.linspace(analysis_band_hz[0], analysis_band_hz[1], 200)
    hq = pole_residue_response(linear.poles, paths, f)
    return np.median((hq / linear.hz_realised(f)[None, :]).real, axis=1)


def regimes_stable(linear: LinearPart, terms: Sequence[Term]) -> bool:
    """Every combination of the terms' regimes — each in its small-amplitude state (slope s_i) or its large one
    (slope α_i, nothing fed back) — is a stable linear system: A + Σ_{i small} (s_i - α_i)·e_i·c."""
    a, _, e, c = linear.path_state_space()
    gain = np.array([SMALL_SLOPE[t.kind] - PATH_KINDS[t.kind] for t in terms])
    for k in range(1, len(terms) + 1):
        for sub in combinations(range(len(terms)), k):
            acl = a + np.outer(e[:, list(sub)] @ gain[list(sub)], c)
            if np.max(np.linalg.eigvals(acl).real) >= 0:
                return False
    return True


def choose_paths(fits: Sequence[PathFit], score: Callable[[PathFit], Sequence[float]],
                 stable: Callable[[PathFit], bool] = lambda fit: True) -> tuple[PathFit, list]:
    """Score every fit by ``score(fit)`` (the identification records' simulation NMSE [%]); of those whose
    regimes are ``stable``, the lowest sum wins.

    Returns the chosen fit and every fit with its score (the grid, for the report; an unstable fit is not
    scored). :class:`ConfigError` when no fit is eligible."""
    scored = []
    for fit in fits:
        if not stable(fit):
            scored.append(PathFit(fit.ridge, fit.paths, float("inf"), (), False))
            continue
        per = tuple(float(v) for v in score(fit))
        total = float(np.sum(per)) if all(np.isfinite(per)) else float("inf")
        scored.append(PathFit(fit.ridge, fit.paths, total, per))
    best = min(scored, key=lambda p: p.score)
    if not np.isfinite(best.score):
        raise ConfigError("no ridge weight gave feedback paths whose every regime (each term stuck or active) is "
                          "stable and that predict the identification records: these data do not determine the paths",
                          hint="identify on levels that include the low-amplitude regime, or use constant "
                               "coefficients (--refine)")
    return best, scored


@dataclass(frozen=True)
class PathResult:
    """A model with feedback paths (:func:`path_model`), the chosen fit and the whole ridge grid.

    ``linear_scores``: the linear model's NMSE [%] on the same records, the baseline on the same metric.
    """

    model: object
    chosen: PathFit
    grid: tuple
    linear_scores: tuple

    @property
    def message(self) -> str:
        lin = float(np.sum(self.linear_scores))
        return (f"feedback paths: ridge {self.chosen.ridge:g} chosen on the identification records' prediction "
                f"NMSE (sum {self.chosen.score:.4g} % against the linear model's {lin:.4g} %)")

    def to_dict(self) -> dict:
        return {"ridge": self.chosen.ridge, "nmse_percent": list(self.chosen.scores),
                "linear_nmse_percent": list(self.linear_scores), "message": self.message,
                "grid": [{"ridge": g.ridge, "nmse_sum_percent": g.score, "nmse_percent": list(g.scores),
                          "regimes_stable": g.stable} for g in self.grid]}


def path_model(linear_model, terms: Sequence[Term], fit_records: Sequence, score_records: Sequence, *,
               period_samples: int | None = None, skip_samples=0, ridges: Sequence[float] = RIDGE_GRID,
               progress: Callable[[float, float], None] | None = None) -> PathResult:
    """The model with ``terms`` through feedback paths on ``linear_model``'s linear part (module docstring).

    Parameters
    ----------
    linear_model : IdentifiedModel
        The linear model identified on the same data (no terms, a rational linear part).
    terms : sequence of Term
        Backlash, clearance or saturation terms.
    fit_records : sequence of Record
        The identification records without their start-up (the least-squares fit).
    score_records : sequence of Record
        The same records from their start (simulated from rest), for the ridge choice.
    period_samples, skip_samples
        Scoring as :func:`nifo_core.predict.refine.model_nmse`; ``period_samples`` also selects the periodic fit.
    progress : callable(ridge, nmse_sum), optional

    Returns
    -------
    PathResult
    """
    lin = linear_model.linear
    band_hz = linear_model.analysis_band_hz
    fits = fit_paths(fit_records, terms, lin, settings=linear_model.settings, band=linear_model.band,
                     analysis_band_hz=band_hz, period_samples=period_samples, ridges=ridges)
    f = linear_model.freq_hz

    def make(paths: np.ndarray):
        b = pole_residue_response(lin.poles, paths, f)
        return replace(linear_model, terms=tuple(terms), c_over_m2=equivalent_gammas(lin, paths, band_hz), b=b,
                       linear=replace(lin, paths=paths, reason=lin.reason + "; the terms through their own "
                                      "feedback paths on its poles"),
                       source="paths", provenance={**dict(linear_model.provenance), "from": "feedback_paths"})

    def score(fit: PathFit):
        out = model_nmse(make(fit.paths), score_records, band_hz=band_hz, period_samples=period_samples,
                         skip_samples=skip_samples)
        if progress is not None:
            progress(fit.ridge, float(np.sum(out)))
        return out

    best, grid = choose_paths(fits, score, lambda fit: regimes_stable(replace(lin, paths=fit.paths), terms))
    base = model_nmse(linear_model, score_records, band_hz=band_hz, period_samples=period_samples,
                      skip_samples=skip_samples)
    return PathResult(make(best.paths), best, tuple(grid), tuple(float(v) for v in base))
