"""The summary of an identification: the numbers ``nifo identify`` prints and stores in identify.json, and its
plain-language warnings, from a :class:`~nifo_core.nifo.result.NifoResult` alone.

One function for every shell that reports an identification (``nifo identify``/``nifo run``, the fleet's per-group
solve, the benchmarks), as :mod:`nifo_core.nifo.engine` is one way to accumulate it: the fleet used to import it from
the identify step (a shell importing a shell).
"""

from __future__ import annotations

import numpy as np

__all__ = ["summarize"]


def _unit(term) -> str:
    u = term.spec.coef_unit
    return f"({u})/kg" if u else "1/kg"


def summarize(res, cond_limit: float) -> tuple[dict, list[str]]:
    """The printed numbers (also stored in identify.json) and plain-language warnings of ``res`` (a
    :class:`~nifo_core.nifo.result.NifoResult`), its conditioning judged against ``cond_limit``."""
    m = res.in_band
    st = res.static
    lo, hi = res.analysis_band_hz
    warn: list[str] = []
    terms = []
    for i, t in enumerate(res.terms):
        free_c = res.c_over_m2[i][m]
        re_mean = float(np.nanmean(free_c.real)) if not res.fixed[i] else None
        im_mean = float(np.nanmean(free_c.imag)) if not res.fixed[i] else None
        re_spread = float(np.nanstd(free_c.real)) if not res.fixed[i] else None
        terms.append({"term": t.to_dict(), "label": t.label, "c_over_m2": float(st.c_over_m2[i]), "unit": _unit(t),
                      "fixed": bool(res.fixed[i]), "per_line_mean_re": re_mean, "per_line_mean_im": im_mean,
                      "per_line_std_re": re_spread})
    with np.errstate(divide="ignore", invalid="ignore"):
        d_h1 = np.abs(st.t21[m] / res.t21_h1[m] - 1)
        d_free = np.abs(res.t21[m] / st.t21[m] - 1)
    cond = res.conditioning(cond_limit)
    frac = cond.ill_fraction
    summary = {
        "analysis_band_hz": [lo, hi], "integration_band_hz": [res.band.f_lo_hz, res.band.f_hi_hz],
        "n_avg": int(res.n_avg), "n_samples": int(res.n_samples), "duration_used_s": res.n_samples / res.fs_hz,
        "terms": terms,
        "t21_static_vs_h1_rel_diff": {"median": float(np.nanmedian(d_h1)), "max": float(np.nanmax(d_h1))},
        "t21_free_vs_static_rel_diff": {"median": float(np.nanmedian(d_free)), "max": float(np.nanmax(d_free))},
        "coherence_h1_median": float(np.nanmedian(res.coherence_h1[m])),
        **cond.to_dict(),
    }
    if st.one_mass is not None:   # a measured force: the body mass and the coefficients in physical units
        m2, k2, c2, misfit = (float(v) for v in st.one_mass)
        summary["force"] = {"spindle_fixed": bool(res.spindle_fixed), "m2_kg": m2, "k2_n_per_m": k2,
                            "c2_n_s_per_m": c2, "natural_frequency_hz": float(np.sqrt(k2 / m2) / (2 * np.pi)),
                            "damping_ratio": float(c2 / (2 * np.sqrt(k2 * m2))), "one_mass_misfit": misfit,
                            "c": [float(v) for v in st.c]}
    if frac > 0.1 and any(not f for f in res.fixed):
        warn.append(f"The per-line (paper Eq. 9) estimate is ill-conditioned on {frac:.0%} of the {lo:g}-{hi:g} Hz "
                    f"lines (median scaled cond {summary['cond_median']:.3g}, limit {cond_limit:.3g}): its T21 and "
                    f"μ_i/K2 are sensitive to noise there. The pooled (constant c/M2) T21, the main result, pools all "
                    f"lines and is much less affected. To improve the per-line estimate, identify correlated terms "
                    f"in two steps (steps: in the model file), drop a term, or record more data.")
    elif frac > 0:
        warn.append(f"{frac:.0%} of the {lo:g}-{hi:g} Hz lines have a scaled cond(G_UU) above {cond_limit:.3g}; "
                    "per-line coefficients there are noise-sensitive.")
    for tm in terms:
        if tm["fixed"] or tm["per_line_mean_re"] is None:
            continue
        pooled, re_m, im_m = tm["c_over_m2"], tm["per_line_mean_re"], tm["per_line_mean_im"]
        if abs(im_m) > 0.5 * max(abs(re_m), 1e-300):
            warn.append(f"{tm['label']}: the per-line c/M2 has a large imaginary part (band mean {re_m:.3g} "
                        f"{im_m:+.3g}j): the term may not act as declared (static), a missing effect is absorbed, or "
                        "(a flexible body with a rational linear part) its force reaches the body through a path of its "
                        "own: --feedback-paths.")
        if np.sign(re_m) != np.sign(pooled) and pooled != 0:
            warn.append(f"{tm['label']}: pooled c/M2 {pooled:.3g} and per-line band mean {re_m:.3g} disagree in sign; "
                        "treat this coefficient as not identified.")
    if summary["coherence_h1_median"] < 0.8:
        warn.append(f"The ordinary coherence spindle→body is low (median {summary['coherence_h1_median']:.2f} in "
                    f"{lo:g}-{hi:g} Hz): noise or unmeasured inputs; average more data.")
    return summary, warn
