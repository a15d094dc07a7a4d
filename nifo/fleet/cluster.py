"""The Dask client of a fleet run: an embedded LocalCluster by default, or an existing scheduler.

One code path: both give a :class:`distributed.Client`; everything after that
is the same. The embedded cluster has one single-threaded worker process per
core (NIFO's numpy work holds the GIL for much of its time, so processes, not
threads, and BLAS/OpenMP pinned to one thread per worker by Dask's nanny),
with glibc's malloc left adaptive and Dask's periodic bookkeeping thinned (:data:`CLUSTER_CONFIG`).

Start-up is paid once, not once per worker: the embedded cluster's workers are
forked from one fork server (:func:`start_worker_server`) that imported and warmed
:mod:`nifo.fleet.preload` (the task path, its lazy imports, the numba kernels from
numba's on-disk cache) before the first worker starts: a worker then costs ~0.06 s
of CPU to start. With Dask's default (spawn) every worker imported the task path
before its first bag (2.8-3.9 s of CPU, measured; scipy.signal the largest part), and
the first bag ~0.3 s more (docs/fleet.md, "Start-up and scaling"). On any cluster, ``nifo fleet`` also
registers :class:`nifo.fleet.worker_plugin.WarmWorker`, which imports the same module
once per worker as soon as it joins (a no-op on a forked worker). Dask and
distributed are imported inside the functions: ``nifo fleet`` starts the fork
server before it imports them (0.5 s of CPU the server's import overlaps).
"""

from __future__ import annotations

import contextlib
import logging
import os
from typing import Iterator

from nifo_core.errors import NifoError

__all__ = ["ClusterError", "FleetError", "fleet_client", "dashboard_line", "start_worker_server", "CLUSTER_CONFIG",
           "PRELOAD"]

#: the module a worker imports to be warm (the fork server's preload; ``dask worker --preload``)
PRELOAD = "nifo.fleet.preload"


#: Dask settings of the embedded cluster (scheduler, nannies, workers), for a batch job on few cores:
#:
#: - Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also freezes
#:   glibc's mmap threshold at 128 kB: every array above that (chunks, FFT blocks) is then
#:   mmap'ed and unmapped again and its pages faulted in anew, which doubled the CPU time of
#:   a bag (measured: 30 bags, 3.4 s instead of 1.9 s, half of it in the kernel). Unset
#:   (None), glibc keeps its adaptive thresholds.
#: - The workers' statistical profiler (a stack sample every 10 ms, for the dashboard's
#:   Profile page) cost each worker ~4 % of a core, busy or idle; it is off. The event-loop
#:   health tick (20 ms), the system monitor (0.5 s) and the memory monitor (0.1 s) run
#:   every 1 s, 5 s and 1 s: idle, the cluster then takes 1.7 % of a core instead of 13 %
#:   (measured with 2 workers).
#:
#: - Workers are forked from a fork server that imported and warmed :data:`PRELOAD` once
#:   (:func:`start_worker_server`), not spawned as fresh interpreters that each import it.
#:
#: BLAS/OpenMP stay at one thread per worker (Dask's default; the fork server starts with
#: Dask's pre-spawn environment, so its workers do too), and so do nifo's own simulation threads
#: (``NIFO_THREADS``, :mod:`nifo_core.signal.parallel`): the workers are the parallelism.
CLUSTER_CONFIG = {"distributed.worker.multiprocessing-method": "forkserver",
                  "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                  "distributed.nanny.pre-spawn-environ.NIFO_THREADS": 1,
                  "distributed.worker.profile.enabled": False,
                  "distributed.admin.tick.interval": "1s",
                  "distributed.admin.system-monitor.interval": "5s",
                  "distributed.worker.memory.monitor-interval": "1s"}


def start_worker_server() -> None:
    """Start, now, the fork server every worker of an embedded cluster is forked from, :data:`PRELOAD` imported in it.

    Idempotent (one fork server per process; a second call returns at once). Call it as
    early as possible: the server imports and warms in its own process while this one
    goes on (``nifo fleet`` calls it before it reads the manifest). The server starts
    with Dask's pre-spawn environment (BLAS/OpenMP one thread, as Dask's nanny sets
    before it starts each worker), which its workers inherit.
    """
    import multiprocessing
    from multiprocessing import forkserver

    import dask     # not distributed: the fork server imports it (0.5 s of CPU) while this process goes on

    with dask.config.set(CLUSTER_CONFIG):
        env = {k: str(v) for k, v in dask.config.get("distributed.nanny.pre-spawn-environ").items() if v is not None}
    os.environ.update(env)         # what Dask's nanny does before each worker start (Nanny docstring)
    multiprocessing.get_context("forkserver").set_forkserver_preload(["distributed", PRELOAD])
    forkserver.ensure_running()


class ClusterError(NifoError, ConnectionError):
    """The Dask scheduler cannot be reached or the local cluster cannot start."""

    exit_code = 20


class FleetError(NifoError, RuntimeError):
    """No group of the fleet could be identified."""

    exit_code = 21


@contextlib.contextmanager
def fleet_client(scheduler: str | None = None, *, workers: int | None = None,
                 dashboard_address: str | None = ":0", timeout_s: float = 20.0) -> Iterator["object"]:
    """Yield a connected :class:`distributed.Client`; close what this function started.

    Parameters
    ----------
    scheduler : str, optional
        Address of an existing scheduler (``tcp://host:8786``); None starts a LocalCluster.
    workers : int, optional
        Worker processes of the LocalCluster (default: the number of cores). Ignored with ``scheduler``.
    dashboard_address : str or None
        Where the LocalCluster serves its dashboard (``":0"``: a free port; None: no dashboard).
    timeout_s : float
        How long to wait for the scheduler [s].
    """
    import dask
    from distributed import Client, LocalCluster

    from nifo.fleet.worker_plugin import WarmWorker

    if scheduler:
        try:
            client = Client(scheduler, timeout=f"{timeout_s}s")
        except (OSError, TimeoutError) as err:
            raise ClusterError(f"cannot reach the Dask scheduler {scheduler} ({err})", channel="--scheduler",
                               hint="start one (dask scheduler; dask worker tcp://HOST:8786) or leave out "
                                    "--scheduler to run on this machine") from None
        try:
            with contextlib.suppress(Exception):   # a worker without nifo: its first task says so, bag by bag
                client.register_plugin(WarmWorker(), name=WarmWorker.name)   # every worker imports once, as it joins
            yield client
        finally:
            client.close()
        return
    n = workers or os.cpu_count() or 1
    if n < 1:
        raise ClusterError(f"--workers {workers!r} must be at least 1", channel="--workers")
    with dask.config.set(CLUSTER_CONFIG):     # for the cluster's life: a worker restarted by its nanny gets it too
        try:
            start_worker_server()
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address=dashboard_address, silence_logs=logging.ERROR)
        except Exception as err:  # noqa: BLE001 - e.g. no free port, no fork
            raise ClusterError(f"cannot start a local Dask cluster of {n} workers ({err})",
                               hint="try --workers 1, or point --scheduler at a running cluster") from None
        try:
            client = Client(cluster, direct_to_workers=True)   # results come from the workers, not via the scheduler
            try:
                client.register_plugin(WarmWorker(), name=WarmWorker.name)
                yield client
            finally:
                client.close()
        finally:
            cluster.close()


def dashboard_line(client) -> str:
    """One line naming the scheduler, the workers and the dashboard address."""
    info = client.scheduler_info()
    workers = info.get("workers", {})
    threads = sum(w.get("nthreads", 1) for w in workers.values())
    try:
        link = client.dashboard_link
    except Exception:  # noqa: BLE001 - no dashboard (bokeh missing or disabled)
        link = None
    dash = f"dashboard {link}" if link else "no dashboard (install bokeh>=3.1 to get one)"
    return f"Dask: scheduler {client.scheduler.address}, {len(workers)} worker(s), {threads} thread(s); {dash}"
