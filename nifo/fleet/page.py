"""The fleet HTML page (jinja2) and its figures (matplotlib): every group on shared axes, units on every axis."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nifo.fleet.results import Coefficient
from nifo.fleet.runner import FleetRun
from nifo.plots import VECTOR_SUFFIXES, pyplot, save_figure
from nifo_core import __version__

__all__ = ["plot_t21", "plot_coefficients", "write_page", "FLEET_HTML"]

FLEET_HTML = "fleet.html"
_FLAG, _OK, _NA = "#c0392b", "#1f4e79", "#999999"

_TEMPLATE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta name="generator" content="nifo {{ version }}"><title>nifo fleet: {{ title }}</title>
<style>
body{font-family:system-ui,sans-serif;margin:2em;max-width:1200px;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:90%}th,td{border:1px solid #ccc;padding:3px 7px}
td.n{text-align:right;font-variant-numeric:tabular-nums}tr.flag{background:#fbe9e7}tr.fail{background:#eee}
.flagtxt{color:#c0392b}img{max-width:100%}
</style></head><body>
<h1>Fleet: {{ title }}</h1>
<p>{{ n_groups }} vehicle/corner groups from {{ n_bags }} bags ({{ n_failed }} failed, {{ n_cached }} from the cache);
<b>{{ n_flagged }} flagged</b>. Robust z-score on each coefficient against the fleet median
(|z| &gt; {{ health.z_limit }} and more than {{ health.se_factor }} of the group's own standard errors;
groups with fewer than {{ health.min_records }} bags or {{ health.min_duration_s }} s are not assessed;
at least {{ health.min_groups }} assessable groups make a fleet).</p>
<h2>Flagged struts</h2>
{% if flags %}<ul>{% for f in flags %}<li><b>{{ f.group }}</b>: <span class="flagtxt">{{ f.text }}</span></li>{% endfor %}</ul>
{% else %}<p>None.</p>{% endif %}
<h2>Transmissibility</h2>
<img src="{{ t21_png }}" alt="T21 of every group">
<h2>Coefficients</h2>
<img src="{{ coef_png }}" alt="coefficients of every group">
<h2>Groups</h2>
<table><tr><th>vehicle</th><th>corner</th><th>bags</th><th>data [s]</th>
{% for c in coef_heads %}<th>{{ c }}</th>{% endfor %}<th>health</th><th>loop</th></tr>
{% for r in rows %}<tr class="{{ r.cls }}"><td>{{ r.vehicle }}</td><td>{{ r.corner }}</td><td class="n">{{ r.bags }}</td>
<td class="n">{{ r.duration }}</td>{% for c in r.coefs %}<td class="n">{{ c }}</td>{% endfor %}
<td>{{ r.health }}</td><td>{{ r.loop }}</td></tr>{% endfor %}</table>
<p>Values ± the half-width of their 95 % interval (Student t over the per-bag estimates: random spread only),
then [robust z].</p>
{% if failed %}<h2>Failed bags</h2><table><tr><th>vehicle</th><th>corner</th><th>bag</th><th>reason</th></tr>
{% for b in failed %}<tr class="fail"><td>{{ b.vehicle }}</td><td>{{ b.corner }}</td><td>{{ b.path }}</td>
<td>{{ b.reason }}</td></tr>{% endfor %}</table>{% endif %}
<p>Tables: fleet.parquet / fleet.csv (one row per group), bags.parquet / bags.csv, fleet.json.</p>
</body></html>
"""


def _label(g) -> str:
    return f"{g[0]}/{g[1]}" if g[1] != "-" else g[0]


def _ok_groups(run: FleetRun):
    return [(g, r) for g, r in run.groups.items() if r.ok]


def plot_t21(path: Path, run: FleetRun) -> Path:
    """|T21| and phase of every group (pooled NIFO T21) on shared axes; flagged groups in red."""
    plt = pyplot()

    fig, (am, ap) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True, constrained_layout=True)
    band = None
    styles = iter(["-", "--", ":", "-."] * 1000)
    for g, r in _ok_groups(run):
        c = r.curves
        f, t = np.asarray(c.freq_hz), np.asarray(c.t21)
        m = f > 0
        flagged = r.health.flagged
        kw = {"color": _FLAG if flagged else _OK, "lw": 1.4 if flagged else 0.7, "alpha": 1 if flagged else 0.5,
              "zorder": 3 if flagged else 2, "label": _label(g) if flagged else None,
              "ls": next(styles) if flagged else "-"}
        am.loglog(f[m], np.abs(t[m]), **kw)
        ap.semilogx(f[m], np.degrees(np.angle(t[m])), **kw)
        band = r.analysis_band_hz
    if band:
        for ax in (am, ap):
            ax.axvspan(*band, color="0.93", zorder=0, label=None)
    am.plot([], [], color=_OK, lw=0.7, label="healthy / not flagged")
    am.set_ylabel("|T21| = |X2/X1| [-]")
    ap.set_ylabel("phase of T21 [°]")
    ap.set_xlabel("frequency [Hz]")
    am.set_title("nominal spindle→body transmissibility of every group (pooled NIFO T21; grey: analysis band)",
                 fontsize=10)
    am.legend(fontsize=8, loc="lower left")
    for ax in (am, ap):
        ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def plot_coefficients(path: Path, run: FleetRun) -> Path:
    """Every coefficient of every group with 95 % interval bars, the fleet median and its ±z_limit·scale band."""
    plt = pyplot()

    ok = _ok_groups(run)
    names = list(dict.fromkeys(c.name for _, r in ok for c in r.health.coefficients))  # the assessed set
    fig, axes = plt.subplots(len(names), 1, figsize=(max(8.0, 0.35 * len(ok) + 3), 1.9 * len(names) + 1),
                             sharex=True, constrained_layout=True, squeeze=False)
    x = np.arange(len(ok))
    zl = run.settings.health.z_limit
    for ax, name in zip(axes[:, 0], names):
        unit, ref = "", None
        for i, (g, r) in enumerate(ok):
            c = r.coefficients.get(name)
            if c is None:
                continue
            unit = c.unit
            ch = next((h for h in r.health.coefficients if h.name == name), None)
            col = _FLAG if (ch and ch.flagged) else (_OK if r.health.assessed else _NA)
            err = (c.hi - c.lo) / 2 if np.isfinite(c.hi - c.lo) else 0.0
            ax.errorbar(i, c.value, yerr=err, fmt="o", ms=4, color=col, capsize=2)
            if ch is not None and np.isfinite(ch.fleet_median):
                ref = (ch.fleet_median, ch.fleet_scale)
        if ref is not None:
            med, sc = ref
            ax.axhline(med, color="0.4", lw=0.8, ls="--")
            ax.axhspan(med - zl * sc, med + zl * sc, color="0.92", zorder=0)
        ax.set_ylabel(f"{name}\n[{unit}]", fontsize=8)
        ax.grid(True, alpha=0.3)
    ax = axes[-1, 0]
    ax.set_xticks(x, [_label(g) for g, _ in ok], rotation=60, ha="right", fontsize=8)
    ax.set_xlabel("group (vehicle/corner)")
    axes[0, 0].set_title(f"coefficients, 95 % intervals; dashed: fleet median; grey: ± {zl:g} robust σ; red: flagged",
                         fontsize=9)
    return save_figure(fig, path)


def _fmt(c: Coefficient, z: float) -> str:
    v = f"{c.value:.4g}"
    if np.isfinite(c.hi - c.lo):
        v += f" ± {(c.hi - c.lo) / 2:.2g}"
    if np.isfinite(z):
        v += f" [{z:+.1f}]"
    return v


def write_page(out: Path, run: FleetRun, *, title: str) -> list[str]:
    """fleet.html and the two figures (PNG, and SVG beside each: :func:`nifo.plots.save_figure`) into ``out``;
    returns the file names."""
    import jinja2

    plot_t21(out / "t21.png", run)
    plot_coefficients(out / "coefficients.png", run)
    ok = _ok_groups(run)
    heads = list(dict.fromkeys(f"{n} [{u}]" for _, r in ok for n, u, _ in r.specs))
    names = list(dict.fromkeys(n for _, r in ok for n in r.coefficients))
    rows, flags = [], []
    for g, r in run.groups.items():
        row = {"vehicle": g[0], "corner": g[1], "cls": "", "loop": r.loop.verdict if r.loop else "not run"}
        if not r.ok:
            row.update(cls="fail", bags=0, duration="", coefs=[""] * len(names), health=f"failed: {r.reason}")
        else:
            h = r.health
            z = {c.name: c.z for c in h.coefficients}
            row.update(bags=len(r.bags), duration=f"{r.duration_s:.0f}",
                       coefs=[_fmt(r.coefficients[n], z.get(n, np.nan)) if n in r.coefficients else ""
                              for n in names],
                       health="FLAGGED" if h.flagged else ("ok" if h.assessed else f"not assessed: {h.reason}"))
            if h.flagged:
                row["cls"] = "flag"
                flags += [{"group": _label(g), "text": t} for t in h.evidence]
        rows.append(row)
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined)
    text = env.from_string(_TEMPLATE).render(
        title=title, version=__version__, n_groups=len(run.groups), n_bags=len(run.bags), n_failed=run.n_failed,
        n_cached=run.n_cached, n_flagged=sum(1 for _, r in ok if r.health.flagged), health=run.settings.health,
        flags=flags, t21_png="t21.png", coef_png="coefficients.png", coef_heads=heads, rows=rows,
        failed=[b for b in run.bags if b["status"] != "ok"])
    (out / FLEET_HTML).write_text(text)
    return [FLEET_HTML, *(f"{stem}{suffix}" for stem in ("t21", "coefficients")
                          for suffix in (".png", *VECTOR_SUFFIXES))]
