"""Figures (matplotlib, Agg backend). matplotlib is imported only inside this package.

One module per family of figures (``restoring``: restoring-force slices,
nonlinear characteristics, candidate ranking). Figures are written, never shown:
a PNG (for the report and quick looks) and the same figure as SVG beside it
(vector, for papers and slides).
"""

from __future__ import annotations

import threading
from pathlib import Path

from nifo.io.atomic import claim

__all__ = ["pyplot", "save_figure", "VECTOR_SUFFIXES", "DRAWING"]

#: held while a thread builds or renders figures: matplotlib (pyplot's state, the mathtext parser) is not
#: thread-safe, so steps that run side by side on threads (``nifo run``'s two levels) draw one at a time
DRAWING = threading.RLock()


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from nifo.plots.mathtext_cache import install

    install()      # math text parsed once per process, not once per renderer
    return plt


#: vector formats written beside every PNG
VECTOR_SUFFIXES = (".svg",)


def save_figure(fig, path: str | Path, *, dpi: int = 130, tight_rect: tuple | None = None, vector: bool = True) -> Path:
    """Write ``fig`` as PNG at ``path`` and (``vector``) as SVG beside it (same stem), close it; the PNG's path.

    ``tight_rect``: lay the figure out tightly within that (left, bottom, right, top) box of the figure just
    before it is rendered (``Figure.tight_layout``): text extents are most of a figure's cost, and measured
    where the figure is rendered they cost the step nothing inside a batch. Inside
    :func:`nifo.plots.writer.figure_batch` the files are rendered by helper processes and are complete when the
    batch ends; elsewhere, here and now."""
    from nifo.plots.writer import figure_paths, submit_figure, write_files

    p = Path(path)
    for target in figure_paths(p, vector):   # inside nifo run's folder: listed in its marker before they are written
        claim(target)
    if submit_figure(fig, p, dpi, tight_rect, vector=vector):
        return p
    try:
        write_files(fig, p, dpi, tight_rect, vector=vector)
    finally:
        pyplot().close(fig)
    return p
