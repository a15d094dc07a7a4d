"""A pure function of an array, its results kept for the arrays seen last (keyed by their content).

The output-error refinement (:mod:`nifo_core.predict.refine`) and its bias correction
(:mod:`nifo_core.predict.refine_bias`) simulate the same records dozens of times with a different θ. What
depends on the record alone — the measured input's band-limited interpolation to the simulator's fine rate
and its decimation back, the measured output's band lines — is the same every time: it is computed once and
looked up by the array's content (a 128-bit XXH3 digest of its bytes, its shape and dtype, and the other
arguments), never by identity, so a changed array can never be given a stale result.

Why XXH3 (``xxhash``, a required dependency, as the fleet's cache keys): every lookup digests the whole array,
and BLAKE2b did that at 1 GB/s. Measured on 300 s at 600 Hz (1.4 MB): BLAKE2b 1.54 ms, SHA-256 0.80 ms, XXH3-128
0.025 ms; in ``nifo loop`` on the four 300 s records of ``benchmarks/bench_loop.py`` (serial, cProfile), the
4204 lookups took 1.98 s with BLAKE2b. A 128-bit digest: two different arrays among the few kept colliding by
chance is not a practical event (the memo guards against changed arrays, not against an adversary).

The results are returned read-only: a caller that needs to write copies.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable, Hashable

import numpy as np
import xxhash

__all__ = ["ArrayMemo"]


class ArrayMemo:
    """``fn(x, *args)`` for an array ``x`` and hashable ``args``, the last ``size`` results kept.

    Parameters
    ----------
    fn : callable(ndarray, *args) -> ndarray
        Pure: its result depends on the values of ``x`` and ``args`` only, and it does not change ``x``.
    size : int
        Results kept (least recently used dropped first).
    max_bytes : int
        At most this many bytes of results kept (a result larger than it is returned, not kept): an hour
        at 600 Hz interpolated 4× is 69 MB.
    """

    def __init__(self, fn: Callable[..., np.ndarray], *, size: int = 8, max_bytes: int = 2 ** 28):
        if size < 1:
            raise ValueError(f"{size=} must be at least 1")
        self._fn = fn
        self._size = int(size)
        self._max_bytes = int(max_bytes)
        self._kept: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    def __call__(self, x: np.ndarray, *args: Hashable) -> np.ndarray:
        x = np.ascontiguousarray(x)
        key = (xxhash.xxh3_128_digest(x.view(np.uint8).reshape(-1)), x.shape, x.dtype.str, args)
        with self._lock:
            got = self._kept.get(key)
            if got is not None:
                self._kept.move_to_end(key)
                return got
        out = np.asarray(self._fn(x, *args))
        out.flags.writeable = False
        if out.nbytes > self._max_bytes:
            return out
        with self._lock:
            self._kept[key] = out
            while len(self._kept) > self._size or sum(v.nbytes for v in self._kept.values()) > self._max_bytes:
                self._kept.popitem(last=False)
        return out

    def clear(self) -> None:
        """Forget every result."""
        with self._lock:
            self._kept.clear()
