"""A fleet worker's start-up, paid once per cluster rather than once per worker: importing this module warms the process.

Importing it is its whole job (side effects on import are the point here): it
imports what a bag task needs, including what the task path imports lazily
(the bag readers, rosbags' type store, the MCAP decoders: ~0.3 s on a first
bag, measured with ``sys.modules`` before and after a first
:func:`nifo.fleet.tasks.compute_batch`), and loads the numba kernels a bag
task may call (the spectral engine's block products, the play operator of a backlash term) from numba's on-disk
cache (``cache=True``: the first run on a machine compiles it and writes the
cache beside the source, or in the user's cache folder when the package is
read-only; later runs load it in ~10 ms). What it did is kept in :data:`WARM`.

Who imports it:

- the embedded cluster's fork server (:func:`nifo.fleet.cluster.start_worker_server`):
  one process imports and warms once, every worker is forked from it warm
  (measured: ~0.05 s of CPU per worker instead of ~2-4 s);
- ``dask worker --preload nifo.fleet.preload`` on an external cluster, and the
  worker plugin :class:`nifo.fleet.worker_plugin.WarmWorker` that ``nifo fleet``
  registers on any cluster (a no-op where the module is in already): the import
  then happens once per worker, before its first bag, not inside it.

It never raises: a failure to warm something is recorded in :data:`WARM`
(``failed``) and the worker pays it later, on the bag that needs it.
"""

from __future__ import annotations

import importlib
import time

__all__ = ["WARM", "TASK_MODULES", "LAZY_MODULES", "warm", "kernel_stats", "dask_setup"]

#: what a worker runs: the task functions (their top-level imports: numpy, scipy.signal, numba, the core)
TASK_MODULES = ("nifo.fleet.tasks",)

#: what a bag task imports inside functions (found by diffing ``sys.modules`` around a first bag; kept
#: in step by ``tests/test_fleet_preload.py``, which checks that a warmed worker's first bag imports nothing)
LAZY_MODULES = ("nifo.io.bag", "nifo.io.bag._read", "nifo.io.bag._stream", "nifo.io.bag._topics", "nifo.io.bag._mcap",
                "nifo.io.bag.cdr", "rosbags.interfaces", "rosbags.rosbag2", "rosbags.typesys", "mcap.reader",
                "mcap.data_stream", "mcap.records", "zstandard", "lz4.frame", "yaml", "ruamel.yaml")


def _kernels():
    """The numba kernels of the bag path, each with a call that loads (or, the first time, compiles) it."""
    import numpy as np

    from nifo_core.kinds import describing
    from nifo_core.signal import _block_products

    def products():     # every bag's cross-spectra: the same argument types as CrossSpectralAccumulator.push
        _block_products.accumulate_block_products(np.zeros((2, 1, 3), complex), np.zeros((3, 2, 2), complex))

    return {"nifo_core.kinds.describing._play": (describing._play,
                                                 lambda: describing.play_operator(np.zeros(4), 0.1)),
            "nifo_core.signal._block_products._accumulate": (_block_products._accumulate, products)}


def kernel_stats() -> dict[str, dict]:
    """Per kernel of the bag path: its compiled signatures and numba's cache hits and misses in this process."""
    return {name: {"signatures": [str(s) for s in d.signatures], "cache_hits": sum(d.stats.cache_hits.values()),
                   "cache_misses": sum(d.stats.cache_misses.values()), "cache_path": d.stats.cache_path}
            for name, (d, _) in _kernels().items()}


def warm() -> dict:
    """Import the task path and its lazy imports, build the bag type store, load the kernels; what it took.

    Wall seconds per step, and ``process_cpu_s``: the CPU time of this process so far (its whole start-up).
    """
    t0 = time.perf_counter()
    failed = []
    for name in TASK_MODULES + LAZY_MODULES:
        try:
            importlib.import_module(name)
        except Exception as err:  # noqa: BLE001 - an optional reader missing: the bag that needs it says so
            failed.append(f"{name}: {type(err).__name__}: {err}")
    t1 = time.perf_counter()
    try:
        from rosbags.typesys import Stores, get_typestore

        get_typestore(Stores.ROS2_JAZZY)          # what every bag read builds first (nifo.io.bag's _stream, _read)
    except Exception as err:  # noqa: BLE001
        failed.append(f"typestore: {type(err).__name__}: {err}")
    t2 = time.perf_counter()
    try:
        for _, load in _kernels().values():
            load()
    except Exception as err:  # noqa: BLE001
        failed.append(f"kernels: {type(err).__name__}: {err}")
    t3 = time.perf_counter()
    return {"import_s": t1 - t0, "typestore_s": t2 - t1, "kernels_s": t3 - t2, "seconds": t3 - t0,
            "process_cpu_s": time.process_time(), "failed": failed}


def dask_setup(worker) -> None:  # noqa: ARG001 - Dask's preload hook (dask worker --preload nifo.fleet.preload)
    """Nothing more to do: importing this module warmed the worker's process."""


#: what warming this process took (seconds per step, anything that failed)
WARM = warm()
