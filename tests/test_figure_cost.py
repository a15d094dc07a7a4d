"""What a figure costs, counted rather than timed (nifo.plots.writer): each file drawn once, the PNG the pixels
matplotlib renders into the same box, nothing of the figure cropped away."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from nifo.plots import pyplot, writer


def _figure(kind: str):
    plt = pyplot()
    if kind == "constrained":     # a layout engine that runs at every drawing, a figure legend below the axes
        fig, axes = plt.subplots(1, 2, figsize=(6, 2.6), layout="constrained")
        for ax in axes:
            ax.plot([0, 1, 2], [1, 0, 2], label="measured")
            ax.set_xlabel("time [s]")
        axes[0].set_ylabel(r"$\mu_1/K_2$ [m/m]")
        fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=2, frameon=False)
        return fig, None
    fig, ax = plt.subplots(figsize=(4, 3))
    x = np.linspace(1, 100, 400)
    ax.loglog(x, 1 / (1 + (x / 10) ** 2), label="$|T_{21}|$")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("|T21| [–]")
    ax.legend()
    if kind == "outside":       # a label reaching past the figure's edge (the tight box takes it in)
        ax.set_ylabel("|T21| [–]", labelpad=12)
    elif kind == "far":         # text beyond the drawn margin: matplotlib renders it into the box instead
        fig.text(1.0 + 2 * writer.MARGIN_PX / 100, 0.5, "far to the right [m]")
    fig.suptitle("a title [m/s²]")
    return fig, (0, 0, 1, 0.95) if kind == "tight" else None


def _drawings(monkeypatch) -> list[str]:
    from matplotlib.figure import Figure

    seen: list[str] = []
    draw = Figure.draw

    def counted(self, renderer):
        seen.append(type(renderer).__name__)
        return draw(self, renderer)

    monkeypatch.setattr(Figure, "draw", counted)
    return seen


@pytest.mark.parametrize("kind", ["plain", "tight", "constrained", "outside"])
def test_each_file_is_drawn_once_and_the_png_is_matplotlibs_own_render_of_its_box(tmp_path, monkeypatch, kind):
    fig, rect = _figure(kind)
    seen = _drawings(monkeypatch)
    writer._lay_out(fig, rect)
    box = writer._png_and_box(fig, tmp_path / "a.png", 130)
    writer._render(fig, tmp_path / "a.svg", 130, box)
    # savefig(bbox_inches="tight") drew each file twice (a drawing to measure the box, one to render into it)
    assert len(seen) == 2, seen
    fig.savefig(tmp_path / "b.png", dpi=130, bbox_inches=box)
    pyplot().close(fig)
    ours, theirs = (np.asarray(Image.open(tmp_path / n)) for n in ("a.png", "b.png"))
    assert ours.shape == theirs.shape
    assert (ours != theirs).any(-1).mean() < 1e-4      # a rounded frame's corner at the box's edge, at most
    # the box holds the whole drawing: the PNG's border is the padding, the figure's colour
    border = np.concatenate([ours[:3].reshape(-1, 4), ours[-3:].reshape(-1, 4), ours[:, :3].reshape(-1, 4),
                             ours[:, -3:].reshape(-1, 4)])
    assert (border == 255).all()
    svg = (tmp_path / "a.svg").read_text()
    assert svg.startswith("<?xml") and "</svg>" in svg
    w_pt = float(svg.split('width="', 1)[1].split("pt", 1)[0])
    assert w_pt == pytest.approx(ours.shape[1] / 130 * 72, abs=0.01)       # both files cropped to the one box


def test_text_beyond_the_margin_is_rendered_into_its_box_by_matplotlib(tmp_path, monkeypatch):
    fig, rect = _figure("far")
    seen = _drawings(monkeypatch)
    box = writer._png_and_box(fig, tmp_path / "a.png", 100)
    assert len(seen) == 2, seen              # the margined drawing, then matplotlib's into the box
    assert box.x1 > fig.get_size_inches()[0] + writer.MARGIN_PX / 100
    ours = np.asarray(Image.open(tmp_path / "a.png"))
    assert ours.shape[1] == round(box.width * 100)
    assert (ours[:, -60:-3, :3] < 128).any()                 # the far text is in it
    pyplot().close(fig)


def test_write_files_draws_a_figure_twice_for_png_and_svg(tmp_path, monkeypatch):
    fig, rect = _figure("tight")
    seen = _drawings(monkeypatch)
    writer.write_files(fig, tmp_path / "f.png", 130, rect)
    pyplot().close(fig)
    assert sorted(seen) == ["MixedModeRenderer", "RendererAgg"]
    assert (tmp_path / "f.png").stat().st_size > 1000 and (tmp_path / "f.svg").stat().st_size > 1000


def test_ticks_are_placed_once_per_drawing_and_the_files_are_the_same_bytes(tmp_path, monkeypatch):
    import contextlib

    from matplotlib.axis import Axis

    from nifo.plots import tick_cache

    assert tick_cache.install(), "matplotlib's Axis._update_ticks is not the one measured"
    own = Axis._update_ticks.__wrapped__
    placed: list[int] = []

    def counted(self):
        placed.append(id(self))
        return own(self)

    files = {}
    for way in ("per question", "once"):
        placed.clear()
        fig, rect = _figure("plain")
        with monkeypatch.context() as m:
            m.setattr(tick_cache, "_installed", None)
            m.setattr(Axis, "_update_ticks", counted)
            tick_cache.install()          # the wrapper, around the counting method
            if way == "per question":
                m.setattr(tick_cache, "placed_once", contextlib.nullcontext)
            writer.write_files(fig, tmp_path / f"{way}.png", 130, rect)
        pyplot().close(fig)
        files[way] = len(placed), len(set(placed))
        for suffix in (".png", ".svg"):
            files[way, suffix] = (tmp_path / f"{way}{suffix}").read_bytes()
    n_axis = files["once"][1]       # x and y
    assert files["once"][0] == 2 * n_axis          # each axis once in the PNG's drawing and tight box, once in the SVG
    assert files["per question"][0] >= 3 * files["once"][0]
    assert files["once", ".png"] == files["per question", ".png"]
    assert files["once", ".svg"] == files["per question", ".svg"]
