"""Bag reading speed: nifo's numpy CDR decoder vs rosbags' generic ``deserialize_cdr`` path.

Writes a two-channel (spindle + body Imu) bag of ``--minutes`` at ``--fs`` Hz,
then reads it both ways in the same run, best of ``--repeat``:

* generic: ``AnyReader`` + ``reader.deserialize(raw, msgtype)`` per message
  (rosbags' documented path), stamps and ``linear_acceleration.z`` collected
  into numpy arrays;
* nifo: :func:`nifo.io.bag.read_bag` end to end (raw bytes from the reader,
  numpy decode, rate/alignment/finiteness checks, Record).

Prints both times and the ratio; exits 1 if the ratio is below ``--min-ratio``
(the requirement is 3).

The cost of the chunk CRC-32 check: the same bag with every chunk CRC (and
the summary CRC) zeroed — "not recorded", so nothing is verified — is read
by :func:`read_bag` in the same run; the ratio with/without is printed, with
the time :func:`nifo.io.bag.write_chunk_crcs` adds to writing. Usage::

    .venv/bin/python benchmarks/bench_bag_read.py [--minutes 10] [--fs 600] [--repeat 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def generic_read(path: Path) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    from rosbags.highlevel import AnyReader

    stamps: dict[str, list[int]] = {}
    values: dict[str, list[float]] = {}
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.msgtype == "sensor_msgs/msg/Imu"]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            stamps.setdefault(conn.topic, []).append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            values.setdefault(conn.topic, []).append(msg.linear_acceleration.z)
    return ({k: np.array(v, np.int64) for k, v in stamps.items()},
            {k: np.array(v) for k, v in values.items()})


def without_crcs(bag: Path, dst: Path) -> Path:
    """A copy of the bag whose chunk and summary CRCs are 0 (MCAP: not recorded, so not checked)."""
    import shutil
    import struct

    from mcap.reader import make_reader

    shutil.copytree(bag, dst)
    mcap = next(dst.glob("*.mcap"))
    with mcap.open("r+b") as f:
        summary = make_reader(f).get_summary()
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8)
            f.write(struct.pack("<I", 0))
        f.seek(mcap.stat().st_size - 8 - 4)
        f.write(struct.pack("<I", 0))
    return dst


def best_of(repeat: int, fn, *args):
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn(*args)
        times.append(time.perf_counter() - t)
    return min(times), out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--fs", type=float, default=600.0)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--min-ratio", type=float, default=3.0)
    p.add_argument("--bag", type=Path, help="read this bag instead of writing one")
    args = p.parse_args(argv)

    from nifo.io.bag import read_bag, write_bag
    from nifo_core.signal.record import Record

    with tempfile.TemporaryDirectory(prefix="nifo-bench-") as tmp:
        path = args.bag
        if path is None:
            n = int(round(args.minutes * 60 * args.fs))
            rng = np.random.default_rng(0)
            rec = Record(args.fs, rng.standard_normal(n), rng.standard_normal(n), t0_ns=1_700_000_000 * 10**9)
            t = time.perf_counter()
            path = write_bag(Path(tmp) / "bench", rec)
            print(f"wrote {2 * n} Imu messages ({args.minutes:g} min, 2 channels, {args.fs:g} Hz) "
                  f"in {time.perf_counter() - t:.2f} s")
        t_fast, rec_back = best_of(args.repeat, read_bag, path)
        t_generic, (stamps, values) = best_of(args.repeat, generic_read, path)
        from nifo.io.bag import write_chunk_crcs

        plain = without_crcs(path, Path(tmp) / "nocrc") if path.is_dir() else None
        t_plain = None
        if plain:   # interleaved, so that the load of a shared machine hits both alike
            pairs = [(best_of(1, read_bag, path)[0], best_of(1, read_bag, plain)[0]) for _ in range(args.repeat)]
            t_fast, t_plain = min(a for a, _ in pairs), min(b for _, b in pairs)
        t_write_crc = best_of(1, write_chunk_crcs, next(plain.glob("*.mcap")))[0] if plain else None
        topics = rec_back.meta["topics"]
        same = (np.array_equal(values[topics["spindle"]], rec_back.spindle_accel)
                and np.array_equal(values[topics["body"]], rec_back.body_accel)
                and int(stamps[topics["spindle"]][0]) == rec_back.t0_ns)
    ratio = t_generic / t_fast
    print(f"generic rosbags deserialize_cdr: {t_generic:.3f} s")
    print(f"nifo read_bag (numpy decode):    {t_fast:.3f} s")
    print(f"ratio: {ratio:.1f}x (required >= {args.min_ratio:g}x); results identical: {same}")
    if t_plain:
        print(f"chunk CRC check: read with CRCs {t_fast:.3f} s, with CRCs zeroed {t_plain:.3f} s: "
              f"x{t_fast / t_plain:.3f} ({100 * (t_fast / t_plain - 1):+.1f} %); "
              f"computing the CRCs when writing: {t_write_crc:.3f} s")
    return 0 if ratio >= args.min_ratio and same else 1


if __name__ == "__main__":
    sys.exit(main())
