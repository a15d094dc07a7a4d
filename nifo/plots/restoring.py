"""Restoring-force figures: slice grids (paper Figs. 3, 4, 7), nonlinear characteristics, candidate ranking.

Every function takes plain arrays or core results and writes one PNG.
Forces are per unit sprung mass (-ẍ2 [m/s²]) unless ``m2_kg`` is given, then
in newtons (-M2·ẍ2). Signals in other units (``units="V"``: an electrical
analogue) are labelled in those units: force [V], z [V·s²], ż [V·s].
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from . import pyplot, save_figure

__all__ = ["SlicePlot", "CharacteristicPlot", "plot_restoring_slices", "plot_characteristics", "plot_ranking",
           "term_label"]

_MEASURED = "#1f4e79"
_MODEL = "#c0392b"
_UP = "#1f77b4"
_DOWN = "#e67e22"
_STATUS_COLOURS = {"suggested": "#2e8b57", "alternative": "#e1a13a", "redundant": "#c8b27a",
                   "unselected": "#5b8bd0", "weak": "#b8b8b8"}


@dataclass(frozen=True)
class SlicePlot:
    """One row of a slice grid: a frequency window, an amplitude bin or a record.

    ``z`` [m], ``zdot`` [m/s], ``force`` and ``model`` [m/s² per unit mass];
    ``connected``: consecutive samples of a sweep (drawn as a line) or
    scattered samples (drawn as dots).
    """

    label: str
    z: np.ndarray
    zdot: np.ndarray
    force: np.ndarray
    model: np.ndarray | None = None
    connected: bool = True
    note: str = ""


@dataclass(frozen=True)
class CharacteristicPlot:
    """A stiffness (z) or damping (ż) characteristic: the force of one variable against it.

    ``measured``: -ẍ2 minus everything fitted that is not of this variable and
    term (the other variable's linear part, the other terms); ``fitted``: this
    variable's linear part plus θ·g (band-passed like the data);
    ``reference``: the plain linear fit's part (what a linear strut would
    give); ``truth``: the true part of this variable (simulated data, from the
    truth file). ``x`` is z [m] or ż [m/s] (``variable``); ``split`` (e.g. ż for
    a z-term) separates loading from unloading so hysteresis shows.
    """

    title: str
    variable: str
    x: np.ndarray
    measured: np.ndarray
    fitted: np.ndarray
    split: np.ndarray | None = None
    reference: np.ndarray | None = None
    truth: np.ndarray | None = None


SI = "m/s²"


def _force_scale(m2_kg: float | None, units: str = SI) -> tuple[float, str]:
    if units != SI:
        return 1.0, f"−ẍ2 [{units}]"
    return (m2_kg, "force −M2·ẍ2 [N]") if m2_kg else (1.0, "−ẍ2 [m/s²]")


def _xscale(variable: str, peak: float, units: str = SI) -> tuple[float, str]:
    """Scale and axis label of z or ż: mm/µm and m/s or mm/s for m/s², else the integrated unit."""
    if units != SI:
        return 1.0, (f"z [{units}·s²]" if variable == "z" else f"ż [{units}·s]")
    return _z_scale(peak) if variable == "z" else _v_scale(peak)


def _z_scale(z_peak: float) -> tuple[float, str]:
    return (1e6, "z [µm]") if z_peak < 1e-4 else (1e3, "z [mm]")


def _v_scale(v_peak: float) -> tuple[float, str]:
    return (1e3, "ż [mm/s]") if v_peak < 0.05 else (1.0, "ż [m/s]")


def _thin(n: int, most: int) -> np.ndarray:
    return np.arange(0, n, max(1, int(np.ceil(n / most))))


def plot_restoring_slices(rows: Sequence[SlicePlot], path: str | Path, *, title: str,
                          m2_kg: float | None = None, subtitle: str = "", units: str = SI) -> Path:
    """Grid of restoring-force plots: one row per slice, velocity view left, displacement view right.

    As the paper's Figs. 3 (frequency slices), 4 (amplitude slices) and 7
    (velocity and displacement views). Each panel has its own scales so the
    shape of small and large motions can be compared. ``subtitle`` (e.g. the
    fitted model's terms) goes under the title; the legend says "fitted model".
    """
    plt = pyplot()
    if not rows:
        raise ValueError("no slices to plot")
    fsc, flabel = _force_scale(m2_kg, units)
    zsc, zlabel = _xscale("z", max(float(np.max(np.abs(r.z))) for r in rows), units)
    vsc, vlabel = _xscale("zdot", max(float(np.max(np.abs(r.zdot))) for r in rows), units)
    n = len(rows)
    fig, axes = plt.subplots(n, 2, figsize=(9.0, 2.35 * n + 0.9), squeeze=False)
    letters = "abcdefghijklmnopqrstuvwxyz"
    for i, (row, (av, ad)) in enumerate(zip(rows, axes)):
        if row.connected:
            views = [(av, row.zdot, vsc, _thin(row.z.size, 6000), ""), (ad, row.z, zsc, _thin(row.z.size, 6000), "")]
        else:  # classic slices of scattered data: damping curve at z ≈ 0, stiffness curve at ż ≈ 0
            sz, sv = 0.15 * np.std(row.z), 0.15 * np.std(row.zdot)
            iv, iz = np.nonzero(np.abs(row.z) < sz)[0], np.nonzero(np.abs(row.zdot) < sv)[0]
            views = [(av, row.zdot, vsc, iv[_thin(iv.size, 8000)], f"|z| < {sz * zsc:.2g} {_unit(zlabel)}"),
                     (ad, row.z, zsc, iz[_thin(iz.size, 8000)], f"|ż| < {sv * vsc:.2g} {_unit(vlabel)}")]
        for ax, x_all, sc, idx, cond in views:
            f = row.force[idx] * fsc
            x = x_all[idx]
            if row.connected:
                ax.plot(x * sc, f, color=_MEASURED, lw=0.55, label="measured")
            else:
                ax.plot(x * sc, f, ".", color=_MEASURED, ms=1.6, alpha=0.4, rasterized=True, label="measured")
                ax.text(0.98, 0.95, cond, transform=ax.transAxes, fontsize=7.5, va="top", ha="right", color="0.25",
                        bbox=dict(facecolor="white", edgecolor="none", alpha=0.8, pad=1.5))
            if row.model is not None:
                m = row.model[idx] * fsc
                if row.connected:
                    ax.plot(x * sc, m, color=_MODEL, lw=0.7, alpha=0.85, ls="--", label="fitted model")
                else:
                    peak = float(np.quantile(np.abs(x), 0.995)) if x.size else 1.0
                    xm, med, _, _ = _binned(x, m, np.linspace(-peak, peak, 31))
                    ax.plot(xm * sc, med, color=_MODEL, lw=1.6, label="fitted model")
            ax.axhline(0, color="0.7", lw=0.5, zorder=0)
            ax.axvline(0, color="0.7", lw=0.5, zorder=0)
            ax.grid(True, lw=0.3, alpha=0.5)
            ax.tick_params(labelsize=8)
            lim = np.max(np.abs(f)) if f.size else 1.0
            ax.set_ylim(-1.1 * lim, 1.1 * lim)
        av.set_ylabel(flabel, fontsize=8)
        av.text(0.02, 0.95, f"({letters[i % 26]}) {row.label}", transform=av.transAxes, fontsize=9,
                va="top", ha="left", bbox=dict(facecolor="white", edgecolor="none", alpha=0.8, pad=1.5))
        if row.note:
            ad.text(0.98, 0.05, row.note, transform=ad.transAxes, fontsize=7.5, va="bottom", ha="right",
                    color="0.25", bbox=dict(facecolor="white", edgecolor="none", alpha=0.8, pad=1.5))
        if i == 0:
            av.set_title("velocity view (damping)", fontsize=9)
            ad.set_title("displacement view (stiffness)", fontsize=9)
        if row.model is not None and not any(r.model is not None for r in rows[:i]):
            # scattered slices: the slice's condition is at the top right and the note (z RMS) at the bottom right;
            # the upper left is where a restoring force (positive stiffness) leaves the panel empty
            ad.legend(fontsize=7, loc="upper left" if not row.connected else "upper right", markerscale=6,
                      framealpha=0.8)
    axes[-1, 0].set_xlabel(vlabel, fontsize=8)
    axes[-1, 1].set_xlabel(zlabel, fontsize=8)
    fig.suptitle(title + (f"\n{subtitle}" if subtitle else ""), fontsize=10 if subtitle else 10.5)
    return save_figure(fig, path, tight_rect=(0, 0, 1, 0.965 if not subtitle else 0.955))


def _binned(x: np.ndarray, y: np.ndarray, edges: np.ndarray, min_count: int = 8):
    k = np.digitize(x, edges) - 1
    nb = edges.size - 1
    ok = (k >= 0) & (k < nb)
    mid, med, lo, hi = [], [], [], []
    order = np.argsort(k[ok], kind="stable")
    ks, ys = k[ok][order], y[ok][order]
    bounds = np.searchsorted(ks, np.arange(nb + 1))
    for b in range(nb):
        seg = ys[bounds[b]:bounds[b + 1]]
        if seg.size >= min_count:
            q = np.quantile(seg, [0.25, 0.5, 0.75])
            mid.append(0.5 * (edges[b] + edges[b + 1]))
            lo.append(q[0])
            med.append(q[1])
            hi.append(q[2])
    return np.array(mid), np.array(med), np.array(lo), np.array(hi)


def _unit(label: str) -> str:
    return label[label.index("[") + 1:label.index("]")]


def plot_characteristics(panels: Sequence[CharacteristicPlot], path: str | Path, *, title: str,
                         m2_kg: float | None = None, units: str = SI) -> Path:
    """Stiffness / damping characteristics, one column per term (the paper's classic slices, cleaned).

    Top row: the characteristic; data as binned medians with their
    interquartile band, the fitted characteristic as a line, the plain linear
    fit dotted. Bottom row: the same minus the linear fit, which magnifies
    the nonlinearity's shape. z-terms are split by the sign of ż (loading vs
    unloading) so hysteresis shows as two branches.
    """
    plt = pyplot()
    if not panels:
        raise ValueError("no characteristics to plot")
    fsc, flabel = _force_scale(m2_kg, units)
    n = len(panels)
    fig, axes = plt.subplots(2, n, figsize=(4.4 * n, 6.4), squeeze=False, sharex="col")
    for col, p in enumerate(panels):
        top, bot = axes[0, col], axes[1, col]
        peak = float(np.quantile(np.abs(p.x), 0.995)) or 1.0
        sc, xl = _xscale(p.variable, peak, units)
        edges = np.linspace(-peak, peak, 41)
        ref = p.reference if p.reference is not None else np.zeros_like(p.x)
        groups = [("", np.ones(p.x.size, bool), _MEASURED)]
        if p.split is not None:
            groups = [("ż > 0", p.split > 0, _UP), ("ż < 0", p.split < 0, _DOWN)]
        for ax, sub in ((top, np.zeros_like(ref)), (bot, ref)):
            idx = _thin(p.x.size, 4000)
            ax.plot(p.x[idx] * sc, (p.measured - sub)[idx] * fsc, ".", color="0.78", ms=1, alpha=0.4,
                    rasterized=True)
            for lab, m, colr in groups:
                xm, med, lo, hi = _binned(p.x[m], (p.measured - sub)[m], edges)
                ax.fill_between(xm * sc, lo * fsc, hi * fsc, color=colr, alpha=0.18, lw=0)
                ax.plot(xm * sc, med * fsc, "o", color=colr, ms=2.8, label=f"data {lab}".strip())
                xf, mf, _, _ = _binned(p.x[m], (p.fitted - sub)[m], edges)
                ax.plot(xf * sc, mf * fsc, color=_MODEL if not lab else colr, lw=1.6, alpha=0.9,
                        ls="--" if lab else "-", label=f"fitted {lab}".strip())
            ax.axhline(0, color="0.6", lw=0.5)
            ax.axvline(0, color="0.6", lw=0.5)
            ax.grid(True, lw=0.3, alpha=0.5)
            ax.tick_params(labelsize=7.5)
        if p.reference is not None:
            xr, mr, _, _ = _binned(p.x, p.reference, edges)
            top.plot(xr * sc, mr * fsc, ":", color="0.3", lw=1.2, label="linear fit")
        if p.truth is not None:   # the simulator's strut, band-passed like the data
            for ax, sub in ((top, np.zeros_like(ref)), (bot, ref)):
                xt, mt, _, _ = _binned(p.x, p.truth - sub, edges)
                ax.plot(xt * sc, mt * fsc, "-.", color="k", lw=1.1, label="true (simulator)" if ax is top else None)
        lim = np.quantile(np.abs(p.measured), 0.99) * fsc or 1.0
        top.set_ylim(-1.3 * lim, 1.3 * lim)
        dev = p.fitted - ref
        dlim = max(np.quantile(np.abs(dev), 0.995), 0.5 * np.quantile(np.abs(p.measured - ref), 0.9)) * fsc or 1.0
        bot.set_ylim(-1.6 * dlim, 1.6 * dlim)
        what = "stiffness" if p.variable == "z" else "damping"
        top.set_ylabel(f"{what} part of {flabel}", fontsize=7.5)
        bot.set_ylabel(f"minus the linear fit [{_unit(flabel)}]", fontsize=7.5)
        bot.set_xlabel(xl, fontsize=8)
        top.set_title(p.title, fontsize=8.5)
        top.legend(fontsize=7, loc="upper left", framealpha=0.8)
    fig.suptitle(title, fontsize=10.5)
    return save_figure(fig, path, tight_rect=(0, 0, 1, 0.95))


def term_label(kind: str, params: dict, *, units: str = SI) -> str:
    """``clearance(gap=0.135 mm)``: a describing function with its parameters in units (a parameter is in
    the unit of the variable the term acts on: z in mm, ż in m/s; z in UNIT·s² for other signal units)."""
    from nifo_core.kinds.describing import make_term

    p = {k: v for k, v in params.items() if not (k == "offset" and v == 0)}
    if not p:
        return kind
    try:
        variable = make_term({"kind": kind, "params": params}).variable
    except (ValueError, KeyError, TypeError):
        variable = None

    def text(v) -> str:
        if not isinstance(v, (int, float)) or isinstance(v, bool) or variable is None:
            return str(v)
        if units != SI:
            return f"{v:.3g} {units}·s²" if variable == "z" else f"{v:.3g} {units}·s"
        return f"{1e3 * v:.3g} mm" if variable == "z" else f"{v:.3g} m/s"

    return kind + "(" + ", ".join(f"{k}={text(v)}" for k, v in p.items()) + ")"


def term_words(term, *, units: str = SI) -> str:
    """A term as a test engineer names it, its key parameter in units: "damper knee at 0.030 m/s", "play 0.43 mm"
    (the kind's ``noun`` in the registry; z in mm and ż in m/s, or the system's unit·s² and unit·s)."""
    spec = term.spec
    key = spec.key_param
    if key is None or key not in term.params:
        return spec.noun or term.kind
    v = float(term.params[key])
    if units != SI:
        text = f"{v:.3g} {units}·s²" if term.variable == "z" else f"{v:.3g} {units}·s"
    elif term.variable == "z":
        text = f"{1e3 * v:.2f} mm" if 1e3 * v < 10 else f"{1e3 * v:.1f} mm"
    else:
        text = f"{v:.3f} m/s"
    side = f" ({term.params['side']})" if "side" in term.params else ""
    return f"{spec.noun or term.kind}{spec.joiner}{text}{side}"


def plot_ranking(candidates: Sequence[dict], path: str | Path, *, title: str, min_err: float,
                 units: str = SI) -> Path:
    """Horizontal bars: each kind's error reduction ratio, coloured by its status; the threshold dashed.

    ``candidates`` as in ``Characterization.to_dict()["candidates"]`` (ranked).
    """
    plt = pyplot()
    n = len(candidates)
    fig, ax = plt.subplots(figsize=(10.5, 0.4 * n + 1.5))
    y = np.arange(n)[::-1]
    errs = np.array([max(c["err"], 1e-5) for c in candidates])
    cols = [_STATUS_COLOURS.get(c["status"], "0.6") for c in candidates]
    ax.barh(y, errs, color=cols, height=0.62, edgecolor="0.3", lw=0.4)
    ax.set_xscale("log")
    ax.set_xlim(1e-4, 1.0)
    ax.axvline(min_err, color="k", ls="--", lw=0.9)
    ax.text(min_err, n - 0.45, f" present above {min_err:g}", fontsize=7.5, va="bottom")
    ax.set_yticks(y)
    ax.set_yticklabels([term_label(c["kind"], c["params"], units=units) for c in candidates], fontsize=7.5)
    for yi, c in zip(y, candidates):
        txt = c["status"]
        if c.get("alternative_to"):
            txt += " ≈ " + c["alternative_to"].split("(")[0]
        elif c["status"] == "weak" and c.get("failed"):
            txt += ": " + c["failed"][0].replace("coefficient ", "")[:34]
        ax.text(1.02, yi, txt, transform=ax.get_yaxis_transform(), fontsize=7.5, va="center", ha="left",
                color=_STATUS_COLOURS.get(c["status"], "0.3") if c["status"] != "weak" else "0.45")
    ax.set_xlabel("error reduction ratio ERR: share of the linear fit's residual variance explained [–]",
                  fontsize=8)
    ax.set_ylim(-0.7, n - 0.3 + 0.6)
    ax.grid(True, axis="x", lw=0.3, alpha=0.5, which="both")
    ax.set_title(title, fontsize=10)
    return save_figure(fig, path, tight_rect=(0, 0, 1, 1))
