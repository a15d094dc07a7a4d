"""``nifo fleet``: many bags of many vehicles on Dask, one model per vehicle/corner, the odd strut flagged.

Each bag becomes a partial spectral accumulation on a Dask worker (cached by
the bag's content hash and the settings), the partials of a group are merged
by tree reduction and NIFO is solved per group (as ``nifo identify`` on the
group's bags), then every coefficient is compared with the fleet (robust
z-score, :mod:`nifo_core.fleet`). See :mod:`nifo.fleet` and docs/fleet.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nifo.commands import SUMMARIES
from nifo.io.loader import add_input_arguments, input_options
from nifo_core.errors import ConfigError

HELP = SUMMARIES["fleet"]
#: the argument naming what this command writes: locked for the whole command (nifo.io.lock)
OUTPUT = "out"
DESCRIPTION = f"""{HELP}.

INPUT is a manifest (CSV or YAML; columns vehicle, corner, date, path, model,
m2_kg) or a folder tree ROOT/<vehicle>/<corner>/<bag>. With m2_kg (the corner's
weighed sprung mass) coefficients are also given in SI and compared in SI. Every bag's spectra are
accumulated on a Dask worker, merged per vehicle/corner by tree reduction,
and NIFO is solved per group exactly as 'nifo identify GROUP_BAGS --model M'.
Each coefficient (K2/M2, C2/M2, c_i/M2) is compared with the fleet by a robust
z-score; a group is flagged where |z| exceeds --z-limit and the deviation is
resolved by its own data (never from fewer than --min-bags bags).

Settings: --block, --overlap, --window, --integration-band, --analysis-band and
--cond-limit override every model file's settings (then its defaults); they are
never read off the data (one set of settings compares the bags of a fleet).

Dask: with no --scheduler a LocalCluster of --workers processes (default: one
per core) runs on this machine; --scheduler tcp://HOST:8786 uses an existing
cluster (its workers must see the bags, the cache folder and have nifo installed).
Partials are cached in --cache (default OUT.cache): a killed run started again
recomputes only the bags that had not finished. A bag that cannot be read is
recorded as failed with its reason; the fleet goes on.

Outputs in --out (written atomically): fleet.parquet and fleet.csv (one row per
group), bags.parquet and bags.csv, fleet.json, fleet.html with t21.png and
coefficients.png, fleet.rrd (Rerun, one entity per vehicle).

Example:
  nifo fleet fleet.csv --model strut.yaml --out fleet_out
  nifo fleet bags/ --model strut.yaml --out fleet_out --scheduler tcp://10.0.0.5:8786"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", type=Path, metavar="INPUT", help="manifest (.csv/.yaml) or fleet folder")
    p.add_argument("--model", type=Path, metavar="MODEL.yaml",
                   help="model file of every group without a model column in the manifest")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory (replaced atomically)")
    d = p.add_argument_group("Dask")
    d.add_argument("--scheduler", metavar="tcp://HOST:8786", help="use this running Dask scheduler "
                   "(default: start a LocalCluster on this machine)")
    d.add_argument("--connect-timeout", type=float, default=20.0, metavar="S",
                   help="how long to wait for --scheduler [s] (default 20)")
    d.add_argument("--workers", type=int, metavar="N", help="LocalCluster worker processes (default: cores)")
    d.add_argument("--cache", type=Path, metavar="DIR", help="cache of per-bag partials (default OUT.cache)")
    d.add_argument("--no-cache", action="store_true", help="recompute every bag, keep nothing")
    d.add_argument("--fanout", type=int, default=2, metavar="K", help="partials merged per reduction task (default 2)")
    d.add_argument("--batch", type=int, metavar="N", help="bags per task (default: about 8 tasks per worker of "
                   "at most 32 bags; a vehicle/corner with no more bags than that stays in one task)")
    h = p.add_argument_group("strut health")
    h.add_argument("--z-limit", type=float, default=3.5, metavar="Z", help="robust |z| that flags (default 3.5)")
    h.add_argument("--min-bags", type=int, default=2, metavar="N", help="fewest bags to assess a group (default 2)")
    h.add_argument("--min-duration", type=float, default=60.0, metavar="S",
                   help="fewest seconds of data to assess a group (default 60)")
    h.add_argument("--min-groups", type=int, default=5, metavar="N",
                   help="fewest assessable groups that make a fleet (default 5)")
    o = p.add_argument_group("results")
    o.add_argument("--freqs", type=float, nargs="+", default=[2.0, 5.0, 10.0, 20.0], metavar="HZ",
                   help="frequencies of the T21 columns [Hz] (default 2 5 10 20)")
    o.add_argument("--loop", action="store_true", help="also run the residual loop per group (slow)")
    o.add_argument("--characterize", action="store_true",
                   help="also rank the restoring force's nonlinearities per group (slow)")
    o.add_argument("--chunk-samples", type=int, default=2 ** 18, metavar="N",
                   help="streaming chunk per bag [samples] (default 262144, as nifo identify)")
    o.add_argument("--no-plots", action="store_true", help="no HTML page and figures")
    o.add_argument("--no-rerun", action="store_true", help="no Rerun recording")
    add_input_arguments(p)
    from nifo.settings import add_settings_arguments

    add_settings_arguments(p, from_data=False)


def _check(args) -> None:
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers {args.workers} must be at least 1", channel="--workers")
    if args.batch is not None and args.batch < 1:
        raise ConfigError(f"--batch {args.batch} must be at least 1", channel="--batch")
    if args.fanout < 2:
        raise ConfigError(f"--fanout {args.fanout} must be at least 2", channel="--fanout")
    if args.chunk_samples < 2:
        raise ConfigError(f"--chunk-samples {args.chunk_samples} must be at least 2", channel="--chunk-samples")
    if any(not (f > 0) for f in args.freqs):
        raise ConfigError(f"--freqs {args.freqs} must be positive frequencies [Hz]", channel="--freqs")
    if args.model is not None and not args.model.is_file():
        raise ConfigError("no such model file", source=str(args.model), hint="check the --model path")
    from nifo.io.atomic import check_output

    check_output(args.out, reads=[args.input, args.model])   # refuse a file, a folder nifo did not write or one
    # holding an input before any work


def run(args: argparse.Namespace) -> dict:
    from nifo.fleet.cluster import FleetError, dashboard_line, fleet_client, start_worker_server

    if not args.scheduler:
        start_worker_server()      # the workers' fork server imports and warms while this process reads the manifest
    from nifo.fleet.manifest import load_fleet_input
    from nifo.fleet.runner import FleetSettings, fleet_settings, run_fleet
    from nifo.settings import given_from_args
    from nifo_core.fleet import HealthSettings

    _check(args)
    entries = load_fleet_input(args.input, default_model=args.model)
    analysis = fleet_settings(entries, given=given_from_args(args))     # once per model file, for every worker
    health = HealthSettings(z_limit=args.z_limit, min_records=args.min_bags, min_duration_s=args.min_duration,
                            min_groups=args.min_groups)
    cache = None if args.no_cache else str((args.cache or Path(str(args.out) + ".cache")).resolve())
    settings = FleetSettings(chunk_samples=args.chunk_samples, freqs_hz=tuple(args.freqs), fanout=args.fanout,
                             batch=args.batch,
                             cache_dir=cache, loop=args.loop, characterize=args.characterize,
                             health=health)
    n_groups = len({e.group for e in entries})
    with fleet_client(args.scheduler, workers=args.workers, timeout_s=args.connect_timeout) as client:
        if not args.quiet:
            print(dashboard_line(client), file=sys.stderr, flush=True)
            print(f"fleet: {len(entries)} bags in {n_groups} vehicle/corner groups; cache "
                  f"{cache or 'off'}", file=sys.stderr, flush=True)
        result = run_fleet(client, entries, analysis=analysis, opts=input_options(args), settings=settings,
                           quiet=args.quiet)
    solved = [g for g, r in result.groups.items() if r.ok]
    if not solved:
        reasons = sorted({b["reason"] for b in result.bags if b["reason"]} |
                         {r.reason for r in result.groups.values()})
        raise FleetError(f"no group could be identified ({len(result.bags)} bags; first reasons: "
                         f"{' | '.join(reasons[:3])})", source=str(args.input),
                         hint="fix the bags listed, or check the model file and the manifest")
    files = write_outputs(args.out, result, inputs=str(args.input), plots=not args.no_plots,
                          rerun=not args.no_rerun)
    print(format_summary(result, out=args.out, files=files))
    failed = [b for b in result.bags if b["reason"]]
    return {"out": str(args.out), "files": files, "bags": len(result.bags), "bags_failed": len(failed),
            "groups": len(result.groups), "groups_identified": len(solved),
            "flagged": sorted(str(g) for g, r in result.groups.items() if r.ok and r.health.flagged)}


def write_outputs(out: Path, result, *, inputs: str, plots: bool = True, rerun: bool = True) -> list[str]:
    """Every output file into ``out``, atomically (all or nothing)."""
    from nifo.fleet.outputs import write_document, write_tables
    from nifo.io.atomic import staged_dir

    with staged_dir(out) as tmp:
        files = write_tables(tmp, result)
        if plots:
            from nifo.fleet.page import write_page
            files += write_page(tmp, result, title=inputs)
        if rerun:
            from nifo.fleet.rerun_fleet import save_fleet_recording
            save_fleet_recording(tmp / "fleet.rrd", result)
            files.append("fleet.rrd")
        files.append(write_document(tmp, result, figures=[f for f in files if f.endswith(".png")], inputs=inputs))
    return files


def format_summary(result, *, out: Path, files: list[str]) -> str:
    ok = {g: r for g, r in result.groups.items() if r.ok}
    lines = [f"fleet: {len(ok)} of {len(result.groups)} groups identified from {len(result.bags)} bags "
             f"({result.n_cached} from the cache, {result.n_failed} failed)"]
    if result.n_redone:
        lines.append(f"  {result.n_redone} bag(s) accumulated twice: a bag shorter than 64 s set its group's "
                     "integration band (as in nifo identify); band_hz in the model file avoids it")
    for b in result.bags:
        if b["status"] != "ok":
            lines.append(f"  FAILED bag {b['vehicle']}/{b['corner']} {b['path']}: {b['reason']}")
    for g, r in result.groups.items():
        if not r.ok:
            lines.append(f"  FAILED group {g[0]}/{g[1]}: {r.reason}")
    flagged = [(g, r) for g, r in ok.items() if r.health.flagged]
    not_assessed = [g for g, r in ok.items() if not r.health.assessed]
    lines.append(f"strut health: {len(flagged)} group(s) flagged, {len(not_assessed)} not assessed (too little data)")
    for g, r in flagged:
        for t in r.health.evidence:
            lines.append(f"  FLAGGED {g[0]}/{g[1]}: {t}")
    lines.append(f"wrote {out}/ ({', '.join(files)})")
    return "\n".join(lines)
