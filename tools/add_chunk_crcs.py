#!/usr/bin/env python3
"""Fill in the chunk CRC-32s of MCAP bags written without them, proving that no sample changes.

    .venv/bin/python tools/add_chunk_crcs.py bags/sample/road_0p5mm bags/sample/road_1mm bags/sample/road_2p5mm

For each bag (a rosbag2 directory or a lone ``.mcap``): the record is read,
the MCAP file is copied, the copy's chunk CRCs and summary CRC are computed
(:func:`nifo.io.bag.write_chunk_crcs`, as ``nifo simulate`` does for
every bag it writes), the copy is read again and must give exactly the same
arrays, rate and start time, and only then replaces the original. The bytes
that differ are counted: they must all lie in CRC fields (4 bytes per chunk,
4 for the summary).

Used once (issue 26) on the bundled sample, written before nifo recorded
chunk CRCs: its samples are unchanged bit for bit (``tools/make_sample.sh``
would give the same samples too, but a new start time: the writer now stamps
simulated records with the current time).
"""

from __future__ import annotations

import os
import shutil
import struct
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nifo.io.loader import load_record  # noqa: E402
from nifo.io.bag import write_chunk_crcs  # noqa: E402
from nifo.io.bag._mcap import _summary  # noqa: E402  (a tool reading the summary section itself)


def _mcap_of(bag: Path) -> Path:
    if bag.is_dir():
        files = sorted(bag.glob("*.mcap"))
        if len(files) != 1:
            raise SystemExit(f"{bag}: expected one .mcap file, found {len(files)}")
        return files[0]
    return bag


def _crc_fields(path: Path) -> set[int]:
    """Byte offsets of every chunk's uncompressed_crc and of the footer's summary_crc."""
    with path.open("rb") as f:
        summary = _summary(f)
        out = set()
        for ci in summary.chunk_indexes:
            at = ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8
            out |= set(range(at, at + 4))
    size = path.stat().st_size
    at = size - 8 - 4
    return out | set(range(at, at + 4))


def _same(a, b) -> bool:
    chans = ("spindle_accel", "body_accel", "tire_patch_disp", "force")
    return (a.fs_hz == b.fs_hz and a.n == b.n and a.t0_ns == b.t0_ns
            and all((getattr(a, c) is None) == (getattr(b, c) is None) for c in chans)
            and all(getattr(a, c) is None or np.array_equal(getattr(a, c), getattr(b, c)) for c in chans))


def add_crcs(bag: Path) -> str:
    mcap = _mcap_of(bag)
    before = load_record(bag)
    old = mcap.read_bytes()
    with tempfile.TemporaryDirectory(dir=bag.parent, prefix=f".{bag.name}.crc-") as tmp:   # same file system
        work = Path(tmp) / bag.name
        if bag.is_dir():
            shutil.copytree(bag, work)
        else:
            shutil.copy2(bag, work)
        copy = _mcap_of(work)
        chunks = write_chunk_crcs(copy)
        after = load_record(work)
        if not _same(before, after):
            raise SystemExit(f"{bag}: the record read after adding CRCs differs; nothing was changed")
        new = copy.read_bytes()
        diff = np.flatnonzero(np.frombuffer(old, np.uint8) != np.frombuffer(new, np.uint8))
        outside = sorted(set(diff.tolist()) - _crc_fields(copy))
        if len(old) != len(new) or outside:
            raise SystemExit(f"{bag}: bytes outside the CRC fields changed ({outside[:5]}); nothing was changed")
        os.replace(copy, mcap)
    blob = mcap.read_bytes()
    with mcap.open("rb") as f:
        zero = sum(1 for ci in _summary(f).chunk_indexes
                   if not struct.unpack_from("<I", blob, ci.chunk_start_offset + 33)[0])
    return (f"{bag}: {chunks} chunk CRCs written, {len(diff)} bytes changed (all in CRC fields), "
            f"{after.n} samples identical; chunks still without CRC: {zero}")


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__)
        return 2
    for a in argv:
        print(add_crcs(Path(a)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
