"""``nifo info DATA...``: what is in each data file, as nifo will read it."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from nifo_core.errors import NifoError
from nifo_core.signal.record import Record

from nifo.commands import SUMMARIES
from nifo.io.loader import add_input_arguments, input_options, load_record
from nifo.io.provenance import add_system_argument, system_of

HELP = SUMMARIES["info"]
DESCRIPTION = """\
Show, for each data file (rosbag2 bag directory or .mcap, .csv, .mat), what
nifo reads from it: format, the topics/columns used, sample rate, duration,
sample count, RMS of each channel and whether a tire-patch displacement is
present. Every file is reported; the exit code is that of the first error.

With --block N it also checks the record is long enough for spectral blocks
of N samples (exit code 8 if not)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", nargs="+", metavar="DATA", help="data files or bag directories")
    add_input_arguments(parser)
    add_system_argument(parser)
    parser.add_argument("--block", type=int, metavar="N",
                        help="spectral block length [samples] the record must hold at least once")


def _mapping(rec: Record) -> str:
    m = rec.meta
    if "topics" in m:
        return ", ".join(f"{k}={v}" for k, v in m["topics"].items() if v)
    return ", ".join(f"{k}={v}" for k, v in m.get("columns", {}).items())


def describe(rec: Record, *, block: int | None = None, units: str = "m/s²") -> list[str]:
    """Lines describing ``rec`` (without the file name); ``units``: of the two signals (--system)."""
    m = rec.meta
    fmt = m.get("format", "?") + (f" ({m['storage']})" if "storage" in m else "")
    kind = "topics" if "topics" in m else "columns"
    lines = [f"  format       {fmt}",
             f"  {kind:<12} {_mapping(rec)}" + (f"  (axis {m['axis']})" if "axis" in m else ""),
             f"  sample rate  {rec.fs_hz:.6g} Hz",
             f"  duration     {rec.duration_s:.3f} s ({rec.n} samples)"]
    if m.get("stamps") == "receive_time":
        lines.append("  stamps       receive time (header stamps are all zero)")
    if "chunk_crc" in m:
        lines.append(f"  integrity    {m['integrity_note']}" if m.get("integrity_note") else
                     f"  integrity    CRC-32 of every chunk checked ({m['chunk_crc']['chunks']} chunks)")
    if "trimmed" in m:
        cut = "; ".join(f"{k}: {a} at start, {b} at end" for k, (a, b) in m["trimmed"].items())
        lines.append(f"  trimmed      {cut} (to samples common to all channels)")
    rms = {"spindle_accel": (rec.spindle_accel, units), "body_accel": (rec.body_accel, units)}
    if rec.tire_patch_disp is not None:
        rms["tire_patch_disp"] = (rec.tire_patch_disp, "m")
    for name, (x, unit) in rms.items():
        lines.append(f"  RMS {name:<16} {float(np.sqrt(np.mean(np.square(x)))):.6g} {unit}")
    lines.append(f"  tire patch   {'present' if rec.has_tire_patch else 'absent'}")
    if block:
        rec.require_samples(block, what=f"spectral blocks of {block} samples")
        lines.append(f"  blocks       {rec.n // block} of {block} samples ({block / rec.fs_hz:.3f} s each)")
    return lines


def run(args: argparse.Namespace) -> dict:
    opts = input_options(args)
    first_code, files = 0, []
    for path in args.data:
        try:
            rec = load_record(path, **opts)
            lines = describe(rec, block=args.block, units=system_of(args)["units"])
        except NifoError as err:
            print(f"nifo info: error: {err}", file=sys.stderr)
            first_code = first_code or err.exit_code
            files.append({"path": str(path), "error": str(err), "exit_code": err.exit_code})
            continue
        print(path)
        print("\n".join(lines))
        files.append({"path": str(path), "format": rec.meta.get("format"), "fs_hz": rec.fs_hz, "n_samples": rec.n,
                      "duration_s": rec.duration_s, "tire_patch": rec.has_tire_patch})
    return {"files": files, "exit_code": first_code}
