"""``nifo report RESULT_DIR... --out report.html``: one self-contained HTML report.

Reads the directories written by ``nifo characterize``, ``identify``,
``predict`` and ``loop`` (any of them, in any order) and writes one HTML file
with every figure embedded (no external assets): the restoring-force grids,
the transmissibilities across levels with the NIFO estimate, the coefficient
functions, the loop's before/after table and evidence plots, and the settings
and data provenance. When the data named in the results are reachable, a
figure of the transmissibility at every level is computed for the report.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nifo.commands import SUMMARIES

HELP = SUMMARIES["report"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "out"
DESCRIPTION = __doc__.split("\n", 1)[1].strip() if __doc__ else HELP


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("results", nargs="+", type=Path, metavar="RESULT_DIR",
                   help="directories written by nifo characterize / identify / predict / loop")
    p.add_argument("--out", required=True, type=Path, metavar="report.html", help="HTML file to write (atomically)")
    p.add_argument("--title", default="nifo report", help="title of the report (default: 'nifo report')")
    p.add_argument("--no-levels", action="store_true",
                   help="do not read the data again for the transmissibility-across-levels figure")


def run(args: argparse.Namespace) -> dict:
    from nifo.io.atomic import check_output
    from nifo.viz.report_html import write_report
    from nifo.viz.results import read_results

    check_output(args.out, kind="file")   # refuse a directory before any work

    results = read_results(args.results)
    out = write_report(results, args.out, title=args.title, levels=not args.no_levels)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB, self-contained: open it in any browser)")
    return {"out": str(out), "size_bytes": out.stat().st_size, "results": [str(r.path) for r in results]}
