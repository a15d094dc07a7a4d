"""The NIFO estimator from cross spectra (paper Eq. 8-10; see :mod:`nifo_core.nifo.identify`).

:func:`nifo_from_spectra` solves the per-line H1 of paper Eq. 9, the
constant-coefficient (static) fit and, with the tire patch, paper Eq. 10's
first row, from the cross-spectral matrix that :class:`nifo_core.nifo.stream.StreamingNifo`
accumulates.
"""

from __future__ import annotations

import warnings
from typing import Mapping, Sequence

import numpy as np

from ..kinds.describing import Term
from ..errors import ConfigError, IllConditionedError
from ..signal.integrate import IntegrationBand
from .result import (A1, A2, DEFAULT_ANALYSIS_BAND_HZ, DEFAULT_COND_LIMIT, FORCE, ILL_FRACTION, XB, FixedTerms,
                          IllConditionedWarning, InputMeasured, NifoResult, OnIll, StaticFit)
from ..signal.frf import MimoFit, coherence, h1, mimo_fit
from ..signal.spectral import CrossSpectra

__all__ = ["nifo_from_spectra", "static_fits"]

# ---------------------------------------------------------------------------------------------
# the estimator, from spectra
# ---------------------------------------------------------------------------------------------
def _channel_names(terms: Sequence[Term], with_tire_patch: bool, with_force: bool = False) -> tuple[str, ...]:
    names = [A1, A2, *(f"g{i}:{t.label}" for i, t in enumerate(terms))]
    return tuple(names + [FORCE] * with_force + [XB] * with_tire_patch)


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



def _static_weights(t21: np.ndarray, n_free: int, n_channels: int) -> np.ndarray:
    """Per-line weights of the static fit's equation error ``y - T21·u - Σ γ_i·(T21 - 1)·Gn_i`` and regressors."""
    t = np.where(np.isfinite(t21), t21, 0)
    wts = np.zeros((t21.size, 1 + n_free, n_channels), complex)
    wts[:, 0, 0] = -t
    wts[:, 0, 1] = 1.0
    for i in range(n_free):
        wts[:, 1 + i, 2 + i] = t - 1
    return wts


def _pooled_gamma(g: np.ndarray, ok: np.ndarray, gnn: np.ndarray) -> np.ndarray:
    """γ by the 1/G_nn-weighted real least squares over the lines ``ok`` of the combined spectra ``g``."""
    if not ok.any():
        raise IllConditionedError("no usable line in the analysis band for the constant-coefficient fit",
                                  hint="widen the analysis band or record more data")
    wt = 1.0 / gnn[ok]
    lhs = np.einsum("f,fij->ij", wt, g[ok][:, 1:, 1:].real)
    rhs = np.einsum("f,fi->i", wt, g[ok][:, 1:, 0].real)
    return np.linalg.lstsq(lhs, rhs, rcond=None)[0]


def _static_fit(spec: CrossSpectra, t21: np.ndarray, gnn: np.ndarray, n_free: int, mask: np.ndarray,
                w: np.ndarray, noise: float | None) -> StaticFit:
    """Constant-coefficient NIFO (see :class:`StaticFit`) of spectra [u, y, g_1..] from the free T21.

    Step 1: γ by the 1/G_nn-weighted real least squares of the equation error
    ``y - T21·u = Σ γ_i·(T21 - 1)·Gn_i`` pooled over the analysis band's lines.
    Step 2: T21 = H1 of u + Σγ·Gn → y + Σγ·Gn (spindle noise floor removed when given).
    """
    nch = spec.n_channels
    gamma = np.zeros(0)
    if n_free:
        g = spec.combine(_static_weights(t21, n_free, nch)).G
        gamma = _pooled_gamma(g, mask & np.isfinite(t21) & (gnn > 0), gnn)
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


def static_fits(specs: Sequence[CrossSpectra], n_terms: int, *,
                analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ) -> tuple[np.ndarray, np.ndarray]:
    """The constant-coefficient fit of several records, each on its own, solved as one batch: (γ, T21).

    Per record, the same arithmetic as ``nifo_from_spectra(spec, terms).static``
    (``c_over_m2`` and ``t21``; no fixed terms, tire patch or spindle noise): the
    per-line solves of all records run together on their stacked lines, only the
    pooled least squares is taken record by record. Used for the spread of the
    coefficients over a vehicle's bags, where one call per bag cost ~1 ms, most
    of it the overhead of some forty small array operations.

    Parameters
    ----------
    specs : sequence of CrossSpectra
        Spectra of [a1, a2, g_1..g_n_terms] of each record, on the same lines.
    n_terms : int

    Returns
    -------
    gamma : ndarray, shape (n_records, n_terms)
        c_i/M2 per record (NaN where a record has no usable line).
    t21 : ndarray, complex, shape (n_records, nf)
        The static T21 per record (NaN where γ is).
    """
    n = len(specs)
    if n == 0:
        return np.zeros((0, n_terms)), np.zeros((0, 0), complex)
    f, nch = specs[0].freq_hz, specs[0].n_channels
    if nch != 2 + n_terms or any(s.n_channels != nch or not np.array_equal(s.freq_hz, f) for s in specs):
        raise ConfigError(f"static_fits takes spectra of [a1, a2, g_1..g_{n_terms}] on the same lines",
                          hint="accumulate every record with the same StreamingNifo set-up")
    nf = f.size
    stack = CrossSpectra(np.tile(f, n), np.concatenate([s.G for s in specs]), min(s.n_avg for s in specs),
                         specs[0].fs_hz, specs[0].settings, specs[0].names)
    lo, hi = analysis_band_hz
    mask = (f >= lo) & (f <= hi)
    fit = mimo_fit(stack, [0, *range(2, 2 + n_terms)], 1)                                # Eq. 9, H1
    t21 = fit.h[0]
    gamma = np.zeros((n, n_terms))
    if n_terms:
        g = stack.combine(_static_weights(t21, n_terms, nch)).G
        ok = np.isfinite(t21) & (fit.residual_psd > 0)
        for r in range(n):
            seg = slice(r * nf, (r + 1) * nf)
            try:
                gamma[r] = _pooled_gamma(g[seg], mask & ok[seg], fit.residual_psd[seg])
            except IllConditionedError:
                gamma[r] = np.nan
    comb = np.zeros((n * nf, 2, nch))
    comb[:, 0, 0] = comb[:, 1, 1] = 1.0
    comb[:, :, 2:] = np.repeat(gamma, nf, axis=0)[:, None, :]
    t21s = mimo_fit(stack.combine(np.nan_to_num(comb)), [0], 1).h[0].reshape(n, nf)
    t21s[~np.isfinite(gamma).all(axis=1)] = np.nan
    return gamma, t21s


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


def _check_request(spec: CrossSpectra, all_terms, with_tire_patch: bool, with_force: bool,
                   spindle_noise_psd: float | None) -> None:
    """ConfigError when the spectra do not hold the channels NIFO needs or the noise floor is not a PSD."""
    want = _channel_names(all_terms, with_tire_patch, with_force)
    if spec.n_channels != len(want):
        raise ConfigError(f"cross spectra hold {spec.n_channels} channels, NIFO with {len(all_terms)} terms needs "
                          f"{len(want)}", hint="accumulate with StreamingNifo")
    if spindle_noise_psd is not None and not (np.isfinite(spindle_noise_psd) and spindle_noise_psd >= 0):
        raise ConfigError(f"spindle_noise_psd={spindle_noise_psd!r} must be a finite PSD >= 0 [(m/s²)²/Hz]")


def _check_inputs(nfx: int, *, with_tire_patch: bool, with_force: bool, spindle_fixed: bool) -> None:
    """ConfigError for a fixed spindle without a force, or a force with fixed terms or the tire patch."""
    if spindle_fixed and not with_force:
        raise ConfigError("a fixed spindle leaves NIFO without an input", channel=FORCE,
                          hint="give the measured force or the spindle acceleration")
    if with_force and (nfx or with_tire_patch):
        raise ConfigError("NIFO with a measured force supports neither fixed (two-step) terms nor the "
                          "tire patch", hint="identify all terms in one step; drop the tire patch")


def _band_lines(f: np.ndarray, analysis_band_hz: tuple[float, float]) -> np.ndarray:
    """The lines of the analysis band (ConfigError for a band that is not one or holds none)."""
    lo, hi = analysis_band_hz
    if not (0 <= lo < hi):
        raise ConfigError(f"analysis band {lo}-{hi} Hz must satisfy 0 <= lo < hi", hint="e.g. 2 30")
    mask = (f >= lo) & (f <= hi)
    if not mask.any():
        raise ConfigError(f"analysis band {lo:g}-{hi:g} Hz holds no frequency line", hint="widen it")
    return mask


def _with_fixed_inputs(spec: CrossSpectra, gamma_fixed: np.ndarray, nt: int) -> CrossSpectra:
    """The spectra of [u, y, g_free..] with u = A1 + Σ_fixed γ_i·Gn_i, y = A2 + Σ_fixed γ_i·Gn_i (the fixed terms
    as an extra known input, exactly: see :func:`nifo_from_spectra`)."""
    nfx = gamma_fixed.size
    comb = np.zeros((2 + nt - nfx, spec.n_channels))
    comb[0, 0] = comb[1, 1] = 1.0
    comb[0:2, 2:2 + nfx] = gamma_fixed
    comb[2:, 2 + nfx:2 + nt] = np.eye(nt - nfx)
    return spec.combine(comb, names=(A1 + "+fixed", A2 + "+fixed", *spec.names[2 + nfx:2 + nt]))


def _per_line(fit: MimoFit, gamma_fixed: np.ndarray, nt: int, inv_w2: np.ndarray):
    """(T21, B, μ/K2, c/M2, partial coherences, random errors) of the per-line fit, the fixed terms' rows from their
    constant γ_i (partial coherence and error NaN there)."""
    nfx = gamma_fixed.size
    t21 = fit.h[0]
    d = np.concatenate([gamma_fixed[:, None] * (t21 - 1)[None, :], fit.h[1:]]) if nfx else fit.h[1:]
    b = -d * inv_w2                                                        # D = -ω²·B
    with np.errstate(divide="ignore", invalid="ignore"):
        mu_over_k2 = b / t21                                               # Eq. 8: B = (μ/K2)·T21
        c_over_m2 = -d / (1 - t21)                                         # = ω²B/(1 - T21) = c/M2 (K3 = 0)
    n_lines = t21.size
    pc = np.full((1 + nt, n_lines), np.nan)
    pc[0] = fit.partial_coherence[0]
    pc[1 + nfx:] = fit.partial_coherence[1:]
    err = np.full((1 + nt, n_lines), np.nan)
    err[0] = fit.random_error[0]
    err[1 + nfx:] = fit.random_error[1:]
    return t21, b, mu_over_k2, c_over_m2, pc, err


def _static_with_fixed(work: CrossSpectra, fit: MimoFit, t21: np.ndarray, gamma_fixed: np.ndarray, nt: int,
                       mask: np.ndarray, w: np.ndarray, inv_w2: np.ndarray, noise: float | None) -> StaticFit:
    """The constant-coefficient fit of the free terms, with the fixed terms' γ_i in front."""
    st = _static_fit(work, t21, fit.residual_psd, nt - gamma_fixed.size, mask, w, noise)  # no free term: H1 u -> y
    gam = np.concatenate([gamma_fixed, st.c_over_m2])
    with np.errstate(divide="ignore", invalid="ignore"):
        bs = gam[:, None] * (1 - st.t21)[None, :] * inv_w2[None, :]
        mus = bs / st.t21
    return StaticFit(c_over_m2=gam, t21=st.t21, b=bs, mu_over_k2=mus, coherence=st.coherence,
                     random_error=st.random_error)


def nifo_from_spectra(spec: CrossSpectra, terms: Sequence[Term], *, band: IntegrationBand,
                      fixed: "NifoResult | FixedTerms | Sequence | None" = None,
                      analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ,
                      with_tire_patch: bool = False, spindle_noise_psd: float | None = None,
                      on_ill_conditioned: OnIll = "warn", cond_limit: float = DEFAULT_COND_LIMIT,
                      n_samples: int = 0, provenance: Mapping | None = None, with_force: bool = False,
                      spindle_fixed: bool = False) -> NifoResult:
    """NIFO estimates from the cross-spectral matrix of [a1, a2, g_fixed.., g_1.., (f), (xb)].

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
        datasheet, a record at rest, or :func:`frf.white_noise_floor` in a
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
    with_force : bool
        The spectra hold a measured force on the body [N] (after the
        describing functions): see :func:`_nifo_with_force`.
    spindle_fixed : bool
        The spindle did not move: its column is left out of the regression.
    """
    fixed = FixedTerms.coerce(fixed)
    fixed_terms = tuple(fixed.terms) if fixed is not None else ()
    all_terms = (*fixed_terms, *terms)
    nfx, nt = len(fixed_terms), len(all_terms)
    _check_request(spec, all_terms, with_tire_patch, with_force, spindle_noise_psd)
    f = spec.freq_hz
    w = 2 * np.pi * f
    mask = _band_lines(f, analysis_band_hz)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_w2 = np.where(w > 0, 1.0 / np.where(w > 0, w, 1) ** 2, np.nan)
    noise = None if spindle_noise_psd is None else float(spindle_noise_psd)
    _check_inputs(nfx, with_tire_patch=with_tire_patch, with_force=with_force, spindle_fixed=spindle_fixed)
    if with_force:
        return _nifo_with_force(spec, all_terms, band=band, mask=mask, w=w, inv_w2=inv_w2,
                                spindle_fixed=spindle_fixed, analysis_band_hz=analysis_band_hz,
                                on_ill_conditioned=on_ill_conditioned, cond_limit=cond_limit,
                                n_samples=n_samples, provenance=provenance)

    # fixed (step-1) terms enter through their constant c_i/M2 = γ_i: with D_i = γ_i·(T21 - 1),
    # A2 = T21·A1 + Σ_fixed D_i·Gn_i + Σ_free D_i·Gn_i  <=>  y = T21·u + Σ_free D_i·Gn_i
    # with u = A1 + Σ_fixed γ_i·Gn_i and y = A2 + Σ_fixed γ_i·Gn_i (an extra known input, exactly).
    gamma_fixed = np.asarray(fixed.c_over_m2, float) if nfx else np.zeros(0)
    work = _with_fixed_inputs(spec, gamma_fixed, nt) if nfx else spec
    free = list(range(2, 2 + nt - nfx))
    fit: MimoFit = mimo_fit(work, [0, *free], 1)                            # Eq. 9, H1
    _check_conditioning(fit.cond, mask, what="output-only NIFO", cond_limit=cond_limit, on_ill=on_ill_conditioned)

    t21, b, mu_over_k2, c_over_m2, pc, err = _per_line(fit, gamma_fixed, nt, inv_w2)
    static = _static_with_fixed(work, fit, t21, gamma_fixed, nt, mask, w, inv_w2, noise)

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




def one_mass_fit(freq_hz: np.ndarray, h_af: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(M2 [kg], K2 [N/m], C2 [N·s/m], relative RMS misfit) of a body driven by a force.

    One mass on a spring-damper to the spindle, force F on the mass
    (M2·ẍ2 = -(K2 + jωC2)·(X2 - X1) - Σ c_i·G_i + F): the acceleration per
    force is h = -ω²/(-ω²M2 + K2 + jωC2), so ``1/h = M2 - K2/ω² - j·C2/ω``,
    linear in the three unknowns; least squares over the ``mask`` lines, each
    line weighted by |h| so that the misfit is relative.
    """
    w = 2 * np.pi * np.asarray(freq_hz, float)
    ok = mask & np.isfinite(h_af) & (np.abs(h_af) > 0) & (w > 0)
    if ok.sum() < 3:
        raise IllConditionedError("fewer than 3 usable lines for the one-mass fit of the force path",
                                  hint="widen the analysis band or record more data")
    wo, inv = w[ok], 1.0 / h_af[ok]
    wt = np.abs(h_af[ok])
    a = np.concatenate([np.column_stack([np.ones_like(wo), -1 / wo**2, np.zeros_like(wo)]),
                        np.column_stack([np.zeros_like(wo), np.zeros_like(wo), -1 / wo])]) * np.tile(wt, 2)[:, None]
    rhs = np.concatenate([inv.real, inv.imag]) * np.tile(wt, 2)
    m2, k2, c2 = np.linalg.lstsq(a, rhs, rcond=None)[0]
    model = -wo**2 / (-wo**2 * m2 + k2 + 1j * wo * c2)
    rms = float(np.sqrt(np.mean(np.abs(model - h_af[ok]) ** 2) / np.mean(np.abs(h_af[ok]) ** 2)))
    return np.array([m2, k2, c2, rms])


def _nifo_with_force(spec: CrossSpectra, terms: Sequence[Term], *, band: IntegrationBand, mask: np.ndarray,
                     w: np.ndarray, inv_w2: np.ndarray, spindle_fixed: bool, analysis_band_hz: tuple[float, float],
                     on_ill_conditioned: OnIll, cond_limit: float, n_samples: int,
                     provenance: Mapping | None) -> NifoResult:
    """NIFO with a measured force on the body (paper Eq. 8 with one more input).

    In accelerations, for the body equation M2·ẍ2 = -Z·z - Σ c_i·g_i + F (Z = K2 + jωC2, K3 = 0):

        A2 = T21·A1 + H·F + Σ D_i·Gn_i,   H = -ω²/(-ω²M2 + Z) = -ω²·T2F,   D_i = -c_i·H

    Free fit: the per-line H1 of A2 on [A1, F, Gn_1..] — without A1 when the
    spindle is fixed (a zero column would make G_UU singular). c_i(ω) = -D_i/H
    in physical units [N per unit of g]. Constant-coefficient fit: the real
    c_i pooled over the band from the equation error
    ``A2 - T21·A1 - H·F = -Σ c_i·H·Gn_i`` (weights 1/G_nn, as :func:`_static_fit`),
    then the H1 of A2 on [A1, F - Σ c_i·Gn_i]. M2 comes from the one-mass fit
    of H (:func:`one_mass_fit`), which makes c_i/M2 = γ_i and, for a fixed
    spindle, the one-mass model's T21 = 1 - M2·H (it is not measured then;
    ``t21_h1`` is then 1 - M2·H1 of the force → body acceleration, the
    equivalent linearisation at the test level in the same form).
    """
    nt = len(terms)
    nch = spec.n_channels
    fi = 2 + nt                                                             # force channel
    gi = list(range(2, 2 + nt))
    lead = [] if spindle_fixed else [0]
    fit: MimoFit = mimo_fit(spec, [*lead, fi, *gi], 1)
    _check_conditioning(fit.cond, mask, what="NIFO with force", cond_limit=cond_limit, on_ill=on_ill_conditioned)
    k = len(lead)
    h_af = fit.h[k]
    d = fit.h[k + 1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        c_free = -d / h_af
    # constant coefficients: the equation error e = A2 - T21·A1 - H·F = Σ c_i·(-H)·Gn_i
    c = np.zeros(0)
    if nt:
        t21f = fit.h[0] if lead else np.zeros_like(h_af)
        hh = np.where(np.isfinite(h_af), h_af, 0)
        wts = np.zeros((w.size, 1 + nt, nch), complex)
        wts[:, 0, 0] = -np.where(np.isfinite(t21f), t21f, 0)
        wts[:, 0, 1] = 1.0
        wts[:, 0, fi] = -hh
        for i in range(nt):
            wts[:, 1 + i, 2 + i] = -hh
        g = spec.combine(wts).G
        ok = mask & np.isfinite(h_af) & (fit.residual_psd > 0)
        if not ok.any():
            raise IllConditionedError("no usable line in the analysis band for the constant-coefficient fit",
                                      hint="widen the analysis band or record more data")
        wt = 1.0 / fit.residual_psd[ok]
        lhs = np.einsum("f,fij->ij", wt, g[ok][:, 1:, 1:].real)
        rhs = np.einsum("f,fi->i", wt, g[ok][:, 1:, 0].real)
        c = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    comb = np.zeros((3, nch))
    comb[0, 0] = comb[1, 1] = comb[2, fi] = 1.0
    comb[2, 2:2 + nt] = -c
    cs = spec.combine(comb, names=(A1, A2, FORCE + "-nl"))
    sfit = mimo_fit(cs, [0, 2] if lead else [2], 1)
    hs = sfit.h[-1]
    one = one_mass_fit(spec.freq_hz, hs, mask)
    m2 = one[0]
    if not (np.isfinite(m2) and m2 > 0):
        raise IllConditionedError(f"the one-mass fit of the force path gives M2 = {m2:.4g} kg (not physical)",
                                  hint="check the force's sign and units, and the analysis band")
    with np.errstate(divide="ignore", invalid="ignore"):
        t21s = sfit.h[0] if lead else 1 - m2 * hs
        t21 = fit.h[0] if lead else 1 - m2 * h_af
        b = -d * inv_w2
        bs = c[:, None] * hs[None, :] * inv_w2[None, :]                    # D_i = -c_i·H, B = -D/ω²
        static = StaticFit(c_over_m2=c / m2, t21=t21s, b=bs, mu_over_k2=bs / t21s,
                           coherence=sfit.multiple_coherence, random_error=sfit.random_error[-1],
                           t2f=-hs * inv_w2, c=c, one_mass=one)
        mu = b / t21
    pc = np.full((1 + nt, w.size), np.nan)
    err = np.full((1 + nt, w.size), np.nan)
    if lead:
        pc[0], err[0] = fit.partial_coherence[0], fit.random_error[0]
    pc[1:], err[1:] = fit.partial_coherence[k + 1:], fit.random_error[k + 1:]
    prov = dict(provenance or {})
    prov["force"] = {"spindle_fixed": bool(spindle_fixed), "m2_kg": float(m2), "k2_n_per_m": float(one[1]),
                     "c2_ns_per_m": float(one[2]), "one_mass_misfit": float(one[3]), "c": c.tolist()}
    return NifoResult(freq_hz=spec.freq_hz.copy(), t21=t21, b=b, mu_over_k2=mu, c_over_m2=c_free / m2,
                      t21_h1=1 - m2 * h1(spec, fi, 1) if spindle_fixed else h1(spec, 0, 1),
                      coherence_h1=coherence(spec, fi, 1) if spindle_fixed else coherence(spec, 0, 1),
                      multiple_coherence=fit.multiple_coherence, partial_coherence=pc, cond=fit.cond,
                      random_error=err, n_avg=spec.n_avg, n_samples=int(n_samples), terms=tuple(terms),
                      fixed=(False,) * nt, fs_hz=spec.fs_hz, settings=spec.settings, band=band,
                      analysis_band_hz=analysis_band_hz, input_measured=None, static=static,
                      spindle_noise_psd=None, provenance=prov, t2f=-h_af * inv_w2, spindle_fixed=spindle_fixed)
