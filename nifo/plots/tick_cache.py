"""Each axis's ticks placed once per drawing of a figure, not once per question about them (figures' rendering).

Why: matplotlib places an axis's ticks (locator, formatter, each tick's position and label text) in
``Axis._update_ticks``, and asks for them again and again in one drawing of a figure: when the axis is drawn,
when its label is placed beside the tick labels, when the title is placed above them, and again for every
artist when the tight box is measured. On the sample's 25 figures that is about 12 placements per axis per
figure. Inside :func:`placed_once` (a drawing, then the tight box measured on it: :func:`nifo.plots.writer.
_png_and_box`) an axis's ticks are placed at the first question and the same ticks answer the others: nothing
moves an axis's limits or its tick values between them (the layout is done before, the limits unstaled at the
first question). Measured on the sample's 25 figures rendered from the same pickles (``benchmarks/bench_figures.py
--ticks``, beside other work): 12.98 -> 12.24 CPU-s (0.94); every PNG and SVG the same bytes, rendered in a fresh
process both ways (``tests/test_figure_cost.py`` counts the placements).

How: matplotlib's method is wrapped, once per process, by one that looks for a cache of the current thread's
:func:`placed_once` block and otherwise calls matplotlib's own; installed only where the method has the
signature it was measured on (matplotlib 3.11.2: ``_update_ticks(self)``), elsewhere nothing changes.
"""

from __future__ import annotations

import contextlib
import inspect
import threading
from typing import Iterator

__all__ = ["install", "placed_once"]

_lock = threading.Lock()
_local = threading.local()
_installed: bool | None = None       # None: not tried yet; False: matplotlib's method is not the one measured


def install() -> bool:
    """Wrap ``Axis._update_ticks`` (idempotent); False where it is not the method measured (nothing changed)."""
    global _installed
    with _lock:
        if _installed is not None:
            return _installed
        from matplotlib.axis import Axis

        own = getattr(Axis, "_update_ticks", None)
        try:
            ok = own is not None and tuple(inspect.signature(own).parameters) == ("self",)
        except (TypeError, ValueError):
            ok = False
        if ok:
            def _update_ticks(self):
                placed = getattr(_local, "placed", None)
                if placed is None:
                    return own(self)
                key = id(self)
                if key not in placed:
                    placed[key] = (self, own(self))     # the axis kept alive with its ticks: its id stays its own
                return placed[key][1]

            _update_ticks.__wrapped__ = own
            Axis._update_ticks = _update_ticks
        _installed = ok
        return ok


@contextlib.contextmanager
def placed_once() -> Iterator[None]:
    """Inside, on this thread, each axis's ticks are placed at the first question and reused (module docstring);
    only where nothing changes an axis's limits, size or formatter inside."""
    if not install():
        yield
        return
    outer = getattr(_local, "placed", None)
    _local.placed = {} if outer is None else outer
    try:
        yield
    finally:
        _local.placed = outer
