"""Independent computations side by side on threads: for work that releases the GIL.

The simulations of a model (:mod:`nifo_core.predict.timesim`: numba kernels compiled ``nogil``, scipy's
polyphase resampling and FFTs, which release the GIL too) are independent and pure. The output-error
refinement's forward-difference Jacobian is one simulation per parameter at the same base point: its columns
run on threads (:func:`forward_jacobian`), or in batches, a batch per thread (:func:`batch_map`: a record's
simulations for a batch of columns marched together, :mod:`nifo_core.predict.timesim_lanes`), each column bit for
bit what the serial loop gives (issue 29, ``benchmarks/bench_run.py --serial``).
Threads rather than processes: no records pickled per evaluation and nothing to start; the records
themselves are shared read-only.

A map called from inside another map's worker runs serially (no nested pools oversubscribing the cores).
``NIFO_THREADS`` (environment) sets the most threads; 1 runs everything serially.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

import numpy as np

__all__ = ["thread_map", "batch_map", "max_threads", "forward_jacobian"]

T = TypeVar("T")
R = TypeVar("R")

#: environment variable: the most threads (1: serial)
THREADS_ENV = "NIFO_THREADS"

_inside = threading.local()


def max_threads() -> int:
    """Most worker threads: ``NIFO_THREADS`` when set, else the CPUs this process may use."""
    env = os.environ.get(THREADS_ENV, "").strip()
    if env.isdigit() and int(env) >= 1:
        return int(env)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def _in_worker(fn: Callable[[T], R]) -> Callable[[T], R]:
    def run(item: T) -> R:
        _inside.active = True
        try:
            return fn(item)
        finally:
            _inside.active = False
    return run


def thread_map(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, the calls on up to :func:`max_threads` threads, results in order.

    ``fn`` must be safe to run concurrently (pure, or touching only its own item). An exception from any
    call is raised here (the first in item order), as the serial loop would raise it.
    """
    items = list(items)
    workers = min(max_threads(), len(items))
    if workers < 2 or getattr(_inside, "active", False):
        return [fn(x) for x in items]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(_in_worker(fn), items))


def batch_map(fn: Callable[[list[T]], list[R]], items: Iterable[T]) -> list[R]:
    """``fn`` of contiguous batches of ``items``, a batch per thread, its results in item order: for work that is
    cheaper together than one by one (several simulations of a record marched together,
    :mod:`nifo_core.predict.timesim_lanes`). Inside another map's worker, or with one thread, one batch of all.
    ``fn(batch)`` returns one result per item of ``batch``."""
    items = list(items)
    if not items:
        return []
    n = 1 if getattr(_inside, "active", False) else min(max_threads(), len(items))
    bounds = np.linspace(0, len(items), n + 1).round().astype(int)
    batches = [items[a:b] for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    return [r for got in thread_map(fn, batches) for r in got]


def forward_jacobian(fun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, f0: np.ndarray,
                     steps: np.ndarray, *, together: Callable[[list[np.ndarray]], list[np.ndarray]] | None = None
                     ) -> np.ndarray:
    """Forward differences of ``fun`` at ``x0`` (``f0 = fun(x0)``), one column per step of ``steps``, the
    columns on threads (:func:`thread_map`: ``fun`` must be safe to call from several threads at once), or, with
    ``together`` (``fun`` of several points at once, the same values), in batches (:func:`batch_map`).

    Each column is divided by its step as represented, (x0 + h)_j - x0_j, as scipy's differences are.

    Returns
    -------
    ndarray, shape (f0.size, x0.size)
    """
    x0 = np.asarray(x0, float)
    f0 = np.asarray(f0, float)
    points = []
    for j in range(x0.size):
        x = x0.copy()
        x[j] += steps[j]
        points.append(x)
    values = batch_map(together, points) if together is not None else thread_map(fun, points)
    cols = [(np.asarray(f, float) - f0) / (x[j] - x0[j]) for j, (x, f) in enumerate(zip(points, values))]
    return np.column_stack(cols) if cols else np.zeros((f0.size, 0))
