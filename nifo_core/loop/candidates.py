"""What a round of the loop tries (:mod:`nifo_core.loop.closing`, steps 2-3): on a one-mass body the significant
ranked candidates in rank order; on a flexible body (a rational linear part) plays over a grid of widths beside the
best ranked candidates of the other kinds.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..kinds.describing import Term, kind as lookup_kind
from ..characterize.score import base_fit, score_candidate
from ..predict.feedback_paths import PATH_KINDS
from .residual import _Evaluator
from .settings import LoopSettings
from .predictor import _Predictor


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
    fit = base_fit(data, base)
    return [score_candidate(data, base, t, thresholds=s.thresholds, n_grid=int(s.path_widths), m2=m2_kg,
                            names=tuple(t.label for t in terms), fit=fit) for t in chosen]


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
