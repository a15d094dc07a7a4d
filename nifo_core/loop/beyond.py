"""Effects below the equation error's reach, found by output error (:mod:`nifo_core.loop` step 7, docs/method.md §5).

The rounds trace the equation-error residual: a term is added only when it explains ``thresholds.min_err`` of it.
That residual holds the noise of z and ż integrated twice from the measured output: an effect whose force is
a few per cent of the damping force explains less of it than its threshold, though the model without it
predicts measurably worse. Measured on the Silverbox circuit at 100 mV: after the cubic and the even spring every
remaining kind explains 0.2-1.2 % of the residual (a damping rising beyond a velocity knee, 0.9 %), none is added,
and yet that damping, refined by output error, halves the held-out prediction error of the level's last third
(band NMSE 0.00126 → 0.00064 %) and predicts 150 mV at 0.90 mV raw RMS against 3.4 mV.

So, once the loop's final model is refined, every kind the last round ranked and did not add (one per kind, its
best grid point) is tried by output error: added to the refined model at the coefficient the ranking fitted,
refined with it on the fit parts (:func:`~nifo_core.predict.refine.refine_model`, its key parameter free) and
scored on the held-out parts like every model of the loop. A candidate passes when it does
predict them better than the model without it beyond the scatter of their blocks and by ``min_prediction_gain``
(:meth:`~nifo_core.loop.ambiguity.Comparison.better`: the margin a term must earn) without raising the
whole-signal NMSE by more than :data:`~nifo_core.loop.gates.WHOLE_RISE`; of those that pass, the one whose
held-out whole signal is predicted best is added. One pass: a second one on the Silverbox at 100 mV added nothing (every
kind within 0.6 % of the model with the first, paired t ≤ 2.0) and doubled the cost.

Where: a one-mass body driven by a measured force (spindle fixed). There the output-error fit is the unbiased
estimator (the measured input drives the simulation; no sensor noise enters it, which the loop otherwise removes by
simulating the refinement, :mod:`nifo_core.predict.refine_bias`, once per model), and each candidate costs one
refinement of a few parameters. A rational linear part's terms act through feedback paths that
:func:`~nifo_core.predict.refine.refine_model` does not refine; a spindle-driven quarter car would need the bias
correction per candidate. Neither is searched: the F-16 and the vehicles keep the rounds' model.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from ..characterize.result import Candidate
from ..errors import NifoError
from ..kinds.describing import Term
from ..predict.heldout import HeldOut
from ..predict.model import IdentifiedModel
from ..predict.refine import refine_model, start_up_samples
from ..signal.parallel import thread_map
from .ambiguity import compare
from .gates import WHOLE_RISE
from .refine import refine_parts
from .residual import _Evaluator
from .settings import LoopSettings

__all__ = ["BeyondTrial", "searches_beyond", "search_beyond"]


@dataclass(frozen=True)
class BeyondTrial:
    """One kind tried by output error: its start (the ranking's), the refined term and coefficient, both held-out
    NMSEs (band, and whole signal) against the model without it, the paired t, and whether it was added."""

    start: Term
    term: Term | None
    coefficient_per_kg: float | None
    heldout_before_pct: float | None
    heldout_after_pct: float | None
    whole_before_pct: float | None
    whole_after_pct: float | None
    t: float | None
    accepted: bool
    why: str

    def text(self) -> str:
        what = self.term.label if self.term is not None else self.start.label
        if self.heldout_after_pct is None:
            return f"{what}: not scored ({self.why})"
        return (f"{what}: held-out prediction NMSE {self.heldout_before_pct:.3g} % → {self.heldout_after_pct:.3g} % "
                f"(paired t {self.t:+.2g}), whole signal {_pct(self.whole_before_pct)} → {_pct(self.whole_after_pct)}"
                f"{'' if self.accepted else ': ' + self.why}")

    def to_dict(self) -> dict:
        return {"start": self.start.to_dict(), "term": None if self.term is None else self.term.to_dict(),
                "label": (self.term or self.start).label, "coefficient_per_kg": self.coefficient_per_kg,
                "heldout_prediction_nmse_before_pct": self.heldout_before_pct,
                "heldout_prediction_nmse_after_pct": self.heldout_after_pct,
                "heldout_whole_nmse_before_pct": self.whole_before_pct,
                "heldout_whole_nmse_after_pct": self.whole_after_pct, "paired_t": self.t, "accepted": self.accepted,
                "why": self.why}


def _pct(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.3g} %"


def searches_beyond(model: IdentifiedModel | None, held: HeldOut) -> bool:
    """Whether the search applies: a one-mass body without feedback paths, driven by a measured force."""
    return bool(model is not None and model.linear.kind == "body" and model.linear.paths is None
                and model.force_gain > 0 and held.records and all(r.spindle_fixed for r in held.records))


def search_beyond(ev: _Evaluator, held: HeldOut, model: IdentifiedModel, ranked: Sequence[Candidate],
                  s: LoopSettings, say: Callable[[float, str], None]) -> tuple[tuple[BeyondTrial, ...], IdentifiedModel]:
    """The kinds of ``ranked`` the model lacks, tried by output error (module docstring): every trial, and the model
    with what was added (``model`` itself when nothing was)."""
    if not searches_beyond(model, held):
        return (), model
    have = {t.kind for t in model.terms}
    cands, seen = [], set()
    for c in ranked:
        if c.kind not in have and c.kind not in seen and np.isfinite(c.theta):
            cands.append(c)
            seen.add(c.kind)
    base = held.score(model)
    if not cands or base.unavailable is not None:
        return (), model
    recs = refine_parts(ev, held)
    p = held.period_samples
    skips = [max(sk, p or 0, start_up_samples(model, r, p)) for r, sk in zip(recs, held.skip)]
    # the kinds' refinements are independent: side by side on threads, each the numbers it gets alone (measured on the
    # Silverbox at 150 mV, seven kinds: 20.7 s one after the other, most of `nifo run`'s loop)
    say(0.985, f"output error: trying {len(cands)} kind(s) side by side: " + ", ".join(c.term.label for c in cands))
    tried = thread_map(lambda c: _try(model, c, recs, held, base, skips, s), cands)
    ok = [tr for tr in tried if tr[0].accepted]
    if not ok:
        return tuple(tr[0] for tr in tried), model
    best = min(ok, key=_whole_first)
    return tuple(tr[0] if tr is best else replace(
        tr[0], accepted=False, why=f"another kind predicts the held-out whole signal better "
                                   f"({_pct(best[0].whole_after_pct)})") if tr[0].accepted else tr[0]
                 for tr in tried), best[1]


def _whole_first(tr: tuple[BeyondTrial, IdentifiedModel | None]) -> tuple[float, float]:
    """Among the kinds that pass, the one whose predicted signal is best (the held-out whole-signal NMSE: what the
    field scores), then the band NMSE. Measured at 100 mV on the Silverbox: the band NMSE ranks a play first
    (0.000584 % against 0.000641 % for a damping rising beyond a velocity knee), the whole signal that damping
    (0.000557 % against 0.000560 %); the play, stuck below its deadband, adds stiffness at small amplitude and
    predicts the 5 mV level at 0.96 mV raw RMS against 0.57 mV."""
    w = tr[0].whole_after_pct
    return (w if w is not None else np.inf, tr[0].heldout_after_pct)


def _try(model: IdentifiedModel, c: Candidate, recs, held: HeldOut, base, skips: Sequence[int],
         s: LoopSettings) -> tuple[BeyondTrial, IdentifiedModel | None]:
    """``c`` added to ``model`` at the ranking's coefficient, refined with it, scored against ``model``."""
    b0, w0 = base.mean, base.whole_mean
    start = replace(model, terms=(*model.terms, c.term), c_over_m2=np.append(model.c_over_m2, float(c.theta)),
                    b=np.vstack([model.b, np.zeros((1, model.freq_hz.size), complex)]))
    try:
        ref = refine_model(start, recs, band_hz=held.band_hz, period_samples=held.period_samples, skip_samples=skips)
    except NifoError as err:
        return BeyondTrial(c.term, None, None, b0, None, w0, None, None, False, str(err)), None
    got = ref.model
    sc = held.score(got)
    if sc.unavailable is not None:
        return BeyondTrial(c.term, got.terms[-1], float(got.c_over_m2[-1]), b0, None, w0, None, None, False,
                           sc.unavailable), None
    cmp = compare(held, sc.predictions, base.predictions)
    why = ""
    if not cmp.better("a", s.min_prediction_gain):
        why = (f"it does not predict the held-out parts better by {100 * s.min_prediction_gain:g} % beyond the "
               f"scatter of their blocks")
    elif w0 is not None and sc.whole_mean is not None and sc.whole_mean > w0 * (1 + WHOLE_RISE):
        why = "it raises the held-out whole-signal NMSE (all frequencies, offset included)"
    trial = BeyondTrial(c.term, got.terms[-1], float(got.c_over_m2[-1]), b0, sc.mean, w0, sc.whole_mean,
                        float(cmp.t), not why, why)
    return trial, (got if not why else None)
