"""Figures rendered by helper processes while the step goes on (issue 29: the main job's figures).

Why a process pool and not the main process: rendering, not drawing the
figure, is what figures cost. Measured on the 23 figures of ``nifo run`` on the
bundled sample (2 idle cores, matplotlib 3.11): PNG 11.0 s + SVG 8.9 s of
rendering, building them a fraction of that, pickling a finished figure 0.27 s
for all 23. Rendering is text layout and tick placement spread over thousands
of small calls, repeated in every drawing of the figure (no hot spot to remove
but the math text every renderer parsed again, now parsed once per process:
:mod:`nifo.plots.mathtext_cache`), so what a figure costs is how often it is
drawn: once per file (:func:`_png_and_box`: the PNG's one drawing also measures
the tight box both files are cropped to; ``savefig(bbox_inches="tight")`` drew
each file twice, and the SVG laid a constrained layout out again). Measured on
the sample's 25 figures, rendered in one process from the same pickles
(``benchmarks/bench_figures.py --drawings``): 0.69 of the CPU before, the PNGs
pixel for pixel what matplotlib renders into the same box. So a figure is
pickled as soon as it is built and its files are rendered in a helper process, PNG then SVG in one task (one
unpickling and one layout for both: measured on the 23 figures of ``nifo run``
on F-16 levels 1/3/5/7, ``benchmarks/bench_figures.py``, see there), while the
step builds the next figure or computes; the step waits for them
before its output is committed (:func:`figure_batch` inside
:func:`nifo.io.atomic.staged_dir`), so an output never lacks a figure it lists.
Inside ``nifo run`` (:func:`deferred_figures`), whose folder nobody sees before
the run is complete, they render while the next steps compute: the run waits
for them before its report reads them.

Outside a batch, in a daemonic process (a Dask worker cannot have children),
with ``NIFO_FIGURE_WORKERS=0`` or where the pool cannot start, figures are
written in the calling process as before. A helper that dies takes no figure
with it: the figure is rendered in the calling process instead. Helpers ignore
Ctrl-C (the step's own process handles it) and exit when the process that
started them is gone.
"""

from __future__ import annotations

import contextlib
import contextvars
import io
import multiprocessing
import os
import pickle
import signal
import sys
import threading
import time
import warnings
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Iterator, Sequence

from nifo.interrupt import by_interrupt, crash_stacks, signals_held

__all__ = ["figure_batch", "deferred_figures", "wait_figures", "submit_figure", "write_files", "figure_paths",
           "figure_workers", "start_helpers", "helpers_started", "abandon_helpers"]

#: environment variable: helper processes for figures (0: write them in the calling process)
WORKERS_ENV = "NIFO_FIGURE_WORKERS"
#: the most seconds to wait for a shut-down pool's manager thread (it ends within milliseconds once its helpers
#: are gone; a bound, not a wait)
ABANDON_WAIT_S = 5.0

_batch: contextvars.ContextVar[list | None] = contextvars.ContextVar("nifo_figure_batch", default=None)
_deferred: contextvars.ContextVar[list | None] = contextvars.ContextVar("nifo_figures_later", default=None)
_pool: ProcessPoolExecutor | None = None
_pool_failed = False
_lock = threading.Lock()


def figure_workers() -> int:
    """Helper processes figures use: ``NIFO_FIGURE_WORKERS`` if set, else one per core up to 2 (0: none)."""
    raw = os.environ.get(WORKERS_ENV, "").strip()
    if raw:
        try:
            return max(0, int(raw))
        except ValueError:
            return 0
    if multiprocessing.current_process().daemon:
        return 0
    return min(2, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def write_files(fig, path: str | Path, dpi: int, tight_rect: tuple | None = None, *, vector: bool = True) -> None:
    """The PNG at ``path`` and (``vector``) the vector files beside it (:data:`nifo.plots.VECTOR_SUFFIXES`), laid
    out first (``tight_rect``: see :func:`nifo.plots.save_figure`); the caller closes ``fig``."""
    _write(fig, figure_paths(path, vector), dpi, tight_rect)


def _write(fig, paths: Sequence[str | Path], dpi: int, tight_rect: tuple | None) -> None:
    """``fig`` laid out once, then each of its files rendered: in the calling process and in a helper alike (the
    same bytes either way). The PNG comes first: its drawing also gives the tight box every file is cropped to
    (:func:`_png_and_box`), so each file costs one drawing of the figure."""
    _lay_out(fig, tight_rect)
    box = None
    for path in map(Path, paths):
        if path.suffix == ".png":
            box = _png_and_box(fig, path, dpi)
        else:
            _render(fig, path, dpi, box)


def figure_paths(path: str | Path, vector: bool = True) -> list[Path]:
    """The files of a figure saved at ``path``: the PNG and (``vector``) the vector files beside it."""
    from nifo.plots import VECTOR_SUFFIXES

    p = Path(path)
    return [p, *(p.with_suffix(s) for s in (VECTOR_SUFFIXES if vector else ()))]


#: the salt of the ids in an SVG (clip paths, glyphs): fixed, so the same figure gives the same file (matplotlib
#: draws a random one per file otherwise, and two runs on the same data differed in every SVG)
SVG_HASH_SALT = "nifo"


def _render(fig, path: Path, dpi: int, box=None) -> None:
    """One vector file of ``fig``, with text kept as text (editable, searchable), the same bytes for the same
    figure; cropped to ``box`` (inches, from :func:`_png_and_box`), or to its own tight box when None (one more
    drawing)."""
    import matplotlib

    from nifo.plots.tick_cache import placed_once

    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": SVG_HASH_SALT}):
        if box is None:
            fig.savefig(path, dpi=dpi, bbox_inches="tight", metadata={"Date": None})
            return
        with placed_once():       # one drawing, laid out before (:func:`_png_and_box`)
            fig.savefig(path, dpi=dpi, bbox_inches=box, metadata={"Date": None})


#: the margin [px] drawn around the figure for the PNG: text reaching that far beyond the figure (a rotated label,
#: an axis label under a tightly laid out axes) and the tight box's padding are in the one drawing
#: (:func:`_png_and_box`); measured on the sample's 25 figures: at most 26 px beyond (with the 13 px padding)
MARGIN_PX = 64


def _png_and_box(fig, path: Path, dpi: int):
    """The PNG of ``fig`` at ``path``, cropped to its tight box; that box (inches, padded) for the other files.

    ``savefig(bbox_inches="tight")`` draws the figure twice: once (not rasterised) to measure the tight box, once
    into that box. Here the figure is drawn once at ``dpi``, on a canvas :data:`MARGIN_PX` wider than the figure
    on every side (``savefig`` of raw pixels into that box, kept by the canvas's renderer), the tight box is
    measured on that drawing (the artists' extents are those just drawn), padded by ``savefig.pad_inches`` and
    widened to whole pixels, and the pixels inside it are written. They are the pixels matplotlib renders into
    that box (the offset is a whole number of pixels, so nothing moves across a pixel boundary;
    ``tests/test_figure_cost.py``). A box reaching beyond the margin is rendered by matplotlib into the box
    instead (one drawing more). Figure legends are anchored to the figure, not to the box drawn into. The layout
    engine, if any, runs once before the drawing and is switched off after it: every file has the same layout,
    laid out once."""
    import matplotlib
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.image import imsave
    from matplotlib.transforms import Bbox

    from nifo.plots.tick_cache import placed_once

    old_dpi = fig.dpi
    fig.set_dpi(dpi)
    try:
        canvas = FigureCanvasAgg(fig)
        engine = fig.get_layout_engine()
        if engine is not None:
            engine.execute(fig)          # as savefig does before it draws (a placeholder's does nothing)
        with matplotlib.rc_context({"figure.autolayout": False, "figure.constrained_layout.use": False}):
            fig.set_layout_engine(None)      # none at all (a placeholder would make savefig measure again)
        for legend in fig.legends:       # a figure legend anchored to the figure, not to the box drawn into
            if legend.get_bbox_to_anchor() is fig.bbox:
                legend.set_bbox_to_anchor(Bbox.unit(), transform=fig.transFigure)
        m = MARGIN_PX / dpi
        w, h = fig.get_size_inches()
        with placed_once():       # the layout is done: the drawing's ticks are the tight box's
            # one drawing (no layout engine, a box given): raw pixels, kept by the canvas's renderer
            fig.savefig(io.BytesIO(), format="rgba", dpi=dpi, bbox_inches=Bbox([[-m, -m], [w + m, h + m]]))
            renderer = canvas.renderer
            tight = fig.get_tightbbox(renderer).padded(matplotlib.rcParams["savefig.pad_inches"])
        (x0, y0), (x1, y1) = np.floor(tight.p0 * dpi).astype(int), np.ceil(tight.p1 * dpi).astype(int)
        box = Bbox([[x0 / dpi, y0 / dpi], [x1 / dpi, y1 / dpi]])
        rgba = np.asarray(renderer.buffer_rgba())
        rows, cols = rgba.shape[:2]
        top, left = rows - MARGIN_PX - y1, x0 + MARGIN_PX       # the box's first row and column on the canvas
        if top < 0 or left < 0 or top + (y1 - y0) > rows or left + (x1 - x0) > cols:
            fig.savefig(path, dpi=dpi, bbox_inches=box)
        else:
            imsave(path, rgba[top:top + y1 - y0, left:left + x1 - x0], format="png", origin="upper", dpi=dpi)
    finally:
        fig.set_dpi(old_dpi)
    return box


def _lay_out(fig, tight_rect: tuple | None) -> None:
    if tight_rect is not None:
        fig.tight_layout(rect=tight_rect)


def _render_pickled(blob: bytes, paths: Sequence[str], dpi: int, tight_rect: tuple | None = None) -> None:
    """In a helper: the files of the pickled figure, laid out once here (the step that built it does not wait for
    that)."""
    fig = pickle.loads(blob)
    try:
        _write(fig, paths, dpi, tight_rect)
    finally:
        from nifo.plots import pyplot

        pyplot().close(fig)


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(0)


def _die_with_parent() -> None:
    """Linux: the kernel kills this helper the moment its parent dies (prctl PR_SET_PDEATHSIG), so a killed step
    leaves no helper writing into its output; elsewhere the watcher thread does, within half a second."""
    import ctypes
    import ctypes.util

    with contextlib.suppress(OSError, AttributeError, TypeError):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)       # PR_SET_PDEATHSIG = 1


def _helper_init(parent: int) -> None:
    """A helper: Ctrl-C is the step's to handle; gone with its parent; a crash says where; matplotlib on Agg,
    imported now."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warnings.simplefilter("ignore")   # a library's warning while rendering is not the user's to read (issue 56)
    crash_stacks()   # Agg, FreeType, the PNG encoder: the stack on the stderr it shares with the step
    _die_with_parent()
    if os.getppid() != parent:       # the parent died before the line above
        os._exit(0)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    from nifo.plots import pyplot

    pyplot()


def _warm() -> None:
    """Nothing: makes a helper start (and import matplotlib) before the first figure needs it."""


@contextlib.contextmanager
def _main_script_kept_out() -> Iterator[None]:
    """The helpers spawned without running the caller's script again.

    A spawned process imports the parent's main module first; for a script run as ``python script.py`` that means
    executing it (as ``__mp_main__``), and a script without an ``if __name__ == "__main__":`` guard would start its
    whole nifo job again in every helper (measured: ``nifo run`` called from such a script ran three times at once,
    into the same folder, and failed). The helpers need nothing from it (they run :func:`_render_pickled`), so
    while they are spawned the main module has no ``__file__`` to be run from. A module run with ``python -m``
    (``nifo`` itself) is imported by name as before."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None) if getattr(main, "__spec__", None) is None else None
    if path is None:
        yield
        return
    del main.__file__
    try:
        yield
    finally:
        main.__file__ = path


def _get_pool() -> ProcessPoolExecutor | None:
    global _pool, _pool_failed
    with _lock:
        if _pool is None and not _pool_failed:
            n = figure_workers()
            if n < 1:
                _pool_failed = True
                return None
            try:
                # the helpers are spawned by the submissions: whole (a signal held until they are), without the
                # caller's script
                with signals_held(), _main_script_kept_out():
                    _pool = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("spawn"),
                                                initializer=_helper_init, initargs=(os.getpid(),))
                    for _ in range(n):
                        _pool.submit(_warm)
            except (OSError, RuntimeError, AssertionError):
                _pool, _pool_failed = None, True
        return _pool


@contextlib.contextmanager
def figure_batch() -> Iterator[None]:
    """Figures saved inside render in helper processes; on leaving, wait for all of them.

    A rendering error is raised here (the first one, as raised). When the block
    raises, figures not yet started are cancelled and running ones waited for,
    so nothing is written into the step's output after it is cleaned up.
    """
    pending: list = []
    token = _batch.set(pending)
    try:
        yield
    except BaseException as exc:
        _drop(pending, exc)
        raise
    else:
        later = _deferred.get()
        if later is not None:     # inside nifo run: the job waits for them (deferred_figures)
            later.extend(pending)
        else:
            _wait(pending)
    finally:
        _batch.reset(token)


def _drop(pending: list, exc: BaseException) -> None:
    """None of the figures of ``pending`` is written after this returns. The block raised ``exc``: the figures not
    yet started are cancelled and the running ones waited for; when ``exc`` is an interruption (Ctrl-C, SIGTERM:
    :func:`nifo.interrupt.by_interrupt`) the helpers are killed and reaped instead (:func:`abandon_helpers`), so
    the command ends without waiting for a figure it will not keep (measured: SIGINT 3-5 s into ``nifo run`` of
    a 20 s record took 0.9-1.6 s to end, waiting for running figures). A file a killed helper left half-written
    is in the output being abandoned, which the caller removes."""
    if pending and by_interrupt(exc):
        # the pool first, our futures after: with the futures cancelled before it, the process hung at exit
        # (measured: six figures handed over, then an interrupt: 7 of 8 runs; tests/test_kill.py once), the
        # pool's threads left waiting on helpers that were gone
        abandon_helpers()
        for fut, *_ in pending:
            fut.cancel()
        return
    for fut, *_ in pending:
        fut.cancel()
    for fut, *_ in pending:
        with contextlib.suppress(BaseException):
            fut.exception()


def _wait(pending: list) -> None:
    """Wait for every figure of ``pending``; the first rendering error is raised, as raised. An interruption while
    waiting (Ctrl-C, SIGTERM) is raised at once, the helpers killed first (:func:`_drop`)."""
    first = None
    for fut, blob, paths, dpi, tight_rect in pending:
        try:
            fut.result()
        except BrokenProcessPool:
            _reset_pool()
            _render_pickled(blob, paths, dpi, tight_rect)   # the helper died: render here
        except BaseException as err:     # noqa: BLE001 — the figure's own error, raised below as it was
            if by_interrupt(err):
                _drop(pending, err)
                raise
            first = first or err
    if first is not None:
        raise first


@contextlib.contextmanager
def deferred_figures() -> Iterator[None]:
    """Inside (``nifo run``), a step's :func:`figure_batch` does not wait for its figures: the helpers render
    them while the next step computes, and they are waited for by :func:`wait_figures` (before the report reads
    them) or on leaving. Only where the steps write into a folder nobody sees before the block is done
    (:func:`nifo.io.atomic.staged_run`). When the block raises, figures not yet started are cancelled and running
    ones waited for, so nothing is written after the caller cleans up."""
    later: list = []
    token = _deferred.set(later)
    try:
        yield
    except BaseException as exc:
        _drop(later, exc)
        raise
    else:
        wait_figures()
    finally:
        _deferred.reset(token)


def wait_figures() -> None:
    """Inside :func:`deferred_figures`: wait for the figures handed to it so far (outside: nothing to wait for)."""
    later = _deferred.get()
    if later:
        pending = list(later)
        later.clear()
        _wait(pending)


def _reset_pool() -> None:
    """The pool shut down (a broken one, or between tests), its manager thread waited for (see abandon_helpers)."""
    global _pool
    with _lock:
        pool, _pool = _pool, None
    if pool is not None:
        _end(pool)


def _end(pool: ProcessPoolExecutor) -> None:
    manager = getattr(pool, "_executor_manager_thread", None)
    with contextlib.suppress(Exception):
        pool.shutdown(wait=False, cancel_futures=True)
    if manager is not None:
        manager.join(timeout=ABANDON_WAIT_S)


def submit_figure(fig, path: str | Path, dpi: int, tight_rect: tuple | None = None, *, vector: bool = True) -> bool:
    """Hand ``fig`` to the helpers when a :func:`figure_batch` is open (closing it here); False: write it yourself."""
    pending = _batch.get()
    if pending is None:
        return False
    pool = _get_pool()
    if pool is None:
        return False
    blob = pickle.dumps(fig, protocol=pickle.HIGHEST_PROTOCOL)
    paths = [str(p) for p in figure_paths(path, vector)]
    try:
        fut = pool.submit(_render_pickled, blob, paths, dpi, tight_rect)
    except (BrokenProcessPool, RuntimeError):
        _reset_pool()
        fut = Future()
        try:
            _render_pickled(blob, paths, dpi, tight_rect)
            fut.set_result(None)
        except BaseException as err:     # noqa: BLE001 — handed to the batch like a helper's error
            fut.set_exception(err)
    pending.append((fut, blob, paths, dpi, tight_rect))
    from nifo.plots import pyplot

    pyplot().close(fig)
    return True


def abandon_helpers(*, again: bool = False) -> None:
    """An interrupted command's helpers, killed at once: none is left starting after its parent has gone. ``again``
    (a failed command's, every figure of it cancelled or waited for): a later figure of this process may start
    helpers anew; else it is written in the calling process.

    A helper still starting when its parent exits unpickles the pool's queues, whose semaphores the parent's exit
    has removed, and prints a traceback to the terminal before any of our code runs in it (measured:
    ``tests/test_kill.py``, SIGTERM 7.3 s into ``nifo identify``: FileNotFoundError in ``SemLock._rebuild``).
    The pool's processes are read from its ``_processes`` (Python 3.11 has no public way to end a pool's workers
    at once; 3.14's ``terminate_workers`` is that).

    Returns once the helpers are dead (none writes any more: an interrupted step's figures, :func:`_drop`) and the
    pool's manager thread has seen them die and closed its pipe: Python 3.11's exit hook writes to that pipe
    unguarded, and a close racing it printed ``OSError: [Errno 9] Bad file descriptor`` with a traceback after the
    interrupted command's own message (CI, ``tests/test_kill.py``, SIGINT 7.0 s into ``nifo run``)."""
    global _pool, _pool_failed
    with _lock:
        pool, _pool, _pool_failed = _pool, None, not again
    if pool is None:
        return
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for proc in procs:
        with contextlib.suppress(Exception):
            proc.kill()
    for proc in procs:
        with contextlib.suppress(Exception):
            proc.join(ABANDON_WAIT_S)
    _end(pool)


def helpers_started() -> bool:
    """Whether the helpers are up (started by :func:`start_helpers` or an earlier figure): a few figures handed to
    them then cost no start-up."""
    return _pool is not None


def start_helpers() -> None:
    """Start the helpers now (they import matplotlib in the background) rather than at the first figure."""
    _get_pool()
