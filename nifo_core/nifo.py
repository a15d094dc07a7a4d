"""Output-only and input-measured NIFO (paper §2.2, Eq. 5 and 7-10; METHOD.md §3).

Output-only (paper Eq. 8-9). The spindle motion is the input to the body:

    X2(ω) = T21(ω)·X1(ω) + Σ_i B_i(ω)·Xn_i(ω),      B_i = (μ_i/K2)·T21        (Eq. 8)

Xn_i is the Fourier transform of describing function g_i evaluated on the
measured relative motion (z, ż), z = x2 - x1. We regress in accelerations
(A = -ω²X, METHOD.md §3: equivalent for the linear part and free of
integration error in x1, x2); only z, ż are integrated (from ẍ2 - ẍ1, subtract
first). With channels [a1, a2, g_1..g_N] in ONE cross-spectral accumulator
(:mod:`nifo_core.spectral`) the per-line H1 solve (Eq. 9 multiplied by the
Hermitian transpose) is

    [T21, D_1 .. D_N]ᵀ = G_UU⁻¹·G_Uy,   U = [A1, Gn_1 .. Gn_N],  y = A2,   D_i = -ω²·B_i

and we report T21, B_i, μ_i/K2 = B_i/T21, and the per-unit-body-mass physical
coefficient c_i/M2 = ω²·B_i/(1 - T21) = -D_i/(1 - T21).

Truth for a simulated strut force c·g (body ``M2·ẍ2 = -K2·z - C2·ż - K3·x2 - c·g``):
T21 = Z/(-ω²M2 + Z + K3) with Z = K2 + jωC2, B = -c·T21/Z, so μ/K2 = -c/Z and,
for K3 = 0, c_i/M2 = c/M2 exactly: flat in frequency for a static
nonlinearity.

Two estimates are reported. The *free* one above is the paper's; per line it
is ill-conditioned (a describing function of z or ż carries the output, so
scaled cond(G_UU) ≈ 10²-10³) and amplifies sensor noise and window leakage
(flattop: ±30-70 % in T21 near 2 Hz on simulated data with 2 % noise). The
*static* one (:class:`StaticFit`) uses the same spectra with each c_i/M2
constrained to one real constant, which turns Eq. 8 into the one-input H1

    A2 + Σ γ_i·Gn_i = T21·(A1 + Σ γ_i·Gn_i),      γ_i = c_i/M2,

with γ pooled over the analysis band: this is the recommended T21 and the one
:mod:`nifo_core.model` predicts with. Check its assumption with the free
``c_over_m2`` (flat and real for a static or rate-independent nonlinearity).

Describing functions are kept whole (METHOD.md §3: removing their linear part
yields the equivalent linearisation), and the integration band must contain
the body-bounce mode (``default_band``: 0.5 Hz upwards).

Input-measured variant (paper Eq. 5, Eq. 10 first row), when the tire-patch
displacement xb is recorded:

    X1 = H11·(K1 + jωC1)·Xb + Σ_i E_i·Xn_i,        E_i = -μ_i·(H11 - H12)     (Eq. 10)

regressed as A1 on [Xb, Gn_1..]: T1b = H11·(K1 + jωC1) is the tire-patch→spindle
transmissibility at a near-zero level (truth: ``QuarterCar.t1b``) and
E_i = c_i·(H11 - H12) for a strut force c·g. The same conditioning problem
applies, so :class:`InputMeasured` also gives ``t1b_nominal`` from the sum of
the two equations of motion, where the strut force cancels.

Two-step identification (paper §3.3): :func:`identify_two_step` identifies
one term set on one data set, then another on a second data set with the
first set held fixed as its constant c_i/M2 (an extra known input:
``A2 + Σγ·Gn = T21·(A1 + Σγ·Gn) + Σ_free D_j·Gn_j``, via :meth:`CrossSpectra.combine`).

Streaming: :class:`StreamingNifo` is the only code path; :func:`identify_nifo`
pushes each record once and merges, so a node that streams gets exactly the
batch answer.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field, replace
from typing import Literal, Mapping, Sequence

import numpy as np

from .describing import Term, make_term, play_operator
from .errors import ConfigError, IllConditionedError, InputError, RecordTooShortError, SampleRateError
from .integrate import IntegrationBand, StreamingIntegrator, default_band, integrator_taps
from .record import Record
from .spectral import (CrossSpectra, CrossSpectralAccumulator, MimoFit, SpectralSettings, coherence, h1,
                       mimo_fit)

__all__ = ["IllConditionedWarning", "InputMeasured", "StaticFit", "NifoResult", "FixedTerms", "StreamingNifo",
           "identify_nifo",
           "identify_two_step", "nifo_from_spectra", "DEFAULT_ANALYSIS_BAND_HZ", "DEFAULT_COND_LIMIT"]

#: the paper's analysis range (§4: 2-30 Hz)
DEFAULT_ANALYSIS_BAND_HZ = (2.0, 30.0)
#: scaled condition number of G_UU above which a line counts as ill-conditioned
DEFAULT_COND_LIMIT = 1e4
#: fraction of the analysis band's lines allowed above the limit before warning/refusing
ILL_FRACTION = 0.1

OnIll = Literal["warn", "raise", "ignore"]

A1, A2, XB = "spindle_accel", "body_accel", "tire_patch_disp"


class IllConditionedWarning(UserWarning):
    """The NIFO input matrix G_UU is ill-conditioned over part of the analysis band.

    Coefficients there are sensitive to noise; the paper avoids this by
    identifying correlated nonlinearities in two steps (§3.3).
    """


# ---------------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------------
def _ro(a) -> np.ndarray:
    a = np.array(a)
    a.flags.writeable = False
    return a


def _cplx(a: np.ndarray) -> dict:
    a = np.asarray(a)
    return {"re": np.real(a).tolist(), "im": np.imag(a).tolist()}


def _uncplx(d: Mapping) -> np.ndarray:
    return np.asarray(d["re"], float) + 1j * np.asarray(d["im"], float)


def _floats(a) -> list:
    return np.asarray(a, float).tolist()


@dataclass(frozen=True, eq=False)
class InputMeasured:
    """Input-measured NIFO, first row of paper Eq. 10 (spindle on tire patch + describing functions).

    Attributes
    ----------
    t1b : ndarray, complex, shape (nf,)
        Nominal (near-zero-level) tire-patch→spindle transmissibility X1/Xb = H11·(K1 + jωC1).
    e : ndarray, complex, shape (n_terms, nf)
        Coefficient of Xn_i in X1 [m per unit of g]: -μ_i·(H11 - H12) of Eq. 10
        (= c_i·(H11 - H12) for a strut force c_i·g_i).
    t1b_h1 : ndarray, complex, shape (nf,)
        Plain H1 of xb→x1 at the test level (the equivalent linearisation).
    coherence_h1, multiple_coherence, cond : ndarray, shape (nf,)
    random_error : ndarray, shape (1 + n_terms, nf)
        Normalized random error of |T1b|, |E_i| (see :class:`nifo_core.spectral.MimoFit`).
    t1b_nominal : ndarray, complex, shape (nf,)
        Nominal T1b from the mass-sum equation and the output-only nominal T21
        (see ``_input_measured``): the strut nonlinearity cancels there, so
        this does not suffer the per-line conditioning of ``t1b``.
    tire_over_m2 : ndarray, shape (3,)
        (M1/M2, K1/M2 [1/s²], C1/M2 [1/s]) of that fit: unsprung mass and
        tire per unit body mass (a linear tire fits with a flat residual).
    """

    t1b: np.ndarray
    e: np.ndarray
    t1b_h1: np.ndarray
    coherence_h1: np.ndarray
    multiple_coherence: np.ndarray
    cond: np.ndarray
    random_error: np.ndarray
    t1b_nominal: np.ndarray | None = None
    tire_over_m2: np.ndarray | None = None

    def __post_init__(self) -> None:
        for k in ("t1b", "e", "t1b_h1", "coherence_h1", "multiple_coherence", "cond", "random_error",
                  "t1b_nominal", "tire_over_m2"):
            if getattr(self, k) is not None:
                object.__setattr__(self, k, _ro(getattr(self, k)))

    def to_dict(self) -> dict:
        return {"t1b": _cplx(self.t1b), "e": [_cplx(x) for x in self.e], "t1b_h1": _cplx(self.t1b_h1),
                "coherence_h1": _floats(self.coherence_h1), "multiple_coherence": _floats(self.multiple_coherence),
                "cond": _floats(self.cond), "random_error": _floats(self.random_error),
                "t1b_nominal": None if self.t1b_nominal is None else _cplx(self.t1b_nominal),
                "tire_over_m2": None if self.tire_over_m2 is None else _floats(self.tire_over_m2)}

    @classmethod
    def from_dict(cls, d: Mapping) -> "InputMeasured":
        nf = len(d["t1b"]["re"])   # e is (0, nf) with no terms
        return cls(t1b=_uncplx(d["t1b"]), e=np.array([_uncplx(x) for x in d["e"]], complex).reshape(len(d["e"]), nf),
                   t1b_h1=_uncplx(d["t1b_h1"]), coherence_h1=np.asarray(d["coherence_h1"], float),
                   multiple_coherence=np.asarray(d["multiple_coherence"], float),
                   cond=np.asarray(d["cond"], float), random_error=np.asarray(d["random_error"], float),
                   t1b_nominal=None if d.get("t1b_nominal") is None else _uncplx(d["t1b_nominal"]),
                   tire_over_m2=None if d.get("tire_over_m2") is None else np.asarray(d["tire_over_m2"], float))


@dataclass(frozen=True, eq=False)
class StaticFit:
    """NIFO with the coefficients constrained to a static strut nonlinearity (pools all lines).

    For a strut force c_i·g_i acting on the body and K3 = 0, paper Eq. 8's
    coefficients take the form D_i = -ω²·B_i = γ_i·(T21 - 1) with one real
    constant γ_i = c_i/M2 per term, so Eq. 8 in accelerations becomes

        A2 + Σ γ_i·Gn_i = T21·(A1 + Σ γ_i·Gn_i),

    an ordinary single-input H1 once γ is known. γ (free terms) comes from a
    weighted least squares of the equation error ``A2 - T21·A1 = Σ γ_i·(T21 - 1)·Gn_i``
    over all lines of the analysis band, with T21 the free (per-line) estimate
    and weights 1/G_nn (its residual spectrum); fixed (step-1) terms keep their γ.

    Why: per line, Gn_i carries the output (z = x2 - x1), so G_UU is
    ill-conditioned (scaled cond 10²-10³) and the free estimate amplifies
    noise and window leakage; pooling the nonlinear information of all lines
    into one real number per term removes that amplification. The price is
    the assumption (static or rate-independent nonlinearity, K3 = 0); check it
    by looking at the free ``c_over_m2``: it should be flat and real.

    Attributes
    ----------
    c_over_m2 : ndarray, shape (n_terms,)
        γ_i = c_i/M2, real [unit of c per kg].
    t21 : ndarray, complex, shape (nf,)
    b, mu_over_k2 : ndarray, complex, shape (n_terms, nf)
        B_i = γ_i·(1 - T21)/ω² and μ_i/K2 = B_i/T21, as in :class:`NifoResult`.
    coherence : ndarray, shape (nf,)
        Coherence of A1 + Σγ·Gn with A2 + Σγ·Gn.
    random_error : ndarray, shape (nf,)
        Normalized random error of |T21| (single-input formula; γ taken as exact).
    """

    c_over_m2: np.ndarray
    t21: np.ndarray
    b: np.ndarray
    mu_over_k2: np.ndarray
    coherence: np.ndarray
    random_error: np.ndarray

    def __post_init__(self) -> None:
        for k in ("c_over_m2", "t21", "b", "mu_over_k2", "coherence", "random_error"):
            object.__setattr__(self, k, _ro(getattr(self, k)))

    def to_dict(self) -> dict:
        return {"c_over_m2": _floats(self.c_over_m2), "t21": _cplx(self.t21), "b": [_cplx(x) for x in self.b],
                "mu_over_k2": [_cplx(x) for x in self.mu_over_k2], "coherence": _floats(self.coherence),
                "random_error": _floats(self.random_error)}

    @classmethod
    def from_dict(cls, d: Mapping) -> "StaticFit":
        nt = len(d["c_over_m2"])
        t21 = _uncplx(d["t21"])
        return cls(c_over_m2=np.asarray(d["c_over_m2"], float), t21=t21,   # (0, nf) with no terms
                   b=np.array([_uncplx(x) for x in d["b"]], complex).reshape(nt, t21.size),
                   mu_over_k2=np.array([_uncplx(x) for x in d["mu_over_k2"]], complex).reshape(nt, t21.size),
                   coherence=np.asarray(d["coherence"], float), random_error=np.asarray(d["random_error"], float))


@dataclass(frozen=True, eq=False)
class NifoResult:
    """What output-only NIFO identified, per frequency line (paper Eq. 8-9).

    Attributes
    ----------
    freq_hz : ndarray, shape (nf,)
        Frequency lines [Hz] (all lines of the spectral block; trust them
        inside ``analysis_band_hz`` and the integration band).
    t21 : ndarray, complex, shape (nf,)
        Nominal linear spindle→body transmissibility X2/X1 (near-zero level).
    b : ndarray, complex, shape (n_terms, nf)
        B_i of Eq. 8, coefficient of Xn_i in X2 [m per unit of g].
    mu_over_k2 : ndarray, complex, shape (n_terms, nf)
        μ_i/K2 = B_i/T21 (the paper's quantity; truth -c_i/(K2 + jωC2)).
    c_over_m2 : ndarray, complex, shape (n_terms, nf)
        ω²·B_i/(1 - T21) = c_i/M2 [unit of c per kg] (exact for K3 = 0, flat in
        frequency and real for a static nonlinearity).
    t21_h1, coherence_h1 : ndarray, shape (nf,)
        Plain H1 a1→a2 and its ordinary coherence on the same blocks (the
        equivalent linearisation at the test level, for comparison).
    multiple_coherence : ndarray, shape (nf,)
        γ²_y:U of the (output-only) fit. Near 1 whatever is missing (METHOD.md
        §3 pitfalls): not a model check.
    partial_coherence : ndarray, shape (1 + n_terms, nf)
        Of a2 with [a1, g_1..] each given the others (NaN for fixed terms).
    cond : ndarray, shape (nf,)
        Condition number of the unit-diagonal-scaled G_UU per line.
    random_error : ndarray, shape (1 + n_terms, nf)
        Normalized random error ε of |T21|, |B_i| of the free fit (Bendat &
        Piersol; ~95 % bounds |H|·(1 ± 2ε), phase ± 2ε rad). Random error only:
        the bias from noise entering the describing functions through z (paper
        §2.2) and from window leakage is not in it. NaN for fixed terms. See
        :meth:`bounds`.
    n_avg : int
        Spectral blocks averaged (all records).
    n_samples : int
        Samples that entered the spectra (after the integrator's edges).
    terms : tuple of Term
    fixed : tuple of bool
        True for terms whose coefficients were held fixed (two-step, step 1).
    fs_hz : float
    settings : SpectralSettings
    band : IntegrationBand
        Integration band used for z, ż.
    analysis_band_hz : (float, float)
        Band over which conditioning was checked and bounds are meaningful.
    input_measured : InputMeasured or None
        Paper Eq. 10 first row, when the tire patch was recorded.
    static : StaticFit
        The same model with each c_i/M2 constrained to one real constant
        (static nonlinearity, K3 = 0): much less sensitive to noise and
        leakage than the free per-line estimate; the recommended T21. Without
        terms it is the plain H1 (spindle noise floor removed when given).
    spindle_noise_psd : float or None
        Spindle noise floor [(m/s²)²/Hz] subtracted from G_a1a1 (errors-in-variables
        correction), when given.
    provenance : mapping
        JSON-able notes (records, steps).
    """

    freq_hz: np.ndarray
    t21: np.ndarray
    b: np.ndarray
    mu_over_k2: np.ndarray
    c_over_m2: np.ndarray
    t21_h1: np.ndarray
    coherence_h1: np.ndarray
    multiple_coherence: np.ndarray
    partial_coherence: np.ndarray
    cond: np.ndarray
    random_error: np.ndarray
    n_avg: int
    n_samples: int
    terms: tuple[Term, ...]
    fixed: tuple[bool, ...]
    fs_hz: float
    settings: SpectralSettings
    band: IntegrationBand
    analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ
    input_measured: InputMeasured | None = None
    static: StaticFit | None = None   # always set by the estimator; None only in hand-made results
    spindle_noise_psd: float | None = None
    provenance: Mapping = field(default_factory=dict)

    def __post_init__(self) -> None:
        for k in ("freq_hz", "t21", "b", "mu_over_k2", "c_over_m2", "t21_h1", "coherence_h1",
                  "multiple_coherence", "partial_coherence", "cond", "random_error"):
            object.__setattr__(self, k, _ro(getattr(self, k)))
        object.__setattr__(self, "terms", tuple(self.terms))
        object.__setattr__(self, "fixed", tuple(bool(f) for f in self.fixed))
        object.__setattr__(self, "analysis_band_hz", (float(self.analysis_band_hz[0]),
                                                      float(self.analysis_band_hz[1])))

    # -- views ---------------------------------------------------------------------------
    @property
    def in_band(self) -> np.ndarray:
        """Boolean mask of the lines inside ``analysis_band_hz``."""
        lo, hi = self.analysis_band_hz
        return (self.freq_hz >= lo) & (self.freq_hz <= hi)

    def term_index(self, term: Term | str | int) -> int:
        """Index of a term given as index, Term, kind name or label."""
        if isinstance(term, (int, np.integer)):
            return int(term)
        for i, t in enumerate(self.terms):
            if term == t or term in (t.kind, t.label):
                return i
        raise InputError(f"no term {term!r} in this result", hint=f"terms are {[t.label for t in self.terms]}")

    def bounds(self, which: Literal["t21"] | Term | str | int = "t21", *, k: float = 2.0
               ) -> tuple[np.ndarray, np.ndarray]:
        """Magnitude bounds |H|·(1 ∓ k·ε) of T21 or of B_i (k = 2: about 95 %)."""
        if isinstance(which, str) and which == "t21":
            h, e = self.t21, self.random_error[0]
        else:
            i = self.term_index(which)
            h, e = self.b[i], self.random_error[1 + i]
        m = np.abs(h)
        return m * np.maximum(1 - k * e, 0), m * (1 + k * e)

    def band_average(self, x: np.ndarray) -> np.ndarray:
        """Mean of per-line quantities (shape (..., nf)) over the analysis band's lines."""
        return np.mean(np.asarray(x)[..., self.in_band], axis=-1)

    # -- serialisation ------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain JSON types (complex arrays as ``{"re": [...], "im": [...]}``)."""
        return {
            "nifo_result": 1,
            "freq_hz": _floats(self.freq_hz), "t21": _cplx(self.t21),
            "b": [_cplx(x) for x in self.b], "mu_over_k2": [_cplx(x) for x in self.mu_over_k2],
            "c_over_m2": [_cplx(x) for x in self.c_over_m2],
            "t21_h1": _cplx(self.t21_h1), "coherence_h1": _floats(self.coherence_h1),
            "multiple_coherence": _floats(self.multiple_coherence),
            "partial_coherence": _floats(self.partial_coherence), "cond": _floats(self.cond),
            "random_error": _floats(self.random_error), "n_avg": int(self.n_avg), "n_samples": int(self.n_samples),
            "terms": [t.to_dict() for t in self.terms], "fixed": list(self.fixed), "fs_hz": float(self.fs_hz),
            "settings": self.settings.to_dict(), "band": self.band.to_dict(),
            "analysis_band_hz": list(self.analysis_band_hz),
            "input_measured": None if self.input_measured is None else self.input_measured.to_dict(),
            "static": None if self.static is None else self.static.to_dict(),
            "spindle_noise_psd": self.spindle_noise_psd,
            "provenance": json.loads(json.dumps(dict(self.provenance), default=str)),
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "NifoResult":
        """Inverse of :meth:`to_dict`."""
        try:
            nt = len(d["terms"])
            nf = len(d["freq_hz"])

            def mat(key):
                return np.array([_uncplx(x) for x in d[key]]).reshape(nt, nf)
            im = d.get("input_measured")
            return cls(
                freq_hz=np.asarray(d["freq_hz"], float), t21=_uncplx(d["t21"]), b=mat("b"),
                mu_over_k2=mat("mu_over_k2"), c_over_m2=mat("c_over_m2"), t21_h1=_uncplx(d["t21_h1"]),
                coherence_h1=np.asarray(d["coherence_h1"], float),
                multiple_coherence=np.asarray(d["multiple_coherence"], float),
                partial_coherence=np.asarray(d["partial_coherence"], float).reshape(nt + 1, nf),
                cond=np.asarray(d["cond"], float),
                random_error=np.asarray(d["random_error"], float).reshape(nt + 1, nf),
                n_avg=int(d["n_avg"]), n_samples=int(d["n_samples"]),
                terms=tuple(make_term(t) for t in d["terms"]), fixed=tuple(d["fixed"]), fs_hz=float(d["fs_hz"]),
                settings=SpectralSettings.from_dict(d["settings"]), band=IntegrationBand(**d["band"]),
                analysis_band_hz=tuple(d["analysis_band_hz"]),
                input_measured=None if im is None else InputMeasured.from_dict(im),
                static=None if d.get("static") is None else StaticFit.from_dict(d["static"]),
                spindle_noise_psd=d.get("spindle_noise_psd"),
                provenance=dict(d.get("provenance") or {}))
        except (KeyError, TypeError, ValueError) as err:
            raise ConfigError(f"cannot read NIFO result: {err!r}", hint="pass what NifoResult.to_dict() wrote") \
                from None


@dataclass(frozen=True, eq=False)
class FixedTerms:
    """Terms held fixed at constant coefficients c_i/M2 (two-step NIFO, paper §3.3).

    Made from a previous :class:`NifoResult` (its ``static.c_over_m2``) or
    from ``[(term, c_over_m2), ...]`` pairs.
    """

    terms: tuple[Term, ...]
    c_over_m2: np.ndarray
    provenance: Mapping = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "terms", tuple(make_term(t) for t in self.terms))
        object.__setattr__(self, "c_over_m2", _ro(np.asarray(self.c_over_m2, float).reshape(-1)))
        if self.c_over_m2.size != len(self.terms) or not np.all(np.isfinite(self.c_over_m2)):
            raise ConfigError(f"fixed terms need one finite c/M2 per term, got {self.c_over_m2.tolist()} "
                              f"for {[t.label for t in self.terms]}")

    @classmethod
    def coerce(cls, fixed) -> "FixedTerms | None":
        """None, a FixedTerms, a NifoResult, or a sequence of (term, c_over_m2) pairs."""
        if fixed is None or isinstance(fixed, FixedTerms):
            return fixed
        if isinstance(fixed, NifoResult):
            return cls(fixed.terms, _constant_coefficients(fixed),
                       {"from": "nifo_result", **json.loads(json.dumps(dict(fixed.provenance), default=str))})
        try:
            pairs = list(fixed)
            return cls(tuple(p[0] for p in pairs), [float(p[1]) for p in pairs], {"from": "pairs"})
        except (TypeError, ValueError, IndexError):
            raise ConfigError(f"cannot hold {fixed!r} fixed",
                              hint="pass a NifoResult or [(term, c_over_m2), ...]") from None

    def to_dict(self) -> dict:
        return {"terms": [t.to_dict() for t in self.terms], "c_over_m2": self.c_over_m2.tolist(),
                "provenance": dict(self.provenance)}

    @classmethod
    def from_dict(cls, d: Mapping) -> "FixedTerms":
        return cls(tuple(make_term(t) for t in d["terms"]), d["c_over_m2"], dict(d.get("provenance") or {}))


# ---------------------------------------------------------------------------------------------
# the estimator, from spectra
# ---------------------------------------------------------------------------------------------
def _channel_names(terms: Sequence[Term], with_tire_patch: bool) -> tuple[str, ...]:
    names = [A1, A2, *(f"g{i}:{t.label}" for i, t in enumerate(terms))]
    return tuple(names + [XB]) if with_tire_patch else tuple(names)


def _check_conditioning(cond: np.ndarray, mask: np.ndarray, *, what: str, cond_limit: float,
                        on_ill: OnIll) -> None:
    if on_ill == "ignore" or not mask.any():
        return
    c = cond[mask]
    bad = float(np.mean(~(c <= cond_limit)))  # NaN/inf count as bad
    if bad <= ILL_FRACTION:
        return
    msg = (f"{what}: G_UU is ill-conditioned on {bad:.0%} of the analysis band's lines "
           f"(median scaled cond {np.median(c):.3g}, limit {cond_limit:.3g})")
    hint = ("identify correlated nonlinearities in two steps on data of different levels "
            "(identify_two_step), drop a term, or average more data")
    if on_ill == "raise":
        raise IllConditionedError(msg, hint=hint)
    warnings.warn(f"{msg}. Fix: {hint}", IllConditionedWarning, stacklevel=3)


def _constant_coefficients(res: "NifoResult") -> np.ndarray:
    """The constant c_i/M2 of a result's terms: its static fit, else the band mean of the free ones."""
    if res.static is not None:
        return np.asarray(res.static.c_over_m2, float)
    return np.nanmean(res.c_over_m2[:, res.in_band].real, axis=1)


def _static_fit(spec: CrossSpectra, t21: np.ndarray, gnn: np.ndarray, n_free: int, mask: np.ndarray,
                w: np.ndarray, noise: float | None) -> StaticFit:
    """Constant-coefficient NIFO (see :class:`StaticFit`) of spectra [u, y, g_1..] from the free T21.

    Step 1: γ by the 1/G_nn-weighted real least squares of the equation error
    ``y - T21·u = Σ γ_i·(T21 - 1)·Gn_i`` pooled over the analysis band's lines.
    Step 2: T21 = H1 of u + Σγ·Gn → y + Σγ·Gn (spindle noise floor removed when given).
    """
    nf, nch = spec.freq_hz.size, spec.n_channels
    t = np.where(np.isfinite(t21), t21, 0)
    wts = np.zeros((nf, 1 + n_free, nch), complex)
    wts[:, 0, 0] = -t
    wts[:, 0, 1] = 1.0
    for i in range(n_free):
        wts[:, 1 + i, 2 + i] = t - 1
    gamma = np.zeros(0)
    if n_free:
        g = spec.combine(wts).G
        ok = mask & np.isfinite(t21) & (gnn > 0)
        if not ok.any():
            raise IllConditionedError("no usable line in the analysis band for the constant-coefficient fit",
                                      hint="widen the analysis band or record more data")
        wt = 1.0 / gnn[ok]
        lhs = np.einsum("f,fij->ij", wt, g[ok][:, 1:, 1:].real)
        rhs = np.einsum("f,fi->i", wt, g[ok][:, 1:, 0].real)
        gamma = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    comb = np.zeros((2, nch))
    comb[0, 0] = comb[1, 1] = 1.0
    comb[:, 2:2 + n_free] = gamma
    cs = spec.combine(comb)
    fit = mimo_fit(cs, [0], 1, input_noise_psd=None if noise is None else [noise])   # Eq. 8, static form
    t21s = fit.h[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        b = gamma[:, None] * (1 - t21s)[None, :] * np.where(w > 0, 1.0 / np.where(w > 0, w, 1) ** 2, np.nan)
        mu = b / t21s
    return StaticFit(c_over_m2=gamma, t21=t21s, b=b, mu_over_k2=mu, coherence=coherence(cs, 0, 1),
                     random_error=fit.random_error[0])


def _input_measured(spec: CrossSpectra, nt: int, t21_nominal: np.ndarray, mask: np.ndarray, w: np.ndarray,
                    inv_w2: np.ndarray, cond_limit: float, on_ill: OnIll, noise: float | None) -> InputMeasured:
    """Paper Eq. 10, first row (free, per line), and the nominal T1b from the mass-sum equation.

    Sum of the two equations of motion (paper Eq. 1; the strut force, linear
    or not, cancels; K3 = 0; linear tire Zt = K1 + jωC1), per unit body mass:

        A2 = -μ·A1 + (k1 + jω·c1)·(Xb - X1),     μ = M1/M2, k1 = K1/M2, c1 = C1/M2

    three real numbers pooled over the analysis band by least squares (with
    the spindle noise floor removed from the regressors' spectra when given);
    then the nominal tire-patch→spindle transmissibility of the linear system is

        T1b = Zt/(-ω²M1 + Zt + Z·(1 - T21)) = (k1 + jωc1)/(k1 + jωc1 - ω²·(μ + T21))

    with the output-only nominal T21. The free per-line Eq. 10 solve suffers
    the same conditioning as output-only NIFO (the describing functions carry x1).
    """
    xb = spec.n_channels - 1
    fit1 = mimo_fit(spec, [xb, *range(2, 2 + nt)], 0)
    _check_conditioning(fit1.cond, mask, what="input-measured NIFO", cond_limit=cond_limit, on_ill=on_ill)
    nf = spec.freq_hz.size
    wts = np.zeros((nf, 4, spec.n_channels), complex)
    wts[:, 0, 0] = -1.0                                   # -A1          (coefficient μ)
    wts[:, 1, xb], wts[:, 1, 0] = 1.0, inv_w2             # Xb - X1      (k1); X1 = -A1/ω²
    wts[:, 2] = wts[:, 1] * (1j * w)[:, None]             # jω·(Xb - X1) (c1)
    wts[:, 3, 1] = 1.0                                    # A2
    ok = mask & (w > 0)
    g = spec.combine(np.nan_to_num(wts)).G[ok].copy()
    if noise is not None:                                 # E[conj(n)·n] of the regressors' spindle noise
        wo = w[ok]
        g[:, 0, 0] -= noise
        g[:, 1, 1] -= noise / wo**4
        g[:, 0, 1] += noise / wo**2
        g[:, 1, 0] += noise / wo**2
        g[:, 2, 2] -= noise / wo**2
    lhs, rhs = g[:, :3, :3].real.sum(axis=0), g[:, :3, 3].real.sum(axis=0)
    mu, k1, c1 = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    zt = k1 + 1j * w * c1
    with np.errstate(divide="ignore", invalid="ignore"):
        t1b_nominal = zt / (zt - w**2 * (mu + t21_nominal))
    return InputMeasured(t1b=-fit1.h[0] * inv_w2, e=-fit1.h[1:] * inv_w2,
                         t1b_h1=-h1(spec, xb, 0) * inv_w2, coherence_h1=coherence(spec, xb, 0),
                         multiple_coherence=fit1.multiple_coherence, cond=fit1.cond,
                         random_error=fit1.random_error, t1b_nominal=t1b_nominal,
                         tire_over_m2=np.array([mu, k1, c1]))


def nifo_from_spectra(spec: CrossSpectra, terms: Sequence[Term], *, band: IntegrationBand,
                      fixed: "NifoResult | FixedTerms | Sequence | None" = None,
                      analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ,
                      with_tire_patch: bool = False, spindle_noise_psd: float | None = None,
                      on_ill_conditioned: OnIll = "warn", cond_limit: float = DEFAULT_COND_LIMIT,
                      n_samples: int = 0, provenance: Mapping | None = None) -> NifoResult:
    """NIFO estimates from the cross-spectral matrix of [a1, a2, g_fixed.., g_1.., (xb)].

    Parameters
    ----------
    spec : CrossSpectra
        Channels in the order of :class:`StreamingNifo`: spindle and body
        acceleration [m/s²], the describing functions of ``fixed.terms`` then
        of ``terms``, and the tire-patch displacement [m] when ``with_tire_patch``.
    terms : sequence of Term
        Terms whose coefficients are estimated.
    band : IntegrationBand
        The band z, ż were integrated in (recorded in the result).
    fixed : NifoResult, FixedTerms or sequence of (Term, float), optional
        Terms held fixed (two-step, paper §3.3), e.g. a previous result.
        They are held as their constant c_i/M2 = γ_i (its ``static`` fit):
        their contribution D_i = γ_i·(T21 - 1) is an extra known input, which
        turns Eq. 8 into ``A2 + Σγ_i·Gn_i = T21·(A1 + Σγ_i·Gn_i) + Σ_free D_j·Gn_j``.
        Holding γ rather than step 1's B_i(ω) keeps step 1's T21 (the
        equivalent linearisation of whatever step 1 did not declare) out of step 2.
    analysis_band_hz : (float, float)
        Lines over which conditioning is checked and the constant-coefficient fit pools.
    with_tire_patch : bool
        Also solve paper Eq. 10's first row (the last channel is xb).
    spindle_noise_psd : float, optional
        White noise floor of the spindle accelerometer [(m/s²)²/Hz] (a
        datasheet, a record at rest, or :func:`spectral.white_noise_floor` in a
        band without signal). Subtracted from the input auto-spectrum of the
        constant-coefficient (``static``) T21, a single-input H1, to remove the
        bias 1/(1 + N/S) that input noise causes where the spindle signal is
        weak (low frequencies). Not applied to the free per-line solve: with
        describing functions that carry the same noise (through z) a diagonal
        correction alone makes that ill-conditioned matrix inconsistent.
        ``t21_h1`` stays the plain H1.
    on_ill_conditioned : {'warn', 'raise', 'ignore'}
        What to do when more than 10 % of the analysis band's lines have a
        scaled cond(G_UU) above ``cond_limit``: warn with
        :class:`IllConditionedWarning` or raise :class:`IllConditionedError`.
    cond_limit : float
        Scaled condition number counted as ill-conditioned.
    """
    fixed = FixedTerms.coerce(fixed)
    fixed_terms = tuple(fixed.terms) if fixed is not None else ()
    all_terms = (*fixed_terms, *terms)
    nfx, nt = len(fixed_terms), len(all_terms)
    want = _channel_names(all_terms, with_tire_patch)
    if spec.n_channels != len(want):
        raise ConfigError(f"cross spectra hold {spec.n_channels} channels, NIFO with {nt} terms needs {len(want)}",
                          hint="accumulate with StreamingNifo")
    if spindle_noise_psd is not None and not (np.isfinite(spindle_noise_psd) and spindle_noise_psd >= 0):
        raise ConfigError(f"spindle_noise_psd={spindle_noise_psd!r} must be a finite PSD >= 0 [(m/s²)²/Hz]")
    f = spec.freq_hz
    w = 2 * np.pi * f
    lo, hi = analysis_band_hz
    if not (0 <= lo < hi):
        raise ConfigError(f"analysis band {lo}-{hi} Hz must satisfy 0 <= lo < hi", hint="e.g. 2 30")
    mask = (f >= lo) & (f <= hi)
    if not mask.any():
        raise ConfigError(f"analysis band {lo:g}-{hi:g} Hz holds no frequency line", hint="widen it")
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_w2 = np.where(w > 0, 1.0 / np.where(w > 0, w, 1) ** 2, np.nan)
    noise = None if spindle_noise_psd is None else float(spindle_noise_psd)

    # fixed (step-1) terms enter through their constant c_i/M2 = γ_i: with D_i = γ_i·(T21 - 1),
    # A2 = T21·A1 + Σ_fixed D_i·Gn_i + Σ_free D_i·Gn_i  <=>  y = T21·u + Σ_free D_i·Gn_i
    # with u = A1 + Σ_fixed γ_i·Gn_i and y = A2 + Σ_fixed γ_i·Gn_i (an extra known input, exactly).
    gamma_fixed = np.zeros(0)
    work = spec
    if nfx:
        gamma_fixed = np.asarray(fixed.c_over_m2, float)
        comb = np.zeros((2 + nt - nfx, spec.n_channels))
        comb[0, 0] = comb[1, 1] = 1.0
        comb[0:2, 2:2 + nfx] = gamma_fixed
        comb[2:, 2 + nfx:2 + nt] = np.eye(nt - nfx)
        work = spec.combine(comb, names=(A1 + "+fixed", A2 + "+fixed",
                                         *spec.names[2 + nfx:2 + nt]))
    free = list(range(2, 2 + nt - nfx))
    fit: MimoFit = mimo_fit(work, [0, *free], 1)                            # Eq. 9, H1
    _check_conditioning(fit.cond, mask, what="output-only NIFO", cond_limit=cond_limit, on_ill=on_ill_conditioned)

    t21 = fit.h[0]
    d = np.concatenate([gamma_fixed[:, None] * (t21 - 1)[None, :], fit.h[1:]]) if nfx else fit.h[1:]
    b = -d * inv_w2                                                        # D = -ω²·B
    with np.errstate(divide="ignore", invalid="ignore"):
        mu_over_k2 = b / t21                                               # Eq. 8: B = (μ/K2)·T21
        c_over_m2 = -d / (1 - t21)                                         # = ω²B/(1 - T21) = c/M2 (K3 = 0)
    pc = np.full((1 + nt, f.size), np.nan)
    pc[0] = fit.partial_coherence[0]
    pc[1 + nfx:] = fit.partial_coherence[1:]
    err = np.full((1 + nt, f.size), np.nan)
    err[0] = fit.random_error[0]
    err[1 + nfx:] = fit.random_error[1:]

    st = _static_fit(work, t21, fit.residual_psd, nt - nfx, mask, w, noise)  # no free term: H1 of u -> y
    gam = np.concatenate([gamma_fixed, st.c_over_m2])
    with np.errstate(divide="ignore", invalid="ignore"):
        bs = gam[:, None] * (1 - st.t21)[None, :] * inv_w2[None, :]
        mus = bs / st.t21
    static = StaticFit(c_over_m2=gam, t21=st.t21, b=bs, mu_over_k2=mus, coherence=st.coherence,
                       random_error=st.random_error)

    im = None
    if with_tire_patch:                                                     # Eq. 10, first row
        im = _input_measured(spec, nt, static.t21, mask, w, inv_w2, cond_limit,
                             on_ill_conditioned, noise)
    prov = dict(provenance or {})
    if nfx:
        prov.setdefault("fixed_from", dict(fixed.provenance))
    return NifoResult(freq_hz=f.copy(), t21=t21, b=b, mu_over_k2=mu_over_k2, c_over_m2=c_over_m2,
                      t21_h1=h1(spec, 0, 1), coherence_h1=coherence(spec, 0, 1),
                      multiple_coherence=fit.multiple_coherence, partial_coherence=pc, cond=fit.cond,
                      random_error=err, n_avg=spec.n_avg, n_samples=int(n_samples), terms=all_terms,
                      fixed=(True,) * nfx + (False,) * len(terms), fs_hz=spec.fs_hz, settings=spec.settings,
                      band=band, analysis_band_hz=analysis_band_hz, input_measured=im, static=static,
                      spindle_noise_psd=noise, provenance=prov)


# ---------------------------------------------------------------------------------------------
# streaming: the one code path
# ---------------------------------------------------------------------------------------------
def _as_terms(terms) -> tuple[Term, ...]:
    if isinstance(terms, (Term, str, Mapping)):
        terms = [terms]
    out = tuple(make_term(t) for t in terms)
    for t in out:
        if t.spec.hysteretic and t.kind != "backlash":
            raise ConfigError(f"{t.label}: streaming NIFO knows how to carry the state of 'backlash' only")
    return out


class StreamingNifo:
    """Output-only (and input-measured) NIFO fed chunk by chunk; batch is one push per record.

    Parameters
    ----------
    fs_hz : float
        Sample rate [Hz].
    terms : sequence of Term (or specs for :func:`describing.make_term`)
        Describing functions whose coefficients are estimated.
    settings : SpectralSettings, optional
        Spectral block/overlap/window (paper Table 2 by default).
    band : IntegrationBand, optional
        Integration band for z, ż; default ``default_band(fs_hz)`` (0.5 Hz up:
        it must contain body bounce, METHOD.md §3).
    fixed : NifoResult, FixedTerms or sequence of (Term, float), optional
        Terms held fixed at constant c_i/M2 (two-step, paper §3.3).
    with_tire_patch : bool
        Also accumulate the tire-patch displacement for the input-measured
        estimate (paper Eq. 10); :meth:`push` then needs it.
    spindle_noise_psd, analysis_band_hz, on_ill_conditioned, cond_limit :
        As in :func:`nifo_from_spectra`.

    Notes
    -----
    Per chunk: z̈ = a2 - a1 goes through a :class:`StreamingIntegrator`; the
    accelerations (and xb) wait ``delay_samples`` in a FIFO so they stay
    aligned with z, ż; the first ``delay_samples`` of a stream are the
    integrator's start-up transient and are dropped (the last ones are never
    released), so the samples used are exactly the ``valid`` part of
    :func:`integrate` on the whole record. Describing functions are evaluated
    on (z, ż) with the play-operator state carried across chunks, and
    [a1, a2, g_fixed.., g.., xb] go into one :class:`CrossSpectralAccumulator`.
    """

    def __init__(self, fs_hz: float, terms: Sequence[Term], *, settings: SpectralSettings | None = None,
                 band: IntegrationBand | None = None, fixed: "NifoResult | FixedTerms | Sequence | None" = None,
                 with_tire_patch: bool = False, spindle_noise_psd: float | None = None,
                 analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ,
                 on_ill_conditioned: OnIll = "warn", cond_limit: float = DEFAULT_COND_LIMIT) -> None:
        if not (np.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError(f"fs_hz={fs_hz!r} must be a positive sample rate [Hz]")
        if on_ill_conditioned not in ("warn", "raise", "ignore"):
            raise ConfigError(f"on_ill_conditioned={on_ill_conditioned!r} must be 'warn', 'raise' or 'ignore'")
        self.fs_hz = float(fs_hz)
        self.terms = _as_terms(terms)
        self.fixed = FixedTerms.coerce(fixed)
        self.all_terms = (*(self.fixed.terms if self.fixed is not None else ()), *self.terms)
        self.settings = settings or SpectralSettings()
        self.band = (band or default_band(self.fs_hz)).validate(self.fs_hz)
        self.with_tire_patch = bool(with_tire_patch)
        self.spindle_noise_psd = None if spindle_noise_psd is None else float(spindle_noise_psd)
        self.analysis_band_hz = (float(analysis_band_hz[0]), float(analysis_band_hz[1]))
        self.on_ill_conditioned = on_ill_conditioned
        self.cond_limit = float(cond_limit)
        self.delay_samples = (integrator_taps(self.fs_hz, self.band)[0].size - 1) // 2
        self._names = _channel_names(self.all_terms, self.with_tire_patch)
        self._acc = CrossSpectralAccumulator(len(self._names), self.fs_hz, self.settings, names=self._names)
        self._n_used = 0
        self._records = 0
        self._reset_stream()

    # -- stream state ---------------------------------------------------------------------
    def _reset_stream(self) -> None:
        self._integ = StreamingIntegrator(self.fs_hz, self.band)
        self._n_raw = 2 + self.with_tire_patch
        self._hist = np.zeros((self._n_raw, 0))      # last ≤ 2·delay raw samples (a1, a2, xb)
        self._n_in = 0                                # raw samples pushed in this stream
        self._play = np.full(len(self.all_terms), np.nan)

    @property
    def min_samples(self) -> int:
        """Samples one record needs for a block after the integrator's edges."""
        return self.settings.block + 2 * self.delay_samples

    @property
    def n_avg(self) -> int:
        """Spectral blocks accumulated so far."""
        return self._acc.n_blocks

    def push(self, spindle_accel: np.ndarray, body_accel: np.ndarray,
             tire_patch_disp: np.ndarray | None = None) -> int:
        """Feed a chunk of the stream: accelerations [m/s²] (and xb [m]), each shape (k,).

        Returns the number of spectral blocks completed by this chunk. Inputs are not modified.
        """
        a1 = np.asarray(spindle_accel, dtype=float).ravel()
        a2 = np.asarray(body_accel, dtype=float).ravel()
        chans = [a1, a2]
        if self.with_tire_patch:
            if tire_patch_disp is None:
                raise InputError("this NIFO accumulates the tire patch (with_tire_patch=True) but none was pushed",
                                 channel=XB, hint="push tire_patch_disp with every chunk")
            chans.append(np.asarray(tire_patch_disp, dtype=float).ravel())
        if len({c.size for c in chans}) != 1:
            raise InputError(f"chunk channels differ in length {[c.size for c in chans]}",
                             hint="push the same samples of every channel")
        raw = np.stack(chans)
        if not np.all(np.isfinite(raw)):
            raise InputError("chunk holds NaN or infinite samples", hint="repair or cut the bad stretch")
        k = raw.shape[1]
        if k == 0:
            return 0
        d = self.delay_samples
        v, x = self._integ.push(a2 - a1)                      # outputs for samples n_out .. n_out+len-1
        n_out_before = max(0, self._n_in - d)
        hist = np.concatenate([self._hist, raw], axis=1)
        self._n_in += k
        pending_before = self._n_in - k - n_out_before        # raw samples that were waiting
        start = hist.shape[1] - k - pending_before
        aligned = hist[:, start:start + v.size]               # raw samples matching v, x
        self._hist = hist[:, -2 * d:].copy() if 2 * d else hist[:, :0].copy()
        drop = max(0, d - n_out_before)                       # the integrator's start-up edge
        if drop:
            v, x, aligned = v[drop:], x[drop:], aligned[:, drop:]
        if v.size == 0:
            return 0
        g = self._evaluate(x, v)
        rows = [aligned[0], aligned[1], *g]
        if self.with_tire_patch:
            rows.append(aligned[2])
        self._n_used += v.size
        return self._acc.push(np.stack(rows))

    def _evaluate(self, z: np.ndarray, zdot: np.ndarray) -> list[np.ndarray]:
        out = []
        for i, t in enumerate(self.all_terms):
            if t.kind == "backlash":   # the play operator's state carries over chunks
                y0 = None if np.isnan(self._play[i]) else float(self._play[i])
                g = play_operator(z, t.params["deadband"], y0=y0)
                self._play[i] = g[-1]
            else:
                g = t.evaluate(z, zdot)
            out.append(g)
        return out

    def end_record(self) -> None:
        """Close the current stream: later pushes start a new, separate record (fresh integrator)."""
        if self._n_in:
            self._records += 1
        empty = CrossSpectralAccumulator(len(self._names), self.fs_hz, self.settings, names=self._names)
        self._acc = self._acc.merge(empty)                   # drops the partial block, keeps the sums
        self._reset_stream()

    # -- results ------------------------------------------------------------------------------
    def spectra(self) -> CrossSpectra:
        """Cross spectra of [a1, a2, g.., (xb)] so far."""
        if self._acc.n_blocks == 0:
            raise RecordTooShortError(
                f"no complete spectral block yet: NIFO needs {self.min_samples} samples in one record "
                f"(block={self.settings.block} plus {self.delay_samples} integrator edge samples at each end "
                f"for f_lo={self.band.f_lo_hz:g} Hz)",
                hint="record longer, choose a smaller block, or raise the integration band's lower edge")
        return self._acc.spectra()

    def result(self) -> NifoResult:
        """The NIFO estimate from all blocks so far (paper Eq. 8-10)."""
        prov = {"records": self._records + (1 if self._n_in else 0), "samples_used": self._n_used,
                "integrator_edge_samples": self.delay_samples}
        return nifo_from_spectra(self.spectra(), self.terms, band=self.band, fixed=self.fixed,
                                 analysis_band_hz=self.analysis_band_hz, with_tire_patch=self.with_tire_patch,
                                 spindle_noise_psd=self.spindle_noise_psd,
                                 on_ill_conditioned=self.on_ill_conditioned, cond_limit=self.cond_limit,
                                 n_samples=self._n_used, provenance=prov)

    def same_setup(self, other: "StreamingNifo") -> bool:
        """True when ``other`` accumulates the same channels the same way (so the two can merge)."""
        return (self.fs_hz, self.all_terms, self.settings, self.band, self.with_tire_patch) == \
            (other.fs_hz, other.all_terms, other.settings, other.band, other.with_tire_patch)

    _same_setup = same_setup   # kept for callers of the earlier private name

    def merge(self, other: "StreamingNifo") -> "StreamingNifo":
        """A new estimator holding the blocks of both (separate records); operands unchanged.

        The merged estimator's stream starts fresh (a further push begins a new record).
        """
        if not isinstance(other, StreamingNifo) or not self.same_setup(other):
            raise ConfigError("cannot merge NIFO accumulators with different sample rates, terms, spectral "
                              "settings, integration bands or channels",
                              hint="accumulate all records with the same set-up")
        out = self._like()
        out._acc = self._acc.merge(other._acc)
        out._n_used = self._n_used + other._n_used
        out._records = self._records + other._records + (1 if self._n_in else 0) + (1 if other._n_in else 0)
        return out

    def _like(self) -> "StreamingNifo":
        return StreamingNifo(self.fs_hz, self.terms, settings=self.settings, band=self.band, fixed=self.fixed,
                             with_tire_patch=self.with_tire_patch, spindle_noise_psd=self.spindle_noise_psd,
                             analysis_band_hz=self.analysis_band_hz, on_ill_conditioned=self.on_ill_conditioned,
                             cond_limit=self.cond_limit)

    # -- checkpointing -------------------------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        """Complete state as plain numpy arrays (``np.savez``-able); see :meth:`from_state`.

        The integrator's state is carried as the last 2·delay raw samples (it
        is rebuilt by replaying them), so no private state of other classes is needed.
        """
        config = {"fs_hz": self.fs_hz, "terms": [t.to_dict() for t in self.terms],
                  "settings": self.settings.to_dict(), "band": self.band.to_dict(),
                  "with_tire_patch": self.with_tire_patch, "spindle_noise_psd": self.spindle_noise_psd,
                  "analysis_band_hz": list(self.analysis_band_hz),
                  "on_ill_conditioned": self.on_ill_conditioned, "cond_limit": self.cond_limit,
                  "fixed": None if self.fixed is None else self.fixed.to_dict()}
        state = {f"acc.{k}": v for k, v in self._acc.state_dict().items()}
        state.update({"config_json": np.array(json.dumps(config)), "hist": self._hist.copy(),
                      "n_in": np.array(self._n_in), "play": self._play.copy(), "n_used": np.array(self._n_used),
                      "records": np.array(self._records)})
        return state

    @classmethod
    def from_state(cls, state: Mapping[str, np.ndarray]) -> "StreamingNifo":
        """Rebuild from :meth:`state_dict` output; pushing continues where it left off."""
        try:
            c = json.loads(str(state["config_json"]))
            fixed = None if c["fixed"] is None else FixedTerms.from_dict(c["fixed"])
            obj = cls(c["fs_hz"], [make_term(t) for t in c["terms"]],
                      settings=SpectralSettings.from_dict(c["settings"]), band=IntegrationBand(**c["band"]),
                      fixed=fixed, with_tire_patch=c["with_tire_patch"], spindle_noise_psd=c["spindle_noise_psd"],
                      analysis_band_hz=tuple(c["analysis_band_hz"]), on_ill_conditioned=c["on_ill_conditioned"],
                      cond_limit=c["cond_limit"])
            acc = CrossSpectralAccumulator.from_state({k[4:]: v for k, v in state.items() if k.startswith("acc.")})
            hist = np.asarray(state["hist"], float)
            n_in = int(state["n_in"])
            play = np.asarray(state["play"], float)
            n_used, records = int(state["n_used"]), int(state["records"])
        except KeyError as err:
            raise ConfigError(f"NIFO state lacks {err.args[0]!r}", hint="pass what state_dict() returned") from None
        if hist.shape[0] != obj._n_raw or play.shape != obj._play.shape or acc.n_channels != len(obj._names):
            raise ConfigError("NIFO state does not match its own configuration", hint="pass what state_dict() returned")
        obj._acc, obj._hist, obj._n_in, obj._play = acc, hist.copy(), n_in, play.copy()
        obj._n_used, obj._records = n_used, records
        if hist.shape[1]:
            obj._integ.push(hist[1] - hist[0])   # replay: the integrator holds exactly these samples again
        return obj


# ---------------------------------------------------------------------------------------------
# batch
# ---------------------------------------------------------------------------------------------
def identify_nifo(records: Sequence[Record] | Record, terms: Sequence[Term], *,
                  settings: SpectralSettings | None = None, band: IntegrationBand | None = None,
                  fixed: "NifoResult | FixedTerms | Sequence | None" = None, input_measured: bool | None = None,
                  spindle_noise_psd: float | None = None,
                  analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ,
                  on_ill_conditioned: OnIll = "warn", cond_limit: float = DEFAULT_COND_LIMIT) -> NifoResult:
    """Output-only NIFO on one or more records (paper Eq. 8-9), averaged over all their blocks.

    Each record is pushed once into its own :class:`StreamingNifo` and the
    accumulators are merged, so this is exactly what the streaming node computes.

    Parameters
    ----------
    records : Record or sequence of Record
        Same sample rate; each at least ``block + 2·integrator delay`` samples.
    terms : sequence of Term
        Describing functions (kept whole).
    settings : SpectralSettings, optional
        Paper Table 2 by default.
    band : IntegrationBand, optional
        Integration band for z, ż; default ``default_band(fs, shortest duration)``
        (0.5 Hz up for records ≥ 64 s; pass it explicitly to match a streaming run).
    fixed : NifoResult, FixedTerms or sequence of (Term, float), optional
        Hold these terms at constant c_i/M2 (two-step; see :func:`identify_two_step`).
    input_measured : bool, optional
        Also estimate paper Eq. 10's first row (needs ``tire_patch_disp`` in
        every record). Default: when every record has it.
    spindle_noise_psd, analysis_band_hz, on_ill_conditioned, cond_limit :
        See :func:`nifo_from_spectra`.

    Returns
    -------
    NifoResult

    Raises
    ------
    RecordTooShortError, SampleRateError, IllConditionedError, ConfigError
    """
    recs = [records] if isinstance(records, Record) else list(records)
    if not recs:
        raise InputError("no records given", hint="pass at least one Record")
    fs = recs[0].fs_hz
    rates = sorted({r.fs_hz for r in recs})
    if len(rates) > 1:
        raise SampleRateError(f"records have different sample rates {rates} Hz", hint="resample to one rate first")
    has_tp = all(r.has_tire_patch for r in recs)
    if input_measured is None:
        input_measured = has_tp
    if input_measured and not has_tp:
        missing = [r.source or f"record {i}" for i, r in enumerate(recs) if not r.has_tire_patch]
        raise InputError(f"input-measured NIFO needs the tire patch, missing in {missing}", channel=XB,
                         hint="drop input_measured or use records with tire_patch_disp")
    band = band or default_band(fs, min(r.duration_s for r in recs))
    proto = StreamingNifo(fs, terms, settings=settings, band=band, fixed=fixed, with_tire_patch=input_measured,
                          spindle_noise_psd=spindle_noise_psd, analysis_band_hz=analysis_band_hz,
                          on_ill_conditioned=on_ill_conditioned,
                          cond_limit=cond_limit)
    total = None
    for r in recs:
        r.require_samples(proto.min_samples, what=(
            f"NIFO (block={proto.settings.block} plus {proto.delay_samples} integrator edge samples at each "
            f"end for f_lo={band.f_lo_hz:g} Hz)"))
        one = proto._like()
        one.push(r.spindle_accel, r.body_accel, r.tire_patch_disp if input_measured else None)
        total = one if total is None else total.merge(one)
    res = total.result()
    prov = dict(res.provenance)
    prov["sources"] = [r.source for r in recs]
    return _replace_provenance(res, prov)


def _replace_provenance(res: NifoResult, prov: Mapping) -> NifoResult:
    return replace(res, provenance=dict(prov))


def identify_two_step(records_1: Sequence[Record] | Record, terms_1: Sequence[Term],
                      records_2: Sequence[Record] | Record, terms_2: Sequence[Term], *,
                      settings: SpectralSettings | None = None, band: IntegrationBand | None = None,
                      analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ,
                      on_ill_conditioned: OnIll = "warn", cond_limit: float = DEFAULT_COND_LIMIT,
                      input_measured: bool | None = None,
                      spindle_noise_psd: tuple[float | None, float | None] = (None, None),
                      rounds: int = 2) -> NifoResult:
    """Two-step NIFO (paper §3.3, METHOD.md §3) combined into one result.

    Step 1 identifies ``terms_1`` (e.g. backlash) on ``records_1`` (a level
    where ``terms_2`` hardly act); step 2 identifies ``terms_2`` (e.g. the
    velocity deadzone) on ``records_2`` (a higher level) with step 1's terms
    held fixed at their constant c_i/M2: their contribution is a known extra
    input (see :func:`nifo_from_spectra`), so the correlated terms never share
    one G_UU. With ``rounds`` > 1 step 1 is repeated with step 2's terms held
    fixed, then step 2 again (block-coordinate refinement): this removes what
    ``terms_2`` still do at the low level.

    Parameters
    ----------
    spindle_noise_psd : (float or None, float or None)
        Spindle noise floor of each data set (see :func:`nifo_from_spectra`).
    rounds : int
        Passes over both steps (1 = the paper's procedure).

    Returns
    -------
    NifoResult
        ``terms = terms_1 + terms_2`` with ``fixed`` marking step 1's; T21,
        coherences and conditioning are step 2's; the step-1 estimate is under
        ``provenance['two_step']``.
    """
    if int(rounds) < 1:
        raise ConfigError(f"rounds={rounds!r} must be at least 1")
    common = dict(settings=settings, analysis_band_hz=analysis_band_hz, on_ill_conditioned=on_ill_conditioned,
                  cond_limit=cond_limit)
    t1, t2 = _as_terms(terms_1), _as_terms(terms_2)
    first = identify_nifo(records_1, t1, band=band, input_measured=False, spindle_noise_psd=spindle_noise_psd[0],
                          **common)
    band = band or first.band
    second = None
    for k in range(int(rounds)):
        if k:
            held = FixedTerms(t2, second.static.c_over_m2[len(t1):], {"from": f"two-step round {k}, step 2"})
            first = identify_nifo(records_1, t1, band=band, fixed=held, input_measured=False,
                                  spindle_noise_psd=spindle_noise_psd[0], **common)
        held = FixedTerms(t1, first.static.c_over_m2[-len(t1):] if t1 else np.zeros(0),
                          {"from": f"two-step round {k + 1}, step 1"})
        second = identify_nifo(records_2, t2, band=band, fixed=held, input_measured=input_measured,
                               spindle_noise_psd=spindle_noise_psd[1], **common)
    prov = dict(second.provenance)
    prov["two_step"] = {"step1_terms": [t.label for t in t1], "step2_terms": [t.label for t in t2],
                        "rounds": int(rounds),
                        "step1_c_over_m2": first.static.c_over_m2[-len(t1):].tolist() if t1 else []}
    return _replace_provenance(second, prov)
