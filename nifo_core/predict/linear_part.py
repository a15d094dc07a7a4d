"""The linear part of an identified model: a one-mass body or a stable rational model.

Every model nifo predicts with has the structure of the static NIFO fit
(:mod:`nifo_core.nifo.identify`, paper Eq. 8 with constant c_i/M2)::

    A2 + Σ γ_i·G_i = T21·(A1 + Σ γ_i·G_i)
    ⇔  Z = Hz(s)·U,   U = A1 + Σ γ_i·G_i(z, ż) [- F/M2],   Hz(s) = -(1 - T21(s))/s²      (z = x2 - x1)

i.e. the nonlinear strut force (and a measured force on the body, per unit
body mass) enters where the spindle's inertial force does, and the linear
part is the single transfer function Hz = Z/U, sharing its poles between the
spindle input and the nonlinear feedback (the structure of FNSI and of
nonlinear state-space models). Two forms of Hz:

``body``
    the physical one-mass body on the strut, per unit body mass (paper Eq. 2 / M2):
    Hz = -(1 + k3/s²)/(s² + c·s + k + k3), k = K2/M2 [1/s²], c = C2/M2 [1/s],
    fitted to T21 by :func:`fit_body_model`. Physical when k, c > 0.
``rational``
    Hz(s) = Σ_n r_n/(s - p_n), poles and residues in conjugate pairs, fitted
    to Hz = (1 - T21)/ω² over the analysis band by vector fitting (Gustavsen &
    Semlyen 1999, relaxed: Gustavsen 2006) with unstable poles flipped into the
    left half plane and damped at least to the line spacing (a resonance
    narrower than df is invisible to the fit and would only ring), plus one fixed well-damped pole pair at 3× the band's top
    for the modes above the band (their in-band residual flexibility), and residues constrained to Σ r_n = 0 so Hz has relative
    degree 2 (z and ż are states: no algebraic loop through the nonlinear
    feedback). The order is chosen or selected automatically (smallest within
    10 % of the best T21 error). A black box: stable, not physical.

:func:`select_linear_part` fits both, chooses by physicality, stability and
fit error, and says why (``LinearPart.reason``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal, Mapping, Sequence

import numpy as np

from ..defaults import DEFAULT_ANALYSIS_BAND_HZ
from ..kinds.describing import KINDS
from ..errors import ConfigError
from ..signal.parallel import max_threads, thread_map
from .vector_fit import RecordLines, conjugate_pairs, fit_residues, refit, start_poles, vector_fit

__all__ = ["BodyModel", "LinearPart", "absorbed_rates", "fit_body_model", "fit_rational",
           "nominal_linear_part", "pole_residue_response", "select_linear_part"]

#: a physical one-mass body is kept unless its T21 misfit exceeds this (relative RMS over the band)
BODY_FIT_LIMIT = 0.10
#: the pole pair a rational part holds besides those vector fitting places, for the modes above the band (residual
#: flexibility): well damped, in units of _RESIDUAL_AT × the band's top angular frequency (:func:`fit_rational`)
_RESIDUAL_PAIR = np.array([-0.7 + 0.714j, -0.7 - 0.714j])
_RESIDUAL_AT = 3
RESIDUAL_POLES = _RESIDUAL_PAIR.size

#: the linear part each kind gives to the linear part of the model: g = α·z + β·ż + (a bounded remainder)
#: (from the kind registry, ``Kind.absorb``)
_ABSORB = {name: k.absorb for name, k in KINDS.items() if any(k.absorb)}


def absorbed_rates(terms, gammas) -> tuple[float, float]:
    """(a, b) = (Σ γ_i·α_i [1/s²], Σ γ_i·β_i [1/s]) of the terms whose remainder g - α·z - β·ż is bounded.

    A backlash (play) is z within ±deadband/2, a clearance z minus a clip,
    a velocity dead zone ż minus a clip: their linear part belongs to the linear
    part of the model. Left in the feedback it can make the nominal linear part
    non-physical (the static fit splits K2 + c_play between them), e.g. k < 0.
    """
    a = b = 0.0
    for t, g in zip(terms, gammas):
        al, be = _ABSORB.get(t.kind, (0.0, 0.0))
        a += float(g) * al
        b += float(g) * be
    return a, b


# ---------------------------------------------------------------------------------------------
# the physical one-mass body
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

    @property
    def physical(self) -> bool:
        return bool(self.k > 0 and self.c > 0 and self.k3 >= 0)

    def to_dict(self) -> dict:
        return {"k": self.k, "c": self.c, "k3": self.k3, "fit_rms": self.fit_rms}

    @classmethod
    def from_dict(cls, d: Mapping) -> "BodyModel":
        """Inverse of :meth:`to_dict` (null, as JSON writes NaN, reads as NaN)."""
        return cls(**{k: float("nan") if v is None else float(v) for k, v in d.items()})


def _usable(freq_hz, t21, band_hz, weights):
    f = np.asarray(freq_hz, float)
    t = np.asarray(t21, complex)
    m = (f >= band_hz[0]) & (f <= band_hz[1]) & np.isfinite(t) & (f > 0)
    if weights is not None:
        m &= np.isfinite(weights) & (np.asarray(weights) > 0)
    return f, t, m


def fit_body_model(freq_hz: np.ndarray, t21: np.ndarray, *, band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ,
                   fit_k3: bool = False, weights: np.ndarray | None = None,
                   require_physical: bool = True) -> BodyModel:
    """Fit k = K2/M2, c = C2/M2 (and k3 = K3/M2) to a nominal T21 (docs/method.md §4).

    Linear least squares of the equation error ``(k + jωc)·(T21 - 1) + k3·T21 - ω²·T21``
    over the lines of ``band_hz`` (real and imaginary parts), each line
    scaled by 1/|ω²·T21| so the error is relative.

    Raises
    ------
    ConfigError
        When the band holds fewer than 3 usable lines, or (``require_physical``)
        the fit is not physical (k or c ≤ 0).
    """
    f, t, m = _usable(freq_hz, t21, band_hz, weights)
    if m.sum() < 3:
        raise ConfigError(f"only {int(m.sum())} usable lines in {band_hz[0]:g}-{band_hz[1]:g} Hz to fit the body model",
                          hint="widen the band")
    w = 2 * np.pi * f
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
    if require_physical and not (k > 0 and c > 0):
        raise ConfigError(f"the body model fitted to T21 is not physical (k={k:.4g} 1/s², c={c:.4g} 1/s)",
                          hint="check the analysis band and the coherence of T21")
    model = BodyModel(k, c, k3)
    with np.errstate(divide="ignore", invalid="ignore"):
        resid = np.abs(model.t21(f[m]) / tm - 1)
    return BodyModel(k, c, k3, float(np.sqrt(np.mean(resid**2))))


# ---------------------------------------------------------------------------------------------
# the linear part Hz = Z/U in either form
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class LinearPart:
    """Hz(s) = Z/U of a model (module docstring), as a one-mass body or a rational model.

    Attributes
    ----------
    kind : {'body', 'rational'}
    body : BodyModel or None
        The one-mass body (kind 'body').
    poles, residues : ndarray, complex, shape (n,)
        Hz = Σ r_n/(s - p_n) [1/s, m/(m/s²)·1/s] (kind 'rational'; conjugate pairs both listed).
    fit_rms : float
        Relative RMS misfit |T21_model/T21 - 1| over the fitted band.
    band_hz : (float, float)
        Band it was fitted on [Hz].
    reason : str
        Why this linear part was chosen (filled by :func:`select_linear_part`).
    candidates : mapping
        The forms that were tried, each with its fit error, stability and physicality.
    absorbed : (float, float)
        (a [1/s²], b [1/s]): the linear part of the strut terms moved into this
        linear part (:func:`absorbed_rates`); it realises Hz' = Hz/(1 - Hz·(a + s·b))
        and the feedback subtracts a·z + b·ż again. ``hz``/``t21`` give the
        nominal Hz, T21 (without it).
    paths : ndarray, complex, shape (n_terms, n), optional
        Feedback paths (kind 'rational'; :mod:`nifo_core.predict.feedback_paths`): term i's
        bounded remainder enters through Hq_i = Σ q_in/(s - p_n) on these poles
        instead of through Hz with a constant coefficient.
    """

    kind: Literal["body", "rational"]
    body: BodyModel | None = None
    poles: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))
    residues: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))
    fit_rms: float = float("nan")
    band_hz: tuple[float, float] = (float("nan"), float("nan"))
    reason: str = ""
    candidates: Mapping = field(default_factory=dict)
    absorbed: tuple[float, float] = (0.0, 0.0)
    paths: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "absorbed", (float(self.absorbed[0]), float(self.absorbed[1])))
        if self.paths is not None:
            q = np.atleast_2d(np.asarray(self.paths, complex))
            if self.kind != "rational" or q.shape[1] != np.asarray(self.poles).size or not np.all(np.isfinite(q)):
                raise ConfigError(f"feedback paths need a rational linear part and finite residues on its "
                                  f"{np.asarray(self.poles).size} poles (got shape {q.shape})")
            q.flags.writeable = False
            object.__setattr__(self, "paths", q)
        if self.kind == "body":
            if not isinstance(self.body, BodyModel):
                raise ConfigError("a linear part of kind 'body' needs a BodyModel")
            object.__setattr__(self, "fit_rms", float(self.body.fit_rms) if np.isnan(self.fit_rms) else self.fit_rms)
        elif self.kind == "rational":
            p = np.asarray(self.poles, complex).ravel()
            r = np.asarray(self.residues, complex).ravel()
            if p.size == 0 or p.shape != r.shape:
                raise ConfigError(f"a rational linear part needs as many residues as poles (got {p.size} poles, "
                                  f"{r.size} residues)")
            for a in (p, r):
                a.flags.writeable = False
            object.__setattr__(self, "poles", p)
            object.__setattr__(self, "residues", r)
        else:
            raise ConfigError(f"linear part kind={self.kind!r} must be 'body' or 'rational'")

    @classmethod
    def from_body(cls, body: BodyModel, **kw) -> "LinearPart":
        return cls("body", body=body, **kw)

    @property
    def order(self) -> int:
        """Number of states."""
        return 2 if self.kind == "body" else int(self.poles.size)

    @property
    def fitted_poles(self) -> int:
        """A rational part's poles placed by vector fitting: its states without the fixed pair standing for the modes
        above the band (:func:`fit_rational`), the ``order`` that fits the same structure again."""
        return int(self.poles.size) - RESIDUAL_POLES if self.kind == "rational" else 0

    @property
    def physical(self) -> bool:
        """A physical parameterisation with physical values (only the one-mass body can be)."""
        return self.kind == "body" and self.body.physical

    @property
    def stable(self) -> bool:
        return bool(np.all(self.all_poles().real < 0))

    def all_poles(self) -> np.ndarray:
        """Poles of Hz [1/s]."""
        if self.kind == "rational":
            return self.poles
        b = self.body
        return np.roots([1.0, b.c, b.k + b.k3]).astype(complex)

    def slowest_decay_s(self) -> float:
        """Time constant of the slowest pole [s] (inf when not stable)."""
        re = -self.all_poles().real
        return float(1.0 / re.min()) if re.size and re.min() > 0 else float("inf")

    def hz(self, freq_hz) -> np.ndarray:
        """Nominal Hz(jω) = Z/U [m per m/s²] (the absorbed strut part taken out again)."""
        s = 2j * np.pi * np.asarray(freq_hz, float)
        h = self.hz_realised(freq_hz)
        a, b = self.absorbed
        return h / (1 + h * (a + b * s)) if (a or b) else h

    def hz_realised(self, freq_hz) -> np.ndarray:
        """Hz'(jω) this part realises (``state_space``), with the absorbed strut part."""
        s = 2j * np.pi * np.asarray(freq_hz, float)
        if self.kind == "body":
            b = self.body
            with np.errstate(divide="ignore", invalid="ignore"):
                k3term = np.where(s != 0, b.k3 / np.where(s != 0, s, 1) ** 2, 0)
            return -(1 + k3term) / (s**2 + b.c * s + b.k + b.k3)
        return pole_residue_response(self.poles, self.residues, freq_hz)

    def t21(self, freq_hz) -> np.ndarray:
        """Nominal T21 = 1 + s²·Hz of this linear part."""
        if self.kind == "body" and not any(self.absorbed):
            return self.body.t21(freq_hz)
        w = 2 * np.pi * np.asarray(freq_hz, float)
        return 1 - w**2 * self.hz(freq_hz)

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Real (A, b, c) with Hz(s) = c·(sI - A)⁻¹·b and c·b = 0 (so ż = c·A·x).

        The body in companion form (x = [z, ż]); a rational model in real
        modal form (one 2×2 block per conjugate pair).
        """
        if self.kind == "body":
            bm = self.body
            return (np.array([[0.0, 1.0], [-(bm.k + bm.k3), -bm.c]]), np.array([0.0, -1.0]), np.array([1.0, 0.0]))
        n = self.poles.size
        a, b, c = np.zeros((n, n)), np.zeros(n), np.zeros(n)
        i = 0
        for p, r in _pairs(self.poles, self.residues):
            if p.imag == 0:
                a[i, i], b[i], c[i] = p.real, 1.0, r.real
                i += 1
            else:
                # r/(s-p) + r̄/(s-p̄) = (2·Re r·(s-σ) - 2·Im r·ω)/((s-σ)² + ω²)
                #                   = [2·Re r, 2·Im r]·(sI - [[σ, ω], [-ω, σ]])⁻¹·[1, 0]ᵀ
                a[i:i + 2, i:i + 2] = [[p.real, p.imag], [-p.imag, p.real]]
                b[i] = 1.0
                c[i], c[i + 1] = 2 * r.real, 2 * r.imag
                i += 2
        return a, b, c

    def path_state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Real (A, b, E, c) of a linear part with feedback paths: Hz = c·(sI - A)⁻¹·b and
        Hq_i = c·(sI - A)⁻¹·E[:, i] (c·b = c·E = 0 by Σ r = Σ q = 0); one block per real pole or conjugate pair."""
        poles, r, q = self.poles, self.residues, self.paths
        idx = np.flatnonzero(poles.imag >= 0)
        n = int(sum(1 if poles[k].imag == 0 else 2 for k in idx))
        a, b, c = np.zeros((n, n)), np.zeros(n), np.zeros(n)
        e = np.zeros((n, q.shape[0]))
        i = 0
        for k in idx:
            p = poles[k]
            if p.imag == 0:
                a[i, i], b[i], e[i], c[i] = p.real, r[k].real, q[:, k].real, 1.0
                i += 1
            else:   # (2·Re r·(s-σ) - 2·Im r·ω)/((s-σ)² + ω²) = [1, 0]·(sI - [[σ, ω], [-ω, σ]])⁻¹·[2·Re r, -2·Im r]ᵀ
                a[i:i + 2, i:i + 2] = [[p.real, p.imag], [-p.imag, p.real]]
                b[i], b[i + 1] = 2 * r[k].real, -2 * r[k].imag
                e[i], e[i + 1] = 2 * q[:, k].real, -2 * q[:, k].imag
                c[i] = 1.0
                i += 2
        return a, b, e, c

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "fit_rms": self.fit_rms, "band_hz": list(self.band_hz), "reason": self.reason,
             "stable": self.stable, "physical": self.physical, "order": self.order,
             "candidates": dict(self.candidates), "absorbed": list(self.absorbed)}
        if self.kind == "body":
            d["body"] = self.body.to_dict()
        else:
            d["poles"] = {"re": self.poles.real.tolist(), "im": self.poles.imag.tolist()}
            d["residues"] = {"re": self.residues.real.tolist(), "im": self.residues.imag.tolist()}
            d["natural_frequencies_hz"] = sorted({round(float(abs(p) / (2 * np.pi)), 6) for p in self.poles})
            if self.paths is not None:
                d["paths"] = [{"re": q.real.tolist(), "im": q.imag.tolist()} for q in self.paths]
        return d

    @classmethod
    def from_dict(cls, d: Mapping) -> "LinearPart":
        try:
            kw = {"fit_rms": float(d.get("fit_rms") if d.get("fit_rms") is not None else np.nan),
                  "band_hz": tuple(float(v) if v is not None else np.nan     # null (the pair or a value): not stated
                                   for v in d.get("band_hz") or (np.nan,) * 2),
                  "reason": str(d.get("reason", "")), "candidates": dict(d.get("candidates") or {}),
                  "absorbed": tuple(d.get("absorbed") or (0.0, 0.0))}
            if d["kind"] == "body":
                return cls("body", body=BodyModel.from_dict(d["body"]), **kw)
            cx = lambda v: np.asarray(v["re"], float) + 1j * np.asarray(v["im"], float)  # noqa: E731
            paths = np.array([cx(q) for q in d["paths"]]) if d.get("paths") else None
            return cls(str(d["kind"]), poles=cx(d["poles"]), residues=cx(d["residues"]), paths=paths, **kw)
        except KeyError as err:
            raise ConfigError(f"linear part lacks {err.args[0]!r}", hint="pass what LinearPart.to_dict() wrote") from None
        except (TypeError, ValueError) as err:
            raise ConfigError(f"cannot read the linear part: {err}") from None


def pole_residue_response(poles: np.ndarray, residues: np.ndarray, freq_hz) -> np.ndarray:
    """Σ_n r_n/(jω - p_n) at ``freq_hz`` [Hz] (residues of shape (n,) or (m, n): one response per row)."""
    s = 2j * np.pi * np.asarray(freq_hz, float)
    return np.sum(np.asarray(residues)[..., :, None] / (s[None, :] - np.asarray(poles)[:, None]), axis=-2)


def _pairs(poles: np.ndarray, residues: np.ndarray):
    """(pole, residue) of each real pole and of the upper member of each conjugate pair."""
    for p, r in zip(poles, residues):
        if p.imag >= 0:
            yield p, r


def fit_rational(freq_hz: np.ndarray, t21: np.ndarray, *, band_hz: tuple[float, float], order: int | None = None,
                 max_order: int = 40, weights: np.ndarray | None = None, n_iter: int = 12,
                 records: "Sequence[RecordLines] | None" = None) -> LinearPart:
    """A stable rational Hz = (1 - T21)/ω² fitted over ``band_hz`` by vector fitting (module docstring).

    Parameters
    ----------
    freq_hz, t21 : ndarray
        Lines [Hz] and the nominal transmissibility on them.
    band_hz : (float, float)
        Lines used [Hz].
    order : int, optional
        Number of poles (even); None selects it: the smallest order whose T21
        error is within 10 % (+0.1 % absolute) of the best of 2, 4, … ``max_order``.
    weights : ndarray, optional
        Per-line weights (e.g. coherence); the fit is relative in T21 otherwise.
    records : sequence of RecordLines, optional
        Each identification record's own transmissibility and prediction weights. The poles are still
        vector-fitted to ``t21`` (the pooled estimate), but the residues are then those that make the
        linear model *predict* every record best, each by its relative error — the output error of a
        linear model driven by the measured input is linear in the residues (A2 - A1 = s²·Hz·A1) — and
        the order is the smallest whose mean prediction error is within 5 % of the best. Measured on the
        F-16 (levels 3/5/7, orders 12-40): the pooled fit's prediction of level 1 spans 0.21-0.57 % with
        the order, the refitted one 0.24-0.26 %.

    Raises
    ------
    ConfigError
        With fewer usable lines than 3 per pole.
    """
    f, t, m = _usable(freq_hz, t21, band_hz, weights)
    orders = [int(order)] if order is not None else list(range(2, int(max_order) + 1, 2))
    if order is not None and (order < 2 or order % 2):
        raise ConfigError(f"order={order!r} must be an even number of poles ≥ 2")
    orders = [o for o in orders if 3 * o <= m.sum()]
    if not orders:
        raise ConfigError(f"only {int(m.sum())} usable lines in {band_hz[0]:g}-{band_hz[1]:g} Hz for a rational fit "
                          f"of order {order or 2}", hint="widen the analysis band")
    w = 2 * np.pi * f[m]
    s = 1j * w
    h = (1 - t[m]) / w**2
    wgt = w**2 / np.maximum(np.abs(t[m]), 1e-12)          # relative error in T21 = 1 - ω²·Hz
    if weights is not None:
        wgt = wgt * np.sqrt(np.asarray(weights)[m])
    fits = []
    # modes above the band act in it as a constant (residual flexibility): one fixed, well-damped pole pair
    # at _RESIDUAL_AT × the band's top frequency represents them with relative degree 2 (a bare constant would not)
    w_res = 2 * np.pi * _RESIDUAL_AT * band_hz[1]
    residual = w_res * _RESIDUAL_PAIR
    # a resonance narrower than the line spacing df cannot be seen in the data, only ring in time: every
    # pole decays at least at π·df (half-power bandwidth ≥ df)
    min_decay = np.pi * float(np.median(np.diff(f[m])))
    refits = {}

    def one(o: int) -> tuple:
        poles = vector_fit(s, h, wgt, start_poles(o // 2, band_hz), n_iter, min_decay)
        p, r = fit_residues(s, h, wgt, conjugate_pairs(np.concatenate([poles, residual])))
        again = refit(list(records), p) if records else None
        if again is not None:
            p, r = again.poles, again.residues
        err = float(np.sqrt(np.mean(np.abs(1 - w**2 * np.sum(r[:, None] / (s[None, :] - p[:, None]), axis=0)
                                           - t[m]) ** 2 / np.abs(t[m]) ** 2)))
        return (o, err, p, r), None if again is None else again.error

    # the orders are independent fits: a few side by side on threads (each its own numbers, so the same result)
    batch, exact = max_threads(), False
    for k in range(0, len(orders), batch):
        for fit, rms in thread_map(one, orders[k:k + batch]):
            fits.append(fit)
            if rms is not None:
                refits[fit[0]] = rms
            if fit[1] < 1e-9:       # exact: higher orders only add spurious poles
                exact = True
                break
        if exact:
            break
    extra = {}
    if records:
        best = min(refits.values())
        o, err, p, r = next(x for x in fits if refits[x[0]] <= 1.05 * best)
        extra = {"prediction_error_by_order": {str(k): v for k, v in refits.items()},
                 "residues": "refitted for the records' prediction"}
    else:
        best = min(e for _, e, _, _ in fits)
        o, err, p, r = next(x for x in fits if x[1] <= 1.1 * best + 1e-3)
    return LinearPart("rational", poles=p, residues=r, fit_rms=err, band_hz=(float(band_hz[0]), float(band_hz[1])),
                      candidates={"orders_tried": {str(x[0]): x[1] for x in fits}, **extra})


def select_linear_part(freq_hz: np.ndarray, t21: np.ndarray, *, band_hz: tuple[float, float],
                       form: Literal["auto", "body", "rational"] = "auto", order: int | None = None,
                       fit_k3: bool = False, weights: np.ndarray | None = None,
                       absorbed: tuple[float, float] = (0.0, 0.0), body: BodyModel | None = None,
                       records: "Sequence[RecordLines] | None" = None) -> LinearPart:
    """Fit the one-mass body and a rational model to T21 and choose (module docstring).

    With ``absorbed`` = (a, b) (:func:`absorbed_rates`) the forms are fitted to
    T21' = 1 - ω²·Hz', Hz' = Hz/(1 - Hz·(a + jω·b)): the nominal linear part
    plus the linear part of the strut terms. ``body`` gives the one-mass body
    instead of fitting it (e.g. K2/M2, C2/M2 of a measured force path, where a
    relative T21 error is meaningless). ``records`` (:class:`RecordLines`, for a
    model without absorbed terms: they describe the plain transmissibility): the
    rational part's residues predict the records best (:func:`fit_rational`).
    """
    a, b = float(absorbed[0]), float(absorbed[1])
    f = np.asarray(freq_hz, float)
    t = np.asarray(t21, complex)
    if a or b:
        w = 2 * np.pi * f
        with np.errstate(divide="ignore", invalid="ignore"):
            hz = (1 - t) / w**2
            t = 1 - w**2 * hz / (1 - hz * (a + 1j * w * b))
    given = None if body is None else BodyModel(body.k + a, body.c + b, body.k3, body.fit_rms)
    out = _select(f, t, band_hz=band_hz, form=form, order=order, fit_k3=fit_k3, weights=weights, given=given,
                  records=None if (a or b) else records)
    if a or b:
        out = replace(out, absorbed=(a, b), reason=out.reason + f" (fitted with the linear part of the strut terms, "
                                                               f"{a:.4g} 1/s² and {b:.4g} 1/s, absorbed)")
    return out


def nominal_linear_part(freq_hz: np.ndarray, t21: np.ndarray, terms, gammas, *, band_hz: tuple[float, float],
                        form: Literal["auto", "body", "rational"] = "auto", order: int | None = None,
                        fit_k3: bool = False, body: BodyModel | None = None,
                        records: "Sequence[RecordLines] | None" = None) -> tuple[LinearPart, BodyModel | None]:
    """The linear part of a model whose strut terms ``terms`` have c/M2 ``gammas``, and its nominal body.

    :func:`select_linear_part` with the terms' linear part absorbed (:func:`absorbed_rates`),
    unless that makes it non-physical (e.g. a softening clearance) and the plain fit is
    physical or fits better. The body (None for a rational part) is the nominal one-mass
    body: the absorbed strut part taken out again.
    """
    fit = dict(band_hz=band_hz, form=form, order=order, fit_k3=fit_k3, body=body, records=None if terms else records)
    lin = select_linear_part(freq_hz, t21, absorbed=absorbed_rates(terms, gammas), **fit)
    if any(lin.absorbed) and not lin.physical:
        plain = select_linear_part(freq_hz, t21, **fit)
        if plain.physical or plain.fit_rms < lin.fit_rms:
            lin = plain
    if lin.kind != "body":
        return lin, None
    bm, (ka, ca) = lin.body, lin.absorbed
    return lin, BodyModel(bm.k - ka, bm.c - ca, bm.k3, bm.fit_rms)


def _select(freq_hz, t21, *, band_hz, form, order, fit_k3, weights, given, records=None) -> LinearPart:
    """select_linear_part on the (absorbed) T21.

    ``form='auto'`` keeps the physical body unless it is not physical, or it
    misfits T21 by more than ``BODY_FIT_LIMIT`` and the rational model halves
    that error (a rational model is only trusted inside the fitted band: the
    body extrapolates physically, e.g. to a body mode below the band);
    ``'body'`` or ``'rational'`` force a form (a forced body must be physical).

    Returns
    -------
    LinearPart
        With ``reason`` and ``candidates`` (fit error, stability, physicality of each form tried).
    """
    band = (float(band_hz[0]), float(band_hz[1]))
    cand: dict = {}
    body = rational = None
    if form in ("auto", "body"):
        try:
            body = given or fit_body_model(freq_hz, t21, band_hz=band, fit_k3=fit_k3, weights=weights,
                                           require_physical=False)
            cand["body"] = {"fit_rms": body.fit_rms, "physical": body.physical, "stable": body.physical,
                            "k": body.k, "c": body.c, "k3": body.k3}
        except ConfigError as err:
            cand["body"] = {"error": err.message}
    # ``auto`` keeps a physical body within BODY_FIT_LIMIT whatever the rational model fits: it is not fitted then
    # (20 vector fits of orders 2-40)
    kept = form == "auto" and body is not None and body.physical and body.fit_rms <= BODY_FIT_LIMIT
    if form == "rational" or (form == "auto" and not kept):
        try:
            rational = fit_rational(freq_hz, t21, band_hz=band, order=order, weights=weights, records=records)
            cand["rational"] = {"fit_rms": rational.fit_rms, "physical": False, "stable": rational.stable,
                                "order": rational.order, **dict(rational.candidates)}
        except ConfigError as err:
            cand["rational"] = {"error": err.message}
    if form == "body":
        if body is None or not body.physical:
            raise ConfigError(f"the one-mass body fitted to T21 is not physical ({cand['body']})",
                              hint="use the rational linear part")
        return LinearPart.from_body(body, band_hz=band, reason="one-mass body requested", candidates=cand)
    if form == "rational":
        if rational is None:
            raise ConfigError(f"no rational fit ({cand['rational']['error']})", hint="widen the analysis band")
        return LinearPart("rational", poles=rational.poles, residues=rational.residues, fit_rms=rational.fit_rms,
                          band_hz=band, reason=f"rational model of order {rational.order} requested", candidates=cand)
    if form != "auto":
        raise ConfigError(f"form={form!r} must be 'auto', 'body' or 'rational'")
    if body is not None and body.physical and (rational is None or not (
            body.fit_rms > BODY_FIT_LIMIT and rational.fit_rms < 0.5 * body.fit_rms)):
        why = (f"one-mass body: physical (k={body.k:.4g} 1/s², c={body.c:.4g} 1/s), T21 fit error "
               f"{100 * body.fit_rms:.2f} %"
               + (f" (the body is kept below a misfit of {100 * BODY_FIT_LIMIT:.0f} %: no rational model fitted)"
                  if kept else "" if rational is None else
                  f" vs {100 * rational.fit_rms:.2f} % for the rational model of order {rational.order}"))
        return LinearPart.from_body(body, band_hz=band, reason=why, candidates=cand)
    if rational is None:
        raise ConfigError(f"no linear part could be fitted to T21 in {band[0]:g}-{band[1]:g} Hz: "
                          f"body {cand.get('body')}, rational {cand.get('rational')}", hint="widen the analysis band")
    if body is None:
        why_b = f"the one-mass body could not be fitted ({cand['body'].get('error')})"
    elif not body.physical:
        why_b = f"the one-mass body fit is not physical (k={body.k:.4g} 1/s², c={body.c:.4g} 1/s)"
    else:
        why_b = f"it fits T21 clearly better than the one-mass body ({100 * body.fit_rms:.2f} %)"
    why = (f"rational model of order {rational.order} (stable, T21 fit error {100 * rational.fit_rms:.2f} %): "
           + why_b)
    return LinearPart("rational", poles=rational.poles, residues=rational.residues, fit_rms=rational.fit_rms,
                      band_hz=band, reason=why, candidates=cand)
