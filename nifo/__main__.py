"""``python -m nifo`` and the ``nifo`` console script (:func:`entry`): the command, with a Ctrl-C or SIGTERM at
any moment (even while the libraries load) ending it with one line and exit 130."""

import sys

#: what an interrupted start says (the command's own interruptions say what was written)
STARTING = "nifo: interrupted while starting; nothing was written"

try:    # a Ctrl-C before nifo's handler is in (watch) arrives as Python's KeyboardInterrupt: here, not a traceback
    import atexit
    import os
    import signal
    import threading

    from nifo.interrupt import by_interrupt, watch   # stdlib only: loaded before anything can be interrupted
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


def _leave_without_teardown() -> None:
    """Registered first, so run last at exit: an interrupted command's process ends here, after the threads were
    joined and every other exit hook ran (the figure helpers' pool, multiprocessing's semaphores), without the
    interpreter tearing its modules down. An interrupt can land inside a library's native state (numba loading a
    kernel from its cache, a ctypes call into LLVM), and tearing that down aborted the process: CI,
    tests/test_kill.py, SIGTERM 3.3 s into ``nifo identify``: its message said "interrupted; nothing was
    written" (true), then ``Fatal Python error: PyThreadState_Get: the function must be called with the GIL held``
    in the runtime's finalization, exit -6 instead of 130. Only for an interrupted command: a finished one exits
    as Python does."""
    if _leaving:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError, AttributeError):   # closed, or replaced by something without flush
                pass
        os._exit(_leaving[0])


def entry() -> int:
    """Run the ``nifo`` command line; its exit code."""
    code = INTERRUPTED
    try:
        atexit.register(_leave_without_teardown)
        sys.unraisablehook = _interrupt_again
        watch()
        from nifo.cli import main

        code = main()
    except BaseException as e:   # Ctrl-C (or SIGINT) while starting up, before a command runs: nothing was written
        if isinstance(e, SystemExit) or not by_interrupt(e):   # (an interrupt inside an import can surface as
            raise                                              # the import's own error, or as nothing of it)
        print(STARTING, file=sys.stderr)
    if code == INTERRUPTED:
        _leaving.append(code)
    return code


if __name__ == "__main__":
    sys.exit(entry())
