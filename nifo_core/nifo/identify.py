"""Output-only and input-measured NIFO (paper §2.2, Eq. 5 and 7-10; docs/method.md §3).

Output-only (paper Eq. 8-9). The spindle motion is the input to the body:

    X2(ω) = T21(ω)·X1(ω) + Σ_i B_i(ω)·Xn_i(ω),      B_i = (μ_i/K2)·T21        (Eq. 8)

Xn_i is the Fourier transform of describing function g_i evaluated on the
measured relative motion (z, ż), z = x2 - x1. We regress in accelerations
(A = -ω²X, docs/method.md §3: equivalent for the linear part and free of
integration error in x1, x2); only z, ż are integrated (from ẍ2 - ẍ1, subtract
first). With channels [a1, a2, g_1..g_N] in ONE cross-spectral accumulator
(:mod:`nifo_core.signal.spectral`) the per-line H1 solve (Eq. 9 multiplied by the
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
:mod:`nifo_core.predict.model` predicts with. Check its assumption with the free
``c_over_m2`` (flat and real for a static or rate-independent nonlinearity).

Describing functions are kept whole (docs/method.md §3: removing their linear part
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

Layout: this module holds the batch entry points and re-exports the rest —
:mod:`nifo_core.nifo.result` (result types), :mod:`nifo_core.nifo.estimate`
(the estimator from spectra), :mod:`nifo_core.nifo.stream` (streaming
accumulation). Import from here.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from ..kinds.describing import Term
from ..errors import ConfigError, InputError
from ..signal.integrate import IntegrationBand
from .engine import IdentifySetup, RecordProbe
from .estimate import nifo_from_spectra, static_fits
from .result import (DEFAULT_ANALYSIS_BAND_HZ, DEFAULT_COND_LIMIT, FixedTerms,
                          IllConditionedWarning, InputMeasured, NifoResult, OnIll, StaticFit)
from .stream import StreamingNifo, _as_terms
from ..signal.record import Record
from ..signal.spectral import SpectralSettings

__all__ = ["IllConditionedWarning", "InputMeasured", "StaticFit", "NifoResult", "FixedTerms", "StreamingNifo",
           "identify_nifo",
           "identify_two_step", "nifo_from_spectra", "static_fits", "DEFAULT_ANALYSIS_BAND_HZ", "DEFAULT_COND_LIMIT"]

# ---------------------------------------------------------------------------------------------
# batch
# ---------------------------------------------------------------------------------------------
def identify_nifo(records: Sequence[Record] | Record, terms: Sequence[Term], *,
                  settings: SpectralSettings | None = None, band: IntegrationBand | None = None,
                  fixed: "NifoResult | FixedTerms | Sequence | None" = None, input_measured: bool | None = None,
                  spindle_noise_psd: float | None = None,
                  analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ,
                  on_ill_conditioned: OnIll = "warn", cond_limit: float = DEFAULT_COND_LIMIT,
                  use_force: bool | None = None) -> NifoResult:
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
    use_force : bool, optional
        Use the records' measured force on the body as one more input
        (X2 = T21·X1 + T2F·F + Σ B_i·Xn_i; gives M2 and physical
        coefficients). Default: when every record has a force. Records with a
        fixed spindle (``Record.spindle_fixed``) need it; their spindle column
        is dropped.

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
    setup = IdentifySetup.for_probes([RecordProbe.of(r, whole=True) for r in recs], terms, spectral=settings, band=band,
                                     analysis_band_hz=analysis_band_hz, cond_limit=cond_limit,
                                     sources=[r.source or f"record {i}" for i, r in enumerate(recs)],
                                     input_measured=input_measured, use_force=use_force)
    band = setup.band
    proto = setup.accumulator(fixed=fixed, spindle_noise_psd=spindle_noise_psd,
                              on_ill_conditioned=on_ill_conditioned)
    total = None
    for r in recs:
        r.require_samples(proto.min_samples, what=(
            f"NIFO (block={proto.settings.block} plus {proto.delay_samples} integrator edge samples at each "
            f"end for f_lo={band.f_lo_hz:g} Hz)"))
        one = proto._like()
        setup.push(one, r)
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
    """Two-step NIFO (paper §3.3, docs/method.md §3) combined into one result.

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

