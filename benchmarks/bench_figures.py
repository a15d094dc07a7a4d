"""Rendering the main job's figures two ways, in one process, alternating (issue 29).

Runs ``nifo run`` in-process (the bundled sample; ``--f16``: levels 1/3/5/7; ``--short``: the kill test's 20 s
record, ``--no-loop --no-refine``), keeps every figure as it is handed to the figure helpers (pickled, not yet
laid out), then renders each one in this process both ways:

- default: one task per file (the old way: unpickled, laid out and rendered for the PNG and again for the SVG)
  against one task per figure (what :mod:`nifo.plots.writer` does: unpickled and laid out once, both files
  rendered). Measured (F-16, 23 figures): 14.85 → 12.30 CPU-s (0.83); two SVGs of figures laid out without
  ``tight_layout`` differ, their bounding box by 0.0004 and 0.8 pt: an SVG rendered after the PNG of the same
  figure object (as the calling process always rendered them) is cropped to text extents measured once.
- ``--mathtext``: per figure, with matplotlib's own cache of parsed math text (one per renderer) against
  :mod:`nifo.plots.mathtext_cache` (one per process, empty at the start of each pass, as in a new helper).
  Measured (2026-11-28, idle, best of 5): sample 15.38 → 13.60 CPU-s (0.884), ``--short`` 5.68 → 5.17
  (0.911), every file the same bytes (a best of 3 beside other work: 15.65 → 16.77, the host's noise).

- ``--drawings``: each file saved with ``savefig(bbox_inches="tight")`` (two drawings a file, the layout engine
  run in each: the way before) against :mod:`nifo.plots.writer`'s one drawing a file (the PNG's drawing measures
  the tight box both files are cropped to). Every file differs: the new boxes are widened to whole pixels (1-2 px
  more of margin), and an SVG is cropped to the box measured on the PNG's drawing, not on its own.

- ``--ticks``: one drawing a file, each axis's ticks placed at every question about them (matplotlib's way)
  against once per drawing (:mod:`nifo.plots.tick_cache`).

Prints the CPU seconds of each way over all figures (the best of ``--repeats``) and per kind of figure, their
ratio, and the files the two ways wrote differently.

    PYTHONPATH=. python benchmarks/bench_figures.py [--f16 | --short] [--mathtext | --drawings | --ticks] [--repeats 3]
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import pickle
import sys
import tempfile
import time
from pathlib import Path

from profile_run import job_options

from nifo.pipeline.job import run_job
from nifo.plots import mathtext_cache, pyplot, tick_cache, writer


def _capture(job) -> list[tuple[bytes, list[str], int, tuple | None]]:
    """Every figure the job hands to the helpers: (pickled figure, file names, dpi, layout box)."""
    kept = []
    submit = writer.submit_figure

    def keep(fig, path, dpi, tight_rect=None, *, vector=True):
        kept.append((pickle.dumps(fig, protocol=pickle.HIGHEST_PROTOCOL),
                     [p.name for p in writer.figure_paths(path, vector)], dpi, tight_rect))
        return submit(fig, path, dpi, tight_rect, vector=vector)

    writer.submit_figure = keep
    try:
        run_job(job)
    finally:
        writer.submit_figure = submit
    return kept


def _per_file(fig_blob: bytes, paths: list[Path], dpi: int, rect) -> None:
    plt = pyplot()
    for p in paths:
        fig = pickle.loads(fig_blob)
        writer._write(fig, [p], dpi, rect)
        plt.close(fig)


def _tight_twice(fig_blob: bytes, paths: list[Path], dpi: int, rect) -> None:
    """Before one drawing per file: each file saved with ``bbox_inches="tight"`` (a drawing to measure the box, one
    to render into it; the layout engine run again in each)."""
    import matplotlib

    fig = pickle.loads(fig_blob)
    writer._lay_out(fig, rect)
    for p in paths:
        if p.suffix == ".png":
            fig.savefig(p, dpi=dpi, bbox_inches="tight")
        else:
            with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": writer.SVG_HASH_SALT}):
                fig.savefig(p, dpi=dpi, bbox_inches="tight", metadata={"Date": None})
    pyplot().close(fig)


def _per_figure(fig_blob: bytes, paths: list[Path], dpi: int, rect) -> None:
    writer._render_pickled(fig_blob, [str(p) for p in paths], dpi, rect)


def _kind(name: str) -> str:
    """A figure's kind from its file name: a predicted record's figures by what they show, not by record."""
    for kind in ("_time.png", "_transmissibility.png"):
        if name.endswith(kind) and name != kind.lstrip("_"):
            return "predict: " + kind[1:]
    return name


def _digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def _short_job(out: Path):
    """The kill test's job (tests/test_kill.py): ``nifo run --no-loop --no-refine`` on 20 s of the paper's
    damper-knee strut at 2.5 mm RMS road."""
    from nifo.io.loader import save_record
    from nifo.pipeline.options import RunOptions
    from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate

    out.mkdir(parents=True)
    sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=20.0, road=RandomRoad(2.5e-3)), rng=2)
    data = save_record(out / "road.mcap", sim.record)
    return RunOptions(data=[data], out=out / "res", no_loop=True, no_refine=True, no_recording=True)


def _ticks_per_question(fig_blob: bytes, paths: list[Path], dpi: int, rect) -> None:
    """Each axis's ticks placed at every question about them, as matplotlib does (no :mod:`nifo.plots.tick_cache`
    block)."""
    placed_once = tick_cache.placed_once
    tick_cache.placed_once = contextlib.nullcontext
    try:
        _per_figure(fig_blob, paths, dpi, rect)
    finally:
        tick_cache.placed_once = placed_once


def _own_cache(fig_blob: bytes, paths: list[Path], dpi: int, rect) -> None:
    mathtext_cache.uninstall()
    _per_figure(fig_blob, paths, dpi, rect)


def _shared_cache(fig_blob: bytes, paths: list[Path], dpi: int, rect) -> None:
    mathtext_cache.install()
    _per_figure(fig_blob, paths, dpi, rect)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    which = ap.add_mutually_exclusive_group()
    which.add_argument("--f16", action="store_true", help="F-16 levels 1/3/5/7 from ../shared/data/f16")
    which.add_argument("--short", action="store_true", help="the kill test's 20 s record, no loop, no refinement")
    way = ap.add_mutually_exclusive_group()
    way.add_argument("--mathtext", action="store_true",
                     help="compare matplotlib's math-text cache with nifo's shared one (default: per file/figure)")
    way.add_argument("--ticks", action="store_true",
                     help="compare ticks placed at every question with ticks placed once per drawing")
    way.add_argument("--drawings", action="store_true",
                     help="compare savefig's tight box (two drawings a file) with one drawing a file")
    ap.add_argument("--repeats", type=int, default=3, help="timed passes of each way (default 3)")
    args = ap.parse_args(argv)
    if args.mathtext:
        ways = (("own cache", _own_cache), ("shared cache", _shared_cache))
    elif args.ticks:
        ways = (("per question", _ticks_per_question), ("placed once", _per_figure))
    elif args.drawings:
        ways = (("tight twice", _tight_twice), ("one drawing", _per_figure))
    else:
        ways = (("per file", _per_file), ("per figure", _per_figure))
    with tempfile.TemporaryDirectory(prefix="nifo_bench_figures_") as tmp:
        root = Path(tmp)
        job = _short_job(root / "short") if args.short else job_options(f16=args.f16, out=root / "job")
        figures = _capture(job)
        print(f"\n{len(figures)} figures, {sum(len(f[1]) for f in figures)} files")
        best = {name: float("inf") for name, _ in ways}
        each = {name: [float("inf")] * len(figures) for name, _ in ways}     # per figure, the best pass
        digests = {}
        # an untimed pass of each way first: the first figures rendered after the job ran in this process can be
        # laid out a little differently from later passes (tick labels 2.7 px apart, either way; a helper, which
        # only renders, gives the same bytes pass after pass)
        (root / "warm-up").mkdir()
        for way, fn in ways:
            for k, (blob, names, dpi, rect) in enumerate(figures):
                fn(blob, [root / "warm-up" / f"{k:02d}_{n}" for n in names], dpi, rect)
        for r in range(args.repeats):
            for way, fn in ways[:: 1 if r % 2 == 0 else -1]:
                folder = root / way.replace(" ", "_")
                folder.mkdir(exist_ok=True)
                mathtext_cache.uninstall()     # each pass starts with an empty shared cache, as a new helper does
                t0 = time.process_time()
                for k, (blob, names, dpi, rect) in enumerate(figures):
                    t1 = time.process_time()
                    fn(blob, [folder / f"{k:02d}_{n}" for n in names], dpi, rect)
                    each[way][k] = min(each[way][k], time.process_time() - t1)
                best[way] = min(best[way], time.process_time() - t0)
                digests[way] = _digest(folder)
                if fn is _shared_cache:
                    info = mathtext_cache.cache_info()
    if args.mathtext:
        print(f"  shared cache, one pass: {info.hits} of {info.hits + info.misses} parses found in it")
    (a, _), (b, _) = ways
    print(f"  per figure kind, CPU-s (best pass of each figure; n: figures of that kind):")
    kinds: dict[str, list] = {}
    for k, (_, names, _, _) in enumerate(figures):
        kind = _kind(names[0])
        row = kinds.setdefault(kind, [0, 0.0, 0.0])
        row[0] += 1
        row[1] += each[a][k]
        row[2] += each[b][k]
    for kind, (n, ta, tb) in sorted(kinds.items(), key=lambda kv: -kv[1][1]):
        print(f"    {kind:<28} n={n:<2} {ta:6.2f} -> {tb:6.2f}  ({tb / ta:.2f})")
    for way, sec in best.items():
        print(f"  {way:<12} {sec:6.2f} CPU-s (best of {args.repeats})")
    differ = [n for n, h in digests[a].items() if digests[b].get(n) != h]
    listed = ", ".join(differ) if len(differ) <= 10 else f"{len(differ)} of {len(digests[a])}"
    print(f"{b} / {a}: {best[b] / best[a]:.3f}; files that differ: {listed or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
