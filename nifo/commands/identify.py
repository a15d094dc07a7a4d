"""``nifo identify``: output-only NIFO on one or more records (paper Eq. 8-9, docs/method.md §3).

Data files are streamed chunk by chunk into one :class:`~nifo_core.nifo.identify.StreamingNifo`
each (bags are decoded chunk by chunk, so memory does not grow with the
recording's length) and the accumulators are merged: several files are
averaged exactly as :func:`~nifo_core.nifo.identify.identify_nifo` averages records.
A two-step model file (``steps:``) runs :func:`~nifo_core.nifo.identify.identify_two_step`
on each step's data. ``--refine`` then refines the model's coefficients by
output error (:mod:`nifo_core.predict.refine`: every record simulated, the band
prediction NMSE minimised). Writes ``identify.json``, ``model.json`` and
figures into ``--out`` atomically (all or nothing); see :mod:`nifo.io.results`
for the files.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nifo.commands import SUMMARIES
from nifo.io.loader import add_input_arguments
from nifo.io.provenance import add_system_argument
from nifo.pipeline.identify import run_identify
from nifo.pipeline.options import CHUNK_SAMPLES, IdentifyOptions
from nifo.settings import add_settings_arguments
from nifo_core.errors import IllConditionedError

HELP = SUMMARIES["identify"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "out"
DESCRIPTION = f"""{HELP}.

Output-only NIFO (Haroon & Adams, Eq. 8-9): from spindle and body
accelerations alone, the nominal (near-zero-level) linear spindle→body
transmissibility T21(ω) and, for every declared nonlinearity g_i(z, ż), its
coefficient function μ_i(ω)/K2, B_i(ω) and c_i/M2. Two estimates are given:
the per-line least squares of the paper (Eq. 9) and the pooled fit with each
c_i/M2 one real constant (static nonlinearity; far less noise-sensitive: the
recommended T21, and the one model.json predicts with).

MODEL.yaml names the nonlinearities (see nifo/io/modelfile.py):

  nifo_model: 1
  nonlinearities:
    - {{kind: velocity_deadzone, params: {{knee: 0.03}}}}
    - {{kind: backlash, params: {{deadband: 0.00043}}}}
  settings: {{block: 6144, overlap: 0.52, window: flattop, integration_band_hz: [0.5, 200],
              analysis_band_hz: [2, 30]}}

Kinds (g of z = x2 - x1 [m] or ż [m/s]): cubic_stiffness, clearance(gap),
saturation(limit), bump_stop(gap, side, offset), backlash(deadband),
velocity_deadzone(knee), velocity_saturation(limit), coulomb(eps),
quadratic_damping, asymmetric_damping(side). With 'steps:' instead of
'nonlinearities:' the terms are identified in two steps (paper §3.3), each on
its own data (paths in the file or --step-data).

--refine: NIFO is an equation-error estimate (noise integrated into z biases
it); the refinement simulates every record with the model and minimises the
band-limited prediction NMSE over the coefficients, the gaps/knees and a
one-mass body's k and c, starting from the NIFO model and, where that is not
already better, from the linear model. model.json holds the refined model
(provenance 'refined'); identify.json keeps NIFO's estimates and the
refinement's before/after under summary.refinement.

Outputs in --out: identify.json, model.json, transmissibility.png (Fig. 9b/12b),
coefficients.png (Fig. 10/13), conditioning.png, tire.png (Fig. 11/14, with a
tire patch). Ill-conditioning is reported as a warning; the command refuses
(exit code {IllConditionedError.exit_code}) only when nothing usable is left.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", nargs="*", type=Path, metavar="DATA",
                   help="records (bag, .mcap, .csv, .mat); several are averaged")
    p.add_argument("--model", required=True, type=Path, metavar="MODEL.yaml", help="model file (nonlinearities)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory (replaced atomically)")
    add_settings_arguments(p)
    p.add_argument("--step-data", action="append", nargs="+", type=Path, metavar="PATH",
                   help="data of one step of a two-step model (repeat once per step, in order)")
    p.add_argument("--chunk-samples", type=int, default=CHUNK_SAMPLES, metavar="N",
                   help=f"streaming chunk length [samples] (default {CHUNK_SAMPLES})")
    p.add_argument("--no-plots", action="store_true", help="write the JSON files only")
    r = p.add_argument_group("output-error refinement (nifo_core.predict.refine)")
    r.add_argument("--refine", action="store_true",
                   help="refine the coefficients (and gaps/knees, a one-mass body's k and c) by simulating every "
                        "record and minimising the band-limited prediction NMSE; starts from the NIFO model and "
                        "from the linear model, keeps the better")
    r.add_argument("--refine-linear", action="store_true",
                   help="--refine, and also refine a rational linear part's residues (poles kept), the linear part "
                        "identified jointly with the terms: the linear model's residues first (written as the "
                        "linear baseline), then the terms with them from NIFO's coefficients and from zero, the "
                        "better kept; 2 parameters per mode, so minutes. It can fit the one excitation it is given "
                        "at the cost of others: on the F-16 it beats the linear model on the multisine and loses "
                        "to it on the sine sweeps; validate on another excitation (docs/f16_predict.md)")
    r.add_argument("--feedback-paths", action="store_true",
                   help="instead of constant coefficients, every term's force through its own linear path on the "
                        "linear model's poles (a flexible body: the interface force reaches the measured point "
                        "through the body's modes); the paths' residues and the linear part's by one least squares "
                        "with a ridge on the paths, the ridge chosen by how well the model predicts held-out parts "
                        "of the records (their last third); needs a rational linear part and backlash, clearance or "
                        "saturation terms; seconds (nifo_core.predict.model_fit.joint_paths, docs/f16_predict.md)")
    r.add_argument("--refine-seconds", type=float, default=120.0, metavar="S",
                   help="simulate at most this much of each record per evaluation (--refine, --feedback-paths; "
                        "default 120 s; whole periods "
                        "with --period-samples), from the record's start: the part --skip-periods/--skip-seconds "
                        "leave out is simulated too but not scored, and not counted here")
    add_input_arguments(p)
    add_system_argument(p)


def run(args: argparse.Namespace) -> dict:
    return run_identify(IdentifyOptions.from_args(args))
