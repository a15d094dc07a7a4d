"""nifo: the application shell around ``nifo_core`` — the ``nifo`` command, file and bag I/O,
plots, reports and Rerun views. The numerics live in ``nifo_core``."""

from nifo_core import __version__

__all__ = ["__version__"]
