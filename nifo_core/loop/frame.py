"""The loop's forms of z measured from the static position its model implies (docs/method.md §5).

z is a band-limited integral: each record's z is measured from its *mean* position. A term with a mean force (a
damper stiffer in rebound than in compression, a one-sided stop, an even spring) moves the mean away from the
static position, the more the harder the road. A form of z acting about the static position (a cubic spring, a
clearance) is then, measured from the mean, another function at every level: a cubic θ(z + m)³ = θz³ + 3θm·z² +
3θm²·z + θm³ holds an even spring and a stiffness that change with the level, and the loop looked for them among the
candidates. Measured on the fleet's tune case 19 (a declared rebound damper 2028 N·s/m, a hidden cubic 2.5e7 N/m³
and a friction 34.5 N; the mean 0.2–2.3 mm into compression over four levels): two compression stops were added
for the cubic.

Characterize measures every form of z from the static position its suggestion implies
(:func:`nifo_core.characterize.static.static_frame`, ``RegressionData.in_frame``); the loop does the same with its
model: the declared terms at the start, and after each round the terms it holds. The frame is taken once a record's
mean lies more than :data:`FRAME_MATERIAL` of its z RMS from the static position (the threshold characterize uses)
and updated when it moves by more than :data:`FRAME_SETTLED` of its largest offset. Every form of z of the model
and of the round's candidates is then evaluated on z from the static position (the evaluator's ``static`` offsets,
the ranking's grid on the data in the frame); a bump stop keeps its own gap from the static position
(:func:`nifo_core.loop.residual._static_candidate`). The key parameter of such a form the loop added (a clearance's
gap) is re-tuned in later rounds in the frame too (:meth:`Frame.retune`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..characterize.automatic import grid_search
from ..characterize.data import GridSearch
from ..characterize.static import equation_fit, static_frame
from ..kinds.describing import Term
from ..signal.parallel import thread_map
from .residual import _Evaluator
from .stops import CLIMBS, RETUNE_GAIN   # a term re-tuned in the frame moves and climbs as a stop's gap does

__all__ = ["FRAME_MATERIAL", "FRAME_SETTLED", "Frame", "framed"]

#: a record's mean position this far from the static one, relative to its z RMS, makes the loop take the frame
FRAME_MATERIAL = 0.05
#: the frame is moved when a record's offset changes by more than this fraction of the largest one
FRAME_SETTLED = 0.1
#: fixed-point passes of the frame (the terms' coefficients depend on it, it on them)
FRAME_PASSES = 3


def framed(term: Term) -> bool:
    """A form of z measured from the static position in the frame (a bump stop has its own gap from it)."""
    return term.spec.variable == "z" and term.spec.static_frame != "threshold"


@dataclass
class Frame:
    """Where the static position lies in each fit part (offset -m_i [m], None: each record's mean) and what it
    holds; the loop's one mutable record of it, like the evaluator's ``static`` offsets it writes."""

    offsets: tuple[float, ...] | None = None
    moves: list[tuple[float, ...]] = field(default_factory=list)   # each frame taken, in order
    _lifted: dict = field(default_factory=dict)    # label → offsets lifted for a re-tune (:meth:`unplace`)

    def place(self, ev: _Evaluator, terms: Sequence[Term]) -> bool:
        """The frame ``terms`` imply, taken when material (module docstring); every form of z of ``terms``
        registered in it. True when a column of the model changed (the callers' errors must be computed again)."""
        new = self._solve(ev, terms)
        if new is None and self.offsets is None:
            return False
        if new is not None and (self.offsets is None or _moved(self.offsets, new) > FRAME_SETTLED):
            self.offsets = new
            self.moves.append(new)
        changed = False
        for t in terms:
            if framed(t):
                changed |= ev.static.get(t.label, self._lifted.get(t.label)) != self.offsets
                ev.static[t.label] = self.offsets
        self._lifted = {}
        if changed:
            ev.forget_equations()
        return changed

    def text(self, sources: Sequence[str]) -> str:
        """The result's note: where the mean positions sat, as the model implied them (rebound positive)."""
        where = ", ".join(f"{1e3 * -o:+.2f} mm ({s or f'record {i}'})"
                          for i, (o, s) in enumerate(zip(self.offsets, sources)))
        return (f"every form of z measured from the static position: the model's mean force moves the mean position, "
                f"which sat {where} from it in the fit parts (rebound positive; placed {len(self.moves)} time(s))")

    def candidate(self, ev: _Evaluator, term: Term) -> None:
        """A round's candidate evaluated in the frame, like the model's terms (a bump stop, an even spring already
        re-measured by the candidate's own static check keep theirs)."""
        if self.offsets is not None and framed(term) and term.label not in ev.static:
            ev.static[term.label] = self.offsets

    def unplace(self, ev: _Evaluator, terms: Sequence[Term]) -> None:
        """The terms' frame offsets lifted while their key parameters are re-tuned (the re-tune leaves a term with
        offsets of its own as it is: a bump stop's gap was fitted with them; these are re-tuned as from each record's
        mean, as before the frame); :meth:`place` registers them again, a column the same as before unchanged."""
        if self.offsets is None:
            return
        for t in terms:
            if framed(t) and ev.static.get(t.label) == self.offsets:
                self._lifted[t.label] = ev.static.pop(t.label)

    def retune(self, ev: _Evaluator, terms: Sequence[Term], *, which: Sequence[int]) -> tuple[list[Term], list[str]]:
        """Each form of z among ``terms[which]`` registered in the frame with its key parameter (a clearance's gap, a
        play's deadband) re-tuned *in the frame*, given the whole model: tried over a factor 2 each way (13 points,
        carried on by a factor 2 at a time, :data:`CLIMBS` times at most, while the best is at an end; then 7
        between the best's neighbours), scored by the equation error on the fit parts' regression rows; moved when
        the sum of squares falls by more than :data:`RETUNE_GAIN`. Returns the terms and one note per
        term moved; ``ev.static`` holds the new labels.

        residual.py's re-tune skips a term with offsets; lifted out of the frame for it (as before), such a term
        was re-tuned from each record's *mean*: another function at every level, the more the harder the road.
        Measured on own draws of the fleet generator (seed 54545, nifo's simulator, a declared rebound damper, a
        hidden clearance and knee, 3 × 90 s; tests/test_loop_frame.py): case 2's clearance (3.09 mm) added at
        3.01 mm, re-tuned from the mean to 1.54 mm, and a compression stop added to make up for it; case 0's
        (1.62 mm) from 1.72 to 1.20 mm. In the frame both stay (3.01 and 1.72 mm), nothing else added."""
        out, notes = list(terms), []
        if self.offsets is None:
            return out, notes
        data = ev.regression()
        for j in which:
            t, key = out[j], out[j].spec.key_param
            if not (framed(t) and key in t.params and ev.static.get(t.label) == self.offsets):
                continue
            offsets = [ev.static.get(u.label) for u in out]

            def rss(x: float, j=j, t=t, key=key, offsets=offsets) -> float:
                at = [*out[:j], Term(t.kind, {**t.params, key: float(x)}), *out[j + 1:]]
                return equation_fit(data, at, offsets)[1]

            x0 = float(t.params[key])
            now = rss(x0)
            best = _best_value(rss, x0, now, lambda x, t=t, key=key: t.spec.may_be(key, x))
            if best[1] != x0 and best[0] < (1 - RETUNE_GAIN) * now:
                out[j] = Term(t.kind, {**t.params, key: best[1]})
                del ev.static[t.label]
                ev.static[out[j].label] = self.offsets
                notes.append(f"{t.label} re-tuned to {key}={best[1]:.4g} in the frame of the static position on "
                             f"these data")
        return out, notes

    def search(self, ev: _Evaluator, kinds: Sequence[str], grid_points: int, old: GridSearch | None,
               progress) -> GridSearch:
        """The candidates' grid on the fit parts in the frame (the same as before while it has not moved), on the
        evaluator's regression rows (their band-passed force, z and ż made once)."""
        if old is not None and getattr(old.data, "frame", None) == self.offsets:
            return old
        return grid_search(ev.fit_rfs, kinds=kinds, grid_points=grid_points, progress=progress,
                           data=ev.regression().in_frame(self.offsets))

    def _solve(self, ev: _Evaluator, terms: Sequence[Term]) -> tuple[float, ...] | None:
        if not terms:
            return None
        data = ev.regression()
        frame = self.offsets
        for _ in range(FRAME_PASSES):
            offs = [frame if (frame is not None and framed(t)) else ev.static.get(t.label) for t in terms]
            new = static_frame(data, terms, [None if o is None else tuple(o) for o in offs])
            if frame is not None and _moved(frame, new) < FRAME_SETTLED / 10:
                frame = new
                break
            frame = new
        if self.offsets is None and all(abs(o) <= FRAME_MATERIAL * float(np.std(rf.z))
                                        for o, rf in zip(frame, ev.fit_rfs)):
            return None
        return tuple(float(o) for o in frame)


def _best_value(rss, x0: float, at_x0: float, may_be) -> tuple[float, float]:
    """(sum of squares, value) of the best key parameter for :meth:`Frame.retune`: a factor 2 each way from ``x0``
    (13 points), carried on by a factor 2 at a time (:data:`CLIMBS` times at most) while the best is at an end, then
    7 points between the best's neighbours; ``x0`` itself among the tries, its sum of squares ``at_x0`` (the caller's,
    not computed again)."""
    def tried(xs) -> list[tuple[float, float]]:
        xs = [float(x) for x in xs if may_be(float(x))]
        return list(zip(thread_map(rss, xs), xs))

    grid = list(np.geomspace(0.5, 2.0, 13) * x0)
    best = min([*tried(grid), (at_x0, x0)])
    for _ in range(CLIMBS):     # the best at an end of the span: the span carried on beyond it
        down = best[1] <= grid[0]
        if not (down or best[1] >= grid[-1]):
            break
        end = grid[0] if down else grid[-1]
        more = list(np.geomspace(end, end * (0.5 if down else 2.0), 7)[1:])
        grid = sorted(grid + more)
        best = min([best, *tried(more)])
    k = int(np.argmin(np.abs(np.asarray(grid) - best[1])))
    return min([best, *tried(np.linspace(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)], 9)[1:-1])])


def _moved(a: Sequence[float], b: Sequence[float]) -> float:
    return max(abs(x - y) for x, y in zip(a, b)) / max(max(abs(x) for x in b), 1e-12)
