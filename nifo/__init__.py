"""nifo: the application shell around ``nifo_core`` — the ``nifo`` command, file and bag I/O,
plots, reports and Rerun views. The numerics live in ``nifo_core``.

Nothing is imported here: ``python -m nifo`` runs this before the command's Ctrl-C guard
(:mod:`nifo.__main__`), so a Ctrl-C this early is Python's traceback, not nifo's one line. For scripts,
``nifo.Model`` and ``nifo.load_record`` (:mod:`nifo.api`) are imported when first used."""

__all__ = ["__version__", "Model", "load_record"]

#: the scripting front door (:mod:`nifo.api`), imported on first use
_API = {"Model": "nifo.api", "load_record": "nifo.api"}


def __getattr__(name: str):
    if name == "__version__":
        from nifo_core import __version__

        return __version__
    if name in _API:
        import importlib

        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'nifo' has no attribute {name!r}")
