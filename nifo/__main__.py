"""``python -m nifo`` and the ``nifo`` console script (:func:`entry`): the command, with a Ctrl-C or SIGTERM at
any moment (even while the libraries load) ending it with one line and exit 130."""

import sys

#: what an interrupted start says (the command's own interruptions say what was written)
STARTING = "nifo: interrupted while starting; nothing was written"

#: a Ctrl-C that landed in a finalizer before the command's hook (:func:`_interrupt_again`) is in
_lost_at_start: list[BaseException] = []


def _keep_lost_interrupt(unraisable) -> None:
    """Until :func:`entry` sets its hook: a KeyboardInterrupt raised inside a finalizer is kept, not printed as
    'Exception ignored' and lost (tests/test_kill.py: SIGINT 0.1 s into ``nifo run`` landed in importlib's module
    lock callback; the command then ran to the end and exited 0)."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        _lost_at_start.append(unraisable.exc_value)
        return
    sys.__unraisablehook__(unraisable)


sys.unraisablehook = _keep_lost_interrupt
try:    # a Ctrl-C before nifo's handler is in (watch) arrives as Python's KeyboardInterrupt: here, not a traceback
    import atexit
    import os
    import signal
    import threading

    from nifo.interrupt import by_interrupt, crash_stacks, watch   # stdlib only: loaded before anything can be cut

    crash_stacks()   # a crash in native code of this process (numba, LLVM) says where
    if _lost_at_start:
        raise KeyboardInterrupt
except KeyboardInterrupt:
    print(STARTING, file=sys.stderr)
    sys.exit(130)


def _interrupt_again(unraisable) -> None:
    """A Ctrl-C that lands in a finalizer (weakref callback, __del__) is not lost with an 'Exception
    ignored' traceback: the signal is raised again and reaches the command, which cleans up and says so."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        # not raised here (it would be "ignored in sys.unraisablehook" with a traceback): a moment later,
        # from a helper thread, so that the main thread receives it where it runs the command
        t = threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT))
        t.daemon = True
        t.start()
        return
    sys.__unraisablehook__(unraisable)


#: exit code of an interrupted command (it has cleaned up and said what was written)
INTERRUPTED = 130
_leaving: list[int] = []


def _end_without_teardown() -> None:
    """Registered first, so run last at exit: a command that has returned (finished, failed with its message, or
    interrupted) ends its process here, after the threads were joined and every other exit hook ran (the figure
    helpers' pool, multiprocessing's semaphores, logging), without the interpreter tearing its modules down.

    - Its output is complete by then: every file is written through a staged folder or file and committed (or
      rolled back) before the command returns, and the streams are flushed here.
    - The teardown cost: 0.84 s after the last exit hook of ``nifo run`` on F-16 1/3/5/7 (numba, LLVM, scipy,
      matplotlib freed object by object), and the suite starts nifo as a process 88 times.
    - It could fail: an interrupt can land inside a library's native state (numba loading a kernel from its cache,
      a ctypes call into LLVM), and tearing that down aborted the process (CI, tests/test_kill.py, SIGTERM 3.3 s
      into ``nifo identify``: its message said "interrupted; nothing was written", true, then ``Fatal Python
      error: PyThreadState_Get`` in the runtime's finalization, exit -6 instead of 130).

    Under coverage measurement (its hook was registered before this one, so runs after it) Python exits as it
    would; so does a command that raised (a bug: its traceback, then the usual exit)."""
    if not _leaving or _measured():
        return
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):   # closed, or replaced by something without flush
            pass
    os._exit(_leaving[0])


def _measured() -> bool:
    """Whether coverage is measuring this process (numba imports coverage whenever it is installed)."""
    coverage = sys.modules.get("coverage")
    current = getattr(getattr(coverage, "Coverage", None), "current", None)
    return current is not None and current() is not None


def entry() -> int:
    """Run the ``nifo`` command line; its exit code. For a process of its own (``python -m nifo``, the console
    script): its exit hook (:func:`_end_without_teardown`), registered before the command imports anything that
    registers one, ends the process when Python exits."""
    code = INTERRUPTED
    try:
        atexit.register(_end_without_teardown)
        sys.unraisablehook = _interrupt_again
        if _lost_at_start:   # swallowed between the guarded imports and here
            raise KeyboardInterrupt
        watch()
        from nifo.cli import main

        code = main()
    except BaseException as e:   # Ctrl-C (or SIGINT) while starting up, before a command runs: nothing was written
        if isinstance(e, SystemExit) or not by_interrupt(e):   # (an interrupt inside an import can surface as
            raise                                              # the import's own error, or as nothing of it)
        print(STARTING, file=sys.stderr)
    _leaving.append(code)
    return code


if __name__ == "__main__":
    sys.exit(entry())
