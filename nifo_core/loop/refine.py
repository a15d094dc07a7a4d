"""The loop's last step: the final model refined by output error, its noise bias removed, scored on the held-out parts.

(:mod:`nifo_core.loop` step 6.) The refined model becomes the loop's model when its held-out
prediction NMSE is not worse than the equation-error model's. A bias correction taken from a step that turned back
(:func:`nifo_core.predict.refine_bias.bracketed`: the bias map far from linear over the step) is kept only where
it predicts the held-out parts at least as well as the uncorrected refinement; otherwise the uncorrected one goes
on, with a note saying so. Measured: the physics fleet's #198 corrected 4.37 % → 1.62 % (kept); the loop
benchmark's corrected 0.572 % against 0.416 % uncorrected (the uncorrected kept, as before the bracketing).
"""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

from ..errors import NifoError
from ..predict.heldout import HeldOut
from .residual import BIAS_SEED, _Evaluator
from .results import LoopRefinement
from .round_results import Errors
from ..predict.model import IdentifiedModel
from ..signal.record import Record
from ..predict.refine import Refinement, refine_model, start_up_samples
from ..predict.refine_bias import bracketed, correct_refinement, noted

__all__ = ["refine_final", "refine_parts"]


def refine_final(ev: _Evaluator, held: HeldOut, model: IdentifiedModel, linear: IdentifiedModel | None,
                 m2_kg: float | None, say: Callable[[float, str], None],
                 final: Errors) -> tuple[LoopRefinement, IdentifiedModel]:
    """Output-error refinement of the loop's final model on the fit parts, scored on the held-out parts.

    :func:`~nifo_core.predict.refine.refine_model` on the first ``refine_seconds`` of every fit part (the
    equation-error fit and, where it does not already beat it, the linear model as starts); both
    models' held-out prediction NMSE on the loop's one metric (the equation-error model's from ``final``,
    the last round's errors of the same terms). Returns the record of it and the model
    the loop keeps: the refined one unless its held-out prediction is worse (or cannot be made).
    """
    recs = refine_parts(ev, held)
    secs = tuple(float(r.duration_s) for r in recs)
    try:
        ref, plain = _refined(ev, held, model, linear, recs, say)
    except NifoError as err:
        return LoopRefinement(False, None, None, seconds=secs, unavailable=str(err)), model
    # the equation-error model's held-out prediction is the final round's (``final``, same model): not re-run
    b, bper = final.prediction_nmse_pct, tuple(final.prediction_nmse_per_record_pct)
    sc = held.score(ref.model)
    if plain is not None:       # a bracketed correction: kept where it predicts at least as well as no correction
        sp = held.score(plain.model)
        if sp.unavailable is None and (sc.unavailable is not None or sp.mean < sc.mean):
            worse = "could not be simulated" if sc.unavailable is not None else \
                f"predicts the held-out parts at {sc.mean:.3g} % against {sp.mean:.3g} % without it"
            ref, sc = noted(plain, f"not bias-corrected (the correction, taken from a second step that turned back "
                                   f"past the first, {worse}): the refined values may be biased by the spindle "
                                   f"sensor's noise"), sp
    a, aper = (None, ()) if sc.unavailable is not None else (sc.mean, tuple(float(v) for v in sc.per_record))
    kept = a is not None and (b is None or a <= b)
    out = LoopRefinement(kept, b, a, bper, aper, tuple(_compare(model, ref.model, m2_kg, ref.parameters)), secs,
                         ref.to_dict(),
                         # beside the band figures, both models' held-out whole signal (all frequencies, offset
                         # included): the field's score
                         whole_before_pct=final.whole_nmse_pct, whole_after_pct=sc.whole_mean,
                         whole_before_per_record_pct=tuple(final.whole_nmse_per_record_pct),
                         whole_after_per_record_pct=tuple(float(v) for v in sc.whole),
                         whole_before_policy=final.whole_policy, whole_after_policy=sc.whole_policy)
    return out, (ref.model if kept else model)


def refine_parts(ev: _Evaluator, held: HeldOut) -> list[Record]:
    """From rest, the fit part of every record, at most ``refine_seconds`` (whole periods of periodic data)."""
    s = ev.settings
    p = held.period_samples
    recs = []
    for r, sk, k in zip(held.records, held.skip, held.split):     # from rest, the fit part, at most refine_seconds
        n = min(k, sk + int(round(s.refine_seconds * r.fs_hz)))
        if p:
            n = sk + max(2 * p, (n - sk) // p * p) if k - sk >= 2 * p else k
        recs.append(r.slice(0, min(n, k)))
    return recs


def _refined(ev: _Evaluator, held: HeldOut, model: IdentifiedModel, linear: IdentifiedModel | None,
             recs: Sequence[Record], say: Callable[[float, str], None]) -> tuple[Refinement, Refinement | None]:
    """``model`` refined on ``recs`` (the equation-error fit and, where it does not already beat it, the linear
    model as starts), its bias from the noisy spindle drive removed when the loop corrects; and the uncorrected
    refinement where the correction was bracketed (else None)."""
    p = held.period_samples
    skips = [max(sk, p or 0, start_up_samples(model, r, p)) for r, sk in zip(recs, held.skip)]
    ref = refine_model(model, recs, linear=linear, band_hz=held.band_hz, period_samples=p, skip_samples=skips,
                       progress=lambda start, n, cost: say(0.98, f"output-error refinement from the {start} "
                                                                 f"start ({n} simulations)"))
    if not ev.corrects:
        return ref, None
    # the spindle's noise drives every simulation: the output-error fit's bias removed too
    corrected = correct_refinement(ref, recs, ev.noise, seed=BIAS_SEED)
    return corrected, (ref if bracketed(corrected) else None)


def _compare(before: IdentifiedModel, after: IdentifiedModel, m2: float | None,
             refined: Sequence[Mapping] = ()) -> list[dict]:
    """Every refined parameter: the equation-error value and the refined one (× M2 where it scales).

    ``refined``: :attr:`~nifo_core.predict.refine.Refinement.parameters`, whose 95 % half-widths (where given)
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
        key = t0.spec.shape_param
        if key is not None and isinstance(t0.params.get(key), float):
            out.append(entry(f"{t0.kind}.{key}", t0.spec.params[key][1], t0.params[key], t1.params[key],
                             hw=named.get(f"{t0.kind}.{key}")))
    if before.body is not None and after.body is not None:
        out.append(entry("k = K2/M2", "1/s²", before.body.k, after.body.k, "N/m", width("k = K2/M2")))
        out.append(entry("c = C2/M2", "1/s", before.body.c, after.body.c, "N·s/m", width("c = C2/M2")))
    return out

