"""Figures of ``nifo loop``: the residual against each added effect's variable, and the errors per round.

Every function takes the plain ``loop.json`` dictionaries (:meth:`nifo_core.loop.results.LoopResult.to_dict`)
and writes one PNG. Residuals are per unit sprung mass (m/s² = N/kg), in newtons when M2 is known.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from . import pyplot, save_figure

__all__ = ["plot_round_evidence", "plot_errors"]

_BEFORE = "#c0392b"
_AFTER = "#1f4e79"
_EFFECT = "#2e8b57"


def plot_round_evidence(rnd: Mapping, path: str | Path, *, m2_kg: float | None = None, units: str = "m/s²") -> Path:
    """Mean equation residual against the added effect's variable, before and after adding it.

    Before: the residual bends the way the missing effect does; after: flat
    (what the added term explains, binned, drawn for reference).
    """
    plt = pyplot()
    ev, add = rnd["evidence"], rnd["added"]
    si = units == "m/s²"
    scale = m2_kg if m2_kg and si else 1.0
    unit = ("N" if m2_kg else "m/s² (N/kg)") if si else units
    x = np.asarray(ev["bins"], float)
    if ev["variable"] == "z":
        x, xl = (1e3 * x, "relative displacement z [mm]") if si else (x, f"relative displacement z [{units}·s²]")
    else:
        xl = "relative velocity ż [m/s]" if si else f"relative velocity ż [{units}·s]"
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    ax.axhline(0, color="0.6", lw=0.8)
    ax.plot(x, scale * np.asarray(ev["residual_before"], float), "o-", color=_BEFORE, ms=3.5,
            label="residual before (declared model)")
    ax.plot(x, scale * np.asarray(ev["effect"], float), "--", color=_EFFECT, lw=1.4,
            label=f"explained by adding {add['label']}")
    ax.plot(x, scale * np.asarray(ev["residual_after"], float), "s-", color=_AFTER, ms=3.0,
            label="residual after adding it")
    ax.set_xlabel(xl)
    ax.set_ylabel(f"mean equation residual [{unit}]")
    ax.set_title(f"round {rnd['round']}: {add['meaning']}\nERR {100 * add['err']:.0f} %, "
                 f"p {add['p_value']:.2g}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return save_figure(fig, path)


def plot_errors(doc: Mapping, path: str | Path) -> Path:
    """Held-out errors of the declared model and after each round: one linear axis per metric.

    Left: held-out NMSE of the output predicted from the input (when a prediction was made);
    middle: the held-out equation error (force balance); right: the residual per band [dB].
    Each bar carries its value, so no legend covers a bar and no metric needs a log axis.
    """
    plt = pyplot()
    stages: list[tuple[str, Mapping]] = [("declared", doc["errors_before"])]
    for r in doc["rounds"]:
        if r.get("added"):
            stages.append((f"+ {r['added']['kind']}", r["after"]))
    names = [s for s, _ in stages]
    pred = [e.get("prediction_nmse_pct") for _, e in stages]
    metrics = [("equation error (force balance)", [e["equation_nmse_pct"] for _, e in stages], _EFFECT)]
    if all(p is not None for p in pred):
        metrics.insert(0, ("prediction of the output", pred, _AFTER))
    fig, axes = plt.subplots(1, len(metrics) + 1, figsize=(4.0 * (len(metrics) + 1), 3.9), layout="constrained",
                             gridspec_kw={"width_ratios": [1] * len(metrics) + [1.4]})
    x = np.arange(len(stages))
    for ax, (what, vals, colour) in zip(axes, metrics):
        bars = ax.bar(x, vals, 0.55, color=colour)
        ax.set_xlim(-0.5 - 0.4 / len(stages), len(stages) - 0.5 + 0.4 / len(stages))
        ax.bar_label(bars, labels=[f"{v:.3g}" for v in vals], fontsize=7.5, padding=2)
        ax.set_xticks(x, names, rotation=20, ha="right", fontsize=8)
        ax.set_ylabel("held-out NMSE [%]")
        ax.set_title(what, fontsize=9)
        ax.set_ylim(0, 1.18 * max(max(vals), 1e-12))
        ax.grid(alpha=0.3, axis="y")
    a2 = axes[-1]
    bands = list(stages[0][1]["band_residual_db"])
    for name, e in stages:
        a2.plot(bands, [e["band_residual_db"][b] for b in bands], "o-", label=name)
    a2.set_xlabel("band [Hz]")
    a2.set_ylabel(r"residual $10\,\log_{10}(G_{ee}/G_{yy})$ [dB]")
    a2.set_title("residual per band, held out", fontsize=9)
    a2.tick_params(axis="x", labelsize=8)
    a2.grid(alpha=0.3)
    a2.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=min(len(stages), 3), frameon=False)
    fig.suptitle("errors on held-out data, before and after each added effect", fontsize=10)
    return save_figure(fig, path)


def figure_names(doc: Mapping) -> Sequence[str]:  # pragma: no cover - helper for callers
    return ["loop_errors.png"] + [f"loop_round{r['round']}.png" for r in doc["rounds"] if r.get("added")]
