"""Whether an error is a Ctrl-C (or SIGTERM) in disguise: imported by ``python -m nifo`` before anything else.

An interrupt that lands inside a library can surface as another error raised from it: matplotlib's savefig
(AttributeError in restore_bbox), or a class being created during an import (dataclasses' ``__set_name__``:
RuntimeError, with the KeyboardInterrupt as its cause; measured in ``tests/test_kill.py``, SIGINT 2.3 s into
``nifo identify``, while the command's parser imported scipy.stats). Those are interruptions, not bugs.
"""

from __future__ import annotations

import os
import sys
from typing import NoReturn

__all__ = ["by_interrupt", "leave"]

#: the exit code of an interrupted command (Ctrl-C, SIGTERM)
INTERRUPTED = 130


def by_interrupt(exc: BaseException | None) -> bool:
    """Whether ``exc`` is a KeyboardInterrupt or was raised from or while handling one (its cause/context chain)."""
    seen: set[int] = set()
    todo = [exc]
    while todo:
        e = todo.pop()
        if e is None or id(e) in seen:
            continue
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        todo += [e.__cause__, e.__context__]
    return False


def leave(code: int) -> NoReturn:
    """End the ``nifo`` process with ``code``. An interrupted command (:data:`INTERRUPTED`) has already cleaned up
    its outputs and said so: it ends at once, its streams flushed, without the interpreter's finalization — where
    whatever a library was doing when the signal came (a figure pool's feeder thread, a native worker) can crash
    the exit. Measured once in ``tests/test_kill.py``: SIGTERM 5.0 s into ``nifo identify``, the one-line message,
    then "Fatal Python error: PyThreadState_Get: ... finalizing" and exit -6 instead of 130. A SIGKILL skips
    finalization too, and the outputs are safe against that."""
    if code == INTERRUPTED:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:   # noqa: BLE001 — a closed or broken stream: nothing left to say on it
                pass
        os._exit(code)
    sys.exit(code)
