"""``nifo export MODEL --out DIR``: the identified strut as tables, a linear model and a figure.

The command line of the step in :mod:`nifo.pipeline.export` (what it writes is said there).
"""

from __future__ import annotations

import nifo.pipeline.export as _step

import argparse
from pathlib import Path

from nifo.commands import SUMMARIES, sprung_mass
from nifo.pipeline.export import run_export
from nifo.pipeline.options import ExportOptions

HELP = SUMMARIES["export"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "out"
DESCRIPTION = _step.__doc__.split("\n", 1)[1].strip() if _step.__doc__ else HELP


def _points(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 3 <= n <= 100_001:
        raise argparse.ArgumentTypeError(f"{n} points: give 3 to 100001")
    return n


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", type=Path, metavar="MODEL",
                   help="model.json, the folder holding it, or a nifo run results folder (its final model)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory (replaced atomically)")
    p.add_argument("--m2", type=sprung_mass, default=None, metavar="KG",
                   help="body (sprung) mass M2 [kg]: forces in N instead of per kg of M2")
    p.add_argument("--points", type=_points, default=201, metavar="N",
                   help="grid points of each table (default 201; odd, so zero is one)")


def run(args: argparse.Namespace) -> dict:
    return run_export(ExportOptions.from_args(args))
