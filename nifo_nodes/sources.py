"""Where the acquisition node's samples come from: the simulator, data files, or a DAQ.

The DAQ-source interface
------------------------
A source is any object with

``fs_hz: float``
    its sample rate [Hz];
``has_tire_patch: bool``
    whether :class:`Samples` carry a tire-patch displacement;
``poll() -> Samples | None``
    the samples that became available since the last call (possibly none;
    never blocks for long), or ``None`` when the source is exhausted;
``close() -> None``
    release the hardware.

Stamps are the *source's* sample times [int ns] (the DAQ's clock, PTP-synced
where there is one), never the time the node read them: live and replay then
agree. Values are SI: accelerations [m/s²] (gravity removed or not, as long as
it is constant), tire-patch displacement [m]. To add hardware, subclass
:class:`Source` in your own package and start the acquisition node with
``source: "your_pkg.daq:YourSource"`` and ``source_options: '{"device": "/dev/..."}'``
(JSON, passed as keyword arguments). :class:`RecordSource` is the reference
implementation (paced by a monotonic clock to play a file "live").
"""

from __future__ import annotations

import importlib
import json
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from nifo_core.errors import ConfigError
from nifo_core.signal.record import Record

__all__ = ["Samples", "Source", "RecordSource", "FileSource", "SimulatorSource", "make_source"]


@dataclass(frozen=True)
class Samples:
    """Consecutive samples of the channels, with their source stamps [ns]."""

    stamp_ns: np.ndarray
    spindle_accel: np.ndarray
    body_accel: np.ndarray
    tire_patch_disp: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.stamp_ns.size)


class Source(ABC):
    """Base of acquisition sources (see the module docstring for the contract)."""

    fs_hz: float
    has_tire_patch: bool = False

    @abstractmethod
    def poll(self) -> Samples | None:
        """Samples available now (maybe none), or None when the source has ended."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release resources."""


class RecordSource(Source):
    """Play a :class:`Record` in real time (``speed`` × real time), optionally looping.

    Stamps are ``stamp0_ns + round(k·1e9/fs)`` with k counting on across loops,
    so a looped record is one continuous stream in time (its content jumps at
    the loop point). ``stamp0_ns`` defaults to the record's ``t0_ns``.
    """

    def __init__(self, record: Record, *, speed: float = 1.0, loop: bool = False, stamp0_ns: int | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not speed > 0:
            raise ConfigError(f"{speed=} must be > 0", channel="speed")
        self.record = record
        self.fs_hz = float(record.fs_hz)
        self.has_tire_patch = record.has_tire_patch
        self._speed, self._loop, self._clock = float(speed), bool(loop), clock
        self._stamp0 = record.t0_ns if stamp0_ns is None else int(stamp0_ns)
        self._k = 0  # samples emitted in total
        self._t_start: float | None = None

    def _due(self) -> int:
        if self._t_start is None:
            self._t_start = self._clock()
        return int((self._clock() - self._t_start) * self._speed * self.fs_hz)

    def poll(self) -> Samples | None:
        n = self.record.n
        if not self._loop and self._k >= n:
            return None
        due = self._due() if self._speed != float("inf") else self._k + n
        if not self._loop:
            due = min(due, n)
        ks = np.arange(self._k, max(due, self._k))
        self._k = max(due, self._k)
        i = ks % n
        r = self.record
        stamps = self._stamp0 + np.rint(ks * (1e9 / self.fs_hz)).astype(np.int64)
        tp = r.tire_patch_disp[i] if r.tire_patch_disp is not None else None
        return Samples(stamps, r.spindle_accel[i], r.body_accel[i], tp)


class FileSource(RecordSource):
    """A CSV, MAT or bag file (anything :func:`nifo.io.loader.load_record` reads), played in real time."""

    def __init__(self, path: str | Path, *, speed: float = 1.0, loop: bool = False, **kw) -> None:
        from nifo.io.loader import load_record

        super().__init__(load_record(path), speed=speed, loop=loop, **kw)


class SimulatorSource(Source):
    """A virtual test vehicle: the nonlinear quarter-car simulator, run chunk by chunk in real time.

    Each chunk of ``chunk_s`` is a fresh simulation (seed ``seed + i``) made in
    a background thread while the previous one plays; stamps run on without a
    break from ``stamp0_ns`` (default: the wall clock at start, as a DAQ would).
    The content restarts at each chunk boundary (the simulator has no
    continuation state), so an identifier sees a step there once per chunk.
    """

    def __init__(self, *, fs_hz: float = 600.0, chunk_s: float = 60.0, road_rms_m: float = 0.0025,
                 strut: str = "paper", seed: int = 0, speed: float = 1.0, stamp0_ns: int | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset

        self.fs_hz = float(fs_hz)
        self.has_tire_patch = True
        self._cfg = SimConfig(strut=preset(strut), road=RandomRoad(road_rms_m), duration_s=chunk_s, fs_hz=fs_hz)
        self._seed, self._speed, self._clock = int(seed), float(speed), clock
        self._stamp0 = time.time_ns() if stamp0_ns is None else int(stamp0_ns)
        self._chunk = 0
        self._next: Record | None = None
        self._thread: threading.Thread | None = None
        self._current = RecordSource(self._simulate(0), speed=speed, stamp0_ns=self._stamp0, clock=clock)
        self._prefetch()

    def _simulate(self, i: int) -> Record:
        from nifo_core.simulate.quarter_car import simulate

        return simulate(self._cfg, rng=self._seed + i).record

    def _prefetch(self) -> None:
        def work(i=self._chunk + 1):
            self._next = self._simulate(i)
        self._next = None
        self._thread = threading.Thread(target=work, daemon=True)
        self._thread.start()

    def poll(self) -> Samples | None:
        s = self._current.poll()
        if s is not None:
            return s
        self._thread.join()
        self._chunk += 1
        n_done = self._chunk * self._cfg.n_samples
        self._current = RecordSource(self._next, speed=self._speed, clock=self._clock,
                                     stamp0_ns=self._stamp0 + int(round(n_done * 1e9 / self.fs_hz)))
        self._prefetch()
        return self._current.poll()


def make_source(kind: str, *, path: str = "", speed: float = 1.0, loop: bool = False, options: str = "",
                fs_hz: float = 600.0, seed: int = 0) -> Source:
    """The acquisition node's ``source`` parameter to a :class:`Source`.

    ``"simulator"``, ``"file"`` (``path``: CSV/MAT/bag) or ``"module:Class"`` (a
    DAQ source, constructed with the JSON ``options`` as keyword arguments).
    """
    try:
        opts = json.loads(options) if options else {}
    except json.JSONDecodeError as err:
        raise ConfigError(f"source_options is not valid JSON ({err})", channel="source_options") from None
    if not isinstance(opts, dict):
        raise ConfigError("source_options must be a JSON object", channel="source_options")
    if kind == "simulator":
        return SimulatorSource(fs_hz=fs_hz, seed=seed, speed=speed, **opts)
    if kind == "file":
        if not path:
            raise ConfigError("source 'file' needs the 'path' parameter", channel="path")
        return FileSource(path, speed=speed, loop=loop, **opts)
    mod, sep, cls = kind.partition(":")
    if not sep:
        raise ConfigError(f"unknown source {kind!r}", channel="source",
                          hint="use simulator, file, or module:Class for a DAQ source")
    try:
        factory = getattr(importlib.import_module(mod), cls)
    except (ImportError, AttributeError) as err:
        raise ConfigError(f"cannot import DAQ source {kind!r} ({err})", channel="source") from err
    src = factory(**opts)
    for attr in ("fs_hz", "poll"):
        if not hasattr(src, attr):
            raise ConfigError(f"DAQ source {kind!r} has no {attr!r}", channel="source",
                              hint="implement nifo_nodes.sources.Source")
    return src
