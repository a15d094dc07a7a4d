"""The identified model and its predictions (METHOD.md §4, paper §3.3 validation).

A model is the nominal linear transmissibility T21(ω) plus describing
functions g_i with their coefficients. Built from a :class:`~nifo_core.nifo.NifoResult`
it keeps both forms the estimator gives:

- non-parametric: T21(ω) and B_i(ω) on the spectral lines (paper Eq. 8);
- parametric: a body-side model fitted to them, per unit body mass M2,

      z̈ + c·ż + k·z + k3·x2 = -ẍ1 - Σ γ_i·g_i(z, ż),     z = x2 - x1,     (paper Eq. 2 / M2)

  with k = K2/M2, c = C2/M2 (and k3 = K3/M2, 0 by default) fitted to T21 by
  linear least squares of ``(k + jωc)·(T21 - 1) + k3·T21 = ω²·T21`` over the
  analysis band, and γ_i = c_i/M2 the constant coefficients (the ``static``
  fit of the result, flat in frequency for a static nonlinearity).

Prediction from a MEASURED spindle acceleration solves the feedback
x2 = T21·x1 + Σ B_i·G_i(x2 - x1) (METHOD.md §4). We solve it in the frequency
domain on the whole (zero-padded) record, for the relative displacement:

    Z = Hz·A1 + Σ Bz_i·G_i(z, ż),   Hz = (1 - T21)/ω²,  Bz_i = B_i   (K3 = 0)

by a relaxed fixed-point iteration with an equivalent-linearisation split:
each iteration regresses g_i on (z, ż) of the current iterate (λ_i = α_i + jωβ_i),
moves that linear part to the left-hand side and iterates only on the
remainder, so the loop gain stays well below one (plain Picard iteration
stalls or diverges when Σ Bz_i·λ_i approaches 1, e.g. a stiff backlash). The
result satisfies the undivided equation exactly at convergence. ``method``
chooses where Hz and Bz_i come from: ``'parametric'`` (default: the fitted body
model at every frequency: smooth, extrapolates, equals simulating the
parametric model in time) or ``'nonparametric'`` (the identified T21(ω),
B_i(ω) inside the analysis band, cross-faded to the parametric model outside
it, where the estimates are not trustworthy).

The body acceleration is then A2 = A1 - ω²·Z. The first and last
``edge_s`` seconds of a prediction carry the start-up transient (the record's
past is unknown) and are best left out of comparisons.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Literal, Mapping, Sequence

import numpy as np
import scipy.fft

from .describing import Term, make_term, play_operator
from .errors import ConfigError, IllConditionedError, InputError
from .integrate import IntegrationBand
from .nifo import NifoResult
from .spectral import SpectralSettings, coherence, cross_spectra, h1

__all__ = ["BodyModel", "IdentifiedModel", "Prediction", "PredictedTransmissibility", "PredictionDivergedError",
           "fit_body_model", "predict_body", "predict_transmissibility"]

Method = Literal["parametric", "nonparametric"]


class PredictionDivergedError(IllConditionedError):
    """The feedback x2 = T21·x1 + Σ B_i·G_i(x2 - x1) could not be solved for this input."""

    exit_code = 12


def _ro(a) -> np.ndarray:
    a = np.array(a)
    a.flags.writeable = False
    return a


def _cplx(a) -> dict:
    return {"re": np.real(a).tolist(), "im": np.imag(a).tolist()}


def _uncplx(d) -> np.ndarray:
    return np.asarray(d["re"], float) + 1j * np.asarray(d["im"], float)


# ---------------------------------------------------------------------------------------------
# the parametric body model
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BodyModel:
    """Body side per unit body mass: k = K2/M2 [1/s²], c = C2/M2 [1/s], k3 = K3/M2 [1/s²].

    ``fit_rms`` is the relative RMS misfit of T21 over the fitted band.
    """

    k: float
    c: float
    k3: float = 0.0
    fit_rms: float = float("nan")

    def t21(self, freq_hz) -> np.ndarray:
        """T21 = (k + jωc)/(-ω² + k + jωc + k3) of this model."""
        w = 2 * np.pi * np.asarray(freq_hz, float)
        zz = self.k + 1j * w * self.c
        return zz / (-(w**2) + zz + self.k3)

    def natural_frequency_hz(self) -> float:
        return float(np.sqrt(self.k + self.k3) / (2 * np.pi))

    def to_dict(self) -> dict:
        return {"k": self.k, "c": self.c, "k3": self.k3, "fit_rms": self.fit_rms}


def fit_body_model(freq_hz: np.ndarray, t21: np.ndarray, *, band_hz: tuple[float, float] = (2.0, 30.0),
                   fit_k3: bool = False, weights: np.ndarray | None = None) -> BodyModel:
    """Fit k = K2/M2, c = C2/M2 (and k3 = K3/M2) to a nominal T21 (METHOD.md §4).

    Linear least squares of the equation error ``(k + jωc)·(T21 - 1) + k3·T21 - ω²·T21``
    over the lines of ``band_hz`` (real and imaginary parts), each line
    scaled by 1/|ω²·T21| so the error is relative.

    Raises
    ------
    ConfigError
        When the band holds fewer than 3 usable lines or the fit is not physical (k or c ≤ 0).
    """
    f = np.asarray(freq_hz, float)
    t = np.asarray(t21, complex)
    w = 2 * np.pi * f
    m = (f >= band_hz[0]) & (f <= band_hz[1]) & np.isfinite(t) & (w > 0)
    if weights is not None:
        m &= np.isfinite(weights) & (np.asarray(weights) > 0)
    if m.sum() < 3:
        raise ConfigError(f"only {int(m.sum())} usable lines in {band_hz[0]:g}-{band_hz[1]:g} Hz to fit the body model",
                          hint="widen the band")
    wm, tm = w[m], t[m]
    scale = 1.0 / np.abs(wm**2 * tm)
    if weights is not None:
        scale = scale * np.sqrt(np.asarray(weights)[m])
    cols = [(tm - 1) * scale, 1j * wm * (tm - 1) * scale]
    if fit_k3:
        cols.append(tm * scale)
    a = np.stack(cols, axis=1)
    y = wm**2 * tm * scale
    x, *_ = np.linalg.lstsq(np.concatenate([a.real, a.imag]), np.concatenate([y.real, y.imag]), rcond=None)
    k, c = float(x[0]), float(x[1])
    k3 = float(x[2]) if fit_k3 else 0.0
    if not (k > 0 and c > 0):
        raise ConfigError(f"the body model fitted to T21 is not physical (k={k:.4g} 1/s², c={c:.4g} 1/s)",
                          hint="check the analysis band and the coherence of T21")
    model = BodyModel(k, c, k3)
    resid = np.abs(model.t21(f[m]) / tm - 1)
    return BodyModel(k, c, k3, float(np.sqrt(np.mean(resid**2))))


# ---------------------------------------------------------------------------------------------
# the identified model
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class IdentifiedModel:
    """T21(ω) + describing functions + coefficients: what ``nifo identify`` produces.

    Attributes
    ----------
    freq_hz : ndarray, shape (nf,)
        Spectral lines of the non-parametric functions [Hz].
    t21 : ndarray, complex, shape (nf,)
        Nominal spindle→body transmissibility.
    b : ndarray, complex, shape (n_terms, nf)
        B_i(ω) of paper Eq. 8 [m per unit of g].
    terms : tuple of Term
    c_over_m2 : ndarray, shape (n_terms,)
        Constant coefficients γ_i = c_i/M2 [unit of c per kg].
    body : BodyModel
        Parametric body side fitted to ``t21``.
    analysis_band_hz : (float, float)
        Where the non-parametric functions are trusted.
    fs_hz : float
        Sample rate of the identification data [Hz].
    settings : SpectralSettings
    band : IntegrationBand
    source : {'static', 'free', 'h1'}
        Which estimate of the result the model was made from.
    provenance : mapping
    """

    freq_hz: np.ndarray
    t21: np.ndarray
    b: np.ndarray
    terms: tuple[Term, ...]
    c_over_m2: np.ndarray
    body: BodyModel
    analysis_band_hz: tuple[float, float]
    fs_hz: float
    settings: SpectralSettings
    band: IntegrationBand
    source: str = "static"
    provenance: Mapping = field(default_factory=dict)

    def __post_init__(self) -> None:
        for k in ("freq_hz", "t21", "b", "c_over_m2"):
            object.__setattr__(self, k, _ro(getattr(self, k)))
        object.__setattr__(self, "terms", tuple(self.terms))
        object.__setattr__(self, "analysis_band_hz", (float(self.analysis_band_hz[0]),
                                                      float(self.analysis_band_hz[1])))
        nt, nf = len(self.terms), self.freq_hz.size
        if self.t21.shape != (nf,) or self.b.shape != (nt, nf) or self.c_over_m2.shape != (nt,):
            raise ConfigError(f"model arrays do not fit {nt} terms on {nf} lines: t21 {self.t21.shape}, "
                              f"b {self.b.shape}, c_over_m2 {self.c_over_m2.shape}")

    @classmethod
    def from_nifo(cls, result: NifoResult, *, source: Literal["static", "free", "h1"] = "static",
                  fit_k3: bool = False) -> "IdentifiedModel":
        """Make a model from a NIFO result.

        ``source='static'`` (default) uses the constant-coefficient fit,
        ``'free'`` the per-line estimates (γ = band mean of Re c_i/M2), and
        ``'h1'`` the plain H1 without terms: the equivalent linearisation at
        the identification level, the linear model to compare against.
        """
        prov = {"from": "nifo", "source": source, "n_avg": result.n_avg, **dict(result.provenance)}
        if source == "h1" or not result.terms:
            t21, terms, b, gam = result.t21_h1, (), np.zeros((0, result.freq_hz.size), complex), np.zeros(0)
        elif source == "static":
            if result.static is None:
                raise ConfigError("this NIFO result has no constant-coefficient (static) fit", hint="use source='free'")
            t21, terms, b, gam = result.static.t21, result.terms, result.static.b, result.static.c_over_m2
        elif source == "free":
            t21, terms, b = result.t21, result.terms, result.b
            gam = np.nanmean(result.c_over_m2[:, result.in_band].real, axis=1)
        else:
            raise ConfigError(f"source={source!r} must be 'static', 'free' or 'h1'")
        body = fit_body_model(result.freq_hz, t21, band_hz=result.analysis_band_hz, fit_k3=fit_k3)
        return cls(freq_hz=result.freq_hz, t21=t21, b=b, terms=terms, c_over_m2=gam, body=body,
                   analysis_band_hz=result.analysis_band_hz, fs_hz=result.fs_hz, settings=result.settings,
                   band=result.band, source=source if terms else "h1", provenance=prov)

    def to_dict(self) -> dict:
        """Plain JSON types (complex arrays as ``{"re": [...], "im": [...]}``)."""
        return {"nifo_identified_model": 1, "freq_hz": self.freq_hz.tolist(), "t21": _cplx(self.t21),
                "b": [_cplx(x) for x in self.b], "terms": [t.to_dict() for t in self.terms],
                "c_over_m2": self.c_over_m2.tolist(), "body": self.body.to_dict(),
                "analysis_band_hz": list(self.analysis_band_hz), "fs_hz": self.fs_hz,
                "settings": self.settings.to_dict(), "band": self.band.to_dict(), "source": self.source,
                "provenance": json.loads(json.dumps(dict(self.provenance), default=str))}

    @classmethod
    def from_dict(cls, d: Mapping) -> "IdentifiedModel":
        """Inverse of :meth:`to_dict`; :class:`ConfigError` naming what is wrong otherwise."""
        try:
            terms = tuple(make_term(t) for t in d["terms"])
            nf = len(d["freq_hz"])
            return cls(freq_hz=np.asarray(d["freq_hz"], float), t21=_uncplx(d["t21"]),
                       b=np.array([_uncplx(x) for x in d["b"]], complex).reshape(len(terms), nf), terms=terms,
                       c_over_m2=np.asarray(d["c_over_m2"], float), body=BodyModel(**d["body"]),
                       analysis_band_hz=tuple(d["analysis_band_hz"]), fs_hz=float(d["fs_hz"]),
                       settings=SpectralSettings.from_dict(d["settings"]), band=IntegrationBand(**d["band"]),
                       source=str(d.get("source", "static")), provenance=dict(d.get("provenance") or {}))
        except KeyError as err:
            raise ConfigError(f"identified model lacks {err.args[0]!r}",
                              hint="pass what IdentifiedModel.to_dict() wrote") from None
        except (TypeError, ValueError) as err:
            raise ConfigError(f"cannot read identified model: {err}") from None


# ---------------------------------------------------------------------------------------------
# prediction
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Prediction:
    """Predicted body response to a measured spindle acceleration.

    Attributes
    ----------
    body_accel : ndarray, shape (n,)
        Predicted body acceleration [m/s²].
    z, zdot : ndarray, shape (n,)
        Predicted relative displacement [m] and velocity [m/s] (no DC).
    iterations : int
        Fixed-point iterations used.
    residual : float
        Final relative change of z between iterations.
    method : str
    edge_samples : int
        Samples at each end affected by the record's unknown past (five decay
        times 2/c of the body mode; ``valid`` selects the rest).
    """

    body_accel: np.ndarray
    z: np.ndarray
    zdot: np.ndarray
    iterations: int
    residual: float
    method: str
    edge_samples: int

    def __post_init__(self) -> None:
        for k in ("body_accel", "z", "zdot"):
            object.__setattr__(self, k, _ro(getattr(self, k)))

    @property
    def valid(self) -> slice:
        return slice(self.edge_samples, self.body_accel.size - self.edge_samples)


def _fade(f: np.ndarray, lo: float, hi: float, width: float) -> np.ndarray:
    """1 inside [lo, hi], 0 outside [lo - width, hi + width], raised cosine between."""
    x = np.clip(np.minimum(f - (lo - width), (hi + width) - f) / width, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def _interp_c(f: np.ndarray, fp: np.ndarray, yp: np.ndarray) -> np.ndarray:
    yp = np.where(np.isfinite(yp), yp, 0)     # 0 Hz is undefined in the estimates (and faded out anyway)
    return np.interp(f, fp, yp.real) + 1j * np.interp(f, fp, yp.imag)


def _responses(model: IdentifiedModel, f: np.ndarray, method: Method) -> tuple[np.ndarray, np.ndarray]:
    """Hz (A1 -> Z) and Bz_i (G_i -> Z) on the record's FFT lines; zero at DC."""
    w = 2 * np.pi * f
    bm = model.body
    den = -(w**2) + bm.k + 1j * w * bm.c + bm.k3
    with np.errstate(divide="ignore", invalid="ignore"):
        hz = -(1 - np.where(w > 0, bm.k3 / np.where(w > 0, w, 1) ** 2, 0)) / den    # z̈ + cż + kz + k3·x2 = -ẍ1 - Σγg
    bz = -model.c_over_m2[:, None] / den[None, :]
    if method == "nonparametric":
        lo, hi = model.analysis_band_hz
        wgt = _fade(f, lo, hi, min(0.5, 0.25 * (hi - lo)))
        with np.errstate(divide="ignore", invalid="ignore"):
            hz_np = (1 - _interp_c(f, model.freq_hz, model.t21)) / np.where(w > 0, w, 1) ** 2
        hz = wgt * hz_np + (1 - wgt) * hz
        for i in range(len(model.terms)):
            bz[i] = wgt * _interp_c(f, model.freq_hz, model.b[i]) + (1 - wgt) * bz[i]
    elif method != "parametric":
        raise ConfigError(f"method={method!r} must be 'parametric' or 'nonparametric'")
    hz[w == 0] = 0
    bz[:, w == 0] = 0
    return hz, bz


def _evaluate(terms: Sequence[Term], z: np.ndarray, zdot: np.ndarray) -> np.ndarray:
    out = np.empty((len(terms), z.size))
    for i, t in enumerate(terms):
        out[i] = play_operator(z, t.params["deadband"]) if t.kind == "backlash" else t.evaluate(z, zdot)
    return out


def predict_body(model: IdentifiedModel, spindle_accel: np.ndarray, fs_hz: float, *, method: Method = "parametric",
                 tol: float = 1e-6, max_iter: int = 200, relax: float = 1.0, pad_s: float = 5.0) -> Prediction:
    """Predict the body acceleration from a measured spindle acceleration (METHOD.md §4).

    Parameters
    ----------
    model : IdentifiedModel
    spindle_accel : ndarray, shape (n,)
        Measured spindle acceleration [m/s²] (any amplitude level).
    fs_hz : float
        Its sample rate [Hz].
    method : {'parametric', 'nonparametric'}
        Source of the linear responses (see the module docstring).
    tol : float
        Convergence: relative RMS change of z between iterations.
    max_iter : int
        Iterations before giving up.
    relax : float
        Initial relaxation factor in (0, 1]; halved automatically when the
        change grows.
    pad_s : float
        Zeros added at both ends [s] so the periodic FFT solution does not wrap.

    Returns
    -------
    Prediction

    Raises
    ------
    PredictionDivergedError
        When the iteration does not converge (the message gives the last change).
    InputError
        For non-finite or empty input.
    """
    a1 = np.asarray(spindle_accel, dtype=float).ravel()
    if a1.size == 0 or not np.all(np.isfinite(a1)):
        raise InputError("spindle acceleration must be a non-empty finite signal", channel="spindle_accel")
    if not (0 < relax <= 1):
        raise ConfigError(f"relax={relax!r} must be in (0, 1]")
    pad = int(round(pad_s * fs_hz))
    n = a1.size
    nfft = scipy.fft.next_fast_len(n + 2 * pad, real=True)
    x = np.zeros(nfft)
    x[pad:pad + n] = a1
    f = np.fft.rfftfreq(nfft, 1.0 / fs_hz)
    w = 2 * np.pi * f
    A1 = scipy.fft.rfft(x)
    hz, bz = _responses(model, f, method)
    nt = len(model.terms)
    Z = hz * A1
    z = scipy.fft.irfft(Z, nfft)
    zd = scipy.fft.irfft(1j * w * Z, nfft)
    it, change, r = 0, 0.0, float(relax)
    if nt:
        sl = slice(pad, pad + n)
        prev_change = np.inf
        for it in range(1, max_iter + 1):
            g = _evaluate(model.terms, z, zd)
            # equivalent linearisation of each g on the current iterate (α·z + β·ż)
            basis = np.stack([z[sl], zd[sl]], axis=1)
            coef = np.linalg.lstsq(basis, g[:, sl].T, rcond=None)[0] if np.any(basis) else np.zeros((2, nt))
            lam = coef[0][:, None] + 1j * w[None, :] * coef[1][:, None]            # (nt, nf)
            G = scipy.fft.rfft(g, axis=1)
            denom = 1 - np.sum(bz * lam, axis=0)
            Znew = (hz * A1 + np.sum(bz * (G - lam * Z[None, :]), axis=0)) / denom
            Znew[~np.isfinite(Znew)] = 0
            Zrel = (1 - r) * Z + r * Znew
            zn = scipy.fft.irfft(Zrel, nfft)
            change = float(np.sqrt(np.mean((zn[sl] - z[sl]) ** 2)) / max(np.sqrt(np.mean(zn[sl] ** 2)), 1e-300))
            if not np.isfinite(change):
                raise PredictionDivergedError(f"prediction diverged after {it} iterations (non-finite response)",
                                              hint="check the model (c_over_m2, body) and the input level")
            if change > prev_change * 1.5 and r > 1 / 64:
                r *= 0.5                                                               # back off, keep iterate
            Z, z = Zrel, zn
            zd = scipy.fft.irfft(1j * w * Z, nfft)
            prev_change = change
            if change < tol:
                break
        else:
            raise PredictionDivergedError(
                f"prediction did not converge in {max_iter} iterations (last relative change {change:.2e}, "
                f"relaxation {r:g})", hint="lower relax, raise max_iter, or check the model at this input level")
    A2 = A1 - w**2 * Z
    a2 = scipy.fft.irfft(A2, nfft)[pad:pad + n]
    edge = int(min(n // 4, np.ceil(10.0 / max(model.body.c, 0.1) * fs_hz)))   # 5 decay times of the body mode
    return Prediction(body_accel=a2, z=z[pad:pad + n], zdot=zd[pad:pad + n], iterations=it, residual=change,
                      method=method, edge_samples=edge)


@dataclass(frozen=True, eq=False)
class PredictedTransmissibility:
    """H1 between a measured spindle signal and the body response predicted from it.

    Attributes
    ----------
    freq_hz : ndarray, shape (nf,)
    t21 : ndarray, complex, shape (nf,)
        H1 spindle→predicted body.
    coherence : ndarray, shape (nf,)
    n_avg : int
    prediction : Prediction
    """

    freq_hz: np.ndarray
    t21: np.ndarray
    coherence: np.ndarray
    n_avg: int
    prediction: Prediction

    def __post_init__(self) -> None:
        for k in ("freq_hz", "t21", "coherence"):
            object.__setattr__(self, k, _ro(getattr(self, k)))


def predict_transmissibility(model: IdentifiedModel, spindle_accel: np.ndarray, fs_hz: float, *,
                             settings: SpectralSettings | None = None, method: Method = "parametric",
                             **solver) -> PredictedTransmissibility:
    """Spindle→body H1 the model predicts at the level of ``spindle_accel`` (paper §3.3, Fig. 9b/12b).

    The prediction's start-up edges are left out; the spectra come from the
    one spectral engine with ``settings`` (the model's by default), so the
    answer compares line by line with the measured transmissibility at that level.
    """
    pred = predict_body(model, spindle_accel, fs_hz, method=method, **solver)
    settings = settings or model.settings
    v = pred.valid
    a1 = np.asarray(spindle_accel, float).ravel()[v]
    spec = cross_spectra(np.stack([a1, pred.body_accel[v]]), fs_hz, settings)
    return PredictedTransmissibility(freq_hz=spec.freq_hz, t21=h1(spec, 0, 1), coherence=coherence(spec, 0, 1),
                                     n_avg=spec.n_avg, prediction=pred)
