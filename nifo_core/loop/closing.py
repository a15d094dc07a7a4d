"""Closing the loop: residual → the effect the model lacks → add it → error before and after (docs/method.md §5).

Given records and a *declared* model (describing functions, :mod:`nifo_core.kinds.describing`),
:func:`close_loop` repeats, for at most ``max_rounds`` rounds:

1. **Residual that can show what is missing.** Each record is split in time:
   the first ``fit_fraction`` fits, the rest is held out. Two residuals:

   - equation error in force-balance form (paper Eq. 2 per unit sprung mass)::

         e = -ẍ2 - k·z - c·ż - Σ_declared θ_i·g_i           θ_i = c_i/M2

     every column band-passed with the one integrator-matched filter
     (:func:`nifo_core.characterize.restoring.bandpass`, g *after* the nonlinear map), the
     coefficients fitted on the fit part and the error scored on the held-out part;
   - prediction error on the held-out part: the declared model is identified by
     NIFO (:func:`nifo_core.nifo.identify.identify_nifo`, static fit) on the fit part and
     the body acceleration predicted from the measured spindle acceleration of
     the held-out part (:func:`nifo_core.predict.model.predict_transmissibility`).

   The displacement-form NIFO residual / multiple coherence is *not* used: a
   describing function of z = x2 - x1 carries the output into the regressors,
   and the fit absorbs whatever is missing (docs/method.md §3).

2. **Tracing.** Every kind of the library, over parameter grids scaled to the
   motion, is scored by the fraction of the linear + declared equation error it
   explains (:func:`nifo_core.characterize.automatic.rank_beyond`: band-limited after the
   map, orthogonalised against z, ż and the declared terms, error reduction
   ratio, refined and refitted at full length).

3. **Acceptance.** The best candidates are tried in rank order; one is added
   only if all hold:

   - *significant*: F-test with an effective number of degrees of freedom,
     N_eff = N·mean(S)²/mean(S²) from the residual spectrum S, Bonferroni over
     the grid, p < ``thresholds.alpha``. An F-test rather than a per-line
     partial coherence because the residual is coloured (band-passed, a
     body-mode peak): N counts samples, not independent information, and the
     effect is static, so its evidence pools over the whole band; per-line
     partial coherence against its 95 % level 1 - 0.05^(1/(n_d - q - 1)) is
     reported as evidence, not used as the gate (it splits the same evidence
     over ~300 lines of 60 averages each);
   - it explains ≥ ``thresholds.min_err`` of the remaining residual, and does
     so on alternate held-in/held-out blocks too (cross-validated ERR);
   - its coefficient is *stable*: across the records (amplitude levels) when
     several are given, else across quarters of the record (weighted relative
     spread ≤ ``thresholds.max_spread``);
   - the *held-out* equation error falls by at least ``min_heldout_gain``
     (relative) with the coefficients fitted on the fit part only, and the
     held-out prediction error does not rise;
   - *tire check*: the body equation holds no tire force (paper Eq. 2: tire
     nonlinearities such as lift-off act on M1 only and cannot appear in the
     spindle→body path), so a tire effect can reach the body-equation residual
     only through processing (the spindle's impacts smeared by integration and
     band-passing). The candidate's coefficient is refitted without the
     samples around the spindle's impacts (|ẍ1| above its ``tire_quantile``
     quantile, ± ``tire_guard_s``); a strut effect acts along the whole
     strut motion and keeps its coefficient (shift ≤ ``max_tire_shift``),
     an artefact of tire events does not.

4. **Add and refit**: the accepted term joins the model, everything is refitted
   (equation error and NIFO), and the next round traces what is left. The loop
   stops when no candidate passes ("Nothing significant is missing.") or after
   ``max_rounds``.

   A bump stop is measured from the static position (:mod:`nifo_core.characterize.static`): the
   ranking reads its gap from each record's mean position, which the one-sided force pushes away
   from the stop, the more the harder the excitation; before its checks the candidate is re-fitted
   with its gap from the static position and one offset -m_i per record (m_i from the balance of
   the mean force), and the loop's columns and later rankings use those offsets.

5. **Report** before and after each addition: NMSE (%) on held-out data
   (Worden & Tomlinson: 100·Σ(y - ŷ)²/(N·σ_y²); < 5 % good, < 1 % excellent),
   per-band residual 10·log10(G_ee/G_yy) in 2-5, 5-10, 10-20, 20-30 Hz (one
   spectral engine, :mod:`nifo_core.signal.spectral`), the transmissibility
   prediction error at each level, and the added effect with its evidence.

6. **Refine** (``settings.refine``): the final model, an equation-error fit, is refined by output
   error (:func:`nifo_core.predict.refine.refine_model`: every fit part simulated from its measured input,
   its first ``refine_seconds``; the coefficients, gaps/knees and the body's k, c that minimise the
   band-limited prediction error), its bias from the noisy spindle drive removed by simulating it
   (:mod:`nifo_core.predict.refine_bias`, with ``noise_correction``; :mod:`nifo_core.loop.refine`) and
   scored on the held-out parts like every model of the loop. The refined model becomes the loop's
   model when its held-out prediction NMSE is not worse; the report gives both fits' parameters and
   both NMSEs. A final step: the acceptance of terms (step 3) does not use it. Measured
   (tests/test_loop_refine.py, 2 % noise): a bump stop 2e5 N/m beyond 8 mm, 1.56e5 at first
   addition → 1.81e5 refined, gap 8.07 mm from static; beside a declared damper knee 1.67e5
   refined plainly, 1.89e5 with the refinement's bias removed.

:func:`close_loop` runs these steps; each lives in its own module: the set-up (records, band, held-out split,
evaluator, predictor) :mod:`~nifo_core.loop.state`; the held-out prediction and both residuals of a term set
:mod:`~nifo_core.loop.predictor`; the rounds :mod:`~nifo_core.loop.rounds`, what each tries
:mod:`~nifo_core.loop.candidates` and how each candidate is judged :mod:`~nifo_core.loop.acceptance`; the best set of
effects :mod:`~nifo_core.loop.best_set`; the final model, its refinement and the declared terms' fates
:mod:`~nifo_core.loop.final`. The result and its words: :mod:`~nifo_core.loop.results`,
:mod:`~nifo_core.loop.round_results`, :mod:`~nifo_core.loop.words`; the settings :mod:`~nifo_core.loop.settings`.

References: Billings (error reduction ratio, forward orthogonal regression);
Bendat & Piersol (conditioned/partial coherence); Worden & Tomlinson (NMSE);
Haroon & Adams (paper Eq. 2, 7-9).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Mapping, Sequence

import numpy as np

from ..kinds.describing import Term, make_term
from .detection import confounded_pairs, detection_limits, undetermined_terms
from ..signal.integrate import IntegrationBand
from ..settings import AnalysisSettings
from .results import LoopResult
from .settings import RETUNE_FACTOR, LoopSettings
from .words import NOTHING_MISSING, before_after_text
from ..signal.record import Record
from .best_set import _best_set_pass
from .final import _bias_note, _final_model, _retune_declared, _rounds_corrected
from .rounds import _Found, _run_rounds
from .state import _set_up, _Setup

__all__ = ["close_loop"]


def close_loop(records: Record | Sequence[Record], declared: Sequence[Term | Mapping | str] = (), *,
               m2_kg: float | None = None, band: IntegrationBand | None = None,
               settings: LoopSettings = LoopSettings(), data: AnalysisSettings | None = None,
               progress: Callable[[float, str], None] | None = None) -> LoopResult:
    """Find what the declared model lacks, add it, refit, repeat; report errors before and after.

    Parameters
    ----------
    records : Record or sequence of Record
        One record, or several at different excitation levels (same vehicle, same rate), each whole from its
        first sample (a transient start is left out by ``data``'s ``skip_periods``/``skip_seconds``).
    declared : sequence of Term (or model-file entries)
        The declared strut nonlinearities besides the linear strut (empty: linear).
    m2_kg : float, optional
        Sprung mass [kg]: coefficients also in N, N/m, N·s/m...
    band : IntegrationBand, optional
        Integration band; default ``data.band``, else :func:`~nifo_core.characterize.restoring.suggest_band` of the records together.
    settings : LoopSettings
    data : AnalysisSettings, optional
        The spectral settings, bands, period and transient (:mod:`nifo_core.settings`); default: the
        loop settings' spectral settings and analysis band, no period, no transient.
    progress : callable, optional
        ``progress(fraction, what)`` as the work advances.

    Returns
    -------
    LoopResult
    """
    say = progress or (lambda f, w: None)
    u = _set_up(records, declared, m2_kg, band, settings, data, say)
    found = _run_rounds(u, say)
    if u.retune_ok and found.search is not None and len(found.terms) > u.n_decl:
        found = _best_set_pass(u, found, say)
    found, retuned = _retune_declared(u, found)
    say(0.95, "rounds done")
    terms, current, ev, pred, s = list(found.terms), found.current, u.ev, u.pred, u.s
    verdict = found.verdict
    n_added = len(terms) - u.n_decl
    if n_added:
        verdict = (f"Added {n_added} effect(s): " + ", ".join(t.label for t in terms[u.n_decl:])
                   + f"; {before_after_text(u.initial, current)}. "
                   + verdict)
    if found.ambiguities:   # never "nothing significant is missing" when the data cannot decide
        verdict = "".join(f"Ambiguity: {a.text()}. " for a in found.ambiguities) + verdict
    notes = _notes(u, retuned)
    limits, confounded, verdict = _limits(u, found, verdict, say)
    bounds = ev.bounds(terms)
    if ev.corrects:     # the rounds' coefficients bias-corrected, from the final set's correction where it holds them
        found = replace(found, rounds=_rounds_corrected(ev, found.rounds, terms, bounds, m2_kg))
    bias_note = _bias_note(ev, terms)
    if bias_note:
        notes.append(bias_note)
    n = ev.n_lin
    undetermined = undetermined_terms(ev.fit_rfs, terms, bounds.half_width[n:n + len(terms)] /
                                      np.maximum(np.abs(bounds.theta[n:n + len(terms)]), 1e-300)) if terms else ()
    if undetermined and verdict.endswith(NOTHING_MISSING):  # not the same as "nothing is missing": say so
        verdict = (verdict[: -len(NOTHING_MISSING)] + "Nothing these data can separate is missing, but "
                   + "; ".join(x.text() for x in undetermined) + ".")
    fin = _final_model(u, found, verdict, say)
    say(1.0, "done")
    return LoopResult(declared=tuple(make_term(t) for t in declared), terms=tuple(terms), rounds=found.rounds,
                      initial=u.initial, final=current, verdict=fin.verdict, band=u.band, m2_kg=m2_kg, settings=s,
                      sources=tuple(r.source for r in u.recs), fit_seconds=tuple(a.duration_s for a in ev.fit_recs),
                      test_seconds=tuple(b.duration_s for b in ev.test_recs), notes=tuple(notes), model=fin.model,
                      linear_model=fin.linear, model_unavailable=fin.unavailable, detection_limits=limits,
                      confounded=confounded, bounds=bounds, undetermined=undetermined, refinement=fin.refinement,
                      linear_heldout_pct=None if pred.linear is None else pred.linear.score, noise=ev.noise,
                      bias_corrected=ev.corrected(terms) is not None,
                      final_heldout_pct=fin.score, ambiguities=found.ambiguities, declared_terms=fin.fates,
                      beyond=fin.beyond)


def _notes(u: _Setup, retuned: Sequence[str]) -> list[str]:
    """The result's notes on the declared terms re-tuned, the band, the block, the evaluator and the linear form."""
    notes = [f"declared {n} at the end (within the stated factor {RETUNE_FACTOR:g} of the declared value; the "
             f"declared form is kept, the data set its parameter)" for n in retuned]
    notes += ([u.band_note] if u.band_note else []) + ([u.adapted] if u.adapted else []) + u.ev.notes
    if u.pred.choice is not None:
        notes.append(u.pred.choice.reason)
    if u.pred.switched:
        notes.append(u.pred.switched)
    if u.band.f_lo_hz > 1.0:
        notes.append(f"the integration band starts at {u.band.f_lo_hz:g} Hz: motion below it is only partly in z, ż")
    if u.frame.moves:
        notes.append(u.frame.text([r.source for r in u.recs]))
    return notes


def _limits(u: _Setup, found: _Found, verdict: str, say: Callable[[float, str], None]) -> tuple[tuple, tuple, str]:
    """The detection limits of the kinds not modelled and the confounded pairs, when the last round added nothing
    (its ranking is on the final model's residual), and the verdict saying so."""
    last = found.rounds[-1] if found.rounds else None
    if last is None or last.added is not None:
        return (), (), verdict
    say(0.97, "detection limits and confounding")
    terms = list(found.terms)
    seen = {t.kind for t in terms} | {t.candidate.kind for t in last.trials}  # modelled, or seen and refused
    others = [c for c in last.ranked if c.kind not in seen]
    limits = detection_limits(u.ev.fit_rfs, terms, others, m2_kg=u.m2_kg, thresholds=u.s.thresholds,
                              n_grid=u.s.grid_points)
    confounded = confounded_pairs(u.ev.fit_rfs, terms, [c.term for c in last.ranked] + list(terms))
    if confounded and verdict.endswith(NOTHING_MISSING):
        verdict = (verdict[: -len(NOTHING_MISSING)] + "Nothing these data can separate is missing, but "
                   + "; ".join(c.text() for c in confounded) + ".")
    return limits, confounded, verdict
