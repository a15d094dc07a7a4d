"""Clipping: a sensor or amplifier that saturated, seen as flat runs at a channel's extremes.

A clipped channel holds its rail value for several samples each time the true
signal goes beyond it, so its largest (or smallest) value repeats in runs,
entered and left by a jump (the signal was still moving). :func:`clipping`
counts the samples in runs of at least ``min_run`` consecutive samples within a
hair (``1e-9`` of the channel's range) of the channel's maximum or minimum,
entered or left by more than half the channel's typical sample-to-sample change.
A continuous signal reaches its extreme at one sample; an oversampled signal
from a coarse converter (a slow sine on 12 bits) sits at its peak's value for
several, but enters that run by one converter step, which the jump rule tells
apart. Merged over chunks (:meth:`Clipping.merge`), so a recording read in
chunks gives what the whole record would (up to runs that straddle two chunks).

The threshold (:data:`REFUSE_FRACTION`, 0.1 %) was measured (``benchmarks/bench_clipping.py``):
every channel of the bundled sample, the F-16 benchmark (all eight files, the
three accelerations and the force) and the Silverbox (input and output, five
levels) holds no such run — fraction 0, so any run at all is named in a
:class:`ClippingWarning`. On the sample's two road levels clipped at ±kσ, NIFO's
play and damper-knee coefficients moved by 0-1.1 % up to 0.033 % flat (the weakly
determined play of the 1 mm road by 8 % at 0.056 %, inside its own per-line
scatter of 38 %), by 0.5-20 % at 0.17-0.76 % flat, and by 34-74 % at 4.0-4.4 %
(the issue's ±2σ spindle, which flipped the knee's sign in ``nifo identify``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Clipping", "ClippingWarning", "clipping", "REFUSE_FRACTION", "MIN_RUN"]

#: above this fraction of its samples flat at its extremes a channel's record is refused (measured, module
#: docstring); any flat run below it is named in a :class:`ClippingWarning`
REFUSE_FRACTION = 1e-3
#: consecutive samples at the extreme that make a flat run
MIN_RUN = 3
#: "at the extreme": within this fraction of the channel's range of it
_TOL = 1e-9


class ClippingWarning(UserWarning):
    """A channel that clipped a little: named, the record used."""


@dataclass(frozen=True)
class Clipping:
    """Flat runs at the extremes of one channel: samples in runs at its maximum and at its minimum, of ``n``."""

    n: int
    high: float
    n_high: int
    low: float
    n_low: int

    @property
    def fraction(self) -> float:
        """Fraction of the samples held flat at either extreme."""
        return (self.n_high + self.n_low) / self.n if self.n else 0.0

    def merge(self, other: "Clipping") -> "Clipping":
        """The clipping of two chunks of one channel together."""
        if self.n == 0:
            return other
        if other.n == 0:
            return self
        span = max(self.high, other.high) - min(self.low, other.low)
        tol = _TOL * span

        def side(a, na, b, nb, top: bool):
            if abs(a - b) <= tol:
                return (max(a, b) if top else min(a, b)), na + nb
            return (a, na) if (a > b) == top else (b, nb)

        high, n_high = side(self.high, self.n_high, other.high, other.n_high, True)
        low, n_low = side(self.low, self.n_low, other.low, other.n_low, False)
        return Clipping(self.n + other.n, high, n_high, low, n_low)

    def to_dict(self) -> dict:
        return {"fraction": self.fraction, "n_samples": self.n, "high": self.high, "n_high": self.n_high,
                "low": self.low, "n_low": self.n_low}


def _in_runs(x: np.ndarray, mask: np.ndarray, rail: float, min_run: int, step: float) -> int:
    """Samples of ``mask`` (``x`` at ``rail``) in runs of at least ``min_run`` consecutive samples that are entered
    or left by a jump larger than ``step``."""
    if not mask.any():
        return 0
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.view(np.int8), [0]))))
    starts, stops = edges[::2], edges[1::2]
    long = stops - starts >= min_run
    starts, stops = starts[long], stops[long]
    n = x.size
    into = np.where(starts > 0, np.abs(rail - x[np.maximum(starts - 1, 0)]), 0.0)
    out = np.where(stops < n, np.abs(rail - x[np.minimum(stops, n - 1)]), 0.0)
    steep = np.maximum(into, out) > step
    return int((stops - starts)[steep].sum())


def clipping(x: np.ndarray, *, min_run: int = MIN_RUN) -> Clipping:
    """Flat runs at the extremes of signal ``x`` (module docstring)."""
    x = np.asarray(x, dtype=np.float64)
    n = int(x.size)
    if n == 0:
        return Clipping(0, 0.0, 0, 0.0, 0)
    hi, lo = float(np.max(x)), float(np.min(x))
    if not hi > lo:       # a constant channel is not clipped: it is dead (other checks name it)
        return Clipping(n, hi, 0, lo, 0)
    tol = _TOL * (hi - lo)
    # a quantised signal's smooth peak is entered by one step of the converter; a rail by a jump (the signal
    # went on beyond it): half the typical sample-to-sample change tells the two apart
    step = 0.5 * float(np.median(np.abs(np.diff(x)))) if n > 1 else 0.0
    return Clipping(n, hi, _in_runs(x, x >= hi - tol, hi, min_run, step),
                    lo, _in_runs(x, x <= lo + tol, lo, min_run, step))
