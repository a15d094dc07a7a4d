"""``nifo view RESULT_DIR... [--save out.rrd | --spawn | --connect]``: results as a Rerun recording.

Turns characterize / identify / predict / loop result directories into a Rerun
recording with the same entities and layout as the live viewer node
(:mod:`nifo.viz.rerun_log`): accelerations and restoring-force points from the
data (when the paths in the results' provenance are reachable), the
transmissibility (magnitude, phase, coherence) and coefficient functions
converging along the data's own stamps, the loop's rounds and a summary.

Output as Rerun's own script options: --save FILE.rrd, --connect [--url],
--serve, --stdout; with none of them a viewer is spawned (--spawn says so
explicitly).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nifo.commands import SUMMARIES

HELP = SUMMARIES["view"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "save"
DESCRIPTION = __doc__.split("\n", 1)[1].strip() if __doc__ else HELP


def add_arguments(p: argparse.ArgumentParser) -> None:
    import rerun as rr

    p.add_argument("results", nargs="+", type=Path, metavar="RESULT_DIR",
                   help="directories written by nifo characterize / identify / predict / loop")
    p.add_argument("--spawn", action="store_true", help="spawn a Rerun viewer (the default without --save/--connect)")
    p.add_argument("--no-data", action="store_true", help="log the results only, do not read the data again")
    rr.script_add_args(p)


def run(args: argparse.Namespace) -> dict:
    import rerun as rr

    from nifo.io.atomic import check_output
    from nifo.viz import rerun_log as rl
    from nifo.viz.offline import log_results, save_recording
    from nifo.viz.results import read_results

    saving = args.save and not (args.connect or args.serve or args.stdout)
    if saving:
        check_output(args.save, kind="file")   # refuse a file nifo did not write before any work
    results = read_results(args.results)
    if saving:
        out = save_recording(results, args.save, with_data=not args.no_data)   # atomic, no global state
        print(f"wrote {out} (open it with: rerun {out})")
        return {"out": str(out)}
    rec = rr.script_setup(args, rl.APP_ID, default_blueprint=rl.blueprint())
    rl.use_data_stamps(rec)
    log_results(results, recording=rec, with_data=not args.no_data)
    rr.script_teardown(args)
    return {"out": None, "results": [str(r.path) for r in results]}
