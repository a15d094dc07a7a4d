"""``nifo characterize DATA... --out DIR``: restoring-force plots and an automatic characterization.

The command line of the step in :mod:`nifo.pipeline.characterize` (what it does is written there).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nifo.commands import SUMMARIES, sprung_mass
from nifo.io.loader import add_input_arguments
from nifo.io.provenance import add_system_argument
from nifo.pipeline.characterize import run_characterize
from nifo.pipeline.options import CharacterizeOptions
from nifo.settings import add_settings_arguments
from nifo_core.characterize.automatic import DEFAULT_KINDS, Thresholds

HELP = SUMMARIES["characterize"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "out"
DESCRIPTION = f"""{HELP}.

The body acceleration, negated, is the strut force per unit sprung mass
(paper Eq. 2); against the relative velocity ż and displacement z (integrated
from ẍ2 - ẍ1 in one band) it shows damping and stiffness nonlinearities.
Every kind of the describing-function library
({", ".join(DEFAULT_KINDS[:4])},
{", ".join(DEFAULT_KINDS[4:])})
is fitted over a grid of its parameters on top of a linear strut; a kind is
reported present only if it explains ≥ 2 % of the linear fit's residual
variance, does so on held-out blocks too (≥ 1 %), is significant (F-test with
effective degrees of freedom, p < 0.001 after Bonferroni over its grid) and its
coefficient is stable across the files / quarters of the record (spread ≤ 0.5).
Correlated near-duplicates (clearance vs cubic, Coulomb vs a velocity knee)
are listed as alternatives of the suggested term, not suggested beside it.

Several DATA files are taken as several excitation levels of one system (one
amplitude slice each). Sweeps (slow chirps, sine sweeps) are detected and
sliced by instantaneous frequency; --freq-window restricts the fit to part of
a sweep (e.g. around one mode of a multi-mode structure).

Example (the F-16 ground vibration test, nonlinearbenchmark.org):
  nifo characterize F16Data_SineSw_Level7.mat --out l7 \\
      --columns spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs \\
      --integration-band 5 160 --freq-window 6.8 7.8 --slices-hz 5.3 7.3 9.2"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", nargs="+", metavar="DATA", help="data files (several: several excitation levels)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory (replaced atomically)")
    add_input_arguments(p)
    add_settings_arguments(p, cond_limit=False)
    add_system_argument(p)
    g = p.add_argument_group("analysis")
    g.add_argument("--m2", type=sprung_mass, metavar="KG", help="sprung mass [kg]: coefficients and plots in newtons")
    g.add_argument("--top", type=int, default=5, metavar="N", help="candidates shown in the table (default 5)")
    g.add_argument("--max-terms", type=int, default=3, metavar="N", help="most terms suggested (default 3)")
    g.add_argument("--kinds", metavar="KIND,...", help=f"kinds to try (default: {','.join(DEFAULT_KINDS)})")
    g.add_argument("--freq-window", nargs=2, type=float, metavar=("LO", "HI"),
                   help="fit only samples of a sweep whose instantaneous frequency is in [LO, HI] Hz")
    g.add_argument("--grid", type=int, default=24, metavar="N", help="grid points per parameter (default 24)")
    g.add_argument("--min-err", type=float, default=Thresholds.min_err, metavar="F",
                   help=f"ERR threshold for 'present' (default {Thresholds.min_err:g})")
    f = p.add_argument_group("figures")
    f.add_argument("--slices-hz", nargs="+", type=float, metavar="HZ",
                   help="centres of frequency slices for sweeps (default: four across the swept range); "
                        "the first is also the frequency of the amplitude figure for several sweeps")
    f.add_argument("--amplitude-bins", type=int, default=4, metavar="N",
                   help="amplitude bins of a single random record (default 4)")


def run(args: argparse.Namespace) -> dict:
    return run_characterize(CharacterizeOptions.from_args(args))
