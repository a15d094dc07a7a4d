import os
import signal
import sys
import threading


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


sys.unraisablehook = _interrupt_again
from nifo.interrupt import by_interrupt  # noqa: E402  (no imports of its own: before anything can be interrupted)

try:
    from nifo.cli import main

    code = main()
except BaseException as e:   # Ctrl-C (or SIGINT) while starting up, before a command runs: nothing was written
    if not by_interrupt(e):  # (an interrupt inside an import can surface as the import's own error)
        raise
    print("nifo: interrupted while starting; nothing was written", file=sys.stderr)
    code = 130
sys.exit(code)
