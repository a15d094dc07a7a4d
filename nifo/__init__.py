"""nifo: the application shell around ``nifo_core`` — the ``nifo`` command, file and bag I/O,
plots, reports and Rerun views. The numerics live in ``nifo_core``.

Nothing is imported here: ``python -m nifo`` runs this before the command's Ctrl-C guard
(:mod:`nifo.__main__`), so a Ctrl-C this early is Python's traceback, not nifo's one line."""

__all__ = ["__version__"]


def __getattr__(name: str):
    if name == "__version__":
        from nifo_core import __version__

        return __version__
    raise AttributeError(f"module 'nifo' has no attribute {name!r}")
