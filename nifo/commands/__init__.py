"""One module per ``nifo`` sub-command.

Each module defines ``HELP`` (one line for ``nifo --help``), ``add_arguments(parser)``
and ``run(args) -> int``. :mod:`nifo.cli` lists them in ``COMMANDS``. Argument types they share live here.
"""

import argparse
import math

__all__ = ["sprung_mass"]


def sprung_mass(text: str) -> float:
    """``--m2``: a finite positive mass [kg], refused as a usage error before any data is read."""
    try:
        m = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of kilograms (e.g. --m2 300)") from None
    if not (math.isfinite(m) and m > 0):
        raise argparse.ArgumentTypeError(f"{text} kg is not a sprung mass: give its positive mass (e.g. --m2 300)")
    return m
