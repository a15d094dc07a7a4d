"""The strut's force law as a figure: force against deflection and against velocity (:class:`nifo.api.ForceLaw`).

Two panels: the total force (solid; a play's two branches of travel alike) with its 95 % bound shaded, the linear
part dashed, each term thin (``terms=True``), the simulator's truth dotted where a truth file exists, and the
measured range: outside it the panel is greyed (the law there is extrapolated).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import pyplot, save_figure

__all__ = ["plot_force_law"]

#: the terms' colours: none of the total's (C3), the linear part's (C0) or the bound's
_TERM_COLORS = ("C2", "C4", "C1", "C5", "C6", "C8", "C9")


def _panel(ax, curve, names, *, xscale: float, xlabel: str, force_unit: str, terms: bool, element: str) -> None:
    x = curve.x * xscale
    if curve.measured is not None:
        lo, hi = (v * xscale for v in curve.measured)
        for a, b in ((x[0], lo), (hi, x[-1])):
            if b > a:
                ax.axvspan(a, b, color="0.88", lw=0, zorder=0)
    for j, br in enumerate(curve.branches):
        first = j == 0
        if curve.bounds is not None:
            hw = curve.bounds[j]
            ax.fill_between(x, br.total - hw, br.total + hw, color="C3", alpha=0.25, lw=0,
                            label="95 % bound (parameters)" if first else None)
        ax.plot(x, br.total, color="C3", lw=1.8, label="identified, total" if first else None)
        if br.linear is not None and first:
            ax.plot(x, br.linear, color="C0", lw=1.2, ls="--", label="linear part")
        if terms:
            for i, name in enumerate(names):
                if np.any(br.terms[i] != 0):
                    ax.plot(x, br.terms[i], color=_TERM_COLORS[i % len(_TERM_COLORS)], lw=0.9, alpha=0.9, label=name if first else None)
    if curve.truth is not None:
        for j, br in enumerate(curve.truth):
            ax.plot(x, br.total, color="k", lw=1.0, ls=":", label="truth (simulator)" if j == 0 else None)
    ax.set_xlim(x[0], x[-1])
    ax.axhline(0, color="0.5", lw=0.5)
    ax.axvline(0, color="0.5", lw=0.5)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"{element} force [{force_unit}]")
    ax.grid(True, alpha=0.3)
    if all(br.linear is None and not np.any(br.terms) for br in curve.branches):
        ax.text(0.5, 0.6, "no term in this variable: its force is in the linear part\n(a transfer function: "
                "linear_part.json of nifo export)", transform=ax.transAxes, ha="center", fontsize=8, color="0.3")


def plot_force_law(path: str | Path, law, *, title: str, terms: bool = False, vector: bool = True,
                   size: tuple[float, float] = (10.0, 3.9), element: str = "strut") -> Path:
    """Force against deflection (left) and velocity (right) of ``law`` (:class:`nifo.api.ForceLaw`) as PNG (and
    SVG with ``vector``)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=size)
    si = law.units["z"] == "m"
    _panel(axes[0], law.deflection, law.term_names, xscale=1e3 if si else 1.0, terms=terms,
           xlabel="deflection z [mm]" if si else f"deflection z [{law.units['z']}]", force_unit=law.units["force"],
           element=element)
    _panel(axes[1], law.velocity, law.term_names, xscale=1.0, terms=terms,
           xlabel=f"velocity ż [{law.units['zdot']}]", force_unit=law.units["force"], element=element)
    axes[0].set_title("stiffness: force against deflection (ż = 0)", fontsize=9.5)
    axes[1].set_title("damping: force against velocity (z = 0)", fontsize=9.5)
    handles, labels = {}, []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in handles:
                handles[lab] = h
                labels.append(lab)
    if law.deflection.measured is not None:
        from matplotlib.patches import Patch   # matplotlib: imported inside the plots package only

        handles["outside the measured range"] = Patch(color="0.88")
        labels.append("outside the measured range")
    ncol = min(len(labels), 5)
    rows = (len(labels) + ncol - 1) // ncol
    fig.legend([handles[k] for k in labels], labels, loc="lower center", ncol=ncol, fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=10.5)
    return save_figure(fig, path, tight_rect=(0, 0.3 / size[1] * rows + 0.02, 1, 1 - 0.3 / size[1]), vector=vector)
