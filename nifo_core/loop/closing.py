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

References: Billings (error reduction ratio, forward orthogonal regression);
Bendat & Piersol (conditioned/partial coherence); Worden & Tomlinson (NMSE);
Haroon & Adams (paper Eq. 2, 7-9).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from functools import partial
from typing import Callable, Mapping, Sequence

import numpy as np

from ..characterize.automatic import rank_beyond
from ..characterize.subsets import best_subsets, subset_rss
from ..kinds.describing import Term, kind as lookup_kind, linear_twin, make_term
from .detection import confounded_pairs, detection_limits, undetermined_terms
from ..errors import ConfigError, InputError, NifoError, RecordTooShortError
from ..signal.integrate import IntegrationBand
from ..signal.parallel import thread_map
from ..characterize.result import Candidate
from ..characterize.score import score_candidate
from ..predict.feedback_paths import PATH_KINDS
from ..predict.heldout import HeldOut, split_records
from ..predict.model import IdentifiedModel
from ..predict.scope_fit import fit_scope
from .residual import _Evaluator, _evidence, _g, _retune, _static_candidate, _tire_check
from .stops import retune_stops
from .rivals import rivals_of
from ..predict.model_fit import RATIONAL_MARGIN, Fitted, LinearChoice, choose_linear_form, fit_model
from ..settings import AnalysisSettings
from .results import DeclaredTerm, LoopRefinement, LoopResult
from .round_results import Errors, Round, Trial
from .settings import RETUNE_FACTOR, LoopSettings
from .words import NOTHING_MISSING, _nothing_text, _round_text, before_after_text, unconfirmed_text
from .ambiguity import Ambiguity, Comparison, Explanation, compare_errors, separating_record
from .gates import (Alternative, heldout_failures, judge_alternatives, one_of_kind_alternatives, prediction_failures,
                    unseen_failures, whole_signal_failures)
from .prune import drop_undetermined
from .refine import refine_final
from .beyond import search_beyond
from .frame import Frame
from ..signal.record import Record
from ..characterize.restoring import suggest_band

__all__ = ["close_loop"]


#: a record must span this many periods of the integration band's lower edge: the integrator takes 16
#: (its edges are dropped), and the held-out third must keep ≈ 4 periods once its band-pass has settled
LOOP_PERIODS_PER_RECORD = 48.0


def loop_band(records: Sequence[Record], band: IntegrationBand | None = None) -> tuple[IntegrationBand, str | None]:
    """The integration band for the loop on these records, and what was adapted (None: nothing).

    Default: :func:`~nifo_core.characterize.restoring.suggest_band` of the records together. Its lower edge is raised
    where the shortest record spans fewer than ``LOOP_PERIODS_PER_RECORD`` periods of it (30 s → 1.6 Hz,
    60 s → 0.8 Hz): every column of the equation error is band-limited alike, so a higher edge costs
    the loop only the motion below it, while a too-low one leaves no held-out part.
    """
    fs = float(records[0].fs_hz)
    band = (band or suggest_band(records).band).validate(fs)
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


class _Predictor:
    """The model class ``nifo identify`` writes, fitted on the fit parts for any term set and scored held out.

    The linear part's form (one-mass body or rational) is chosen once, by which linear model predicts the
    held-out parts better (:func:`~nifo_core.predict.model_fit.choose_linear_form`). On a one-mass body every term set
    is the force-balance equation-error fit itself (k, c, the terms' coefficients and a measured force's 1/M2:
    the loop's own estimator of that structure; NIFO's where that body is not physical); on a rational part
    :func:`~nifo_core.predict.model_fit.fit_model` (feedback paths). Each term set is fitted once.
    """

    def __init__(self, held: HeldOut, data: AnalysisSettings, settings: LoopSettings, ev: _Evaluator) -> None:
        self.held, self.data, self.settings, self.ev = held, data, settings, ev
        self.off = settings.prediction == "none"
        self._cache: dict = {}
        # fit_model's fits on the chosen linear part, by the terms' labels: the same whatever form is in use, so kept
        # across a switch to the body and shared with the body twin (where its equation-error fit is not physical)
        self._models: dict = {}
        self.choice = None
        self._form: str | None = None      # the form in use when it changed after the linear choice
        self.switched = ""
        if not self.off:
            try:
                self.choice = choose_linear_form(held, data)
            except NifoError as err:   # NIFO cannot run on these fit parts: the equation error's own body, if any
                lin = self._equation([])
                if lin is None:
                    raise
                self.choice = LinearChoice("body", lin, {"nifo": {"error": err.message}},
                                           f"one-mass body from the force-balance equation error ({err.message})")
        if self.choice is not None and self.choice.form == "body":
            lin = self._equation([])
            if lin is not None:
                self.choice = replace(self.choice, linear=lin)

    @property
    def linear(self) -> Fitted | None:
        return None if self.choice is None else self.choice.linear

    def body_twin(self) -> "_Predictor":
        """The same predictor on the one-mass body (its own cache, the rational part's fits shared): to judge a term
        on the body while the rational form is in use."""
        twin = copy.copy(self)
        twin._form, twin._cache = "body", {}
        return twin

    def forget(self) -> None:
        """The fits kept dropped (kept by the terms' labels: a term's column changed with its frame)."""
        self._cache = {}
        self._models.clear()

    def switch_to_body(self, why: str) -> None:
        self._form, self._cache, self.switched = "body", {}, why

    @property
    def flexible(self) -> bool:
        """A rational linear part: a multi-mode structure, the terms' forces through their own paths."""
        return self.choice is not None and self.form == "rational"

    @property
    def form(self) -> str:
        return self._form or self.choice.form

    def _body_instead(self, terms: Sequence[Term]) -> tuple[Fitted, Fitted] | None:
        """(body, rational) fits of ``terms`` when the one-mass body would be taken back with them (the rule of
        :meth:`reconsider`), else None."""
        if self.off or not self.flexible or not terms:
            return None
        body, flex = self._equation(terms), self.fit(terms)
        if body is None or body.score is None or flex.score is None or flex.score <= RATIONAL_MARGIN * body.score:
            return None
        return body, flex

    def onward_score(self, terms: Sequence[Term]) -> tuple[float, str]:
        """The held-out prediction NMSE [%] of ``terms`` in the form the loop goes on with once they are in, and that
        form's name: the one-mass body's when :meth:`reconsider` would take it back with them, else this form's.

        Candidates of a round on the rational part are compared on it: the one the loop keeps is then predicted
        in that form. Measured (fleet case 64, a hidden friction 27.9 N, ż/√(ż² + v_s²), beside a declared cubic,
        the rational part chosen on the linear model): on the rational part a damper knee at 3.3 mm/s predicted
        the held-out parts at 0.98 % against 2.23 % for the friction and was added; on the one-mass body, taken
        back with either, the knee predicts them at 0.050 % and the friction at 0.013 %."""
        back = self._body_instead(terms)
        return (back[0].score, "one-mass body") if back is not None else (self.fit(terms).score, "rational part")

    def reconsider(self, terms: Sequence[Term]) -> bool:
        """Once terms are in, the one-mass body again (True when the form changes): a linear model of a strongly
        nonlinear quarter car predicts poorly in either form, and the black box's extra poles stand in for what the
        terms now model — the choice made on the linear model alone is biased towards it. The body is taken when
        its equation-error fit with the terms is physical and the rational model does not predict the held-out
        parts clearly better (:data:`~nifo_core.predict.model_fit.RATIONAL_MARGIN`), as for the linear choice."""
        back = self._body_instead(terms)
        if back is None:
            return False
        body, flex = back
        self._form, self._cache = "body", {}
        self.switched = (f"one-mass body from round {len(terms)} on: with {', '.join(t.label for t in terms)} its "
                         f"equation-error fit is physical and predicts the held-out parts at {body.score:.4g} % "
                         f"against {flex.score:.4g} % for the rational model (the rational form was chosen on the "
                         f"linear model alone)")
        return True

    def _equation(self, terms: Sequence[Term]) -> Fitted | None:
        model = self.ev.equation_model(terms, self.data.spectral, self.data.analysis_band_hz)
        if model is None:
            return None
        return Fitted(model, "constant" if terms else "linear", self.held.score(model),
                      "one-mass body and constant coefficients: the force-balance equation-error fit")

    def fit(self, terms: Sequence[Term]) -> Fitted:
        key = tuple(t.label for t in terms)
        if key not in self._cache:
            got = self._equation(terms) if self.form == "body" else None
            if got is None and key not in self._models:
                self._models[key] = fit_model(self.held, terms, self.data, linear=self.linear,
                                              structure=self.settings.structure)
            self._cache[key] = got or self._models[key]
        return self._cache[key]


def _errors(ev: _Evaluator, pred: _Predictor, terms: Sequence[Term]) -> Errors:
    """Both residuals of ``terms``: the equation error (:class:`_Evaluator`) and the held-out prediction of the
    model class ``nifo identify`` writes (:class:`_Predictor`), each labelled."""
    eq = ev.equation(terms)
    notes: list[str] = []
    pred_nmse, per, trans, bands, unavailable, fitted = None, (), (), None, None, None
    whole = (None, (), "")
    if pred.off:
        unavailable = "prediction switched off (prediction='none')"
    else:
        try:
            fitted = pred.fit(terms)
        except (NifoError, np.linalg.LinAlgError) as err:
            unavailable = str(err)
        else:
            if fitted.scores.unavailable is not None:
                unavailable = fitted.scores.unavailable
            else:
                pred_nmse, per = fitted.score, fitted.scores.per_record
                whole = (fitted.scores.whole_mean, fitted.scores.whole, fitted.scores.whole_policy)
                bands, trans = ev.band_numbers(fitted.scores.predictions)
        if unavailable is not None:
            notes.append(f"no held-out prediction for this model ({unavailable}); equation error only")
    return Errors(terms=tuple(terms), theta_per_kg=eq["theta_per_kg"], k_per_kg=eq["k_per_kg"],
                  c_per_kg=eq["c_per_kg"], equation_nmse_pct=eq["equation_nmse_pct"],
                  equation_nmse_fit_pct=eq["equation_nmse_fit_pct"], prediction_nmse_pct=pred_nmse,
                  prediction_nmse_per_record_pct=tuple(per),
                  band_residual_db=bands if bands else eq["equation_band_residual_db"],
                  residual_of="prediction" if bands else "equation",
                  equation_band_residual_db=eq["equation_band_residual_db"],
                  transmissibility_error_pct=tuple(trans), prediction_unavailable=unavailable, notes=tuple(notes),
                  structure="" if fitted is None else fitted.structure,
                  model_note="" if fitted is None else fitted.note, fitted=fitted, whole_nmse_pct=whole[0],
                  whole_nmse_per_record_pct=tuple(whole[1]), whole_policy=whole[2])


#: a term whose describing function the linear columns z, ż explain to this R² on the fit parts acts linearly there
#: (a play wider than the motion is stuck: its force a constant; a slipping play of 0.4 mm in 5 mm of motion: 0.998)
LINEAR_R2 = 0.9999


def acts_linearly(ev: _Evaluator, term: Term) -> float:
    """R² of the term's band-passed describing function on the fit parts regressed on z and ż (1: it never leaves
    one regime — a play wider than the motion, a clearance never reached — and only adds a linear term)."""
    g = np.concatenate([_g(p, term, ev.static) for p in ev.fit_parts])
    x = np.column_stack([np.concatenate([p.z for p in ev.fit_parts]), np.concatenate([p.zdot for p in ev.fit_parts])])
    tss = float(g @ g)
    if not tss > 0:
        return 1.0
    r = g - x @ np.linalg.lstsq(x, g, rcond=None)[0]
    return float(1 - (r @ r) / tss)


def _path_grid(ev: _Evaluator, kinds: Sequence[str], points: int) -> list[Term]:
    """Terms of the kinds that can act through feedback paths over widths spanning the relative motion.

    Geometric from twice the smallest record's RMS of z (narrower: the term acts on noise) to twice the
    largest record's 99th percentile of |z| (wider: it never leaves its small-amplitude regime); a play's
    width is its total deadband, a clearance's and a saturation's their half-width.
    """
    rms = [float(np.std(p.z)) for p in ev.fit_parts]
    peak = [float(np.quantile(np.abs(p.z), 0.99)) for p in ev.fit_parts]
    lo, hi = min(rms), 2 * max(peak)
    out = []
    for kind in kinds:
        if kind not in PATH_KINDS or not hi > lo > 0:
            continue
        k = lookup_kind(kind)
        scale = k.path_width
        out += [Term(kind, {k.key_param: float(w)}) for w in np.geomspace(scale * lo, scale * hi, points)]
    return out


def _grid_candidates(ev: _Evaluator, pred: _Predictor, terms: Sequence[Term], s: LoopSettings,
                     m2_kg: float | None) -> list:
    """Plays over a grid of widths for a flexible body (a discrete Iwan model: patches of a joint that slip one
    after another), with their equation-error statistics. Clearances and saturations come from the ranking."""
    grid = _path_grid(ev, [k for k in s.kinds if _iwan(k)], int(s.path_widths))
    if not grid or pred.linear is None:
        return []
    chosen = [t for t in grid if all(t.label != u.label for u in terms)]
    data = ev.regression()
    base = [data.regressor(t, offsets=ev.static.get(t.label)) for t in terms]
    return [score_candidate(data, base, t, thresholds=s.thresholds, n_grid=int(s.path_widths), m2=m2_kg,
                            names=tuple(t.label for t in terms)) for t in chosen]


def _reach(ev: _Evaluator) -> float:
    """The peak |z| of the fitted records [m]."""
    return max(float(np.max(np.abs(p.z))) for p in ev.fit_parts)


def _iwan(kind: str) -> bool:
    """A kind tried over a grid of widths on a flexible body: a hysteretic one a feedback path carries (a play)."""
    k = lookup_kind(kind)
    return k.hysteretic and k.path_slopes is not None


def _round_candidates(ev, pred, terms, ranked, s, m2_kg) -> list:
    """What a round tries: on a one-mass body the significant ranked candidates in rank order; on a flexible body
    (rational linear part, where the one-mass equation error is mis-specified and only the held-out prediction
    judges) plays over a grid of widths and the best ranked candidates of the other kinds."""
    if not pred.flexible:
        return [c for c in ranked if c.present][: s.top_tried]
    others = [c for c in ranked if not _iwan(c.kind)][: s.top_tried]
    seen = {c.term.label for c in others}
    return [c for c in _grid_candidates(ev, pred, terms, s, m2_kg) if c.term.label not in seen] + others


def _data_settings(recs: Sequence[Record], band: IntegrationBand | None, s: LoopSettings) -> AnalysisSettings:
    """Without explicit data settings: the loop's spectral settings and analysis band, its integration band."""
    return AnalysisSettings(spectral=s.spectral, band=band, analysis_band_hz=s.analysis_band_hz)


# Long (over 100 lines): each round's fit, residual, ranking, acceptance tests and refit share the round's
# state. Left whole here while the noise branch (issue 28) edits its body; to split after the merge.
@dataclass(frozen=True)
class _Setup:
    """What every round of :func:`close_loop` works on: the records (as measured and centred), the declared model
    fitted as declared, the settings, the held-out split, the evaluator and the linear part's predictor."""

    raw: tuple[Record, ...]
    recs: tuple[Record, ...]
    declared_terms: tuple[Term, ...]
    decl_theta: Sequence[float]
    m2_kg: float | None
    s: LoopSettings
    band: IntegrationBand
    band_note: str | None
    adapted: str | None
    held: HeldOut
    ev: _Evaluator
    pred: _Predictor
    floor: object
    initial: Errors
    frame: Frame
    # re-tuning by the one-mass equation error: on the body the loop is on *now* (taken back once a term is in)
    retune_ok = property(lambda self: self.s.retune and not self.pred.flexible)

    @property
    def n_decl(self) -> int:
        return len(self.declared_terms)

    def keeps(self, errs: Errors) -> tuple[bool, str]:
        """Whether the model of ``errs`` keeps the declared physics (every declared term within the stated factor of
        its declared parameter, its coefficient with the sign of the declared fit), and how it changes it."""
        fates = [DeclaredTerm(d, float(t0), t, float(t1), self.m2_kg)
                 for d, t0, t, t1 in zip(self.declared_terms, self.decl_theta, errs.terms, errs.theta_per_kg)]
        changed = [f for f in fates if f.changed_meaning]
        return not changed, " ".join(f.text() for f in changed)

    def explanation(self, what: str, errs: Errors) -> Explanation:
        return Explanation(what, tuple(errs.terms), tuple(errs.theta_per_kg), errs.prediction_nmse_pct, self.m2_kg)


@dataclass(frozen=True)
class _Found:
    """The model the rounds arrived at: its terms and errors, the rounds, what the data could not tell apart, the
    verdict so far and the candidates' grid (None: no round traced the residual)."""

    terms: tuple[Term, ...]
    current: Errors
    rounds: tuple[Round, ...]
    ambiguities: tuple[Ambiguity, ...]
    verdict: str
    search: object = None


@dataclass(frozen=True)
class _Tried:
    """A round's trials, the one added (None: none) and the model's errors they were judged against."""

    trials: tuple[Trial, ...]
    added: Trial | None
    current: Errors
    ambiguity: Ambiguity | None = None
    why: str = ""          # why ``added`` was taken over another that passed, when the round's text must say so


@dataclass(frozen=True)
class _Final:
    """The predictive model at the end (None with the reason), its refinement, the declared terms' fates and the
    held-out score the result reports."""

    model: IdentifiedModel | None
    linear: IdentifiedModel | None
    unavailable: str | None
    refinement: LoopRefinement | None
    fates: tuple[DeclaredTerm, ...]
    verdict: str
    score: float | None
    beyond: tuple = ()    # BeyondTrial (nifo_core.loop.beyond): the kinds tried by output error


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


def _set_up(records: Record | Sequence[Record], declared: Sequence[Term | Mapping | str], m2_kg: float | None,
            band: IntegrationBand | None, settings: LoopSettings, data: AnalysisSettings | None,
            say: Callable[[float, str], None]) -> _Setup:
    """The records checked and centred, the band, the held-out split, the evaluator and the predictor, the declared
    model fitted as declared (:func:`close_loop`'s arguments)."""
    raw = [records] if isinstance(records, Record) else list(records)
    if not raw:
        raise InputError("no records to run the loop on")
    # every analysis on the records without their accelerations' constant offsets (removed in float64: offsets of
    # any size give the same loop); the model's static part is fitted on the records as measured (fit_scope)
    recs = [r.centred() for r in raw]
    if m2_kg is not None and not (np.isfinite(m2_kg) and m2_kg > 0):
        raise ConfigError(f"m2_kg={m2_kg!r} must be a positive mass [kg]")
    rates = sorted({r.fs_hz for r in recs})
    if len(rates) > 1:
        raise InputError(f"records have different sample rates {rates} Hz", hint="resample to one rate first")
    terms = [make_term(t) for t in declared]
    s = settings
    data = data or _data_settings(recs, band, s)
    fs = float(recs[0].fs_hz)
    skip = data.skip_samples(fs)
    band, band_note = loop_band([r.slice(min(skip, r.n - 1), r.n) for r in recs], band or data.band)
    data = replace(data, band=band)
    if data.period_samples is None:
        s = replace(s, spectral=data.spectral, analysis_band_hz=data.analysis_band_hz)
    held = split_records(recs, skip_samples=skip, period_samples=data.period_samples, fit_fraction=s.fit_fraction,
                         band_hz=data.analysis_band_hz)
    adapted = None
    if data.period_samples is None:     # NIFO on the fit parts: blocks short enough for their length
        shortest = min(k - sk for k, sk in zip(held.split, held.skip))
        block = data.spectral.block
        while block > 256 and 2 * block > shortest:
            block //= 2
        if block != data.spectral.block:
            adapted = (f"spectral block {data.spectral.block} → {block} samples for the models fitted on the fit "
                       f"parts and the per-band residual: the shortest fit part is {shortest / fs:.1f} s")
            data = replace(data, spectral=replace(data.spectral, block=block))
    say(0.0, "restoring force and the declared model")
    ev = _Evaluator(held, band, s, spectral=data.spectral if data.period_samples is None else None)
    say(0.02, "the linear part: one-mass body or rational, by held-out prediction")
    pred = _Predictor(held, data, s, ev)
    floor = held.noise_floor()
    declared_terms = tuple(terms)
    frame = Frame()     # every form of z from the static position the declared model implies, when it is material
    frame.place(ev, declared_terms)
    # the declared model fitted as declared: the signs its terms mean (a falling knee, a hardening spring...). The
    # declared parameters are not re-tuned before the rounds: with effects still missing the re-tune takes them up
    # (measured, a hidden quadratic damping beside the paper's knee: the knee walked from 0.03 to 0.055 m/s)
    decl_theta = ev.equation(declared_terms)["theta_per_kg"] if terms else ()
    return _Setup(raw=tuple(raw), recs=tuple(recs), declared_terms=declared_terms, decl_theta=decl_theta, m2_kg=m2_kg,
                  s=s, band=band, band_note=band_note, adapted=adapted, held=held, ev=ev, pred=pred, floor=floor,
                  initial=_errors(ev, pred, terms), frame=frame)


def _run_rounds(u: _Setup, say: Callable[[float, str], None]) -> _Found:
    """Round after round, the best candidate that passes every gate added, until none does or the rounds run out."""
    terms, current = list(u.declared_terms), u.initial
    rounds: list[Round] = []
    ambiguities: tuple[Ambiguity, ...] = ()
    search = None
    for i in range(1, u.s.max_rounds + 1):
        step = _round(u, i, terms, current, search, ambiguities, say)
        rounds += step.rounds
        terms, current, ambiguities, search = list(step.terms), step.current, step.ambiguities, step.search
        if step.verdict:
            verdict = step.verdict
            break
    else:
        verdict = (f"Stopped after the limit of {u.s.max_rounds} round(s); more may be missing: run again with more "
                   f"rounds.")
    return _Found(tuple(terms), current, tuple(rounds), ambiguities, verdict, search)


def _round(u: _Setup, i: int, terms: list[Term], current: Errors, search, ambiguities: tuple[Ambiguity, ...],
           say: Callable[[float, str], None]) -> _Found:
    """Round ``i``: re-tune what the loop added, trace and rank the residual, judge the candidates, add the best
    that passes. Its ``verdict`` is set when the loop stops here."""
    s, ev, pred = u.s, u.ev, u.pred
    total = s.max_rounds + 1
    base = (i - 1) / total
    tuned: list[str] = []
    if u.retune_ok and i > 1 and len(terms) > u.n_decl:   # the terms the loop added (a declared one: at the end)
        say(base, f"round {i}: re-tuning the model's parameters")
        terms, tuned = _retune(ev, terms, s, which=range(u.n_decl, len(terms)))   # not a term with offsets: those
        terms, in_frame = u.frame.retune(ev, terms, which=range(u.n_decl, len(terms)))   # in the frame (frame.py)
        placed = _placed(u, terms)    # then a stop's static gap given the model in its frame (stops.py; a new label)
        terms, moved = retune_stops(ev.regression(), ev.static, terms, which=range(u.n_decl, len(terms)))
        tuned += in_frame + moved
        if _placed(u, terms) or placed or tuned:
            current = _errors(ev, pred, terms)
    say(base, f"round {i}: tracing the residual")
    # the candidates' grid on the fit parts: the data's in the model's frame, built again only when that moved
    search = u.frame.search(ev, s.kinds, s.grid_points, search,
                            lambda f, b=base: say(b + 0.5 * f / total, f"round {i}: tracing"))
    ranked = rank_beyond(ev.fit_rfs, terms, m2_kg=u.m2_kg, kinds=s.kinds, thresholds=s.thresholds,
                         grid_points=s.grid_points, offsets=[ev.static.get(t.label) for t in terms], search=search)
    cands = _round_candidates(ev, pred, terms, ranked, s, u.m2_kg)
    twin = None
    if pred.flexible and cands and all(t.kind in PATH_KINDS for t in terms):
        say(base + 0.5 / total, f"round {i}: the linear twin (one more linear path)")
        twin = _errors(ev, pred, [*terms, linear_twin(_reach(ev))])
    tried = _try_candidates(u, i, terms, ranked, cands, current, partial(_judge, u, terms, ranked, twin), say)
    trials, added, current = list(tried.trials), tried.added, tried.current
    ambiguities += () if tried.ambiguity is None else (tried.ambiguity,)
    pre = "".join(f"(Re-tuned first: {n}.) " for n in tuned)
    if added is None:
        return replace(_nothing_added(u, i, terms, current, ranked, trials, ambiguities, pre), search=search)
    if added.ties:   # a declared term changed in meaning would do as well: the declared physics kept, both named
        ambiguities += (Ambiguity(
            i, (u.explanation(f"{added.candidate.term.label} added", added.after),
                *[u.explanation(f"{terms[a.index].label} re-placed by {a.term.label} ({a.changes})", a.errors)
                  for a in added.ties]),
            tuple(a.comparison for a in added.ties), "it keeps the declared physics",
            separating_record(ev.fit_rfs, added.candidate.term, added.ties[0].term)),)
    added = _with_joint_coefficient(ev, terms, added, u.m2_kg)
    evid = _evidence(ev, terms, added.candidate.term, s)
    text = pre + _round_text(i, added, current, evid, u.m2_kg, len(u.recs), ranked) + tried.why
    text += "".join(f" Ambiguity: {a.text()}." for a in ambiguities if a.round == i)
    done = Round(i, tuple(terms), ranked, tuple(trials), current, added, evid, text)
    terms = [*terms, added.candidate.term]
    current = added.after
    placed = _placed(u, terms)      # the frame the model with the new term implies
    if pred.reconsider(terms) or placed:
        current = _errors(ev, pred, terms)
    return _Found(tuple(terms), current, (done,), ambiguities, "", search)


def _placed(u: _Setup, terms: Sequence[Term]) -> bool:
    """The frame ``terms`` imply placed (:class:`~nifo_core.loop.frame.Frame`); True when a column changed, the
    predictor's fits forgotten then."""
    if not u.frame.place(u.ev, terms):
        return False
    u.pred.forget()
    return True


def _try_candidates(u: _Setup, i: int, terms: Sequence[Term], ranked: Sequence[Candidate],
                    cands: Sequence[Candidate], current: Errors, judge_in: Callable[..., Trial],
                    say: Callable[[float, str], None]) -> _Tried:
    """A round's candidates judged: on a flexible body side by side (the best that passes), on a one-mass body in
    rank order (the first that passes, with a rival that does as well named); on a flexible body that accepts
    nothing, the round again on the one-mass body."""
    s, pred = u.s, u.pred
    total = s.max_rounds + 1
    base = (i - 1) / total
    judge = partial(judge_in, pred, current)
    trials: list[Trial] = []
    added = amb = None
    why = ""
    if pred.flexible:      # every candidate judged on the one metric, side by side: the best that passes
        say(base + 0.5 / total, f"round {i}: checking {len(cands)} candidates side by side")
        trials = thread_map(judge, cands)
        added, why = _best_onward(pred, terms, [t for t in trials if t.accepted])
    else:                  # in rank order, the first that passes
        for j, c in enumerate(cands):
            say(base + (0.5 + 0.45 * j / max(len(cands), 1)) / total, f"round {i}: checking {c.term.label}")
            trials.append(judge(c))
            if trials[-1].accepted:
                added = trials[-1]
                break
        if added is not None:   # another kind that explains as much and predicts as well: named beside it
            got = rivals_of(i, u.held, u.ev.fit_rfs, added, cands[len(trials):], judge, trials, u.explanation,
                            s.min_prediction_gain)
            added, amb, why = got.kept, got.ambiguity, got.words
    if added is None and pred.flexible:   # the one-mass body again, with a term in (:meth:`_Predictor.reconsider`)
        got = _body_round(u.ev, pred, terms, ranked, s, u.m2_kg, judge_in, say, base + 0.9 / total, i)
        if got is not None:
            body_trials, added, current = got
            trials += body_trials
    return _Tried(tuple(trials), added, current, amb, why)


def _best_onward(pred: _Predictor, terms: Sequence[Term], ok: Sequence[Trial]) -> tuple[Trial | None, str]:
    """Of the trials that passed on the rational part, the one predicting best in the form the loop goes on with
    once it is in (:meth:`_Predictor.onward_score`), and the round's words when that is not the best on the rational
    part itself."""
    if not ok:
        return None, ""
    onward = [pred.onward_score([*terms, t.candidate.term]) for t in ok]
    j = min(range(len(ok)), key=lambda k: onward[k])
    here = min(range(len(ok)), key=lambda k: ok[k].after.prediction_nmse_pct)
    if j == here:
        return ok[j], ""
    a, b = ok[j], ok[here]
    return a, (f" Taken instead of {b.candidate.term.label}, which predicts the held-out parts better on the rational "
               f"part ({b.after.prediction_nmse_pct:.3g} % against {a.after.prediction_nmse_pct:.3g} %): once in, "
               f"the loop goes on with the {onward[j][1]}, where {a.candidate.term.label} predicts them at "
               f"{onward[j][0]:.3g} %, and {b.candidate.term.label} with the {onward[here][1]} at "
               f"{onward[here][0]:.3g} %.")


def _judge(u: _Setup, terms: Sequence[Term], ranked: Sequence[Candidate], twin: Errors | None, pred: _Predictor,
           current: Errors, c: Candidate) -> Trial:
    """The acceptance of a candidate with ``pred``'s linear form, against the model ``current`` (every gate)."""
    ev, s, held = u.ev, u.s, u.held
    c = _static_candidate(ev, terms, c, s, u.m2_kg)  # a bump stop: its gap from the static position
    u.frame.candidate(ev, c.term)                     # a form of z: from the static position of the model's frame
    failed = []
    r2 = acts_linearly(ev, c.term)
    if r2 >= LINEAR_R2:
        failed.append(f"it acts linearly on these data (z and ż explain {100 * r2:.2f} % of it: it never "
                      f"leaves one regime)")
    shift, frac = _tire_check(ev, terms, c.term, s)
    if not shift <= s.max_tire_shift and not pred.flexible:   # impacts: a vehicle's tire, a one-mass body
        failed.append(f"impact check: the coefficient moves {100 * shift:.0f} % without the samples near "
                      f"the input side's impacts (> {100 * s.max_tire_shift:.0f} %): an artefact of impacts "
                      f"(tire events on a vehicle), not an effect of the nonlinear element")
    after = _errors(ev, pred, [*terms, c.term])
    gain = 1 - after.equation_nmse_pct / current.equation_nmse_pct if current.equation_nmse_pct > 0 else 0.0
    if pred.flexible:
        eq_failed = unseen_failures(c.p_value, c.err, s)
        pred_failed = prediction_failures(current, after, s, twin, u.floor)
    else:
        eq_failed, pred_failed = heldout_failures(current, after, s, compare_errors(held, after, current))
    failed += eq_failed + pred_failed + whole_signal_failures(current, after, s)
    ties = instead = ()
    passed = not failed
    # failing the prediction alone makes a candidate "unconfirmed" (maybe missing), unless a term of a kind
    # already present, re-placed, does as well: then it only stands in for that one (measured: a declared
    # friction at eps 0.005 m/s, the truth, and a second friction at 0.01 m/s "unconfirmed")
    only_pred = bool(pred_failed) and len(failed) == len(pred_failed) and not pred.flexible
    more: list[str] = []
    if (passed or only_pred) and not pred.flexible:  # one term of a kind already present must not do as well
        alts = []
        for k, a in one_of_kind_alternatives(terms, c.term, [r.term for r in ranked], ev.static):
            u.frame.candidate(ev, a)
            e = _errors(ev, pred, [*terms[:k], a, *terms[k + 1:]])
            alts.append(Alternative(k, a, e, compare_errors(held, after, e), *u.keeps(e),
                                    against_model=compare_errors(held, e, current)))
        judged = judge_alternatives(terms, c.term, alts, s, candidate_keeps=u.keeps(after)[0])
        more, ties, instead = list(judged.failed), list(judged.ties), list(judged.instead)
        failed += more
    return Trial(candidate=c, tire_shift=shift, tire_excluded_fraction=frac, heldout_gain=gain, after=after,
                 accepted=not failed, failed=tuple(failed), unconfirmed=only_pred and not more,
                 ties=tuple(ties), instead=tuple(instead), gates_passed=passed)


def _nothing_added(u: _Setup, i: int, terms: list[Term], current: Errors, ranked: Sequence[Candidate],
                   trials: Sequence[Trial], ambiguities: tuple[Ambiguity, ...], pre: str) -> _Found:
    """A round that adds nothing: a term re-placed instead when one does as well or better (the loop goes on when it
    does better and re-tuning is on), else the verdict."""
    s = u.s
    text = pre + _nothing_text(i, ranked, trials)
    retune = _retune_instead(trials, current)
    if retune is not None:      # a term re-placed does as well as (or better than) a term added
        t, a, is_better = retune
        old, model_before, before = terms[a.index], tuple(terms), current
        text = text.replace(f" {NOTHING_MISSING}", "")     # the round found something: said below
        if s.retune:
            terms = [*terms[:a.index], a.term, *terms[a.index + 1:]]
            current = a.errors
        if not is_better:
            why = ("re-tuning is off: the model is kept as it was" if not s.retune else
                   f"it keeps the declared physics within the stated factor {RETUNE_FACTOR:g} and adds no term"
                   if a.keeps_declared else "it adds no term (neither keeps the declared physics)")
            ambiguities += (Ambiguity(i, (u.explanation(f"{old.label} re-placed by {a.term.label}", a.errors),
                                          u.explanation(f"{t.candidate.term.label} added", t.after)),
                                      (compare_errors(u.held, a.errors, t.after),), why,
                                      separating_record(u.ev.fit_rfs, t.candidate.term, a.term)),)
            text += (f" {old.label} re-placed by {a.term.label} instead: these data cannot tell it from "
                     f"{t.candidate.term.label} added." if s.retune else
                     f" These data cannot tell {t.candidate.term.label} added from {old.label} re-placed by "
                     f"{a.term.label}; re-tuning is off.")
            done = Round(i, model_before, ranked, tuple(trials), before, None, None, text)
            return _Found(tuple(terms), current, (done,), ambiguities, NOTHING_ELSE)
        if s.retune:
            text += (f" {old.label} re-placed by {a.term.label} instead: it predicts the held-out parts "
                     f"better than {t.candidate.term.label} added ({a.comparison.nmse_b:.3g} % against "
                     f"{a.comparison.nmse_a:.3g} %, paired t {a.comparison.t:+.2g}).")
            done = Round(i, model_before, ranked, tuple(trials), before, None, None, text)
            return _Found(tuple(terms), current, (done,), ambiguities, "")
    done = Round(i, tuple(terms), ranked, tuple(trials), current, None, None, text)
    unconfirmed = [t for t in trials if t.unconfirmed]
    if unconfirmed:
        verdict = unconfirmed_text(unconfirmed, current)
    elif ambiguities:
        verdict = NOTHING_ELSE
    else:
        verdict = NOTHING_MISSING if i > 1 else f"The declared model lacks nothing the library can name. " \
                                                 f"{NOTHING_MISSING}"
    return _Found(tuple(terms), current, (done,), ambiguities, verdict)


def _best_set_pass(u: _Setup, found: _Found, say: Callable[[float, str], None]) -> _Found:
    """The best set of effects, fewer or as many than the rounds added one at a time (a one-mass body)."""
    say(0.95, "the best set of effects")
    terms, current, ambiguities, n_decl = list(found.terms), found.current, list(found.ambiguities), u.n_decl
    swapped = []
    for _ in range(len(terms) - n_decl + 1):
        changed = False
        for fewer, new, e, comp in _best_sets(u.ev, u.pred, found.search, terms, n_decl, current, u.s, u.m2_kg,
                                              u.frame):
            if (fewer and not comp.better("b", u.s.min_prediction_gain)) or (not fewer and comp.better("a")):
                how = ("one effect fewer predicts the held-out parts as well" if fewer else
                       "that set predicts the held-out parts better; one effect added at a time had stopped "
                       "short of it")
                swapped.append(f"{', '.join(t.label for t in terms[n_decl:])} re-chosen as "
                               f"{', '.join(t.label for t in new[n_decl:]) or 'nothing'}: {how} "
                               f"({comp.nmse_a:.3g} % against {comp.nmse_b:.3g} %, paired t {comp.t:+.2g})")
                terms, current, changed = new, e, True
                labels = {t.label for t in terms}    # what the rounds could not tell apart, if still held
                ambiguities = [a for a in ambiguities if {t.label for t in a.options[0].terms} <= labels]
                break
            if not fewer and not comp.apart():
                options = (u.explanation("as found, one effect at a time", current),
                           u.explanation("the best set of as many effects", e))
                ambiguities.append(Ambiguity(len(found.rounds), options, (compare_errors(u.held, current, e),),
                                             "found first", separating_record(u.ev.fit_rfs, terms[-1], new[-1])))
        if not changed or len(terms) == n_decl:
            break
    pruned = drop_undetermined(   # an added effect the final fit does not determine
        u.ev, u.held, terms, current, ambiguities, n_decl, u.s, partial(_errors, u.ev, u.pred), partial(_placed, u))
    terms, current, ambiguities = pruned.terms, pruned.current, pruned.ambiguities
    verdict = "".join(f"{d.text(u.s.min_prediction_gain)}. " for d in pruned.dropped) + found.verdict
    if swapped:
        verdict = "Effects re-chosen: " + "; then ".join(swapped) + ". " + verdict
    return replace(found, terms=tuple(terms), current=current, ambiguities=tuple(ambiguities), verdict=verdict)


def _retune_declared(u: _Setup, found: _Found) -> tuple[_Found, list[str]]:
    """With every effect found, the declared parameters set by the data (kept when the held-out prediction is no
    worse); the model and what was re-tuned."""
    if not (u.retune_ok and u.n_decl and found.terms):
        return found, []
    u.frame.unplace(u.ev, found.terms[:u.n_decl])   # re-tuned as from each record's mean, then placed again
    new, retuned = _retune(u.ev, list(found.terms), u.s, which=range(u.n_decl), declared=u.declared_terms)
    _placed(u, new if retuned else found.terms)
    if retuned:
        e = _errors(u.ev, u.pred, new)
        if e.prediction_nmse_pct is not None and found.current.prediction_nmse_pct is not None and \
                e.prediction_nmse_pct <= found.current.prediction_nmse_pct:
            return replace(found, terms=tuple(new), current=e), retuned
    return found, []


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


def _final_model(u: _Setup, found: _Found, verdict: str, say: Callable[[float, str], None]) -> _Final:
    """The predictive model, refined by output error when that keeps the declared physics, with its static part and
    the band it covers; the declared terms' fates and the verdict with them."""
    terms, current, pred, s, m2_kg = list(found.terms), found.current, u.pred, u.s, u.m2_kg
    model = linear = unavailable = refinement = None
    if current.fitted is not None and current.prediction_unavailable is None:
        model, linear = current.fitted.model, pred.linear.model
    else:
        unavailable = f"no predictive model: {current.prediction_unavailable}"
    if model is not None and terms and s.refine and current.structure == "constant":
        say(0.98, "output-error refinement")
        refinement, refined = refine_final(u.ev, pred.held, model, linear, m2_kg, say, current)
        already = {f.declared.label for f in _fates(u.declared_terms, u.decl_theta, model, m2_kg) if f.changed_meaning}
        changed = [f for f in _fates(u.declared_terms, u.decl_theta, refined, m2_kg)
                   if f.changed_meaning and f.declared.label not in already]
        if refinement.kept and changed:   # a refinement never silently replaces the user's term by another physics
            refinement = replace(refinement, kept=False, refused="it changes a declared term: " + " ".join(
                f.text() for f in changed))
        else:
            model = refined
    beyond: tuple = ()
    if model is not None and refinement is not None and refinement.kept and found.rounds:
        beyond, model = search_beyond(u.ev, pred.held, model, found.rounds[-1].ranked, s, say)
        added = [b for b in beyond if b.accepted]
        if added:   # then something was missing after all: the verdict must not say otherwise
            verdict = (verdict.replace(NOTHING_MISSING, "The equation error shows nothing more.")
                       + " Added by output error (below the equation error's reach): "
                       + "; ".join(b.text() for b in added) + ".")
    fates = _fates(u.declared_terms, u.decl_theta, model, m2_kg) if model is not None else tuple(
        DeclaredTerm(d, float(t0), t, float(t1), m2_kg)
        for d, t0, t, t1 in zip(u.declared_terms, u.decl_theta, terms, current.theta_per_kg))
    changed = [f for f in fates if f.changed_meaning]
    if changed:
        verdict = " ".join(f.text() for f in changed) + " " + verdict
    if refinement is not None and refinement.refused:
        verdict += (" The output-error refinement predicts the held-out parts at "
                    f"{refinement.heldout_after_pct:.3g} % but is not kept: {refinement.refused}")
    final_score = current.prediction_nmse_pct
    if refinement is not None and refinement.kept and refinement.heldout_after_pct is not None:
        final_score = refinement.heldout_after_pct
    if any(b.accepted for b in beyond):
        final_score = [b for b in beyond if b.accepted][-1].heldout_after_pct
    if model is not None:   # what the model carries besides its dynamics: offsets, the band it covers, its range
        say(0.99, "the static part and the band the prediction covers")
        held_raw = replace(u.held, records=u.raw)
        linear = None if linear is None else fit_scope(linear, held_raw)
        model = fit_scope(model, held_raw, linear=linear)
    floor_note = _floors(final_score, pred, terms)
    if floor_note:
        verdict = floor_note + " " + verdict.replace(NOTHING_MISSING, "").replace(
            "The declared model lacks nothing the library can name. ", "").strip()
    return _Final(model, linear, unavailable, refinement, tuple(fates), verdict, final_score, beyond)


def _with_joint_coefficient(ev: _Evaluator, terms: Sequence[Term], trial: Trial, m2_kg: float | None, *,
                            corrected: bool = False) -> Trial:
    """The added term's coefficient from the loop's joint fit beside the model's terms (each re-estimated), with its
    bound: the ranking's coefficient is conditional on the others held. ``corrected``: with the fit's bias removed
    (:meth:`_Evaluator.bounds`), else the plain fit and its random error. A round adds the plain fit; the
    corrected one is given it at the end (:func:`_rounds_corrected`)."""
    b = ev.bounds([*terms, trial.candidate.term], corrected=corrected)
    th, hw = float(b.theta[-1]), float(b.half_width[-1])
    c = trial.candidate
    done = corrected and ev.corrected([*terms, trial.candidate.term]) is not None
    return replace(trial, candidate=replace(c, theta=th, theta_half_width=hw,
                                            coefficient=None if m2_kg is None else th * m2_kg),
                   coefficient_corrected=done)


def _rounds_corrected(ev: _Evaluator, rounds: Sequence[Round], terms: Sequence[Term], bounds,
                      m2_kg: float | None) -> tuple[Round, ...]:
    """Each round's added coefficient with the fit's bias removed: the final model's corrected coefficient where the
    term is in it unchanged and that correction was made (``bounds``: the final set's, :meth:`_Evaluator.bounds`);
    else its round's own set corrected (a term re-tuned since, or a final set whose correction is refused — terms
    that share their shape, a friction beside a damper knee: measured on ``benchmarks/bench_loop.py``'s records, a
    hidden cubic of 2e8 N/m³ at 1.73e8 by the plain fit and 2.00e8 corrected beside the declared knee alone, the
    final set with the friction not correctable); else the plain fit as added. One correction for the loop where
    the final set's holds every added term (issue 58: one per round took 5.7 of the bundled sample's 19.6 s)."""
    final = {t.label: ev.n_lin + k for k, t in enumerate(terms)} if ev.corrected(terms) is not None else {}
    out = []
    for r in rounds:
        if r.added is not None and not r.added.coefficient_corrected:
            c = r.added.candidate
            k = final.get(c.term.label)
            if k is not None:
                th, hw = float(bounds.theta[k]), float(bounds.half_width[k])
                got = replace(r.added, candidate=replace(c, theta=th, theta_half_width=hw, coefficient=None
                                                         if m2_kg is None else th * m2_kg), coefficient_corrected=True)
            else:
                got = _with_joint_coefficient(ev, r.model_before, r.added, m2_kg, corrected=True)
            r = r.with_added(got, m2_kg) if got.coefficient_corrected else r
        out.append(r)
    return tuple(out)


def _bias_note(ev: _Evaluator, terms: Sequence[Term]) -> str:
    """What the bias correction moved, or why the coefficients may be biased."""
    noise = "; ".join(e.text() for e in ev.noise)
    cor = ev.corrected(terms)
    if cor is None:
        why = ("switched off" if not ev.corrects else "the model cannot be simulated, or its terms share their shape "
               "so that the correction does not converge")
        return (f"the equation-error coefficients are not bias-corrected ({why}): noise on ż and the band-limited "
                f"z, ż may bias them (a friction or a stiffness low); {noise}")
    names = ["k", "c", *[t.label for t in terms]]
    moved = ", ".join(f"{n} {100 * (a / b - 1):+.1f} %" for n, a, b in zip(names, cor.theta, cor.theta_fit) if b != 0)
    return (f"coefficients corrected for the fit's bias (noise on both sensors and the band-limited z, ż; simulated "
            f"with the estimated noise, nifo_core.signal.bias_correction): against the plain fit {moved}; {noise}")


def _floors(final: float | None, pred: _Predictor, terms: Sequence[Term]) -> str:
    """The verdict when the final model predicts no better than a floor: the linear model of the same data, or
    predicting nothing (100 %). Empty when it beats both."""
    if pred.off or pred.linear is None:
        return ""
    lin = pred.linear.score
    what = ("the model with " + ", ".join(t.label for t in terms)) if terms else "the linear model"
    if final is None or not np.isfinite(final) or final >= 100.0:
        return (f"The model class cannot predict these data: {what} predicts the held-out parts at "
                + ("no computable error" if final is None or not np.isfinite(final) else f"{final:.3g} %")
                + " — no better than predicting nothing (100 %). Check the channels, the band and the linear "
                  f"part ({pred.choice.reason}).")
    if terms and final >= lin:
        return (f"The model class does not predict these data better than a linear model: {what} predicts the "
                f"held-out parts at {final:.3g} %, the linear model of the same data at {lin:.3g} %.")
    return ""


#: the verdict when nothing is missing beyond what an ambiguity or a conflict names
NOTHING_ELSE = "Nothing else the library can name is missing."


def _fates(declared: Sequence[Term], theta_declared: Sequence[float], model: IdentifiedModel,
           m2_kg: float | None) -> tuple[DeclaredTerm, ...]:
    """Each declared term as declared and in ``model`` (its first terms are the declared ones, in order)."""
    coef = [] if getattr(model, "c_over_m2", None) is None else [float(v) for v in np.ravel(model.c_over_m2)]
    return tuple(DeclaredTerm(d, float(t0), t, float(coef[k]) if k < len(coef) else float("nan"), m2_kg)
                 for k, (d, t0, t) in enumerate(zip(declared, theta_declared, model.terms)))


def _retune_instead(trials: Sequence[Trial], current: Errors) -> tuple[Trial, Alternative, bool] | None:
    """The term re-placed instead of a term added, and whether it predicts better than the term (else the data
    cannot tell them apart): of the candidates refused only by one-of-kind alternatives taken instead of them
    (:func:`~nifo_core.loop.gates.judge_alternatives`), one that predicts better first, then the one predicting
    the held-out parts best; never one that predicts worse than the model ``current``."""
    now = current.prediction_nmse_pct
    options = [(t, a, a not in t.ties) for t in trials if t.gates_passed and not t.accepted
               for a in t.instead if a.errors.prediction_nmse_pct is not None
               and (now is None or a.errors.prediction_nmse_pct <= now)]
    if not options:
        return None
    return min(options, key=lambda o: (not o[2], o[1].errors.prediction_nmse_pct))


def _body_round(ev: _Evaluator, pred: _Predictor, terms: Sequence[Term], ranked: Sequence[Candidate],
                s: LoopSettings, m2_kg: float | None, judge_in: Callable, say: Callable[[float, str], None],
                at: float, i: int) -> tuple[list[Trial], Trial, Errors] | None:
    """When the rational linear part adds nothing: the round again on the one-mass body, whose form is taken
    (with the term it accepts) unless the rational model with that term predicts clearly better
    (:data:`~nifo_core.predict.model_fit.RATIONAL_MARGIN`, as :meth:`_Predictor.reconsider`).

    The form was chosen on the linear model alone, and a strong nonlinearity the body lacks makes its linear model
    predict worse than a black box's extra poles do: measured, a bump stop 3.5e5 N/m beyond 5.6 mm beside a declared
    knee (3 levels up to 5.5 mm road): the linear body 41 % against the rational 16 %; on the rational part every
    candidate made the held-out prediction worse (the stop through no path of its own), so nothing was added.
    None when the body is not physical with ``terms`` or accepts nothing."""
    body = pred.body_twin()
    current = _errors(ev, body, terms)
    if current.prediction_nmse_pct is None or body._equation(terms) is None:
        return None
    trials = []
    for c in [c for c in ranked if c.present][: s.top_tried]:
        say(at, f"round {i}: checking {c.term.label} on the one-mass body")
        t = judge_in(body, current, c)
        trials.append(t)
        if not t.accepted:
            continue
        flex = pred.fit([*terms, t.candidate.term])
        if flex.score <= RATIONAL_MARGIN * t.after.prediction_nmse_pct:
            return None      # the rational model with it predicts clearly better: its form stays
        pred.switch_to_body(f"one-mass body from round {i} on: with {t.candidate.term.label} its equation-error fit "
                            f"is physical and predicts the held-out parts at {t.after.prediction_nmse_pct:.4g} % "
                            f"against {flex.score:.4g} % for the rational model with it (the rational form was "
                            f"chosen on the linear model alone)")
        return trials, t, current
    return None


#: a set of as many effects from the subset search is tried when it leaves this much less of the subsample's residual
SUBSET_GAIN = 0.01


def _best_sets(ev: _Evaluator, pred: _Predictor, search, terms: Sequence[Term], n_decl: int, current: Errors,
               s: LoopSettings, m2_kg: float | None, frame: Frame) -> list[tuple[bool, list[Term], Errors, Comparison]]:
    """The best set of one effect fewer than the rounds added, and of as many, beside the declared terms
    (:func:`~nifo_core.characterize.subsets.best_subsets` on the ranking's grid): (fewer?, its model's terms, their
    errors, their comparison with ``current`` — A: that set, B: as found). The set of as many is tried when its kinds
    differ and it leaves :data:`SUBSET_GAIN` less of the residual. Adding one effect at a time can stop short of the
    best set, and can take one effect more than it needs: measured on the fleet of issue 54, a cubic and an even
    spring beside a knee were taken for a one-sided stop, then a second stop and a clearance."""
    data = search.data
    fixed = [data.regressor(t, offsets=ev.static.get(t.label)) for t in terms[:n_decl]]
    added = list(terms[n_decl:])
    now = subset_rss(search, fixed + [data.regressor(t, offsets=ev.static.get(t.label)) for t in added], [])
    kinds = list(search.grids)
    out = []
    for size in ([len(added) - 1] if len(added) > 1 else []) + [len(added)]:
        fewer = size < len(added)
        for rss, js in best_subsets(search, fixed, kinds, size):
            new = [search.terms[j] for j in js]
            if not fewer and sorted(t.kind for t in new) == sorted(t.kind for t in added):
                continue          # the same kinds: their parameters are the rounds' own
            if not fewer and not rss < (1 - SUBSET_GAIN) * now:
                break
            model = list(terms[:n_decl])
            for t in new:         # each at full length, a stop or an even spring re-measured from the static position
                base = [data.regressor(u, offsets=ev.static.get(u.label)) for u in model]
                c = score_candidate(data, base, t, thresholds=s.thresholds, n_grid=s.grid_points, m2=m2_kg,
                                    names=tuple(u.label for u in model))
                model.append(_static_candidate(ev, model, c, s, m2_kg).term)
                frame.candidate(ev, model[-1])
            e = _errors(ev, pred, model)
            if e.prediction_nmse_pct is not None and current.prediction_nmse_pct is not None:
                out.append((fewer, model, e, compare_errors(ev.held, e, current)))
            break
    return out
