"""``python -m nifo`` and the ``nifo`` console script (:func:`entry`): the command, with a Ctrl-C or SIGTERM at
any moment (even while the libraries load) ending it with one line and exit 130."""

import sys

#: what an interrupted start says (the command's own interruptions say what was written)
STARTING = "nifo: interrupted while starting; nothing was written"

try:    # a Ctrl-C before nifo's handler is in (watch) arrives as Python's KeyboardInterrupt: here, not a traceback
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


def entry() -> int:
    """Run the ``nifo`` command line; its exit code."""
    try:
        sys.unraisablehook = _interrupt_again
        watch()
        from nifo.cli import main

        return main()
    except BaseException as e:   # Ctrl-C (or SIGINT) while starting up, before a command runs: nothing was written
        if isinstance(e, SystemExit) or not by_interrupt(e):   # (an interrupt inside an import can surface as
            raise                                              # the import's own error, or as nothing of it)
        print(STARTING, file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(entry())
