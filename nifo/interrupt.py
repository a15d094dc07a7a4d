"""Ctrl-C and SIGTERM in the ``nifo`` command: imported by ``python -m nifo`` before anything else.

- :func:`watch` (start of the process): SIGINT raises KeyboardInterrupt as Python's own handler does, and this
  process remembers that it was signalled.
- :func:`term_as_interrupt` (around a command, around an output's writing): SIGTERM ends the work as Ctrl-C does.
- :func:`signals_held` (around what must not be cut in the middle): SIGINT and SIGTERM wait until the block is done.
- :func:`crash_stacks` (start of the command's process and of each figure helper): a crash in native code (numba,
  LLVM, Agg, FreeType) prints every thread's Python stack on stderr before the process dies of the signal.
- :func:`by_interrupt`: whether an error is an interruption. An interrupt that lands inside a library can
  surface as another error raised from it: matplotlib's savefig (AttributeError in restore_bbox), or a class
  being created during an import (dataclasses' ``__set_name__``: RuntimeError, with the KeyboardInterrupt as its
  cause; measured in ``tests/test_kill.py``, SIGINT 2.3 s into ``nifo identify``, while the command's parser
  imported scipy.stats). A C extension can also drop the KeyboardInterrupt altogether: numpy's import, cut while
  it imported ``datetime``, raised ``ImportError: PyCapsule_Import could not import module "datetime"`` with no
  trace of the interrupt (CI, ``tests/test_kill.py``, SIGINT 0.1 s into ``nifo identify``). So an error in a
  process that has received SIGINT or SIGTERM is an interruption too.

Nothing heavy is imported here: a Ctrl-C at start-up must find this module already loaded.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator   # loaded with the interpreter; typing is not (4 ms of start-up)

__all__ = ["watch", "term_as_interrupt", "signals_held", "by_interrupt", "crash_stacks"]

_signalled = False


def _note() -> None:
    global _signalled
    _signalled = True


def _on_int(signum, frame):  # noqa: ARG001
    _note()
    raise KeyboardInterrupt


def crash_stacks() -> None:
    """A segmentation fault (or another fatal signal) in native code prints every thread's Python stack on stderr,
    then the process dies of it as before (:mod:`faulthandler`). A stderr without a file descriptor (embedded use)
    keeps Python's default."""
    import faulthandler

    with contextlib.suppress(AttributeError, ValueError, OSError):
        faulthandler.enable()


def watch() -> None:
    """From now on SIGINT is remembered (:func:`by_interrupt`) and raises KeyboardInterrupt as before. Main thread,
    and only over Python's own handler (a host that set its own keeps it)."""
    if threading.current_thread() is threading.main_thread() \
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _on_int)


@contextlib.contextmanager
def term_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt inside the block, so the work is cleaned up as after Ctrl-C. Main thread of
    this process, over the default handler only (nested blocks keep the outer one's); a forked child (a pool's
    worker) dies of the signal as it would have."""
    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return
    pid = os.getpid()

    def on_term(signum, frame):  # noqa: ARG001
        if os.getpid() != pid:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        _note()
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM held back until the block is done, then delivered (once each) to the handlers it had.

    For what must not be cut in the middle: an output's pair of renames (:mod:`nifo.io.atomic`), the spawning of
    figure helpers, each of which reads its start-up data through a pipe from this process (cut, a half-started
    helper printed an ``EOFError`` traceback: tests/test_kill.py, SIGINT 2.8 s into ``nifo run``). The handlers are
    swapped rather than the signals blocked (``pthread_sigmask``): a process spawned inside the block would
    inherit a blocked mask. Main thread only (handlers are set there); elsewhere nothing is held."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    old = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            before = signal.getsignal(sig)
            if before is not None:          # None: a handler not set from Python, which cannot be put back
                old[sig] = before
                signal.signal(sig, lambda signum, frame: held.append(signum))
        yield
    finally:
        for sig, before in old.items():
            signal.signal(sig, before)
        for sig in dict.fromkeys(held):
            signal.raise_signal(sig)


def by_interrupt(exc: BaseException | None) -> bool:
    """Whether ``exc`` is an interruption: a KeyboardInterrupt, an error raised from or while handling one (its
    cause/context chain), or any error once this process has received SIGINT (:func:`watch`) or SIGTERM
    (:func:`term_as_interrupt`)."""
    if exc is None:
        return False
    if _signalled:
        return True
    seen: set[int] = set()
    todo: list[BaseException | None] = [exc]
    while todo:
        e = todo.pop()
        if e is None or id(e) in seen:
            continue
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        todo += [e.__cause__, e.__context__]
    return False
