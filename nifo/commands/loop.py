"""``nifo loop DATA... --model MODEL.yaml --out DIR``: trace the residual to the effect the model lacks, add it.

The command line of the step in :mod:`nifo.pipeline.loop` (what it does is written there).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nifo.commands import SUMMARIES, checked_by, sprung_mass
from nifo.io.loader import add_input_arguments
from nifo.io.provenance import add_system_argument
from nifo.pipeline.loop import run_loop
from nifo.pipeline.options import LoopOptions
from nifo.settings import add_settings_arguments
from nifo_core.characterize.automatic import DEFAULT_KINDS
from nifo_core.loop.settings import LoopSettings

HELP = SUMMARIES["loop"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "out"
DESCRIPTION = f"""{HELP}.

Each DATA file is split in time: the first --fit-fraction fits, the rest is
held out. The residual of the body equation (paper Eq. 2, band-limited) is
traced to the library's describing functions ({", ".join(DEFAULT_KINDS)}),
each over a grid of its parameters; one effect is added per round if it is
significant (F-test with effective degrees of freedom), explains at least
2 % of what is left (also on alternate held-out blocks), has a stable
coefficient across the files (levels) or the quarters of one record, lowers
the held-out error, and survives the tire check. Stops when nothing
significant is missing, or after --max-rounds. Then the final model is
refined by output error (every fit part simulated from its measured input,
the prediction error minimised over the coefficients, gaps/knees and the
body's k, c) and model.json holds the refined model when its held-out
prediction is not worse (--no-refine: the equation-error fit).

Example:
  nifo loop road_1mm.mcap road_2.5mm.mcap --model declared.yaml --out loop/ --m2 300"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", nargs="+", metavar="DATA", help="data files (several: several excitation levels)")
    p.add_argument("--model", type=Path, metavar="MODEL.yaml",
                   help="declared model file (default: a linear strut)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory (replaced atomically)")
    add_input_arguments(p)
    add_settings_arguments(p)
    add_system_argument(p)
    g = p.add_argument_group("loop")
    g.add_argument("--max-rounds", type=checked_by(LoopSettings, "max_rounds"), default=4, metavar="N",
                   help="most effects added (1-10, default 4)")
    g.add_argument("--m2", type=sprung_mass, metavar="KG", help="sprung mass [kg]: coefficients in newtons")
    g.add_argument("--fit-fraction", type=checked_by(LoopSettings, "fit_fraction", float), default=2 / 3,
                   metavar="F", help="leading fraction of each record used for fitting (0.3-0.9, default 2/3; the "
                                     "rest is held out; periodic data: whole periods)")
    g.add_argument("--kinds", metavar="KIND,...", help=f"kinds to try (default: {','.join(DEFAULT_KINDS)})")
    g.add_argument("--grid", type=int, default=24, metavar="N", help="grid points per parameter (default 24)")
    g.add_argument("--prediction", choices=("model", "none"), default="model",
                   help="'model' (default): every model fitted as nifo identify fits it and its held-out output "
                        "predicted; 'none': the equation error only")
    g.add_argument("--structure", choices=("auto", "constant", "paths"), default="auto",
                   help="feedback structure: constant coefficients, each term through its own path (a rational "
                        "linear part), or auto (paths where possible)")
    g.add_argument("--no-retune", action="store_true",
                   help="keep the declared terms' parameters as given (default: re-tune them to the data)")
    g.add_argument("--no-refine", action="store_true",
                   help="write the equation-error fit (default: refine the final model by output error on the fit "
                        "parts and keep it when its held-out prediction is not worse)")
    g.add_argument("--refine-seconds", type=checked_by(LoopSettings, "refine_seconds", float), default=60.0,
                   metavar="S", help="leading seconds of each fit part the refinement simulates (at least 5, "
                                     "default 60)")


def run(args: argparse.Namespace) -> dict:
    return run_loop(LoopOptions.from_args(args))
