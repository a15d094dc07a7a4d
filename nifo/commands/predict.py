"""``nifo predict``: apply an identified model to other data (docs/method.md §4, paper §3.3 validation).

The command line of the step in :mod:`nifo.pipeline.predict` (what it does is written there).
"""

from __future__ import annotations

import nifo.pipeline.predict as _step

import argparse
from pathlib import Path

from nifo.commands import SUMMARIES
from nifo.io.loader import add_input_arguments
from nifo.io.provenance import add_system_argument
from nifo.pipeline.options import PredictOptions
from nifo.pipeline.predict import run_predict
from nifo.settings import add_settings_arguments

HELP = SUMMARIES["predict"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "out"
DESCRIPTION = _step.__doc__.split("\n", 1)[1].strip() if _step.__doc__ else HELP


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", nargs="+", type=Path, metavar="DATA", help="records to predict (bag, .mcap, .csv, .mat)")
    p.add_argument("--model", required=True, type=Path, metavar="MODEL.json",
                   help="model.json written by nifo identify or nifo loop (or the directory holding it)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory (replaced atomically)")
    p.add_argument("--method", choices=("parametric", "nonparametric"), default="parametric",
                   help="the model's linear part (one-mass body or rational, simulated in time; default) or the "
                        "identified T21(ω), B_i(ω) line by line (frequency domain where provably convergent, else "
                        "a rational fit of them in time)")
    p.add_argument("--no-plots", action="store_true", help="write predict.json only")
    add_input_arguments(p)
    add_settings_arguments(p, cond_limit=False, band=False)   # --analysis-band: default the model's analysis band
    add_system_argument(p)


def run(args: argparse.Namespace) -> dict:
    return run_predict(PredictOptions.from_args(args))
