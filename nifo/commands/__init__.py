"""One module per ``nifo`` sub-command.

Each module defines ``HELP`` (one line for ``nifo --help``, from :data:`SUMMARIES`), ``add_arguments(parser)``
and ``run(args) -> int``. :mod:`nifo.cli` lists them in ``COMMANDS``. Argument types they share live here.
"""

import argparse
import math
from typing import Callable

__all__ = ["SUMMARIES", "sprung_mass", "checked_by"]

#: each command's line in ``nifo --help`` (its module's ``HELP``): here, so that the top-level help lists the
#: commands without importing them (each imports its step and the libraries: 1-1.3 s)
SUMMARIES = {    # in the order of ``nifo --help``
    "run": "the whole job on the bundled sample (or given data): characterize, identify, predict, loop, report",
    "simulate": "simulate a nonlinear quarter car and write the record and its truth",
    "info": "show format, channels, sample rate, duration and RMS of data files",
    "characterize": "restoring-force plots and automatic characterization of strut nonlinearities",
    "identify": "identify the nominal linear transmissibility and the nonlinear coefficient functions (NIFO)",
    "predict": "predict the body response of other data with an identified model and compare with the measurement",
    "loop": "find the effect the model lacks from the residual, add it, report the error before and after",
    "replay": "publish a recorded bag into the ROS 2 graph (live nodes see it as the vehicle)",
    "view": "turn result directories into a Rerun recording (save, spawn a viewer, or connect)",
    "report": "write a self-contained HTML report of result directories",
    "export": "the identified strut as tables (force against deflection and velocity), a linear model and a figure",
    "fleet": "identify a fleet: many bags of many vehicles on Dask, one model per vehicle/corner, odd struts flagged",
}


def sprung_mass(text: str) -> float:
    """``--m2``: a finite positive mass [kg], refused as a usage error before any data is read."""
    try:
        m = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of kilograms (e.g. --m2 300)") from None
    if not (math.isfinite(m) and m > 0):
        raise argparse.ArgumentTypeError(f"{text} kg is not a sprung mass: give its positive mass (e.g. --m2 300)")
    return m


def checked_by(settings: Callable, field: str, convert: Callable = int) -> Callable[[str], object]:
    """An argument type for one field of a settings class: the value converted, then checked by the class itself
    (its one rule, ``settings(**{field: value})``), so a value it refuses is a usage error at once (exit 2, one line
    naming the flag) rather than an error after the data are read."""
    from nifo_core.errors import NifoError

    what = "a whole number" if convert is int else "a number"

    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        try:
            settings(**{field: value})
        except NifoError as err:     # "max_rounds=0 must be ..." said of what was typed: "0 must be ..."
            message = err.message
            if message.startswith(f"{field}="):
                message = f"{text} {message.split(' ', 1)[-1]}"
            raise argparse.ArgumentTypeError(message + (f". Fix: {err.hint}" if err.hint else "")) from None
        return value

    parse.__name__ = field
    return parse
