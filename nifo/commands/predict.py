"""``nifo predict``: apply an identified model to other data (docs/method.md §4, paper §3.3 validation).

For each record the measured spindle acceleration (and a measured force on
the body, for a model identified with one) drives the model
(:func:`nifo_core.predict.model.predict_body`: the identified model simulated in
time, from its linear part — one-mass body or rational, as model.json says —
with the strut forces fed back), and the predicted body acceleration is
compared with the measured one:

- NMSE in time, 100·Σ(y - ŷ)²/(N·σ_y²) % over the prediction's valid part
  (start-up edges left out; below 5 % good, below 1 % excellent);
- the band NMSE, 100·Σ|Y - Ŷ|²/Σ|Y|² over the DFT lines of ``--freq-range``
  (:mod:`nifo_core.predict.prediction_error`; the same number ``nifo identify --refine``
  minimises): after the start-up edge, or — with ``--period-samples`` — on the
  period average after the first, transient period of the prediction (the
  multisine benchmarks' convention);
- the transmissibility error |T_pred/T_meas - 1|, median and max over the
  lines of ``--freq-range`` (default 2-30 Hz), where T is the H1 from the
  measured spindle signal to the predicted or the measured body signal, on
  the same spectral settings.

The same is done with the linear model stored beside it in model.json (the
plain H1 at the identification level, i.e. the equivalent linearisation a
linear identification would give), so the gain from the nonlinear terms is
explicit. A record that cannot be predicted (unreadable, or a model whose
response grows without bound at that level) is named with the reason; every
other record is still predicted and written, and the command then exits
non-zero. MODEL may be a model.json or a directory holding one (from
``nifo identify`` or ``nifo loop``). When a simulator truth file ``<DATA>.truth.json`` lies beside the
data, the model's nominal T21 is also compared with the true linear T21.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nifo.io.loader import add_input_arguments
from nifo.io.provenance import add_system_argument
from nifo.pipeline.options import PredictOptions
from nifo.pipeline.predict import run_predict
from nifo.settings import add_settings_arguments

HELP = "predict the body response of other data with an identified model and compare with the measurement"
DESCRIPTION = __doc__.split("\n", 1)[1].strip() if __doc__ else HELP


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
    add_settings_arguments(p, cond_limit=False, band=False)   # --freq-range: default the model's analysis band
    add_system_argument(p)


def run(args: argparse.Namespace) -> dict:
    return run_predict(PredictOptions.from_args(args))
