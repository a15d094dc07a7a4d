"""Closing the loop: residual → the effect the model lacks → add it → error before and after (METHOD.md §5).

Given records and a *declared* model (describing functions, :mod:`nifo_core.describing`),
:func:`close_loop` repeats, for at most ``max_rounds`` rounds:

1. **Residual that can show what is missing.** Each record is split in time:
   the first ``fit_fraction`` fits, the rest is held out. Two residuals:

   - equation error in force-balance form (paper Eq. 2 per unit sprung mass)::

         e = -ẍ2 - k·z - c·ż - Σ_declared θ_i·g_i           θ_i = c_i/M2

     every column band-passed with the one integrator-matched filter
     (:func:`nifo_core.restoring.bandpass`, g *after* the nonlinear map), the
     coefficients fitted on the fit part and the error scored on the held-out part;
   - prediction error on the held-out part: the declared model is identified by
     NIFO (:func:`nifo_core.nifo.identify_nifo`, static fit) on the fit part and
     the body acceleration predicted from the measured spindle acceleration of
     the held-out part (:func:`nifo_core.model.predict_transmissibility`).

   The displacement-form NIFO residual / multiple coherence is *not* used: a
   describing function of z = x2 - x1 carries the output into the regressors,
   and the fit absorbs whatever is missing (METHOD.md §3).

2. **Tracing.** Every kind of the library, over parameter grids scaled to the
   motion, is scored by the fraction of the linear + declared equation error it
   explains (:func:`nifo_core.characterize.rank_beyond`: band-limited after the
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

   A bump stop is measured from the static position (:mod:`nifo_core.characterize_static`): the
   ranking reads its gap from each record's mean position, which the one-sided force pushes away
   from the stop, the more the harder the excitation; before its checks the candidate is re-fitted
   with its gap from the static position and one offset -m_i per record (m_i from the balance of
   the mean force), and the loop's columns and later rankings use those offsets.

5. **Report** before and after each addition: NMSE (%) on held-out data
   (Worden & Tomlinson: 100·Σ(y - ŷ)²/(N·σ_y²); < 5 % good, < 1 % excellent),
   per-band residual 10·log10(G_ee/G_yy) in 2-5, 5-10, 10-20, 20-30 Hz (one
   spectral engine, :mod:`nifo_core.spectral`), the transmissibility
   prediction error at each level, and the added effect with its evidence.

6. **Refine** (``settings.refine``): the final model, an equation-error fit, is refined by output
   error (:func:`nifo_core.refine.refine_model`: every fit part simulated from its measured input,
   its first ``refine_seconds``; the coefficients, gaps/knees and the body's k, c that minimise the
   band-limited prediction error) and scored on the held-out parts like every model of the loop.
   The refined model becomes the loop's model when its held-out prediction NMSE is not worse; the
   report gives both fits' parameters and both NMSEs. A final step: the acceptance of terms
   (step 3) does not use it. Measured (tests/test_loop_refine.py, 2 % noise): a bump stop
   2e5 N/m beyond 8 mm, 1.56e5 at first addition → 1.81e5 refined, gap 8.07 mm from static.

References: Billings (error reduction ratio, forward orthogonal regression);
Bendat & Piersol (conditioned/partial coherence); Worden & Tomlinson (NMSE);
Haroon & Adams (paper Eq. 2, 7-9).
"""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np

from .characterize import rank_beyond
from .describing import Term, make_term
from .detection import confounded_pairs, detection_limits, undetermined_terms
from .errors import ConfigError, InputError, NifoError, RecordTooShortError
from .integrate import IntegrationBand
from .loop_residual import _design, _Evaluator, _evidence, _retune, _static_candidate, _tire_check
from .loop_results import (NOTHING_MISSING, RESIDUAL_BANDS_HZ, Errors, Evidence, LoopRefinement, LoopResult,
                           LoopSettings, Round, Trial, _nothing_text, _round_text, before_after_text,
                           unconfirmed_text)
from .model import IdentifiedModel
from .refine import refine_model
from .record import Record
from .restoring import suggest_band
from .uncertainty import coefficient_bounds

__all__ = ["LoopSettings", "Errors", "Trial", "Evidence", "Round", "LoopRefinement", "LoopResult", "close_loop",
           "RESIDUAL_BANDS_HZ", "NOTHING_MISSING"]


#: a record must span this many periods of the integration band's lower edge: the integrator takes 16
#: (its edges are dropped), and the held-out third must keep ≈ 4 periods once its band-pass has settled
LOOP_PERIODS_PER_RECORD = 48.0


def loop_band(records: Sequence[Record], band: IntegrationBand | None = None) -> tuple[IntegrationBand, str | None]:
    """The integration band for the loop on these records, and what was adapted (None: nothing).

    Default: :func:`~nifo_core.restoring.suggest_band` of the first record. Its lower edge is raised
    where the shortest record spans fewer than ``LOOP_PERIODS_PER_RECORD`` periods of it (30 s → 1.6 Hz,
    60 s → 0.8 Hz): every column of the equation error is band-limited alike, so a higher edge costs
    the loop only the motion below it, while a too-low one leaves no held-out part.
    """
    fs = float(records[0].fs_hz)
    band = (band or suggest_band(records[0]).band).validate(fs)
    shortest = min(r.duration_s for r in records)
    need = LOOP_PERIODS_PER_RECORD / shortest if shortest > 0 else float("inf")
    if band.f_lo_hz >= need:
        return band, None
    new = IntegrationBand(round(float(np.ceil(need * 100) / 100), 2), band.f_hi_hz)
    if new.f_lo_hz >= new.f_hi_hz:
        raise RecordTooShortError(f"a {shortest:.1f} s record is too short for the loop",
                                  hint=f"record at least {LOOP_PERIODS_PER_RECORD / band.f_lo_hz:.0f} s")
    new.validate(fs)
    return new, (f"integration band's lower edge raised {band.f_lo_hz:g} → {new.f_lo_hz:g} Hz: the shortest record "
                 f"({shortest:.0f} s) must span {LOOP_PERIODS_PER_RECORD:g} periods of it to keep a held-out part "
                 f"after the integrator's edges (records of {LOOP_PERIODS_PER_RECORD / band.f_lo_hz:.0f} s keep "
                 f"{band.f_lo_hz:g} Hz)")


def _heldout_failures(current: Errors, after: Errors, s: LoopSettings) -> tuple[list[str], list[str]]:
    """Why a candidate does not improve the model on held-out data: (equation side, prediction side).

    Equation side: it must lower the held-out equation error by ``min_heldout_gain`` (relative) and
    raise no band of it by more than ``max_band_rise_db``. Prediction side: it must lower the held-out
    prediction NMSE whenever the current model has one (a model that cannot be predicted any more
    fails) and raise no band of the prediction error by more than ``max_band_rise_db``. A significance
    test alone trusts a mis-specified model (F-16 level 1: a multi-mode structure read as one mass
    takes a play that lowers the error at 2-15 Hz while the 20-30 Hz residual grows by 22 dB).
    """
    eq, pred = [], []
    e0, e1 = current.equation_nmse_pct, after.equation_nmse_pct
    gain = 1 - e1 / e0 if e0 > 0 else 0.0
    if not gain >= s.min_heldout_gain:
        eq.append(f"held-out equation error {e0:.3g} % → {e1:.3g} % does not fall by {100 * s.min_heldout_gain:g} %")
    eq += _worse_bands("equation error", current.equation_band_residual_db, after.equation_band_residual_db, s)
    p0, p1 = current.prediction_nmse_pct, after.prediction_nmse_pct
    if p0 is not None and p1 is None:
        pred.append(f"the model with it cannot be predicted ({after.prediction_unavailable})")
    elif p0 is not None:
        if not p1 < p0:
            pred.append(f"held-out prediction NMSE does not fall ({p0:.3g} % → {p1:.3g} %)")
        pred += _worse_bands("prediction error", current.band_residual_db, after.band_residual_db, s)
    return eq, pred


def _worse_bands(what: str, b0, b1, s: LoopSettings) -> list[str]:
    worse = [f"{k} Hz {b0[k]:+.1f} → {b1[k]:+.1f} dB" for k in b0
             if k in b1 and np.isfinite(b0[k]) and np.isfinite(b1[k]) and b1[k] > b0[k] + s.max_band_rise_db]
    return [f"the held-out {what} grows by more than {s.max_band_rise_db:g} dB in " + ", ".join(worse)] if worse else []


def close_loop(records: Record | Sequence[Record], declared: Sequence[Term | Mapping | str] = (), *,
               m2_kg: float | None = None, band: IntegrationBand | None = None,
               settings: LoopSettings = LoopSettings(),
               progress: Callable[[float, str], None] | None = None) -> LoopResult:
    """Find what the declared model lacks, add it, refit, repeat; report errors before and after.

    Parameters
    ----------
    records : Record or sequence of Record
        One record, or several at different excitation levels (same vehicle, same rate).
    declared : sequence of Term (or model-file entries)
        The declared strut nonlinearities besides the linear strut (empty: linear).
    m2_kg : float, optional
        Sprung mass [kg]: coefficients also in N, N/m, N·s/m...
    band : IntegrationBand, optional
        Integration band; default :func:`~nifo_core.restoring.suggest_band` of the first record.
    settings : LoopSettings
    progress : callable, optional
        ``progress(fraction, what)`` as the work advances.

    Returns
    -------
    LoopResult
    """
    recs = [records] if isinstance(records, Record) else list(records)
    if not recs:
        raise InputError("no records to run the loop on")
    if m2_kg is not None and not (np.isfinite(m2_kg) and m2_kg > 0):
        raise ConfigError(f"m2_kg={m2_kg!r} must be a positive mass [kg]")
    rates = sorted({r.fs_hz for r in recs})
    if len(rates) > 1:
        raise InputError(f"records have different sample rates {rates} Hz", hint="resample to one rate first")
    terms = [make_term(t) for t in declared]
    s = settings
    band, band_note = loop_band(recs, band)
    say = progress or (lambda f, w: None)
    say(0.0, "restoring force and the declared model")
    ev = _Evaluator(recs, band, s)
    retuned: list[str] = []
    if s.retune and terms:
        terms, retuned = _retune(ev, terms, s)
    current = ev.errors(terms)
    initial = current
    rounds: list[Round] = []
    verdict = ""
    total = s.max_rounds + 1
    for i in range(1, s.max_rounds + 1):
        base = (i - 1) / total
        tuned: list[str] = []
        if s.retune and i > 1:
            say(base, f"round {i}: re-tuning the model's parameters")
            terms, tuned = _retune(ev, terms, s)
            current = ev.errors(terms)
        say(base, f"round {i}: tracing the residual")
        ranked = rank_beyond(ev.fit_rfs, terms, m2_kg=m2_kg, kinds=s.kinds, thresholds=s.thresholds,
                             grid_points=s.grid_points, offsets=[ev.static.get(t.label) for t in terms],
                             progress=lambda f, b=base: say(b + 0.8 * f / total, f"round {i}: tracing"))
        trials: list[Trial] = []
        added = None
        for c in [c for c in ranked if c.present][: s.top_tried]:
            say(base + 0.85 / total, f"round {i}: checking {c.term.label}")
            c = _static_candidate(ev, terms, c, s, m2_kg)  # a bump stop: its gap from the static position
            failed = []
            shift, frac = _tire_check(ev, terms, c.term, s)
            if not shift <= s.max_tire_shift:
                failed.append(f"impact check: the coefficient moves {100 * shift:.0f} % without the samples near "
                              f"the input side's impacts (> {100 * s.max_tire_shift:.0f} %): an artefact of impacts "
                              f"(tire events on a vehicle), not an effect of the nonlinear element")
            after = ev.errors([*terms, c.term])
            gain = 1 - after.equation_nmse_pct / current.equation_nmse_pct if current.equation_nmse_pct > 0 else 0.0
            eq_failed, pred_failed = _heldout_failures(current, after, s)
            failed += eq_failed + pred_failed
            t = Trial(candidate=c, tire_shift=shift, tire_excluded_fraction=frac, heldout_gain=gain, after=after,
                      accepted=not failed, failed=tuple(failed),
                      unconfirmed=bool(pred_failed) and len(failed) == len(pred_failed))
            trials.append(t)
            if t.accepted:
                added = t
                break
        pre = "".join(f"(Re-tuned first: {n}.) " for n in tuned)
        if added is None:
            text = pre + _nothing_text(i, ranked, trials)
            rounds.append(Round(i, tuple(terms), ranked, tuple(trials), current, None, None, text))
            unconfirmed = [t for t in trials if t.unconfirmed]
            if unconfirmed:
                verdict = unconfirmed_text(unconfirmed, current)
            else:
                verdict = NOTHING_MISSING if i > 1 else f"The declared model lacks nothing the library can name. " \
                                                         f"{NOTHING_MISSING}"
            break
        evid = _evidence(ev, terms, added.candidate.term, s)
        text = pre + _round_text(i, added, current, evid, m2_kg, len(recs), ranked)
        rounds.append(Round(i, tuple(terms), ranked, tuple(trials), current, added, evid, text))
        terms = [*terms, added.candidate.term]
        current = added.after
    else:
        verdict = (f"Stopped after the limit of {s.max_rounds} round(s); more may be missing: run again with more "
                   f"rounds.")
    say(0.95, "rounds done")
    n_added = sum(1 for r in rounds if r.added)
    if n_added:
        verdict = (f"Added {n_added} effect(s): " + ", ".join(r.added.candidate.term.label for r in rounds if r.added)
                   + f"; {before_after_text(initial, current)}. "
                   + verdict)
    notes = [f"declared {n} (the declared form is kept; the data set its parameter)" for n in retuned]
    notes += ([band_note] if band_note else []) + ev.notes
    if band.f_lo_hz > 1.0:
        notes.append(f"the integration band starts at {band.f_lo_hz:g} Hz: motion below it is only partly in z, ż")
    limits, confounded = (), ()
    last = rounds[-1] if rounds else None
    if last is not None and last.added is None:  # its ranking is on the final model's residual
        say(0.97, "detection limits and confounding")
        seen = {t.kind for t in terms} | {t.candidate.kind for t in last.trials}  # modelled, or seen and refused
        others = [c for c in last.ranked if c.kind not in seen]
        limits = detection_limits(ev.fit_rfs, terms, others, m2_kg=m2_kg, thresholds=s.thresholds,
                                  n_grid=s.grid_points)
        confounded = confounded_pairs(ev.fit_rfs, terms, [c.term for c in last.ranked] + list(terms))
        if confounded and verdict.endswith(NOTHING_MISSING):
            verdict = (verdict[: -len(NOTHING_MISSING)] + "Nothing these data can separate is missing, but "
                       + "; ".join(c.text() for c in confounded) + ".")
    y_fit, x_fit = _design(ev.fit_parts, terms, ev.static)
    bounds = coefficient_bounds(x_fit, y_fit, recs[0].fs_hz, segments=[p.y.size for p in ev.fit_parts])
    undetermined = undetermined_terms(ev.fit_rfs, terms, bounds.half_width[2:] /
                                      np.maximum(np.abs(bounds.theta[2:]), 1e-300)) if terms else ()
    if undetermined and verdict.endswith(NOTHING_MISSING):  # not the same as "nothing is missing": say so
        verdict = (verdict[: -len(NOTHING_MISSING)] + "Nothing these data can separate is missing, but "
                   + "; ".join(u.text() for u in undetermined) + ".")
    model = linear = unavailable = refinement = None
    try:  # the model whose held-out prediction was scored, fitted on the fit parts: what `nifo predict` takes
        model, linear = ev.model(terms), ev.model([])
    except (NifoError, np.linalg.LinAlgError) as err:
        unavailable = f"no predictive model: {err}"
    if model is not None and terms and s.refine and s.prediction != "none":  # it simulates: not with prediction off
        say(0.98, "output-error refinement")
        refinement, model = _refine_final(ev, model, linear, m2_kg, say, current)
    say(1.0, "done")
    return LoopResult(declared=tuple(make_term(t) for t in declared), terms=tuple(terms), rounds=tuple(rounds),
                      initial=initial, final=current, verdict=verdict, band=band, m2_kg=m2_kg, settings=s,
                      sources=tuple(r.source for r in recs),
                      fit_seconds=tuple(a.duration_s for a in ev.fit_recs),
                      test_seconds=tuple(b.duration_s for b in ev.test_recs), notes=tuple(notes), model=model,
                      linear_model=linear, model_unavailable=unavailable, detection_limits=limits,
                      confounded=confounded, bounds=bounds, undetermined=undetermined, refinement=refinement)


def _refine_final(ev: _Evaluator, model: IdentifiedModel, linear: IdentifiedModel | None, m2_kg: float | None,
                  say: Callable[[float, str], None], final: Errors) -> tuple[LoopRefinement, IdentifiedModel]:
    """Output-error refinement of the loop's final model on the fit parts, scored on the held-out parts.

    :func:`~nifo_core.refine.refine_model` on the first ``refine_seconds`` of every fit part (the
    equation-error fit and, where it does not already beat it, the linear model as starts); both
    models' held-out prediction NMSE on the loop's one metric (the equation-error model's from ``final``,
    the last round's errors of the same terms). Returns the record of it and the model
    the loop keeps: the refined one unless its held-out prediction is worse (or cannot be made).
    """
    s = ev.settings
    recs = [r.slice(0, min(r.n, int(round(s.refine_seconds * r.fs_hz)))) for r in ev.fit_recs]
    secs = tuple(float(r.duration_s) for r in recs)
    try:
        ref = refine_model(model, recs, linear=linear, band_hz=s.analysis_band_hz,
                           progress=lambda start, n, cost: say(0.98, f"output-error refinement from the {start} "
                                                                     f"start ({n} simulations)"))
    except NifoError as err:
        return LoopRefinement(False, None, None, seconds=secs, unavailable=str(err)), model
    # the equation-error model's held-out prediction is the final round's (``final``, same model): not re-run
    b, bper = final.prediction_nmse_pct, tuple(final.prediction_nmse_per_record_pct)
    a, aper = _heldout(ev, ref.model)
    kept = a is not None and (b is None or a <= b)
    out = LoopRefinement(kept, b, a, bper, aper, tuple(_compare(model, ref.model, m2_kg, ref.parameters)), secs,
                         ref.to_dict())
    return out, (ref.model if kept else model)


def _heldout(ev: _Evaluator, model: IdentifiedModel) -> tuple[float | None, tuple[float, ...]]:
    try:
        nmse, per, _, _ = ev.predict_model(model)
    except (NifoError, np.linalg.LinAlgError):
        return None, ()
    return float(nmse), tuple(float(v) for v in per)


def _compare(before: IdentifiedModel, after: IdentifiedModel, m2: float | None,
             refined: Sequence[Mapping] = ()) -> list[dict]:
    """Every refined parameter: the equation-error value and the refined one (× M2 where it scales).

    ``refined``: :attr:`~nifo_core.refine.Refinement.parameters`, whose 95 % half-widths (where given)
    are carried as ``refined_half_width_95`` (and × M2).
    """
    widths = [p.get("half_width_95") for p in refined]
    n_terms = len(before.terms)
    coef_w = widths[:n_terms] + [None] * (n_terms - len(widths[:n_terms]))
    named = {p["name"]: p.get("half_width_95") for p in refined[n_terms:]}

    def width(prefix):
        return next((w for n, w in named.items() if n.startswith(prefix)), None)

    def entry(name, unit, v0, v1, unit_m2=None, hw=None):
        d = {"name": name, "unit": unit, "equation_error": float(v0), "refined": float(v1),
             "refined_half_width_95": None if hw is None else float(hw)}
        if m2 is not None and unit_m2 is not None:
            d.update(equation_error_times_m2=float(v0) * m2, refined_times_m2=float(v1) * m2, unit_times_m2=unit_m2,
                     refined_half_width_95_times_m2=None if hw is None else float(hw) * m2)
        return d

    out = []
    for i, (t0, t1, g0, g1) in enumerate(zip(before.terms, after.terms, before.c_over_m2, after.c_over_m2)):
        out.append(entry(f"{t0.kind} coefficient", f"{t0.spec.coef_unit}/kg", g0, g1, t0.spec.coef_unit, coef_w[i]))
        key = t0.spec.key_param
        if key is not None and isinstance(t0.params.get(key), float):
            out.append(entry(f"{t0.kind}.{key}", t0.spec.params[key][1], t0.params[key], t1.params[key],
                             hw=named.get(f"{t0.kind}.{key}")))
    if before.body is not None and after.body is not None:
        out.append(entry("k = K2/M2", "1/s²", before.body.k, after.body.k, "N/m", width("k = K2/M2")))
        out.append(entry("c = C2/M2", "1/s", before.body.c, after.body.c, "N·s/m", width("c = C2/M2")))
    return out
