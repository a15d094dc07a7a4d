"""The worker plugin that warms every worker of any cluster as it joins (see :mod:`nifo.fleet.preload`)."""

from __future__ import annotations

import importlib

from distributed.diagnostics.plugin import WorkerPlugin

__all__ = ["WarmWorker"]


class WarmWorker(WorkerPlugin):
    """Import :mod:`nifo.fleet.preload` on every worker as it joins: once per worker, before its first task.

    A no-op on a worker forked from the embedded cluster's fork server (the module is in already);
    on an external cluster each worker pays its imports here, not inside its first bag.
    """

    name = "nifo-warm"

    def setup(self, worker) -> None:  # noqa: ARG002 - WorkerPlugin's signature
        importlib.import_module("nifo.fleet.preload")
