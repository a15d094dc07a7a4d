"""MCAP chunks straight into numpy: the index walk, decompression, CRC checks, and the CDR gather.

Every chunk nifo writes carries the CRC-32 of its uncompressed records
(:func:`write_chunk_crcs`); a chunk whose CRC (when present) or size does not
match is a :class:`~nifo_core.errors.CorruptDataError` naming the file offset.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from .cdr import AXES as _AXES, CDR_LE as _CDR_LE, IMU, IMU_BODY as _IMU_BODY, IMU_VALUE as _IMU_VALUE
from .cdr import POINT_BODY as _POINT_BODY, POINT_VALUE as _POINT_VALUE, Axis

__all__ = ["iter_mcap_indexed", "write_chunk_crcs", "decode_buffer", "decode"]

_GATHER16 = np.arange(16)
_GATHER8 = np.arange(8)


def _decode_buffer(buf: np.ndarray, starts: np.ndarray, sizes: np.ndarray, *, msgtype: str, axis: Axis,
                   typestore) -> tuple[np.ndarray, np.ndarray]:
    """Header stamps [ns] and the ``axis`` value of messages at ``buf[starts[i]:starts[i] + sizes[i]]``.

    Fast path, per group of equally sized messages: check the encapsulation
    (CDR little endian) and that the ``frame_id`` length puts the fixed block
    where the size says, then read stamp and value with strided gathers.
    Anything else goes through rosbags' generic ``deserialize_cdr``.
    """
    body, value = (_IMU_BODY, _IMU_VALUE) if msgtype == IMU else (_POINT_BODY, _POINT_VALUE)
    value += 8 * _AXES[axis]
    n = starts.size
    stamps = np.empty(n, np.int64)
    values = np.empty(n, np.float64)
    done = np.zeros(n, bool)
    for size in np.unique(sizes).tolist():
        if size < 16 + body:
            continue
        idx = np.flatnonzero(sizes == size)
        st = starts[idx]
        hdr = buf[st[:, None] + _GATHER16]
        name_len = hdr[:, 12:16].copy().view("<u4")[:, 0].astype(np.int64)
        block = size - body  # where the 8-aligned block after std_msgs/Header begins
        ok = ((hdr[:, :4].copy().view("<u4")[:, 0] == int.from_bytes(_CDR_LE, "little"))
              & (4 + -(-(12 + name_len) // 8) * 8 == block))
        if not ok.any():
            continue
        sec = hdr[:, 4:8].copy().view("<i4")[:, 0].astype(np.int64)
        nsec = hdr[:, 8:12].copy().view("<u4")[:, 0].astype(np.int64)
        val = buf[(st + block + value)[:, None] + _GATHER8].view("<f8")[:, 0]
        good = idx[ok]
        stamps[good] = (sec * 1_000_000_000 + nsec)[ok]
        values[good] = val[ok]
        done[good] = True
    for i in np.flatnonzero(~done).tolist():  # odd messages: the generic deserializer
        msg = typestore.deserialize_cdr(buf[starts[i]:starts[i] + sizes[i]].tobytes(), msgtype)
        stamps[i] = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        values[i] = getattr(msg.linear_acceleration if msgtype == IMU else msg.point, axis)
    return stamps, values


def _decode(raws: Sequence[bytes], *, msgtype: str, axis: Axis, typestore) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_decode_buffer` for a list of serialized messages."""
    sizes = np.fromiter(map(len, raws), np.int64, count=len(raws))
    starts = np.zeros_like(sizes)
    np.cumsum(sizes[:-1], out=starts[1:])
    buf = np.frombuffer(b"".join(raws), np.uint8)
    return _decode_buffer(buf, starts, sizes, msgtype=msgtype, axis=axis, typestore=typestore)


# --- MCAP chunks straight into numpy ----------------------------------------------

def _decompress(data: bytes, compression: str, size: int) -> bytes | None:
    if compression == "":
        return data
    try:
        if compression == "zstd":
            import zstandard
            return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        if compression == "lz4":
            import lz4.frame
            return lz4.frame.decompress(data)
    except ImportError:
        return None
    return None


#: one topic's messages, decoded: (header stamp [ns], value, log time [ns]) per message
_Decoded = tuple[np.ndarray, np.ndarray, np.ndarray]


class _NoUsableIndex(Exception):
    """The MCAP file has no chunk/message index nifo can use: read it with rosbags instead."""


def _iter_mcap_indexed(path: Path, wanted: Mapping[str, tuple[str, str]], *, axis: Axis,
                       typestore) -> "Iterator[dict[str, _Decoded]]":
    """Per MCAP chunk (in file order): {role: (stamps, values, log_ns)} of the ``wanted`` roles.

    The same index walk and numpy decoder as :func:`_read_mcap_indexed`, but
    each chunk's messages are handed out (sorted by log time within the chunk)
    instead of being collected, so memory stays about one chunk. Yields
    nothing and returns early by raising :class:`_NoUsableIndex` when the file has
    no usable index (the caller then reads the whole bag).
    """
    import struct
    import zlib

    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import Chunk

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        if summary is None or not summary.chunk_indexes:
            raise _NoUsableIndex("no chunk index")
        ids = {role: {cid for cid, ch in summary.channels.items() if ch.topic == topic}
               for role, (topic, _) in wanted.items()}
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            present = {role: [c for c in cids if c in ci.message_index_offsets] for role, cids in ids.items()}
            if not any(present.values()):
                continue
            f.seek(ci.chunk_start_offset)
            op, _ = struct.unpack("<BQ", f.read(9))
            if op != 0x06:
                raise ValueError(f"no chunk at offset {ci.chunk_start_offset}")
            chunk = Chunk.read(ReadDataStream(f))
            data = _decompress(chunk.data, chunk.compression, chunk.uncompressed_size)
            if data is None:
                raise _NoUsableIndex(f"cannot decompress {chunk.compression!r} chunks")
            if len(data) != chunk.uncompressed_size or (chunk.uncompressed_crc
                                                        and zlib.crc32(data) != chunk.uncompressed_crc):
                raise ValueError("chunk checksum or size mismatch")
            buf = np.frombuffer(data, np.uint8)
            out: dict[str, _Decoded] = {}
            for role, cids in present.items():
                parts = []
                for cid in cids:
                    f.seek(ci.message_index_offsets[cid])
                    op, _, ch, nbytes = struct.unpack("<BQHI", f.read(15))
                    if op != 0x07 or ch != cid:
                        raise ValueError("bad message index")
                    idx = np.frombuffer(f.read(nbytes), dtype=[("t", "<u8"), ("o", "<u8")])
                    o = idx["o"].astype(np.int64)
                    if o.size and (o.max() + 31 > buf.size or (buf[o] != 0x05).any()):
                        raise ValueError("message index points outside the messages")
                    length = buf[(o + 1)[:, None] + _GATHER8].view("<u8")[:, 0].astype(np.int64)
                    if (buf[(o + 9)[:, None] + np.arange(2)].view("<u2")[:, 0] != cid).any() \
                            or (o + 9 + length > buf.size).any() or (length < 22).any():
                        raise ValueError("message records do not match their index")
                    stamps, values = _decode_buffer(buf, o + 31, length - 22, msgtype=wanted[role][1], axis=axis,
                                                    typestore=typestore)
                    parts.append((stamps, values, idx["t"].astype(np.int64)))
                if parts:
                    s, v, t = (np.concatenate([p[k] for p in parts]) for k in range(3))
                    order = np.argsort(t, kind="stable")
                    out[role] = (s[order], v[order], t[order])
            yield out
