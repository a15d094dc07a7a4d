"""Figures are publication-grade: units on every axis, mathtext (no literal ``μ_i``), no overlapping
labels, no mixed log axis, an SVG beside every PNG, the true curve where a truth file is present,
and the record's units (``--system '... [V]'``) instead of m/s².

Result directories from :func:`test_run_cmd.pipeline` (``nifo run`` on the bundled sample: simulated quarter cars
with their truth files).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from test_run_cmd import pipeline


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    out, code, _ = pipeline(tmp_path_factory)
    assert code == 0
    return out


def _captured(monkeypatch, module):
    """Keep the figures ``module`` saves open (for their layout), still writing the files."""
    from nifo import plots

    figs = []

    def keep(fig, path, **kw):
        figs.append(fig)
        fig.canvas.draw()
        return Path(path)

    monkeypatch.setattr(module, "save_figure", keep)
    return figs


def _overlap(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def _svg_text(path: Path) -> str:
    """The text of an SVG written with svg.fonttype 'none': each <text> (mathtext: its <tspan>s) joined."""
    blocks = re.findall(r"<text\b[^>]*>(.*?)</text>", path.read_text(), re.S)
    return " ".join("".join(t.strip() for t in re.findall(r">([^<>]*)<", f">{b}<")) for b in blocks)


def test_every_png_has_a_vector_svg_beside_it(ran):
    pngs = [p for p in ran.rglob("*.png")]
    assert len(pngs) >= 8
    for p in pngs:
        svg = p.with_suffix(".svg")
        assert svg.is_file() and svg.read_text().lstrip().startswith("<?xml"), p


def test_every_axis_label_has_a_unit_and_no_literal_mu_i(ran, tmp_path, monkeypatch):
    from nifo.cli import main
    from nifo.plots import loop, nifo, restoring

    figs = []
    for mod in (loop, nifo, restoring):
        monkeypatch.setattr(mod, "save_figure", lambda fig, path, **kw: (figs.append(fig), Path(path))[1])
    data = str(tmp_path / "road_hi")   # 60 s of the paper's strut at 2.5 mm road: each command's figures
    assert main(["-q", "simulate", "--out", data, "--preset", "paper", "--road-rms", "2.5", "--duration", "60",
                 "--noise", "0.02", "--seed", "12"]) == 0
    assert main(["-q", "characterize", data, "--out", str(tmp_path / "c"), "--grid", "8"]) == 0
    assert main(["-q", "identify", data, "--model", str(tmp_path / "c" / "suggested_model.yaml"),
                 "--out", str(tmp_path / "i")]) == 0
    assert main(["-q", "loop", data, "--out", str(tmp_path / "l"), "--max-rounds", "1", "--grid", "8"]) == 0
    assert len(figs) >= 7
    for fig in figs:
        texts = [fig._suptitle.get_text() if fig._suptitle else ""]
        for ax in fig.axes:
            for label in (ax.get_xlabel(), ax.get_ylabel()):
                assert not label or "[" in label, label
            texts.append(ax.get_title())
        assert not any("μ_i" in t or "μ{" in t for t in texts), texts
    coef = _svg_text(ran / "identify" / "coefficients.svg")
    assert "[s]" in coef            # μ/K2 of a velocity term (g in m/s) is in seconds


def test_coefficient_labels_do_not_overlap_ticks_and_loop_errors_has_no_log_axis(ran, monkeypatch):
    from nifo.io.results import read_identify
    from nifo.plots import loop as ploop
    from nifo.plots import nifo as pnifo

    figs = _captured(monkeypatch, pnifo)
    res, _ = read_identify(ran / "identify")
    pnifo.plot_coefficients(ran / "unused.png", res)
    fig = figs[-1]
    r = fig.canvas.get_renderer()
    for ax in fig.axes:
        lab = ax.yaxis.label.get_window_extent(r)
        assert "[" in ax.get_ylabel() and "\\mu" in ax.get_ylabel()
        for t in ax.get_yticklabels():
            if t.get_text():
                assert not _overlap(lab, t.get_window_extent(r)), (ax.get_ylabel(), t.get_text())
    figs = _captured(monkeypatch, ploop)
    doc = json.loads((ran / "loop" / "loop.json").read_text())
    ploop.plot_errors(doc, ran / "unused.png")
    fig = figs[-1]
    r = fig.canvas.get_renderer()
    assert all(ax.get_yscale() == "linear" for ax in fig.axes)
    bars = [p.get_window_extent(r) for ax in fig.axes for p in ax.patches]
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is not None:
            assert not any(_overlap(leg.get_window_extent(r), b) for b in bars)


@pytest.mark.parametrize("connected", [False, True])
def test_the_slice_grid_legend_hides_no_text_of_its_panel(monkeypatch, connected):
    """The legend sat on the first row's note (z RMS, bottom right) of the sample's restoring_amplitude figure."""
    from nifo.plots import restoring

    figs = _captured(monkeypatch, restoring)
    rng = np.random.default_rng(1)
    rows = []
    for k, amp in enumerate((1e-3, 3e-3)):
        t = np.linspace(0, 20, 4000)
        z, zd = amp * np.sin(2 * np.pi * t), amp * 2 * np.pi * np.cos(2 * np.pi * t)
        if not connected:
            z, zd = amp * rng.standard_normal(4000), 6 * amp * rng.standard_normal(4000)
        force = 100 * z + 2 * zd + 0.01 * amp * rng.standard_normal(4000)
        rows.append(restoring.SlicePlot(f"level {k}", z, zd, force, model=100 * z + 2 * zd, connected=connected,
                                        note=f"z RMS {1e3 * np.std(z):.2f} mm"))
    restoring.plot_restoring_slices(rows, "unused.png", title="restoring force by amplitude")
    fig = figs[-1]
    r = fig.canvas.get_renderer()
    legends = [ax for ax in fig.axes if ax.get_legend() is not None]
    assert legends
    for ax in legends:
        box = ax.get_legend().get_window_extent(r)
        texts = [t for t in ax.texts if t.get_text()]
        assert texts
        hidden = [t.get_text() for t in texts if _overlap(box, t.get_window_extent(r))]
        assert not hidden, hidden


def test_true_curves_are_drawn_when_a_truth_file_is_beside_the_data(ran):
    assert "true nominal linear T21" in _svg_text(ran / "identify" / "transmissibility.svg")
    assert "true (simulator)" in _svg_text(ran / "characterize" / "characteristic.svg")


def test_record_units_and_system_words_carry_into_the_figures(tmp_path):
    from nifo.cli import main

    volts = tmp_path / "v.csv"
    assert main(["-q", "simulate", "--out", str(volts), "--duration", "60", "--seed", "3", "--preset",
                 "paper"]) == 0
    out = tmp_path / "c"
    assert main(["-q", "characterize", str(volts), "--out", str(out), "--grid", "6", "--system",
                 "Duffing circuit [V]"]) == 0
    text = " ".join(_svg_text(p) for p in out.glob("*.svg"))
    assert "[V]" in text and "V·s" in text and "m/s²" not in text
    doc = json.loads((out / "characterize.json").read_text())
    assert doc["system"] == {"description": "Duffing circuit", "units": "V", "vehicle": False}
    assert not np.isnan(doc["linear"]["r2"])


def _bands(fig) -> list:
    """The shaded 95 % bands (fill_between collections labelled as bounds) of a figure."""
    from matplotlib.collections import PolyCollection

    return [c for ax in fig.axes for c in ax.collections
            if isinstance(c, PolyCollection) and "95 % bound" in str(c.get_label())]


def test_coefficient_and_t21_figures_shade_the_95_percent_bounds_of_the_result(ran, monkeypatch):
    from nifo.io.results import read_identify
    from nifo.plots import nifo as pnifo
    from nifo.viz import report_html
    from nifo.viz.results import read_results

    figs = _captured(monkeypatch, pnifo)
    res, doc = read_identify(ran / "identify")
    pnifo.plot_coefficients(ran / "unused.png", res)
    bands = _bands(figs[-1])
    free = [i for i, fx in enumerate(res.fixed) if not fx]
    assert len(bands) == 2 * len(free)              # Re and Im of every free term
    # the band spans μ ± 2|μ|·sqrt(ε_B² + ε_T²) at each line: check its widest point against the result
    i = free[0]
    eps = np.sqrt(res.random_error[1 + i] ** 2 + res.random_error[0] ** 2)
    half = 2 * np.abs(res.mu_over_k2[i]) * eps
    ys = bands[0].get_paths()[0].vertices[:, 1]
    m = pnifo._view(res.freq_hz, res.analysis_band_hz, pad=0.2)
    assert np.nanmax(ys) - np.nanmin(ys) >= np.nanmax(2 * half[m]) * 0.99

    figs.clear()
    report_html.levels_figure(read_results([ran / "identify"]), ran / "unused_levels.png")
    (band,) = [b for b in _bands(figs[-1])]        # the pooled T21's band on the magnitude axis
    lower, upper = (np.asarray(doc["bounds"]["t21_static"][k]) for k in ("lower", "upper"))
    v = band.get_paths()[0].vertices
    f0 = v[np.argmin(np.abs(v[:, 0] - np.mean(res.analysis_band_hz))), 0]
    j = int(np.argmin(np.abs(res.freq_hz - f0)))
    assert np.min(np.abs(v[np.isclose(v[:, 0], f0), 1] - upper[j])) < 1e-9 * upper[j] + 1e-12


def test_the_report_shows_the_t21_and_coefficient_bounds(ran):
    html = (ran / "report" / "report.html").read_text()
    assert 'alt="levels"' in html and "vector: levels.svg" not in html   # embedded alone: no vector file claimed
    assert "95 % bounds of the nominal T21" in html and "median half-width" in html
    assert "Final model with 95 % bounds" in html and "±" in html
