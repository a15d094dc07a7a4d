"""What a job read from a file, kept for the job's next read of the same file (issue 29: repeated reads).

``nifo run``'s steps each read the same data files: measured on the bundled sample (3 bags of 120 s),
26 whole reads of 0.3-0.4 s each (decompressing, checking every chunk's CRC, decoding the messages) and 21
probes of their first samples. Inside :func:`reuse_reads` a file read once is not read again: the result is
kept under the file's identity (:func:`file_identity`: its resolved path, size, modification time and inode,
for a bag directory every file in it) and the read's options. A :class:`~nifo_core.signal.record.Record` is
immutable (read-only arrays), so every step can share one. Outside, every read reads the file: the memo is
for work that reads files it does not change, within one command (the test that rewrites a file in place
between two reads gets both reads).

Each memo is bounded (least recently used first out): :data:`RECORD_MEMO_BYTES` of records, whatever the
length of the recordings. A channel read from another file (``NAME@FILE``) is keyed by that file's name
only: within one command the files do not change.
"""

from __future__ import annotations

import contextlib
import contextvars
import threading
from collections import OrderedDict
from dataclasses import fields
from pathlib import Path
from typing import Callable, Iterator, TypeVar

import numpy as np

__all__ = ["BoundedMemo", "file_identity", "nbytes", "reuse_reads", "remembered", "known", "RECORD_MEMO_BYTES"]

T = TypeVar("T")

#: bytes of whole records kept inside :func:`reuse_reads` (an hour at 1 kHz of three channels is 86 MB)
RECORD_MEMO_BYTES = 2 ** 28


def file_identity(path: Path) -> tuple:
    """What changes when a file (or a bag directory's files) changes: name, size, modification time, inode."""
    st = path.stat()
    if not path.is_dir():
        return (str(path.resolve()), st.st_size, st.st_mtime_ns, st.st_ino)
    return (str(path.resolve()),) + tuple(sorted((q.name, q.stat().st_size, q.stat().st_mtime_ns)
                                                for q in path.iterdir() if q.is_file()))


def nbytes(obj) -> int:
    """Bytes held by a dataclass's array fields (a record's channels)."""
    return sum(getattr(obj, f.name).nbytes for f in fields(obj) if isinstance(getattr(obj, f.name), np.ndarray))


class BoundedMemo:
    """Results by key, least recently used out first once their :func:`nbytes` pass ``max_bytes``; thread-safe."""

    def __init__(self, max_bytes: int, size: Callable[[object], int] = nbytes) -> None:
        self.max_bytes, self._size = int(max_bytes), size
        self._items: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        with self._lock:
            if key not in self._items:
                return None
            self._items.move_to_end(key)
            return self._items[key]

    def put(self, key, value) -> None:
        size = self._size(value)
        if size > self.max_bytes:
            return
        with self._lock:
            self._items[key] = value
            while sum(self._size(v) for v in self._items.values()) > self.max_bytes:
                self._items.popitem(last=False)


_memos: contextvars.ContextVar[dict | None] = contextvars.ContextVar("nifo_reads", default=None)


@contextlib.contextmanager
def reuse_reads() -> Iterator[None]:
    """Inside, a file read once is not read again (module docstring); on leaving, everything kept is let go."""
    token = _memos.set({})
    try:
        yield
    finally:
        _memos.reset(token)


def _key(path: Path, options: dict) -> tuple:
    return file_identity(Path(path)), repr(sorted(options.items(), key=lambda kv: kv[0]))


def known(path: Path, options: dict, *, kind: str = "record"):
    """What :func:`remembered` gave for the same file and ``options`` before in this job, else None (never reads)."""
    memos = _memos.get()
    memo = None if memos is None else memos.get(kind)
    if memo is None:
        return None
    try:
        return memo.get(_key(path, options))
    except OSError:
        return None


def remembered(path: Path, options: dict, read: Callable[[], T], *, kind: str = "record",
               max_bytes: int = RECORD_MEMO_BYTES, size: Callable[[object], int] = nbytes) -> T:
    """``read()``, or inside :func:`reuse_reads` what it gave for the same file and ``options`` before.

    ``kind`` names the memo (each bounded by its own ``max_bytes`` of ``size``): a whole record, a probe of
    the first samples.
    """
    memos = _memos.get()
    if memos is None:
        return read()
    try:
        key = _key(path, options)
    except OSError:
        return read()        # unreadable: the reader says why
    memo = memos.setdefault(kind, BoundedMemo(max_bytes, size))
    got = memo.get(key)
    if got is None:
        got = read()
        memo.put(key, got)
    return got
