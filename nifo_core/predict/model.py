"""The identified model and its predictions (docs/method.md §4, paper §3.3 validation).

A model is what the static NIFO fit identifies (:mod:`nifo_core.nifo.identify`)::

    A2 + Σ γ_i·G_i = T21·(A1 + Σ γ_i·G_i)   ⇔   Z = Hz(s)·(A1 + Σ γ_i·G_i(z, ż) [+ k3·X1] [- F/M2]),

z = x2 - x1, γ_i = c_i/M2 the constant coefficients, Hz = -(1 - T21)/s². It
keeps both forms the estimator gives:

- non-parametric: T21(ω) and B_i(ω) on the spectral lines (paper Eq. 8);
- parametric: the linear part Hz (:class:`~nifo_core.predict.linear_part.LinearPart`):
  the physical one-mass body (k = K2/M2, c = C2/M2: paper Eq. 2 / M2) where
  it fits, a stable rational model otherwise, chosen by
  :func:`~nifo_core.predict.linear_part.select_linear_part`, which says why.

Prediction from a MEASURED spindle acceleration (and, when the model has one,
a measured force on the body) simulates this model in time
(:mod:`nifo_core.predict.timesim`: exact discretisation of the stable linear part,
implicit strut feedback, every kind of :mod:`nifo_core.kinds.describing` including
the hysteretic backlash). It cannot diverge numerically; a response that grows
without bound means the identified model is unstable at that level and raises
:class:`PredictionDivergedError` naming the record, the level and the reason.

``method='nonparametric'`` uses the identified T21(ω), B_i(ω) on the lines
instead (cross-faded to the linear part outside the analysis band), solved in
the frequency domain by Picard iteration ONLY where that provably converges
(:func:`~nifo_core.predict.fixed_point.contraction_bound` < 1); elsewhere it falls back
to the time-domain engine with a rational fit of the identified T21 and says
so in :attr:`Prediction.method`.

The first and last ``edge_s`` seconds of a prediction carry the start-up
transient (the record's past is unknown) and are best left out of comparisons
(:attr:`Prediction.valid`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Literal, Mapping

import numpy as np
import scipy.fft

from ..defaults import DEFAULT_ANALYSIS_BAND_HZ
from ..kinds.describing import Term, make_term
from ..errors import ConfigError
from .fixed_point import contraction_bound, fixed_point_solve
from ..signal.integrate import IntegrationBand
from .linear_part import BodyModel, LinearPart, absorbed_rates, fit_body_model, nominal_linear_part, select_linear_part
from ..nifo.identify import NifoResult
from ..nifo.result import complex_from_json, complex_json, read_only  # one home for the JSON forms of complex arrays
from ..signal.band import band_taper
from .scope import Offsets, PeriodicResponse, PredictionBand, Validity
from ..signal.frf import coherence, h1
from ..signal.spectral import SpectralSettings, cross_spectra
from .time_prediction import (DIVERGENCE_FACTOR, FINE_RATE_HZ, Prediction, PredictionDivergedError, _checked_drive,
                              _edge, _external, _predict_time, fine_factor, predict_bodies, predict_records,
                              record_inputs, time_method)

__all__ = ["BodyModel", "LinearPart", "IdentifiedModel", "Prediction", "PredictedTransmissibility",
           "PredictionDivergedError", "fit_body_model", "predict_body", "predict_bodies", "predict_records",
           "predict_transmissibility", "record_inputs", "fine_factor", "DIVERGENCE_FACTOR", "FINE_RATE_HZ"]

Method = Literal["parametric", "nonparametric"]
Engine = Literal["time", "frequency"]


# ---------------------------------------------------------------------------------------------
# the identified model
# ---------------------------------------------------------------------------------------------
#: what a model carries besides its dynamics (:mod:`nifo_core.predict.scope`), by its key in model.json
_SCOPE = {"offsets": Offsets, "prediction_band": PredictionBand, "periodic_response": PeriodicResponse,
          "validity": Validity}


@dataclass(frozen=True, eq=False)
class IdentifiedModel:
    """T21(ω) + describing functions + coefficients + linear part: what ``nifo identify`` produces.

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
    body : BodyModel or None
        The one-mass body fitted to ``t21`` (None when it could not be or is not physical).
    analysis_band_hz : (float, float)
        Where the non-parametric functions are trusted.
    fs_hz : float
        Sample rate of the identification data [Hz].
    settings : SpectralSettings
    band : IntegrationBand
    source : {'static', 'free', 'h1'}
        Which estimate of the result the model was made from.
    provenance : mapping
    linear : LinearPart, optional
        The linear part Hz predictions use; default: the one-mass ``body``.
    force_gain : float
        1/M2 [1/kg] for a measured force on the body (0: no force input).
    offsets : Offsets, optional
        The static part the prediction adds (:mod:`nifo_core.predict.scope`; None: not yet taken from data —
        each record's own input means, no output offset).
    prediction_band : PredictionBand, optional
        The band the prediction covers (None: every frequency).
    periodic_response : PeriodicResponse, optional
        What the prediction of a periodic input is (None: the simulation as it comes).
    validity : Validity, optional
        The band and input amplitudes the model was identified on.
    """

    freq_hz: np.ndarray
    t21: np.ndarray
    b: np.ndarray
    terms: tuple[Term, ...]
    c_over_m2: np.ndarray
    body: BodyModel | None
    analysis_band_hz: tuple[float, float]
    fs_hz: float
    settings: SpectralSettings
    band: IntegrationBand
    source: str = "static"
    provenance: Mapping = field(default_factory=dict)
    linear: LinearPart | None = None
    force_gain: float = 0.0
    offsets: Offsets | None = None
    prediction_band: PredictionBand | None = None
    periodic_response: PeriodicResponse | None = None
    validity: Validity | None = None

    def __post_init__(self) -> None:
        for k in ("freq_hz", "t21", "b", "c_over_m2"):
            object.__setattr__(self, k, read_only(getattr(self, k)))
        object.__setattr__(self, "terms", tuple(self.terms))
        object.__setattr__(self, "analysis_band_hz", (float(self.analysis_band_hz[0]),
                                                      float(self.analysis_band_hz[1])))
        nt, nf = len(self.terms), self.freq_hz.size
        if self.t21.shape != (nf,) or self.b.shape != (nt, nf) or self.c_over_m2.shape != (nt,):
            raise ConfigError(f"model arrays do not fit {nt} terms on {nf} lines: t21 {self.t21.shape}, "
                              f"b {self.b.shape}, c_over_m2 {self.c_over_m2.shape}")
        if self.linear is None:
            if self.body is None:
                raise ConfigError("a model needs a linear part: give body= (one-mass) or linear= (LinearPart)")
            object.__setattr__(self, "linear", LinearPart.from_body(self.body, band_hz=self.analysis_band_hz,
                                                                    reason="one-mass body given"))
        fg = float(self.force_gain)
        if not np.isfinite(fg) or fg < 0:
            raise ConfigError(f"force_gain={self.force_gain!r} must be 1/M2 ≥ 0 [1/kg]")
        object.__setattr__(self, "force_gain", fg)

    @classmethod
    def from_body(cls, body: BodyModel, terms=(), gammas=(), *, fs_hz: float,
                  settings: SpectralSettings | None = None, band: IntegrationBand | None = None,
                  analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ, source: str = "static",
                  provenance: Mapping | None = None) -> "IdentifiedModel":
        """A model from known physical parameters: a one-mass body and constant coefficients γ_i = c_i/M2.

        T21 and B_i = γ_i·(1 - T21)/ω² (paper Eq. 8) are put on the lines of ``settings``
        (e.g. the true model of a simulation, or an equation-error fit).
        """
        settings = settings or SpectralSettings()
        f = settings.freq_hz(fs_hz)
        t21 = body.t21(f)
        gam = np.asarray(gammas, float).reshape(len(terms))
        with np.errstate(divide="ignore", invalid="ignore"):
            b = gam[:, None] * ((1 - t21) / (2 * np.pi * f) ** 2)[None, :]
        return cls(freq_hz=f, t21=t21, b=b, terms=tuple(terms), c_over_m2=gam, body=body,
                   analysis_band_hz=analysis_band_hz, fs_hz=fs_hz, settings=settings,
                   band=band or IntegrationBand(0.5, min(200.0, 0.4 * fs_hz)), source=source,
                   provenance=dict(provenance or {}))

    @classmethod
    def from_nifo(cls, result: NifoResult, *, source: Literal["static", "free", "h1"] = "static",
                  fit_k3: bool = False, linear_form: Literal["auto", "body", "rational"] = "auto",
                  order: int | None = None, records=None) -> "IdentifiedModel":
        """Make a model from a NIFO result.

        ``source='static'`` (default) uses the constant-coefficient fit,
        ``'free'`` the per-line estimates (γ = band mean of Re c_i/M2), and
        ``'h1'`` the plain H1 without terms: the equivalent linearisation at
        the identification level, the linear model to compare against.
        The linear part is chosen by :func:`select_linear_part` (``linear_form``,
        ``order``): never fails for a non-physical body when a stable rational
        fit exists. ``records`` (:class:`~nifo_core.predict.vector_fit.RecordLines` of each
        identification record; used for the linear model, ``'h1'``): a rational
        linear part's residues are those that predict every record best.
        """
        prov = {"from": "nifo", "source": source, "n_avg": result.n_avg, **dict(result.provenance)}
        st = result.static
        if source == "h1" or not result.terms:
            t21, terms, b, gam = result.t21_h1, (), np.zeros((0, result.freq_hz.size), complex), np.zeros(0)
        elif source == "static":
            if st is None:
                raise ConfigError("this NIFO result has no constant-coefficient (static) fit", hint="use source='free'")
            t21, terms, b, gam = st.t21, result.terms, st.b, st.c_over_m2
        elif source == "free":
            t21, terms, b = result.t21, result.terms, result.b
            gam = np.nanmean(result.c_over_m2[:, result.in_band].real, axis=1)
        else:
            raise ConfigError(f"source={source!r} must be 'static', 'free' or 'h1'")
        force_gain, given = 0.0, None
        m2 = getattr(st, "m2", None) if st is not None else None
        if m2 is not None and np.isfinite(m2) and m2 > 0:      # a measured force: M2, K2, C2 of its path
            force_gain = 1.0 / m2
            _, k2, c2, misfit = (float(v) for v in st.one_mass)
            given = BodyModel(k2 / m2, c2 / m2, 0.0, misfit)
        lin, body = nominal_linear_part(result.freq_hz, t21, terms, gam, band_hz=result.analysis_band_hz,
                                        form=linear_form, order=order, fit_k3=fit_k3, body=given,
                                        records=records if not terms else None)
        return cls(freq_hz=result.freq_hz, t21=t21, b=b, terms=terms, c_over_m2=gam, body=body,
                   analysis_band_hz=result.analysis_band_hz, fs_hz=result.fs_hz, settings=result.settings,
                   band=result.band, source=source if terms else "h1", provenance=prov, linear=lin,
                   force_gain=force_gain)

    def to_dict(self) -> dict:
        """Plain JSON types (complex arrays as ``{"re": [...], "im": [...]}``)."""
        return {"nifo_identified_model": 1, "freq_hz": self.freq_hz.tolist(), "t21": complex_json(self.t21),
                "b": [complex_json(x) for x in self.b], "terms": [t.to_dict() for t in self.terms],
                "c_over_m2": self.c_over_m2.tolist(), "body": None if self.body is None else self.body.to_dict(),
                "linear_part": self.linear.to_dict(), "force_gain": self.force_gain,
                "analysis_band_hz": list(self.analysis_band_hz), "fs_hz": self.fs_hz,
                "settings": self.settings.to_dict(), "band": self.band.to_dict(), "source": self.source,
                "provenance": json.loads(json.dumps(dict(self.provenance), default=str)),
                **{k: getattr(self, k).to_dict() for k in _SCOPE if getattr(self, k) is not None}}

    @classmethod
    def from_dict(cls, d: Mapping) -> "IdentifiedModel":
        """Inverse of :meth:`to_dict` (files without ``linear_part`` use the body);
        :class:`ConfigError` naming what is wrong otherwise."""
        try:
            terms = tuple(make_term(t) for t in d["terms"])
            nf = len(d["freq_hz"])
            body = None if d["body"] is None else BodyModel.from_dict(d["body"])
            lin = LinearPart.from_dict(d["linear_part"]) if d.get("linear_part") else None
            return cls(freq_hz=np.asarray(d["freq_hz"], float), t21=complex_from_json(d["t21"]),
                       b=np.array([complex_from_json(x) for x in d["b"]], complex).reshape(len(terms), nf), terms=terms,
                       c_over_m2=np.asarray(d["c_over_m2"], float), body=body,
                       analysis_band_hz=tuple(d["analysis_band_hz"]), fs_hz=float(d["fs_hz"]),
                       settings=SpectralSettings.from_dict(d["settings"]), band=IntegrationBand(**d["band"]),
                       source=str(d.get("source", "static")), provenance=dict(d.get("provenance") or {}),
                       linear=lin, force_gain=float(d.get("force_gain") or 0.0),
                       **{k: kind.from_dict(d[k]) for k, kind in _SCOPE.items() if d.get(k) is not None})
        except KeyError as err:
            raise ConfigError(f"identified model lacks {err.args[0]!r}",
                              hint="pass what IdentifiedModel.to_dict() wrote") from None
        except (TypeError, ValueError) as err:
            raise ConfigError(f"cannot read identified model: {err}") from None


# ---------------------------------------------------------------------------------------------
# prediction
# ---------------------------------------------------------------------------------------------


def _interp_c(f: np.ndarray, fp: np.ndarray, yp: np.ndarray) -> np.ndarray:
    yp = np.where(np.isfinite(yp), yp, 0)     # 0 Hz is undefined in the estimates (and faded out anyway)
    return np.interp(f, fp, yp.real) + 1j * np.interp(f, fp, yp.imag)


def _line_responses(model: IdentifiedModel, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hz (V -> Z) and Bz_i (G_i -> Z) from the identified T21(ω), B_i(ω), faded to the linear part
    outside the analysis band; zero at DC."""
    w = 2 * np.pi * f
    hz = model.linear.hz(f)
    bz = model.c_over_m2[:, None] * hz[None, :]
    lo, hi = model.analysis_band_hz
    wgt = band_taper(f, (lo, hi))
    with np.errstate(divide="ignore", invalid="ignore"):
        hz_np = (1 - _interp_c(f, model.freq_hz, model.t21)) / np.where(w > 0, w, 1) ** 2
    hz = wgt * hz_np + (1 - wgt) * hz
    for i in range(len(model.terms)):
        bz[i] = wgt * _interp_c(f, model.freq_hz, model.b[i]) + (1 - wgt) * bz[i]
    hz[w == 0] = 0
    bz[:, w == 0] = 0
    return hz, bz


def predict_body(model: IdentifiedModel, spindle_accel: np.ndarray | None, fs_hz: float, *,
                 force: np.ndarray | None = None, method: Method = "parametric", engine: Engine | None = None,
                 oversample: int | None = None, label: str | None = None, tol: float = 1e-6,
                 max_iter: int = 200, relax: float = 1.0, pad_s: float = 5.0) -> Prediction:
    """Predict the body acceleration from a measured spindle acceleration (docs/method.md §4).

    Parameters
    ----------
    model : IdentifiedModel
    spindle_accel : ndarray, shape (n,), or None
        Measured spindle acceleration [m/s²] (any amplitude level); None for a
        fixed spindle (then ``force`` drives the model).
    fs_hz : float
        Its sample rate [Hz].
    force : ndarray, shape (n,), optional
        Measured force on the body [N] (models with ``force_gain`` > 0).
    method : {'parametric', 'nonparametric'}
        Linear responses from the model's linear part (default), or the
        identified T21(ω), B_i(ω) (module docstring).
    engine : {'time', 'frequency'}, optional
        Force an engine: 'frequency' raises :class:`ConfigError` where its
        convergence is not guaranteed. Default: 'time' for 'parametric'; the
        frequency domain where provable, else time, for 'nonparametric'.
    oversample : int, optional
        Fine steps per sample of the time-domain engine; default: enough for
        ``FINE_RATE_HZ`` (4 at 600 Hz), at least 2.
    label : str, optional
        Names the record in error messages.
    tol, max_iter : float, int
        Frequency domain only: convergence (relative RMS change of z) and iterations.
    relax : float
        Accepted for compatibility; the provable Picard iteration does not relax.
    pad_s : float
        Frequency domain only: zeros added at both ends [s].

    Returns
    -------
    Prediction

    Raises
    ------
    PredictionDivergedError
        When the model's response grows without bound (names the record, level, reason).
    InputError
        For non-finite or empty input.
    """
    a1, force = _checked_drive(spindle_accel, force)
    if not (0 < relax <= 1):
        raise ConfigError(f"relax={relax!r} must be in (0, 1]")
    n = (a1 if a1 is not None else force).size
    if method not in ("parametric", "nonparametric"):
        raise ConfigError(f"method={method!r} must be 'parametric' or 'nonparametric'")
    if engine not in (None, "time", "frequency"):
        raise ConfigError(f"engine={engine!r} must be 'time' or 'frequency'")
    linear = model.linear
    note = ""
    if linear.paths is not None and (method != "parametric" or engine == "frequency"):
        raise ConfigError("a model with feedback paths predicts in the time domain from its linear part only",
                          hint="use method='parametric' and the time-domain engine (the defaults)")
    if method == "nonparametric" and engine != "time":
        nfft = scipy.fft.next_fast_len(n + 2 * int(round(pad_s * fs_hz)), real=True)
        f = np.fft.rfftfreq(nfft, 1.0 / fs_hz)
        hz, bz = _line_responses(model, f)
        rho = contraction_bound(model.terms, bz, f)
        if rho < 1 and not (linear.kind == "body" and linear.body.k3 != 0):
            return _predict_frequency(model, a1, force, fs_hz, hz, bz, nfft, rho, method, tol, max_iter, pad_s)
        if engine == "frequency":
            raise ConfigError(f"the frequency-domain fixed point is not provably convergent for this model "
                              f"(contraction bound {rho:.3g} ≥ 1)", hint="use the time-domain engine (the default)")
        linear = model.linear if model.linear.kind == "rational" else select_linear_part(
            model.freq_hz, model.t21, band_hz=model.analysis_band_hz, form="rational",
            absorbed=absorbed_rates(model.terms, model.c_over_m2))
        note = f" (frequency domain not provably convergent: contraction bound {rho:.3g})"
    elif engine == "frequency":
        nfft = scipy.fft.next_fast_len(n + 2 * int(round(pad_s * fs_hz)), real=True)
        f = np.fft.rfftfreq(nfft, 1.0 / fs_hz)
        hz = linear.hz(f)
        hz[f == 0] = 0
        bz = model.c_over_m2[:, None] * hz[None, :]
        rho = contraction_bound(model.terms, bz, f)
        if rho >= 1 or (linear.kind == "body" and linear.body.k3 != 0):
            raise ConfigError(f"the frequency-domain fixed point is not provably convergent for this model "
                              f"(contraction bound {rho:.3g} ≥ 1, or k3 ≠ 0)",
                              hint="use the time-domain engine (the default)")
        return _predict_frequency(model, a1, force, fs_hz, hz, bz, nfft, rho, method, tol, max_iter, pad_s)
    return _predict_time(model, linear, a1, force, fs_hz, oversample, label, time_method(linear, note))


def _predict_frequency(model, a1, force, fs_hz, hz, bz, nfft, rho, method, tol, max_iter, pad_s) -> Prediction:
    n = (a1 if a1 is not None else force).size
    pad = int(round(pad_s * fs_hz))
    x = np.zeros(nfft)
    x[pad:pad + n] = _external(model, model.linear, a1, force, fs_hz, n)
    f = np.fft.rfftfreq(nfft, 1.0 / fs_hz)
    w = 2 * np.pi * f
    sl = slice(pad, pad + n)
    solved = fixed_point_solve(model.terms, hz, bz, scipy.fft.rfft(x), nfft, fs_hz, sl, tol=tol, max_iter=max_iter)
    Z, it, change = solved.z_spec, solved.iterations, solved.change
    a1p = np.zeros(nfft)
    if a1 is not None:
        a1p[pad:pad + n] = a1
    a2 = scipy.fft.irfft(scipy.fft.rfft(a1p) - w**2 * Z, nfft)[sl]
    z = scipy.fft.irfft(Z, nfft)[sl]
    zd = scipy.fft.irfft(1j * w * Z, nfft)[sl]
    return Prediction(body_accel=a2, z=z, zdot=zd, iterations=it, residual=change,
                      method=f"frequency domain ({method}), Picard iteration, contraction bound {rho:.3g}",
                      edge_samples=_edge(model.linear, fs_hz, n), engine="frequency", oversample=0)


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
            object.__setattr__(self, k, read_only(getattr(self, k)))


def predict_transmissibility(model: IdentifiedModel, spindle_accel: np.ndarray, fs_hz: float, *,
                             settings: SpectralSettings | None = None, method: Method = "parametric",
                             **solver) -> PredictedTransmissibility:
    """Spindle→body H1 the model predicts at the level of ``spindle_accel`` (paper §3.3, Fig. 9b/12b).

    The prediction's start-up edges are left out; the spectra come from the
    one spectral engine with ``settings`` (the model's by default), so the
    answer compares line by line with the measured transmissibility at that
    level. ``solver`` goes to :func:`predict_body` (``force``, ``engine``, ``label``, …).
    """
    pred = predict_body(model, spindle_accel, fs_hz, method=method, **solver)
    settings = settings or model.settings
    v = pred.valid
    a1 = np.asarray(spindle_accel, float).ravel()[v]
    spec = cross_spectra(np.stack([a1, pred.body_accel[v]]), fs_hz, settings)
    return PredictedTransmissibility(freq_hz=spec.freq_hz, t21=h1(spec, 0, 1), coherence=coherence(spec, 0, 1),
                                     n_avg=spec.n_avg, prediction=pred)
