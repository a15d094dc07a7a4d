"""``nifo run [DATA...] [--out DIR]``: the whole job — characterize, identify, predict, loop, report, recording.

The command line of the step in :mod:`nifo.pipeline.job` (what it does is written there).
"""

from __future__ import annotations

import nifo.pipeline.job as _step

import argparse
from pathlib import Path

from nifo.commands import SUMMARIES
from nifo.io.loader import add_input_arguments
from nifo.io.provenance import add_system_argument
from nifo.pipeline.job import loop_available, run_job
from nifo.pipeline.options import RunOptions
from nifo.settings import add_settings_arguments
from nifo_core.errors import InputError

__all__ = ["add_arguments", "run", "sample_data", "loop_available", "SAMPLE_DIR"]

HELP = SUMMARIES["run"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "out"
DESCRIPTION = _step.__doc__.split("\n", 1)[1].strip() if _step.__doc__ else HELP

#: the bundled sample, relative to the checkout
SAMPLE_DIR = Path(__file__).resolve().parents[2] / "bags" / "sample"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", nargs="*", type=Path, metavar="DATA",
                   help="records at one or more excitation levels (default: the bundled sample bags/sample/*)")
    p.add_argument("--out", type=Path, default=Path("results"), metavar="DIR", help="output directory (default results/)")
    p.add_argument("--no-loop", action="store_true", help="skip the loop step (the identified model is the final one)")
    p.add_argument("--no-refine", action="store_true",
                   help="keep NIFO's coefficients (skip identify's output-error refinement)")
    p.add_argument("--no-recording", action="store_true", help="skip the Rerun recording")
    add_input_arguments(p)   # passed through to every step that reads data
    add_settings_arguments(p)
    add_system_argument(p)


def sample_data() -> list[Path]:
    """The bundled sample's bags (sorted), or InputError when the checkout has none."""
    found = sorted(p for p in SAMPLE_DIR.glob("*") if p.is_dir() and (p / "metadata.yaml").is_file())
    if not found:
        raise InputError("no data given and no bundled sample found", source=str(SAMPLE_DIR),
                         hint="nifo run DATA... (bags, .mcap, .csv or .mat files)")
    return found


def run(args: argparse.Namespace) -> dict:
    data = [Path(p) for p in args.data] or sample_data()
    return run_job(RunOptions.from_args(args, data=data))
