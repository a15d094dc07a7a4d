"""The words of the loop's report (:mod:`nifo_core.loop.closing`): a round's paragraph, each metric before → after,
the verdicts when a round adds nothing or the held-out prediction does not confirm a candidate.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..characterize.automatic import Candidate
from .round_results import Errors, Evidence, Trial, _effect_words

__all__ = ["NOTHING_MISSING", "before_after_text", "unconfirmed_text"]

#: the verdict when the last round found nothing
NOTHING_MISSING = "Nothing significant is missing."


def _errors_line(e: Errors) -> str:
    parts = []
    if e.prediction_nmse_pct is not None:
        parts.append(f"held-out prediction NMSE {e.prediction_nmse_pct:.2f} % (output acceleration simulated from the "
                     f"measured input)")
    else:
        parts.append(f"held-out prediction NMSE not computed ({e.prediction_unavailable or 'prediction off'})")
    parts.append(f"held-out equation error {e.equation_nmse_pct:.2f} % (force balance, band-limited)")
    parts.append(f"residual of the {e.residual_of} " + ", ".join(f"{k} Hz {v:+.1f} dB"
                                                              for k, v in e.band_residual_db.items()))
    if e.transmissibility_error_pct:
        parts.append("transmissibility error " + ", ".join(f"{s or 'record'} {v:.1f} %"
                                                           for s, v in e.transmissibility_error_pct))
    return "; ".join(parts) + "."


def before_after_text(before: Errors, after: Errors) -> str:
    """Before → after on each metric, each labelled; a side without a prediction says so (never another metric)."""
    p0, p1 = before.prediction_nmse_pct, after.prediction_nmse_pct
    if p0 is not None and p1 is not None:
        pred = f"held-out prediction NMSE {p0:.2f} % → {p1:.2f} %"
    elif p0 is None and p1 is None:
        pred = f"held-out prediction NMSE not computed ({before.prediction_unavailable or 'prediction off'})"
    else:
        pred = ("held-out prediction NMSE " + (f"{p0:.2f} %" if p0 is not None else "not computed")
                + " → " + (f"{p1:.2f} %" if p1 is not None else "not computed")
                + f" ({(after if p1 is None else before).prediction_unavailable})")
    w0, w1 = before.whole_nmse_pct, after.whole_nmse_pct
    whole = ""
    if w0 is not None and w1 is not None:
        whole = f"; held-out whole-signal NMSE (all frequencies, offset included) {w0:.3g} % → {w1:.3g} %"
        if w1 > w0 and p0 is not None and p1 is not None and p1 < p0:
            whole += " (worse over all frequencies while better in the band: not confirmed outside the band)"
    return (f"{pred}{whole}; held-out equation error {before.equation_nmse_pct:.2f} % → "
            f"{after.equation_nmse_pct:.2f} %")


def _p_text(p: float) -> str:
    if p < 1e-6:
        return "p < 1e-6"
    return f"p = {p:.1g}"


def _stability_words(c: Candidate, n_records: int) -> str:
    if not np.isfinite(c.spread):
        return "stability unknown"
    what = f"the {n_records} records (levels)" if n_records > 1 else "the four quarters of the record"
    return f"stable across {what} (±{100 * c.spread:.0f} %)"


def _round_text(i: int, trial: Trial, before: Errors, ev: Evidence | None, m2: float | None,
                n_records: int, ranked: Sequence[Candidate] = ()) -> str:
    c, after = trial.candidate, trial.after
    alts = [a for a in ranked if a.kind != c.kind and a.err >= 0.98 * c.err]
    alt = ""
    if alts:
        alt = (" Nearly as good: " + ", ".join(f"{a.term.label} (explains {100 * a.err:.2f} %)" for a in alts)
               + f" — the data barely tell them apart; {c.kind} explains most ({100 * c.err:.2f} %).")
    assert after is not None
    pc = ""
    if ev is not None and np.isfinite(ev.partial_coherence_mean):
        pc = (f", partial coherence {ev.partial_coherence_mean:.2f} (95 % level {ev.partial_coherence_level:.2f}) "
              f"in the analysis band, {100 * ev.fraction_lines_above_level:.0f} % of lines above it")
    return (f"Round {i}: added {_effect_words(c, m2)}. It explains {100 * c.err:.0f} % of the remaining "
            f"body-acceleration residual ({100 * c.err_cv:.0f} % on alternate held-out blocks), "
            f"{_p_text(c.p_value)}{pc}, {_stability_words(c, n_records)}, and is not an artefact of impacts "
            f"on the input side (coefficient moves {100 * trial.tire_shift:.0f} % without the samples around "
            f"them); "
            f"{before_after_text(before, after)}.{alt}")


def unconfirmed_text(trials: Sequence[Trial], current: Errors) -> str:
    """The verdict when candidates pass everything on the equation error but the held-out prediction refuses them."""
    names = "; ".join(f"{t.candidate.term.label} ({t.candidate.describe()}, explains {100 * t.candidate.err:.0f} % "
                      f"of the equation residual)" for t in trials)
    why = "; ".join(dict.fromkeys(f for t in trials for f in t.failed))
    return (f"Found but not added: {names}. Significant, stable and lowering the held-out equation error with no "
            f"band worse, but the held-out prediction does not confirm it ({why}). Either the effect is not "
            f"there, or the predicting model (held-out prediction NMSE "
            + (f"{current.prediction_nmse_pct:.2f} %" if current.prediction_nmse_pct is not None else "not computed")
            + ") cannot use it at these levels: not proven missing, not proven absent.")


def _nothing_text(i: int, ranked: Sequence[Candidate], trials: Sequence[Trial]) -> str:
    if trials:
        t = trials[0]
        why = "; ".join(t.failed)
        end = ("Not added: the held-out prediction does not confirm it." if any(x.unconfirmed for x in trials)
               else NOTHING_MISSING)
        # a candidate below the significance tests is tried too where the held-out prediction judges (a rational part)
        tests = ("passes the significance tests but" if t.candidate.present else
                 "is tried for its held-out prediction and")
        return (f"Round {i}: the best remaining candidate, {t.candidate.term.label}, {tests} fails the acceptance: "
                f"{why}. {end}")
    if ranked:
        c = ranked[0]
        return (f"Round {i}: the best remaining candidate, {c.term.label}, explains "
                f"{100 * c.err:.1f} % of what is left and fails: {'; '.join(c.failed)}. {NOTHING_MISSING}")
    return f"Round {i}: no candidate to try. {NOTHING_MISSING}"
