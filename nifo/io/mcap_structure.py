"""The MCAP container's structure, checked before any library trusts its lengths and offsets.

Below the bag package (:mod:`nifo.io.bag`, which reads and writes MCAP bags) and beside
:mod:`nifo.io.ownership` (which reads a bag's ``custom_data.generator`` to tell whether nifo wrote it): both check
a file with :func:`check_structure` first, so neither imports the other.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

from nifo_core.errors import CorruptDataError, DataFileError

__all__ = ["check_structure", "MCAP_MAGIC", "FOOTER_OP"]

#: the 8 bytes at both ends of an MCAP file
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: the footer record's opcode
FOOTER_OP = 0x02


def _damaged(path: Path, offset: int, what: str, *, cls: type[DataFileError] = CorruptDataError) -> DataFileError:
    return cls(f"cannot read the bag (byte offset {offset}: {what}); the file is damaged or truncated",
               source=str(path), hint="re-copy the bag; a recording cut short can often be repaired with "
                                      "'ros2 bag reindex' (directory) or 'mcap recover' (.mcap file)")



def check_structure(path: Path) -> None:
    """Walk the MCAP file's top-level records before any library reads it.

    Every record must fit in the file (a damaged length would make a reader
    allocate gigabytes or run off the end), the footer must sit at the end
    and point inside the file, and the summary section's CRC must match when
    recorded. Raises :class:`CorruptDataError` naming the byte offset.
    """
    size = path.stat().st_size
    with path.open("rb") as f:
        if f.read(8) != MCAP_MAGIC:
            raise _damaged(path, 0, "no MCAP magic at the start: not an MCAP file", cls=DataFileError)
        f.seek(size - 8)
        if size < 8 + 8 + 9 + 20 or f.read(8) != MCAP_MAGIC:
            raise _damaged(path, max(size - 8, 0), "no MCAP magic at the end: the file was cut short",
                          cls=DataFileError)
        pos = 8
        end = size - 8
        footer = None
        while pos < end:
            f.seek(pos)
            head = f.read(9)
            if len(head) < 9:
                raise _damaged(path, pos, "record header cut short")
            op, length = struct.unpack("<BQ", head)
            if length > end - pos - 9:
                raise _damaged(path, pos, f"record 0x{op:02x} claims {length} bytes, past the end of the file")
            if op == FOOTER_OP:
                footer = pos
                if pos + 9 + length != end:
                    raise _damaged(path, pos, "the footer is not at the end of the file")
                break
            pos += 9 + length
        if footer is None:
            raise _damaged(path, pos, "no footer record")
        f.seek(footer + 9)
        summary_start, offset_start, crc = struct.unpack("<QQI", f.read(20))
        if summary_start > footer or offset_start > footer:
            raise _damaged(path, footer, "the footer points outside the file")
        if crc and summary_start:
            f.seek(summary_start)
            got = zlib.crc32(f.read(footer + 1 + 8 + 16 - summary_start))
            if got != crc:
                raise _damaged(path, summary_start, f"summary CRC-32 {got:08x} does not match the recorded {crc:08x}")
