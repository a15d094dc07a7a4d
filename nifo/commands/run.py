"""``nifo run [DATA...] [--out DIR]``: the whole job — characterize, identify, predict, loop, report, recording.

With no DATA, the bundled sample (``bags/sample/*``: a simulated quarter car
at two road levels). Steps, each into its own subdirectory of ``--out``
(default ``results/``), by the steps of :mod:`nifo.pipeline` (:func:`nifo.pipeline.job.run_job`), each
with its own command line's defaults and this command's input and settings options:

0. the settings, chosen once from the data where not given (the excitation's period and transient, the
   excited band, blocks, integration band: :mod:`nifo.settings`), printed with their reasons and passed to
   every step;
1. ``characterize/``  restoring-force plots and the suggested model (all DATA as levels);
2. ``identify/``      NIFO with the suggested model on every level (several levels that call for it: the
   paper's two-step model), then the output-error refinement of its coefficients, kept when it predicts a
   held-out part no worse (``nifo identify --refine``; ``--no-refine``: NIFO's equation-error values);
3. ``loop/``          from the linear model, what the data need: terms added while the held-out prediction
   improves, with the model class ``nifo identify`` writes (``nifo loop``): the run's final model,
   ``loop/model.json``;
4. ``predict/``       the final model and the linear model of the same data on every record;
5. ``report/report.html``  the self-contained HTML report of all of the above;
6. ``recording/nifo.rrd``  the Rerun recording (``rerun results/recording/nifo.rrd``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nifo.io.loader import add_input_arguments
from nifo.io.provenance import add_system_argument
from nifo.pipeline.job import loop_available, run_job
from nifo.pipeline.options import RunOptions
from nifo.settings import add_settings_arguments
from nifo_core.errors import InputError

__all__ = ["add_arguments", "run", "sample_data", "loop_available", "SAMPLE_DIR"]

HELP = "the whole job on the bundled sample (or given data): characterize, identify, predict, loop, report"
DESCRIPTION = __doc__.split("\n", 1)[1].strip() if __doc__ else HELP

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
