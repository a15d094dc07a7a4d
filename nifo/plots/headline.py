"""The report's headline figure of the prediction: what the final model predicts, against the linear model.

Three panels: a few seconds of one record's output, measured and predicted by both models; then for every record
the whole-signal RMS error (the raw predicted signal over all frequencies, offset included, in the output's unit)
and the band NMSE (over the analysis band), the final model beside the linear model of the same data. A record
outside the range the model was identified on is hatched (never presented as validated).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from . import pyplot, save_figure

__all__ = ["plot_prediction_summary", "RecordErrors"]

#: (name, model, linear, outside the identified range) per record
RecordErrors = tuple[str, float | None, float | None, bool]


def _short(names: Sequence[str]) -> list[str]:
    """Record names without what they all share at the start and the end ("F16Data_FullMSine_Level3.mat" ->
    "Level3"), unless that leaves one empty."""
    names = [str(n) for n in names]
    if len(names) < 2:
        return names
    pre = len(os.path.commonprefix(names))
    suf = len(os.path.commonprefix([n[::-1] for n in names]))
    cut = [n[pre:len(n) - suf] for n in names]
    return cut if all(cut) and pre + suf > 0 else names


def _bars(ax, rows: Sequence[RecordErrors], *, ylabel: str, title: str, log: bool) -> None:
    x = np.arange(len(rows))
    w = 0.38
    for k, (label, color, off) in enumerate((("final model", "C3", -w / 2), ("linear model", "C0", w / 2))):
        vals = np.array([np.nan if r[1 + k] is None else float(r[1 + k]) for r in rows])
        bars = ax.bar(x + off, np.where(np.isfinite(vals), vals, 0), w, color=color, label=label)
        for b, r, v in zip(bars, rows, vals):
            if r[3]:
                b.set_hatch("///")
                b.set_edgecolor("0.25")
            if not np.isfinite(v):
                ax.annotate("not computed", (b.get_x() + b.get_width() / 2, 0), ha="center", va="bottom",
                            fontsize=7, rotation=90)
    ax.set_xticks(x, [n + (" *" if r[3] else "") for n, r in zip(_short([r[0] for r in rows]), rows)], fontsize=8,
                  rotation=20 if len(rows) > 3 else 0)
    if log:
        ax.set_yscale("log")
    ax.set_ylabel(ylabel, fontsize=8.5)
    ax.set_title(title, fontsize=9.5)
    ax.grid(True, axis="y", alpha=0.3, which="both" if log else "major")


def plot_prediction_summary(path: str | Path, *, t_s: np.ndarray, measured: np.ndarray, model: np.ndarray,
                            linear: np.ndarray, record: str, output: str, unit: str,
                            rms: Sequence[RecordErrors], band: Sequence[RecordErrors], band_hz: tuple[float, float],
                            size: tuple[float, float] = (12.0, 3.0), vector: bool = False) -> Path:
    """The three panels of the module docstring as one PNG (a report's embedded figure: no vector file)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=size, gridspec_kw={"width_ratios": [2.2, 1, 1]})
    ax = axes[0]
    ax.plot(t_s, measured, color="k", lw=0.9, label="measured")
    ax.plot(t_s, model, color="C3", lw=0.9, ls="--", label="final model")
    ax.plot(t_s, linear, color="C0", lw=0.8, ls=":", label="linear model")
    ax.set_xlabel("time [s]", fontsize=8.5)
    ax.set_ylabel(f"{output} [{unit}]", fontsize=8.5)
    ax.set_title(f"{record}: {output}, measured and predicted", fontsize=9.5)
    ax.legend(fontsize=7.5, loc="upper right", ncol=3)
    ax.grid(True, alpha=0.3)
    _bars(axes[1], rms, ylabel=f"RMS error [{unit}]", title="whole signal (all frequencies, offset in)", log=False)
    _bars(axes[2], band, ylabel="band NMSE [%]", title=f"band {band_hz[0]:.3g}-{band_hz[1]:.3g} Hz", log=True)
    axes[1].legend(fontsize=7.5, loc="upper left")
    for a in axes:
        a.tick_params(labelsize=8)
    if any(r[3] for r in rms):
        fig.text(0.99, 0.01, "* outside the range the model was identified on (hatched)", ha="right", fontsize=7.5)
    return save_figure(fig, path, tight_rect=(0, 0.03, 1, 1), vector=vector)
