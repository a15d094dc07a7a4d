"""The fleet's tables: one row per group (Parquet via pyarrow, and CSV), one row per bag, and fleet.json.

Group table columns: ``vehicle, corner, status, reason``; data used
(``n_bags, n_bags_failed, n_bags_cached, duration_s, n_avg, fs_hz``); for every
coefficient NAME (see :func:`nifo.fleet.tasks.coefficient_specs`) ``NAME``,
``NAME_lo``, ``NAME_hi`` (95 % interval: Student t over the per-bag
estimates; NaN from one bag), ``NAME_se``, ``NAME_z`` (robust z against the
fleet); ``t21_<f>hz_mag`` with ``_mag_lo/_mag_hi`` (~95 % random-error bounds)
and ``_phase_deg`` at the chosen frequencies; ``coherence_h1_median``,
``cond_median``; ``flagged``, ``flag_evidence``, ``health_note``;
``loop_verdict`` and, with ``--loop``, the loop's held-out scores before and after
(``loop_heldout_band_nmse_before_pct`` … ``loop_heldout_whole_nmse_after_pct``: the band NMSE and the
whole-signal NMSE, the raw predicted output over all frequencies, offset included), ``characterization``;
``warnings``. Units are in ``fleet.json`` (``units``).
"""

from __future__ import annotations

import math
from pathlib import Path

import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from nifo.fleet.runner import FleetRun
from nifo.fleet.tasks import LOOP_SCORES
from nifo.io.results import write_json

__all__ = ["group_rows", "write_tables", "fleet_document", "GROUPS_PARQUET", "GROUPS_CSV", "BAGS_CSV",
           "FLEET_JSON"]

GROUPS_PARQUET, GROUPS_CSV, BAGS_CSV, BAGS_PARQUET, FLEET_JSON = (
    "fleet.parquet", "fleet.csv", "bags.csv", "bags.parquet", "fleet.json")


def _nan(x):
    return float("nan") if x is None else x


def group_rows(run: FleetRun) -> list[dict]:
    """One flat row per group (columns in the module docstring)."""
    rows = []
    for (vehicle, corner), r in run.groups.items():
        bags = [b for b in run.bags if (b["vehicle"], b["corner"]) == (vehicle, corner)]
        row = {"vehicle": vehicle, "corner": corner, "status": "ok" if r.ok else "failed",
               "reason": "" if r.ok else r.reason, "n_bags": sum(b["status"] == "ok" for b in bags),
               "n_bags_failed": sum(b["status"] != "ok" for b in bags),
               "n_bags_cached": sum(bool(b["cached"]) for b in bags)}
        if r.ok:
            h = r.health
            z = {c.name: c.z for c in h.coefficients} if h else {}
            row.update(duration_s=r.duration_s, n_avg=r.n_avg, fs_hz=r.fs_hz)
            for name, c in r.coefficients.items():
                row.update({name: c.value, f"{name}_lo": c.lo, f"{name}_hi": c.hi, f"{name}_se": c.se,
                            f"{name}_z": _nan(z.get(name))})
            row.update(r.t21)
            row.update(coherence_h1_median=r.summary["coherence_h1_median"],
                       cond_median=r.summary["cond_median"],
                       flagged=bool(h and h.flagged), flag_evidence="; ".join(h.evidence) if h else "",
                       health_note="" if (h is None or h.assessed) else f"not assessed: {h.reason}",
                       warnings=" | ".join(r.warnings))
        else:
            row.update(flagged=False, flag_evidence="", health_note="not assessed: no result")
        loop = r.loop
        row["loop_verdict"] = loop.verdict if loop else "loop not run (give --loop)"
        for key in LOOP_SCORES:        # the loop's held-out band and whole-signal NMSE before and after [%]
            row[f"loop_{key}"] = _nan(loop.scores.get(key) if loop else None)
        ch = r.characterization
        row["characterization"] = ch.text if ch else "not run (give --characterize)"
        rows.append(row)
    return rows


def _table(rows: list[dict]) -> pa.Table:
    cols = list(dict.fromkeys(k for r in rows for k in r))
    return pa.Table.from_pylist([{c: r.get(c) for c in cols} for r in rows])


def write_tables(out: Path, run: FleetRun) -> list[str]:
    """fleet.parquet, fleet.csv, bags.parquet, bags.csv into ``out``."""
    groups = _table(group_rows(run))
    pq.write_table(groups, out / GROUPS_PARQUET)
    pacsv.write_csv(groups, out / GROUPS_CSV)
    bags = _table([{k: v for k, v in b.items()} for b in run.bags])
    pq.write_table(bags, out / BAGS_PARQUET)
    pacsv.write_csv(bags, out / BAGS_CSV)
    return [GROUPS_PARQUET, GROUPS_CSV, BAGS_PARQUET, BAGS_CSV]


def _clean(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    return x


def fleet_document(run: FleetRun, *, figures: list[str], inputs: str) -> dict:
    """fleet.json: settings, units, per-group coefficients with health evidence, per-bag status."""
    groups = []
    units = {}
    for (vehicle, corner), r in run.groups.items():
        g = {"vehicle": vehicle, "corner": corner, "ok": r.ok, "reason": r.reason}
        if r.ok:
            units.update({n: u for n, u, _ in r.specs})
            g.update(coefficients={n: c.to_dict() for n, c in r.coefficients.items()}, t21=dict(r.t21),
                     summary=r.summary, warnings=list(r.warnings), n_avg=r.n_avg, duration_s=r.duration_s,
                     health=r.health.to_dict(), meanings={n: m for n, _, m in r.specs})
        if r.loop:
            g["loop"] = r.loop.to_dict()
        if r.characterization:
            g["characterization"] = r.characterization.to_dict()
        groups.append(g)
    return _clean({"nifo_fleet": 1, "input": inputs, "units": units,
                   "settings": {"health": run.settings.health.to_dict(), "freqs_hz": list(run.settings.freqs_hz),
                                "fanout": run.settings.fanout, "chunk_samples": run.settings.chunk_samples,
                                "cache_dir": run.settings.cache_dir,
                                "groups": {f"{v}/{c}": st for (v, c), st in run.setups.items()}},
                   "groups": groups, "bags": run.bags, "figures": figures,
                   "bounds": "coefficient bounds are the 95 % interval (Student t) of the per-bag estimates' mean (random "
                             "spread only); |T21| bounds are |T21|(1 ± 2ε), ε the normalized random error"})


def write_document(out: Path, run: FleetRun, *, figures: list[str], inputs: str) -> str:
    write_json(out / FLEET_JSON, fleet_document(run, figures=figures, inputs=inputs), atomic=False, indent=1)
    return FLEET_JSON
