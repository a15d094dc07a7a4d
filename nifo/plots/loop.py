"""Figures of ``nifo loop``: the residual against each added effect's variable, and the errors per round.

Every function takes the plain ``loop.json`` dictionaries (:meth:`nifo_core.loop.LoopResult.to_dict`)
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


def plot_round_evidence(rnd: Mapping, path: str | Path, *, m2_kg: float | None = None) -> Path:
    """Mean equation residual against the added effect's variable, before and after adding it.

    Before: the residual bends the way the missing effect does; after: flat
    (what the added term explains, binned, drawn for reference).
    """
    plt = pyplot()
    ev, add = rnd["evidence"], rnd["added"]
    scale = m2_kg or 1.0
    unit = "N" if m2_kg else "m/s² (N/kg)"
    x = np.asarray(ev["bins"], float)
    if ev["variable"] == "z":
        x, xl = 1e3 * x, "relative displacement z [mm]"
    else:
        xl = "relative velocity ż [m/s]"
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    ax.axhline(0, color="0.6", lw=0.8)
    ax.plot(x, scale * np.asarray(ev["residual_before"], float), "o-", color=_BEFORE, ms=3.5,
            label="residual before (declared model)")
    ax.plot(x, scale * np.asarray(ev["effect"], float), "--", color=_EFFECT, lw=1.4,
            label=f"explained by adding {add['label']}")
    ax.plot(x, scale * np.asarray(ev["residual_after"], float), "s-", color=_AFTER, ms=3.0,
            label="residual after adding it")
    ax.set_xlabel(xl)
    ax.set_ylabel(f"mean body-equation residual [{unit}]")
    ax.set_title(f"round {rnd['round']}: {add['meaning']}\nERR {100 * add['err']:.0f} %, "
                 f"p {add['p_value']:.2g}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return save_figure(fig, path)


def plot_errors(doc: Mapping, path: str | Path) -> Path:
    """Held-out NMSE and per-band residual of the declared model and after each round."""
    plt = pyplot()
    stages: list[tuple[str, Mapping]] = [("declared", doc["errors_before"])]
    for r in doc["rounds"]:
        if r.get("added"):
            stages.append((f"+ {r['added']['kind']}", r["after"]))
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.8))
    names = [s for s, _ in stages]
    x = np.arange(len(stages))
    pred = [e.get("prediction_nmse_pct") for _, e in stages]
    eq = [e["equation_nmse_pct"] for _, e in stages]
    w = 0.38
    if all(p is not None for p in pred):
        a1.bar(x - w / 2, pred, w, color=_AFTER, label="prediction (body accel. from spindle)")
    a1.bar(x + w / 2, eq, w, color=_EFFECT, label="equation error (force balance)")
    a1.set_xticks(x, names, rotation=20, fontsize=8)
    a1.set_ylabel("held-out NMSE [%]")
    a1.set_yscale("log")
    a1.legend(fontsize=7)
    a1.grid(alpha=0.3, axis="y")
    bands = list(stages[0][1]["band_residual_db"])
    for i, (name, e) in enumerate(stages):
        a2.plot(bands, [e["band_residual_db"][b] for b in bands], "o-", label=name)
    a2.set_xlabel("band [Hz]")
    a2.set_ylabel("10·log10(G_ee/G_yy) [dB]")
    a2.grid(alpha=0.3)
    a2.legend(fontsize=7)
    fig.suptitle("errors on held-out data, before and after each added effect", fontsize=10)
    return save_figure(fig, path)


def figure_names(doc: Mapping) -> Sequence[str]:  # pragma: no cover - helper for callers
    return ["loop_errors.png"] + [f"loop_round{r['round']}.png" for r in doc["rounds"] if r.get("added")]
