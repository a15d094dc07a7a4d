"""Figures of ``nifo identify`` and ``nifo predict``, in the style of the paper's Figs. 9-14.

- :func:`plot_transmissibility`: measured spindle→body transmissibility
  magnitude(s) and the NIFO estimate of the nominal linear T21, log scale
  (paper Fig. 9b/12b); also used by ``predict`` for predicted vs measured.
- :func:`plot_coefficients`: real and imaginary parts of μ_i(ω)/K2, per line
  (paper Eq. 9, with its shaded 95 % random-error band) and from the pooled
  constant-coefficient fit (Fig. 10/13).
- :func:`plot_conditioning`: coherences and the scaled condition number of G_UU.
- :func:`plot_tire`: tire-patch→spindle H11·(K1 + jωC1), nominal vs measured (Fig. 11/14).
- :func:`plot_time_excerpt`: measured vs predicted body acceleration.

Every function writes one PNG and returns its path.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from nifo_core.nifo.identify import NifoResult

from . import pyplot, save_figure

__all__ = ["Curve", "plot_transmissibility", "plot_coefficients", "plot_conditioning", "plot_tire",
           "plot_time_excerpt"]

#: a curve: (label, frequency [Hz], complex or real values, matplotlib style keywords)
Curve = tuple[str, np.ndarray, np.ndarray, dict]


def _band(ax, band_hz, label: str | None = None) -> None:
    ax.axvspan(band_hz[0], band_hz[1], color="0.93", zorder=0, label=label)


def _freq_axis(ax) -> None:
    """Plain-number frequency ticks on a log axis (no overlapping minor labels)."""
    from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter

    lo, hi = ax.get_xlim()
    ticks = [t for t in (0.5, 1, 2, 3, 5, 7, 10, 15, 20, 30, 50, 70, 100, 150, 200) if lo <= t <= hi]
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())


def _view(f: np.ndarray, band_hz: tuple[float, float], pad: float = 0.6) -> np.ndarray:
    """Lines to show: the analysis band widened by ``pad`` of itself on a log axis."""
    lo, hi = band_hz
    return (f >= lo * (1 - pad / 2)) & (f <= hi * (1 + pad)) & (f > 0)


def plot_transmissibility(path: str | Path, curves: Sequence[Curve], *, band_hz: tuple[float, float],
                          title: str, ylabel: str = "|T21| = |X2/X1| [–]", phase: bool = True,
                          vector: bool = True) -> Path:
    """Magnitude (log-log) and optionally phase of complex transmissibilities.

    A curve whose style holds ``random_error`` (the normalized random error ε per line, same shape
    as its values) is drawn with its 95 % band shaded: |H|·(1 ∓ k·ε) and phase ± k·ε rad, k the
    style's ``bound_k`` (the fit's Student-t factor, :meth:`~nifo_core.nifo.identify.NifoResult.bound_factor`;
    1.96 when not given: ε of many degrees of freedom).
    """
    plt = pyplot()
    fig, axes = plt.subplots(2 if phase else 1, 1, figsize=(7.5, 6.2 if phase else 4.2), sharex=True,
                             squeeze=False, gridspec_kw={"height_ratios": [2.2, 1]} if phase else None)
    ax = axes[0, 0]
    for label, f, h, style in curves:
        style = dict(style)
        eps = style.pop("random_error", None)
        band_label = style.pop("band_label", "95 % bound (random error)")
        k = float(style.pop("bound_k", 1.96))
        m = _view(f, band_hz)
        line, = ax.loglog(f[m], np.abs(h[m]), label=label, **style)
        if eps is not None:   # 95 %: |H|(1 ∓ kε), phase ± kε rad (Bendat & Piersol)
            e = k * np.asarray(eps, float)[m]
            mag = np.abs(h[m])
            ax.fill_between(f[m], mag * np.where(e < 1, 1 - e, np.nan), mag * (1 + e), color=line.get_color(), alpha=0.22,
                            lw=0, label=band_label)
        if phase:
            ph = np.degrees(np.angle(h[m]))
            axes[1, 0].semilogx(f[m], ph, **style)
            if eps is not None:
                axes[1, 0].fill_between(f[m], ph - np.degrees(e), ph + np.degrees(e), color=line.get_color(),
                                        alpha=0.22, lw=0)
    _band(ax, band_hz, "analysis band")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    if phase:
        _band(axes[1, 0], band_hz)
        axes[1, 0].set_ylabel("phase [°]")
        axes[1, 0].grid(True, which="both", alpha=0.3)
    axes[-1, 0].set_xlabel("frequency [Hz]")
    for a in axes[:, 0]:
        _freq_axis(a)
    return save_figure(fig, path, vector=vector)


#: unit of g_i (the describing function's output) from the unit of its coefficient c_i (force per unit of g_i)
_G_UNIT = {"N/m": "m", "N/m³": "m³", "N·s/m": "m/s", "N·s²/m²": "m²/s²", "N": ""}
#: unit of μ_i/K2 = B_i/T21 [m of x2 per unit of g_i] (paper Eq. 8), by the unit of g_i
_MU_UNIT = {"m": "m/m", "m³": "1/m²", "m/s": "s", "m²/s²": "s²/m", "": "m"}


def mu_unit(term) -> str:
    """Unit of μ_i/K2 for ``term`` (mathtext): X2 [m] = B_i·G_i, B_i = (μ_i/K2)·T21 with T21 [m/m]."""
    g = _G_UNIT.get(getattr(term.spec, "coef_unit", None), None)
    return _MU_UNIT.get(g, "m per unit of g") if g is not None else "m per unit of g"


def plot_coefficients(path: str | Path, result: NifoResult, *, title: str = "") -> Path:
    """Re and Im of μ_i(ω)/K2 (paper Fig. 10/13): per line (Eq. 9) and the pooled static fit, with units."""
    plt = pyplot()
    nt = len(result.terms)
    fig, axes = plt.subplots(max(nt, 1), 2, figsize=(10, 2.8 * max(nt, 1) + 0.8), squeeze=False, sharex=True,
                             layout="constrained")
    f = result.freq_hz
    m = _view(f, result.analysis_band_hz, pad=0.2)
    for i, term in enumerate(result.terms):
        for j, (part, name) in enumerate(((np.real, "Re"), (np.imag, "Im"))):
            ax = axes[i, j]
            _band(ax, result.analysis_band_hz)
            if not result.fixed[i]:
                mu = result.mu_over_k2[i][m]
                ax.semilogx(f[m], part(mu), color="C0", lw=1.0, label="per line (Eq. 9)")
                hw = result.bound_factor() * np.abs(mu) * _mu_error(result, i)[m]
                ax.fill_between(f[m], part(mu) - hw, part(mu) + hw, color="C0", alpha=0.2, lw=0,
                                label="95 % bound per line (random error)")
            ax.semilogx(f[m], part(result.static.mu_over_k2[i][m]), color="C3", lw=1.4, ls="--",
                        label="pooled constant c/M2" + (" (held fixed)" if result.fixed[i] else ""))
            ax.axhline(0, color="0.5", lw=0.6)
            ax.set_ylabel(rf"$\mathrm{{{name}}}\,\mu_{{{i + 1}}}/K_2$ [{mu_unit(term)}]")
            ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 4), useMathText=True)
            ax.set_title(f"{term.label}: {'real' if name == 'Re' else 'imaginary'} part", fontsize=9)
            ax.grid(True, which="both", alpha=0.3)
            _robust_ylim(ax, part(result.mu_over_k2[i][result.in_band]), part(result.static.mu_over_k2[i][m]))
            if i == 0 and j == 0:
                ax.legend(fontsize=8)
    if nt == 0:
        axes[0, 0].text(0.5, 0.5, "no nonlinear terms declared", ha="center", transform=axes[0, 0].transAxes)
    for ax in axes[-1]:
        ax.set_xlabel("frequency [Hz]")
    for ax in axes.ravel():
        _freq_axis(ax)
    fig.suptitle(title or r"coefficient functions $\mu_i(\omega)/K_2$ (paper Eq. 8-9)", fontsize=10)
    return save_figure(fig, path)


def _mu_error(result: NifoResult, i: int) -> np.ndarray:
    """Normalized random error of μ_i/K2 = B_i/T21 per line: sqrt(ε_B² + ε_T²) (first order, the two
    errors' correlation neglected); NaN where unknown."""
    eb, et = np.asarray(result.random_error[1 + i], float), np.asarray(result.random_error[0], float)
    return np.sqrt(eb ** 2 + et ** 2)


def _robust_ylim(ax, *series) -> None:
    """Limits from the 2nd-98th percentiles: single lines near a zero of T21 should not squash the plot."""
    vals = np.concatenate([np.asarray(s, float).ravel() for s in series])
    vals = vals[np.isfinite(vals)]
    if vals.size < 3:
        return
    lo, hi = np.percentile(vals, [2, 98])
    span = max(hi - lo, 1e-12 * max(abs(lo), abs(hi), 1e-300))
    ax.set_ylim(min(lo - 0.25 * span, 0), max(hi + 0.25 * span, 0))


def plot_conditioning(path: str | Path, result: NifoResult, *, cond_limit: float, title: str = "") -> Path:
    """Ordinary (plain H1), multiple and partial coherences, and scaled cond(G_UU) per line."""
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7.5, 6), sharex=True)
    f = result.freq_hz
    m = _view(f, result.analysis_band_hz)
    _band(a1, result.analysis_band_hz)
    a1.semilogx(f[m], result.coherence_h1[m], color="k", lw=1.0, label="ordinary γ² (a1→a2)")
    a1.semilogx(f[m], result.multiple_coherence[m], color="C0", lw=1.0, label="multiple γ² (NIFO fit)")
    a1.semilogx(f[m], result.static.coherence[m], color="C3", lw=1.0, ls="--", label="γ² of the static form")
    for i, term in enumerate(result.terms):
        if not result.fixed[i]:
            a1.semilogx(f[m], result.partial_coherence[1 + i][m], lw=0.8, color=f"C{4 + i}",
                        label=f"partial γ² {term.label}")
    a1.set_ylim(0, 1.05)
    a1.set_ylabel("coherence γ² [–]")
    a1.grid(True, which="both", alpha=0.3)
    a1.legend(fontsize=7, loc="lower left")
    _band(a2, result.analysis_band_hz)
    a2.loglog(f[m], result.cond[m], color="C2", lw=1.0, label="scaled cond(G_UU)")
    a2.axhline(cond_limit, color="C3", ls=":", label=f"limit {cond_limit:.3g}")
    a2.set_ylabel("scaled cond(G_UU) [–]")
    a2.set_xlabel("frequency [Hz]")
    a2.grid(True, which="both", alpha=0.3)
    a2.legend(fontsize=8)
    _freq_axis(a1)
    _freq_axis(a2)
    fig.suptitle(title or "coherence and conditioning", fontsize=10)
    return save_figure(fig, path)


def plot_tire(path: str | Path, result: NifoResult) -> Path:
    """Tire-patch→spindle H11·(K1 + jωC1): nominal (Eq. 10 row 1 and mass sum) vs measured H1 (Fig. 11/14)."""
    im = result.input_measured
    f = result.freq_hz
    curves: list[Curve] = [("measured H1 xb→x1 (test level)", f, im.t1b_h1, {"color": "k", "lw": 1.0}),
                           ("NIFO Eq. 10 per line", f, im.t1b, {"color": "C0", "lw": 0.8, "alpha": 0.7})]
    if im.t1b_nominal is not None:
        curves.append(("nominal (mass sum + NIFO T21)", f, im.t1b_nominal, {"color": "C3", "lw": 1.4, "ls": "--"}))
    return plot_transmissibility(path, curves, band_hz=result.analysis_band_hz, ylabel="|X1/Xb| [–]",
                                 title="tire patch → spindle: H11·(K1 + jωC1), nominal vs measured")


def plot_time_excerpt(path: str | Path, t_s: np.ndarray, traces: Sequence[tuple[str, np.ndarray, dict]], *,
                      title: str, ylabel: str = "body acceleration [m/s²]") -> Path:
    """A few seconds of measured and predicted signals."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 3.6))
    for label, y, style in traces:
        ax.plot(t_s, y, label=label, **style)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    return save_figure(fig, path)
