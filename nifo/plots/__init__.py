"""Figures (matplotlib, Agg backend). matplotlib is imported only inside this package.

One module per family of figures (``restoring``: restoring-force slices,
nonlinear characteristics, candidate ranking). Figures are written, never shown:
a PNG (for the report and quick looks) and the same figure as SVG beside it
(vector, for papers and slides).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["pyplot", "save_figure", "VECTOR_SUFFIXES"]


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


#: vector formats written beside every PNG
VECTOR_SUFFIXES = (".svg",)


def save_figure(fig, path: str | Path, *, dpi: int = 130) -> Path:
    """Write ``fig`` as PNG at ``path`` and as SVG beside it (same stem), close it; the PNG's path."""
    import matplotlib

    plt = pyplot()
    p = Path(path)
    try:
        fig.savefig(p, dpi=dpi, bbox_inches="tight")
        # text stays text in the SVG (editable, searchable); dense point clouds are rasterized inside
        with matplotlib.rc_context({"svg.fonttype": "none"}):
            for suffix in VECTOR_SUFFIXES:
                fig.savefig(p.with_suffix(suffix), dpi=dpi, bbox_inches="tight", metadata={"Date": None})
    finally:
        plt.close(fig)
    return p
