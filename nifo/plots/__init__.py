"""Figures (matplotlib, Agg backend). matplotlib is imported only inside this package.

One module per family of figures (``restoring``: restoring-force slices,
nonlinear characteristics, candidate ranking). Figures are written, never shown.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["pyplot", "save_figure"]


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path, *, dpi: int = 130) -> Path:
    """Write ``fig`` as PNG at ``path`` and close it."""
    plt = pyplot()
    p = Path(path)
    fig.savefig(p, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return p
