"""What NIFO identifies: the result types (paper Eq. 8-10; see :mod:`nifo_core.nifo.identify`).

:class:`NifoResult` (free per-line estimate plus the constant-coefficient
:class:`StaticFit`), :class:`InputMeasured` (paper Eq. 10 first row) and
:class:`FixedTerms` (terms held fixed in two-step NIFO, paper §3.3), with
their JSON forms, and the module's shared constants.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Literal, Mapping

import numpy as np

from ..defaults import DEFAULT_ANALYSIS_BAND_HZ, DEFAULT_COND_LIMIT
from ..kinds.describing import Term, make_term
from ..errors import ConfigError, IllConditionedError, InputError
from ..signal.frf import bound_factor
from ..signal.integrate import IntegrationBand
from ..signal.spectral import SpectralSettings

__all__ = ["IllConditionedWarning", "InputMeasured", "StaticFit", "NifoResult", "FixedTerms", "Conditioning",
           "DEFAULT_ANALYSIS_BAND_HZ", "DEFAULT_COND_LIMIT", "ILL_FRACTION", "OnIll", "read_only", "complex_json",
           "complex_from_json"]

#: fraction of the analysis band's lines allowed above the limit before warning/refusing
ILL_FRACTION = 0.1

OnIll = Literal["warn", "raise", "ignore"]

A1, A2, XB, FORCE = "spindle_accel", "body_accel", "tire_patch_disp", "force"


class IllConditionedWarning(UserWarning):
    """The NIFO input matrix G_UU is ill-conditioned over part of the analysis band.

    Coefficients there are sensitive to noise; the paper avoids this by
    identifying correlated nonlinearities in two steps (§3.3).
    """


# ---------------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------------
def read_only(a) -> np.ndarray:
    """A read-only copy of ``a`` (what a frozen result holds)."""
    a = np.array(a)
    a.flags.writeable = False
    return a


def complex_json(a: np.ndarray) -> dict:
    """A complex array as JSON: ``{"re": [...], "im": [...]}`` (read back by :func:`complex_from_json`)."""
    a = np.asarray(a)
    return {"re": np.real(a).tolist(), "im": np.imag(a).tolist()}


def complex_from_json(d: Mapping) -> np.ndarray:
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
        Normalized random error of |T1b|, |E_i| (see :class:`nifo_core.signal.frf.MimoFit`).
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
                object.__setattr__(self, k, read_only(getattr(self, k)))

    def to_dict(self) -> dict:
        return {"t1b": complex_json(self.t1b), "e": [complex_json(x) for x in self.e], "t1b_h1": complex_json(self.t1b_h1),
                "coherence_h1": _floats(self.coherence_h1), "multiple_coherence": _floats(self.multiple_coherence),
                "cond": _floats(self.cond), "random_error": _floats(self.random_error),
                "t1b_nominal": None if self.t1b_nominal is None else complex_json(self.t1b_nominal),
                "tire_over_m2": None if self.tire_over_m2 is None else _floats(self.tire_over_m2)}

    @classmethod
    def from_dict(cls, d: Mapping) -> "InputMeasured":
        nf = len(d["t1b"]["re"])   # e is (0, nf) with no terms
        return cls(t1b=complex_from_json(d["t1b"]), e=np.array([complex_from_json(x) for x in d["e"]], complex).reshape(len(d["e"]), nf),
                   t1b_h1=complex_from_json(d["t1b_h1"]), coherence_h1=np.asarray(d["coherence_h1"], float),
                   multiple_coherence=np.asarray(d["multiple_coherence"], float),
                   cond=np.asarray(d["cond"], float), random_error=np.asarray(d["random_error"], float),
                   t1b_nominal=None if d.get("t1b_nominal") is None else complex_from_json(d["t1b_nominal"]),
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
    t2f : ndarray, complex, shape (nf,), optional
        With a measured force: body displacement per force X2/F [m/N] of the
        constant-coefficient fit (see :func:`nifo_core.nifo.estimate.nifo_from_spectra`).
    c : ndarray, shape (n_terms,), optional
        With a measured force: the physical coefficients c_i [N per unit of g].
    one_mass : ndarray, shape (4,), optional
        With a measured force: (M2 [kg], K2 [N/m], C2 [N·s/m], relative RMS
        misfit) of the one-mass fit F/A2 = M2 - (K2 + jωC2)/ω² over the analysis band.
    """

    c_over_m2: np.ndarray
    t21: np.ndarray
    b: np.ndarray
    mu_over_k2: np.ndarray
    coherence: np.ndarray
    random_error: np.ndarray
    t2f: np.ndarray | None = None
    c: np.ndarray | None = None
    one_mass: np.ndarray | None = None

    def __post_init__(self) -> None:
        for k in ("c_over_m2", "t21", "b", "mu_over_k2", "coherence", "random_error", "t2f", "c", "one_mass"):
            if getattr(self, k) is not None:
                object.__setattr__(self, k, read_only(getattr(self, k)))

    @property
    def m2(self) -> float | None:
        """Body mass M2 [kg] from the measured force (None without a force)."""
        return None if self.one_mass is None else float(self.one_mass[0])

    def to_dict(self) -> dict:
        out = {"c_over_m2": _floats(self.c_over_m2), "t21": complex_json(self.t21), "b": [complex_json(x) for x in self.b],
               "mu_over_k2": [complex_json(x) for x in self.mu_over_k2], "coherence": _floats(self.coherence),
               "random_error": _floats(self.random_error)}
        if self.t2f is not None:
            out.update(t2f=complex_json(self.t2f), c=_floats(self.c), one_mass=_floats(self.one_mass))
        return out

    @classmethod
    def from_dict(cls, d: Mapping) -> "StaticFit":
        nt = len(d["c_over_m2"])
        opt = {}
        if d.get("t2f") is not None:
            opt = {"t2f": complex_from_json(d["t2f"]), "c": np.asarray(d["c"], float),
                   "one_mass": np.asarray(d["one_mass"], float)}
        t21 = complex_from_json(d["t21"])
        return cls(c_over_m2=np.asarray(d["c_over_m2"], float), t21=t21,   # (0, nf) with no terms
                   b=np.array([complex_from_json(x) for x in d["b"]], complex).reshape(nt, t21.size),
                   mu_over_k2=np.array([complex_from_json(x) for x in d["mu_over_k2"]], complex).reshape(nt, t21.size),
                   coherence=np.asarray(d["coherence"], float), random_error=np.asarray(d["random_error"], float),
                   **opt)


@dataclass(frozen=True)
class Conditioning:
    """How well-posed the per-line fit was over the analysis band (:meth:`NifoResult.conditioning`).

    ``median``, ``max``: scaled cond(G_UU) over the analysis band's lines (NaN lines ignored; NaN with no line);
    ``ill_fraction``: share of those lines above ``limit`` (NaN and infinite count as above; 1 with no line).
    """

    median: float
    max: float
    ill_fraction: float
    limit: float

    def to_dict(self) -> dict:
        return {"cond_median": self.median, "cond_max": self.max, "ill_conditioned_fraction": self.ill_fraction,
                "cond_limit": self.limit}


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
        γ²_y:U of the (output-only) fit. Near 1 whatever is missing (docs/method.md
        §3 pitfalls): not a model check.
    partial_coherence : ndarray, shape (1 + n_terms, nf)
        Of a2 with [a1, g_1..] each given the others (NaN for fixed terms).
    cond : ndarray, shape (nf,)
        Condition number of the unit-diagonal-scaled G_UU per line.
    random_error : ndarray, shape (1 + n_terms, nf)
        Normalized random error ε of |T21|, |B_i| of the free fit (Bendat &
        Piersol; 95 % bounds |H|·(1 ± k·ε), phase ± k·ε rad, k =
        :meth:`bound_factor`: Student t, ≈ 2 for 20 blocks). Random error only:
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
    t2f : ndarray, complex, shape (nf,), optional
        With a measured force on the body: X2/F [m/N] of the free fit (the
        force is one more input of Eq. 8: X2 = T21·X1 + T2F·F + Σ B_i·Xn_i).
        ``c_over_m2`` is then c_i/M2 with c_i = -D_i/(-ω²·T2F) and M2 from
        the one-mass fit (``static.one_mass``).
    spindle_fixed : bool
        The spindle did not move (force-driven single mass): T21 was not
        regressed; ``t21`` is the one-mass model's 1 - M2·(-ω²·T2F), ``t21_h1``
        the same of the plain H1 force → body and ``coherence_h1`` its
        coherence; row 0 of ``partial_coherence``/``random_error`` is NaN.
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
    t2f: np.ndarray | None = None
    spindle_fixed: bool = False

    def __post_init__(self) -> None:
        for k in ("freq_hz", "t21", "b", "mu_over_k2", "c_over_m2", "t21_h1", "coherence_h1",
                  "multiple_coherence", "partial_coherence", "cond", "random_error"):
            object.__setattr__(self, k, read_only(getattr(self, k)))
        if self.t2f is not None:
            object.__setattr__(self, "t2f", read_only(self.t2f))
        object.__setattr__(self, "spindle_fixed", bool(self.spindle_fixed))
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

    def inputs_fitted(self, *, static: bool = False) -> int:
        """Inputs of the per-line fit that gave ``random_error`` (``static``: of the static fit's)."""
        n = int(not self.spindle_fixed) + int(self.t2f is not None)
        return n if static else n + sum(not f for f in self.fixed)

    def bound_factor(self, *, static: bool = False, level: float = 0.95) -> float:
        """k of the ``level`` bounds |H|·(1 ∓ k·ε) (:func:`nifo_core.signal.frf.bound_factor`: Student t, this fit's
        degrees of freedom)."""
        return bound_factor(self.n_avg, self.inputs_fitted(static=static), level=level)

    def bounds(self, which: Literal["t21"] | Term | str | int = "t21", *, k: float | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """Magnitude bounds |H|·(1 ∓ k·ε) of T21 or of B_i of the free fit (k: :meth:`bound_factor`, 95 %)."""
        if k is None:
            k = self.bound_factor()
        if isinstance(which, str) and which == "t21":
            h, e = self.t21, self.random_error[0]
        else:
            i = self.term_index(which)
            h, e = self.b[i], self.random_error[1 + i]
        m = np.abs(h)
        return m * np.maximum(1 - k * e, 0), m * (1 + k * e)

    def conditioning(self, cond_limit: float = DEFAULT_COND_LIMIT) -> Conditioning:
        """The conditioning summary of the analysis band against ``cond_limit`` (what every shell reports)."""
        c = np.asarray(self.cond)[self.in_band]
        if c.size == 0:
            return Conditioning(float("nan"), float("nan"), 1.0, float(cond_limit))
        with np.errstate(invalid="ignore"):
            ill = float(np.mean(~(c <= cond_limit)))
        if np.isnan(c).all():
            return Conditioning(float("nan"), float("nan"), ill, float(cond_limit))
        return Conditioning(float(np.nanmedian(c)), float(np.nanmax(c)), ill, float(cond_limit))

    def check_usable(self, cond_limit: float = DEFAULT_COND_LIMIT, *, periodic: bool = False) -> None:
        """Refuse (:class:`IllConditionedError`) only when nothing usable is left.

        The pooled coefficients must be finite, the pooled T21 defined on at least half the analysis band, and
        (with free terms) some line of the band conditioned within ``cond_limit``. ``periodic``: one period of a
        periodic excitation per block — every block is the same period, so the per-line G_UU of several inputs is
        singular by construction and only the pooled fit determines the terms (refused only when that is not
        finite)."""
        m = self.in_band
        st = self.static
        free = [i for i, f in enumerate(self.fixed) if not f]
        if not np.all(np.isfinite(st.c_over_m2)):
            raise IllConditionedError(f"the pooled coefficients c/M2 are not finite ({st.c_over_m2.tolist()}): the "
                                      "declared describing functions are linearly dependent on the data",
                                      hint="drop a duplicated or redundant term, or identify them in two steps")
        ok_static = np.isfinite(st.t21[m]) & (np.abs(st.t21[m]) > 0)
        if ok_static.mean() < 0.5:
            raise IllConditionedError(f"the pooled T21 is undefined on {1 - ok_static.mean():.0%} of the analysis "
                                      "band", hint="check the data (coherence) and the analysis band")
        if free and not periodic and not np.any(self.cond[m] <= cond_limit):
            raise IllConditionedError(
                f"G_UU is ill-conditioned on every line of the analysis band {self.analysis_band_hz[0]:g}-"
                f"{self.analysis_band_hz[1]:g} Hz (median scaled cond {np.nanmedian(self.cond[m]):.3g} > "
                f"{cond_limit:.3g}): the declared terms cannot be told apart in these data",
                hint="drop a term, identify correlated terms in two steps (steps: in the model file), "
                     "or use data with more amplitude range")

    def band_average(self, x: np.ndarray) -> np.ndarray:
        """Mean of per-line quantities (shape (..., nf)) over the analysis band's lines."""
        return np.mean(np.asarray(x)[..., self.in_band], axis=-1)

    # -- serialisation ------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain JSON types (complex arrays as ``{"re": [...], "im": [...]}``)."""
        return {
            "nifo_result": 1,
            "freq_hz": _floats(self.freq_hz), "t21": complex_json(self.t21),
            "b": [complex_json(x) for x in self.b], "mu_over_k2": [complex_json(x) for x in self.mu_over_k2],
            "c_over_m2": [complex_json(x) for x in self.c_over_m2],
            "t21_h1": complex_json(self.t21_h1), "coherence_h1": _floats(self.coherence_h1),
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
            "t2f": None if self.t2f is None else complex_json(self.t2f), "spindle_fixed": self.spindle_fixed,
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "NifoResult":
        """Inverse of :meth:`to_dict`."""
        try:
            nt = len(d["terms"])
            nf = len(d["freq_hz"])

            def mat(key):
                return np.array([complex_from_json(x) for x in d[key]]).reshape(nt, nf)
            im = d.get("input_measured")
            return cls(
                freq_hz=np.asarray(d["freq_hz"], float), t21=complex_from_json(d["t21"]), b=mat("b"),
                mu_over_k2=mat("mu_over_k2"), c_over_m2=mat("c_over_m2"), t21_h1=complex_from_json(d["t21_h1"]),
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
                provenance=dict(d.get("provenance") or {}),
                t2f=None if d.get("t2f") is None else complex_from_json(d["t2f"]),
                spindle_fixed=bool(d.get("spindle_fixed", False)))
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
        object.__setattr__(self, "c_over_m2", read_only(np.asarray(self.c_over_m2, float).reshape(-1)))
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



def _constant_coefficients(res: "NifoResult") -> np.ndarray:
    """The constant c_i/M2 of a result's terms: its static fit, else the band mean of the free ones."""
    if res.static is not None:
        return np.asarray(res.static.c_over_m2, float)
    return np.nanmean(res.c_over_m2[:, res.in_band].real, axis=1)

