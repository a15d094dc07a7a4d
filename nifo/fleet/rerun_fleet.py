"""The fleet as a Rerun recording (``fleet.rrd``): one entity per vehicle.

Entity tree (all static: a fleet result has no time axis)
----------------------------------------------------------
====================================================  =======================================================
``fleet/<vehicle>/<corner>/t21/magnitude_db``          |T21| [dB] vs frequency [Hz] (bar chart, pooled NIFO T21)
``fleet/<vehicle>/<corner>/t21/phase_deg``             phase [°] vs frequency [Hz]
``fleet/<vehicle>/<corner>/summary``                   markdown: coefficients, 95 % intervals, robust z, flags, data used
``fleet_coefficients/<name>``                          one bar per group (x: group index), every coefficient
``summary``                                            markdown: the fleet, the flags, the groups' index
====================================================  =======================================================

Flagged groups are drawn red, the others blue.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nifo.fleet.runner import FleetRun

__all__ = ["save_fleet_recording", "APP_ID"]

APP_ID = "nifo_fleet"
_RED, _BLUE = (192, 57, 43), (31, 78, 121)


def _group_markdown(g, r) -> str:
    h = r.health
    lines = [f"## {g[0]} / {g[1]}", "", f"{len(r.bags)} bags, {r.duration_s:.0f} s, {r.n_avg} averages; "
             + ("**FLAGGED**" if h.flagged else ("not flagged" if h.assessed else f"not assessed: {h.reason}")), "",
             "| coefficient | value | ± (95 %) | unit | robust z |", "|---|---|---|---|---|"]
    z = {c.name: c.z for c in h.coefficients}
    for n, c in r.coefficients.items():
        lines.append(f"| {n} | {c.value:.5g} | {(c.hi - c.lo) / 2:.2g} | {c.unit} | {z.get(n, float('nan')):+.2f} |")
    lines += ["", *[f"- {t}" for t in h.evidence]]
    return "\n".join(lines)


def save_fleet_recording(path: Path, run: FleetRun) -> Path:
    """Write ``path`` (``.rrd``); the caller stages it (atomic output directory)."""
    import rerun as rr

    from nifo.viz.rerun_log import entity_name

    rec = rr.RecordingStream(APP_ID)
    rec.save(str(path))
    ok = [(g, r) for g, r in run.groups.items() if r.ok]
    for g, r in ok:
        base = f"fleet/{entity_name(g[0])}/{entity_name(g[1])}"
        col = _RED if r.health.flagged else _BLUE
        f = np.asarray(r.curves.freq_hz, float)
        t = np.asarray(r.curves.t21, complex)
        m = (f > 0) & np.isfinite(t)
        df = float(np.median(np.diff(f))) if f.size > 1 else 1.0
        w = np.full(int(m.sum()), df, np.float32)
        with np.errstate(divide="ignore"):
            db = 20 * np.log10(np.abs(t[m]))
        rec.log(f"{base}/t21/magnitude_db", rr.BarChart(db, abscissa=f[m], widths=w, color=col), static=True)
        rec.log(f"{base}/t21/phase_deg", rr.BarChart(np.degrees(np.angle(t[m])), abscissa=f[m], widths=w,
                                                      color=col), static=True)
        rec.log(f"{base}/summary", rr.TextDocument(_group_markdown(g, r), media_type=rr.MediaType.MARKDOWN),
                static=True)
    names = list(dict.fromkeys(n for _, r in ok for n in r.coefficients))
    for n in names:
        vals = np.array([r.coefficients[n].value if n in r.coefficients else np.nan for _, r in ok], float)
        rec.log(f"fleet_coefficients/{entity_name(n)}",
                rr.BarChart(np.nan_to_num(vals), abscissa=np.arange(len(ok), dtype=float)), static=True)
    index = "\n".join(f"{i}. {g[0]}/{g[1]}" + (" — **FLAGGED**" if r.health.flagged else "")
                      for i, (g, r) in enumerate(ok))
    rec.log("summary", rr.TextDocument(f"# Fleet\n\n{len(run.groups)} groups, {len(run.bags)} bags, "
                                       f"{run.n_failed} failed.\n\nGroup index (x of fleet_coefficients):\n\n"
                                       f"{index}\n", media_type=rr.MediaType.MARKDOWN), static=True)
    rec.flush()
    rec.disconnect()
    return path
