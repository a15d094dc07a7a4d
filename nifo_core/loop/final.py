"""The loop's final model (:mod:`nifo_core.loop.closing`, steps 5-6): the declared parameters re-tuned once every
effect is found, the rounds' coefficients with the fit's bias removed, the output-error refinement and the search
beyond it, the static part and the band the prediction covers, the declared terms' fates and the floors the
verdict is judged against.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from ..kinds.describing import Term
from ..predict.model import IdentifiedModel
from ..predict.scope_fit import fit_scope
from .residual import _Evaluator, _retune
from .results import DeclaredTerm, LoopRefinement
from .round_results import Round
from .words import NOTHING_MISSING
from .refine import refine_final
from .beyond import search_beyond
from .predictor import _errors, _Predictor
from .rounds import _Found, _with_joint_coefficient
from .state import _placed, _Setup


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


def _rounds_corrected(ev: _Evaluator, rounds: Sequence[Round], terms: Sequence[Term], bounds,
                      m2_kg: float | None) -> tuple[Round, ...]:
    """Each round's added coefficient with the fit's bias removed where that costs no correction of its own: the
    final model's corrected coefficient where the term is in it unchanged and that correction was made (``bounds``:
    the final set's, :meth:`_Evaluator.bounds`). A term re-tuned or replaced since keeps its round's plain fit, and
    its round says so (:func:`_as_added`): the final model holds its corrected value in its final form, and
    correcting the round's own set for a coefficient of a form the model no longer has cost a whole correction (39
    simulations; the bundled sample's whole run 53.4 → 46.9 CPU-s without it, three runs each alternating). Where
    the final set's correction is refused (terms that share their shape, a friction beside a damper knee), each
    round's own set is corrected, the only corrected value its term gets (measured on ``benchmarks/bench_loop.py``'s
    records: a hidden cubic of 2e8 N/m³ at 1.73e8 by the plain fit and 2.00e8 corrected beside the declared knee
    alone, the final set with the friction not correctable). One correction for the loop where the final set's
    holds every added term (issue 58: one per round took 5.7 of the bundled sample's 19.6 s)."""
    held = ev.corrected(terms) is not None
    final = {t.label: ev.n_lin + k for k, t in enumerate(terms)} if held else {}
    out = []
    for r in rounds:
        if r.added is not None and not r.added.coefficient_corrected:
            c = r.added.candidate
            k = final.get(c.term.label)
            if k is not None:
                th, hw = float(bounds.theta[k]), float(bounds.half_width[k])
                got = replace(r.added, candidate=replace(c, theta=th, theta_half_width=hw, coefficient=None
                                                         if m2_kg is None else th * m2_kg), coefficient_corrected=True)
            elif held:
                r = _as_added(r, terms)
                got = r.added
            else:
                got = _with_joint_coefficient(ev, r.model_before, r.added, m2_kg, corrected=True)
            r = r.with_added(got, m2_kg) if got.coefficient_corrected else r
        out.append(r)
    return tuple(out)


def _as_added(r: Round, terms: Sequence[Term]) -> Round:
    """Round ``r``, whose added term the final model holds in another form, with its words saying that its
    coefficient is the round's plain fit."""
    t = r.added.candidate.term
    same = any(f.kind == t.kind and f.params.get("side") == t.params.get("side") for f in terms)
    since = "re-tuned since" if same else "not in the final model"
    return replace(r, text=f"{r.text} (Its coefficient is that round's plain fit: the term is {since}, and the final "
                           f"model's coefficients below are bias-corrected.)")


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


def _fates(declared: Sequence[Term], theta_declared: Sequence[float], model: IdentifiedModel,
           m2_kg: float | None) -> tuple[DeclaredTerm, ...]:
    """Each declared term as declared and in ``model`` (its first terms are the declared ones, in order)."""
    coef = [] if getattr(model, "c_over_m2", None) is None else [float(v) for v in np.ravel(model.c_over_m2)]
    return tuple(DeclaredTerm(d, float(t0), t, float(coef[k]) if k < len(coef) else float("nan"), m2_kg)
                 for k, (d, t0, t) in enumerate(zip(declared, theta_declared, model.terms)))
