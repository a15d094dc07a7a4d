"""MCAP chunks straight into numpy: the index walk, decompression, CRC checks, and the CDR gather.

Every chunk nifo writes carries the CRC-32 of its uncompressed records
(:func:`write_chunk_crcs`); a chunk whose CRC (when present) or size does not
match is a :class:`~nifo_core.errors.CorruptDataError` naming the file offset.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import BinaryIO

import numpy as np

from nifo_core.errors import CorruptDataError, DataFileError, TimestampError

from ..mcap_structure import FOOTER_OP, MCAP_MAGIC, check_structure
from .cdr import AXES as _AXES, CDR_LE as _CDR_LE, IMU
from .cdr import LAYOUT as _LAYOUT, POINT_STAMPED, Axis

__all__ = ["receive_stamps", "indexed_counts", "write_chunk_crcs", "check_structure", "file_topics", "check_metadata_topics",
           "chunk_crc_status"]

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
    body, value = _LAYOUT[msgtype]
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
        values[i] = getattr(msg.linear_acceleration if msgtype == IMU else
                            msg.point if msgtype == POINT_STAMPED else msg.wrench.force, axis)
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


#: one topic's messages, decoded: (header stamp [ns] int64, value, log time [ns] uint64 as MCAP stores it)
_Decoded = tuple[np.ndarray, np.ndarray, np.ndarray]

_INT64_MAX = np.iinfo(np.int64).max


def receive_stamps(log_ns: np.ndarray, *, source: str, channel: str) -> np.ndarray:
    """Receive (log) times [ns, uint64] as int64 stamps, or :class:`TimestampError` beyond what int64 holds
    (2^63 ns: the year 2262; a wrapped value would put the record in 1677)."""
    log = np.asarray(log_ns, np.uint64)
    if log.size and int(log.max()) > _INT64_MAX:
        i = int(np.argmax(log > np.uint64(_INT64_MAX)))
        raise TimestampError(f"the header stamps are all zero and the receive times reach {int(log.max())} ns "
                             f"(first at message {i}), beyond 2^63 ns (the year 2262): not a time",
                             source=source, channel=channel,
                             hint="re-record with header stamps set by the sensor driver, or fix the recorder's "
                                  "clock; nifo cannot tell when these samples were taken")
    return log.astype(np.int64)


class _NoUsableIndex(Exception):
    """The MCAP file has no chunk/message index nifo can use: read it with rosbags instead."""


def _corrupt(path: Path, offset: int, what: str) -> CorruptDataError:
    return CorruptDataError(f"corrupt chunk at byte offset {offset}: {what}", source=str(path),
                            hint="the file was damaged (copy, disk or transfer): re-copy it from the original "
                                 "recording; 'mcap recover' can salvage the intact chunks")


def _read_chunk(f: BinaryIO, path: Path, offset: int) -> bytes | None:
    """The uncompressed records of the chunk at ``offset``, CRC and size checked; None: cannot decompress."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk

    f.seek(offset)
    head = f.read(9)
    if len(head) < 9 or head[0] != 0x06:
        raise _corrupt(path, offset, "no chunk record where the chunk index points")
    try:
        chunk = Chunk.read(ReadDataStream(f))
    except Exception as err:
        raise _corrupt(path, offset, f"unreadable chunk header ({type(err).__name__})") from err
    if chunk.uncompressed_size > _MAX_CHUNK:
        raise _corrupt(path, offset, f"chunk claims {chunk.uncompressed_size} bytes uncompressed")
    try:
        data = _decompress(chunk.data, chunk.compression, chunk.uncompressed_size)
    except Exception as err:  # zstd/lz4 frame errors on damaged payloads
        raise _corrupt(path, offset, f"the {chunk.compression} payload does not decompress ({err})") from err
    if data is None:
        return None
    if len(data) != chunk.uncompressed_size:
        raise _corrupt(path, offset, f"{len(data)} bytes uncompressed, the header says {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise _corrupt(path, offset, f"CRC-32 {zlib.crc32(data):08x} does not match the recorded "
                                     f"{chunk.uncompressed_crc:08x}")
    return data


#: a chunk larger than this (uncompressed) is not one nifo or a recorder wrote: refuse, do not allocate
_MAX_CHUNK = 1 << 31


def _summary(f: BinaryIO):
    from mcap.reader import make_reader

    summary = make_reader(f).get_summary()
    if summary is None or not summary.chunk_indexes:
        raise _NoUsableIndex("no chunk index")
    return summary


def _message_index(f: BinaryIO, path: Path, offset: int, cid: int) -> np.ndarray:
    f.seek(offset)
    head = f.read(15)
    if len(head) < 15:
        raise _corrupt(path, offset, "message index cut short")
    op, _, ch, nbytes = struct.unpack("<BQHI", head)
    if op != 0x07 or ch != cid or nbytes % 16:
        raise _corrupt(path, offset, "bad message index record")
    raw = f.read(nbytes)
    if len(raw) != nbytes:
        raise _corrupt(path, offset, "message index cut short")
    return np.frombuffer(raw, dtype=[("t", "<u8"), ("o", "<u8")])


def file_topics(path: Path) -> dict[str, str]:
    """{topic: message type} of the channels the MCAP file itself declares (its summary)."""
    with path.open("rb") as f:
        summary = _summary(f)
    return {ch.topic: summary.schemas[ch.schema_id].name if ch.schema_id in summary.schemas else ""
            for ch in summary.channels.values()}


def _writer(f: BinaryIO) -> str:
    """The MCAP header's ``library`` (who wrote the file), or '' when unreadable."""
    f.seek(0)
    head = f.read(8 + 9 + 4 + 256 + 4 + 256)
    try:
        if head[:8] != MCAP_MAGIC or head[8] != 0x01:
            return ""
        pos = 17
        n = struct.unpack_from("<I", head, pos)[0]
        pos += 4 + n
        n = struct.unpack_from("<I", head, pos)[0]
        return head[pos + 4:pos + 4 + n].decode("utf-8", "replace")
    except struct.error:
        return ""


def chunk_crc_status(path: Path) -> dict | None:
    """``{"chunks", "without_crc", "writer"}`` of an MCAP file (None when it has no chunk index to tell).

    A chunk whose ``uncompressed_crc`` is 0 has none recorded: a flipped bit inside it cannot be detected
    (nifo writes a CRC for every chunk; some other writers do not).
    """
    try:
        with path.open("rb") as f:
            summary = _summary(f)
            without = 0
            for ci in summary.chunk_indexes:
                # chunk record: opcode u8, length u64, start u64, end u64, uncompressed_size u64, uncompressed_crc u32
                f.seek(ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8)
                raw = f.read(4)
                without += len(raw) == 4 and struct.unpack("<I", raw)[0] == 0
            return {"chunks": len(summary.chunk_indexes), "without_crc": int(without), "writer": _writer(f)}
    except Exception:  # noqa: BLE001 - damage is reported by the reader; here only what can be told
        return None


def crc_note(status: dict | None) -> str | None:
    """The sentence ``nifo info`` and the results' provenance carry for chunks without CRC (None: all have one)."""
    if not status or not status["without_crc"]:
        return None
    who = f" (written by {status['writer']})" if status["writer"] else ""
    return (f"{status['without_crc']} of {status['chunks']} chunks carry no CRC-32{who}: damage inside them "
            "cannot be detected")


def check_metadata_topics(listed: Mapping[str, str], path: Path, *, source: str) -> None:
    """metadata.yaml's {topic: type} must be the MCAP file's own (else metadata.yaml was damaged or edited)."""
    try:
        own = file_topics(path)
    except _NoUsableIndex:
        return
    if dict(listed) != own:
        diff = sorted(set(listed.items()) ^ set(own.items()))
        raise DataFileError(f"metadata.yaml and {path.name} disagree on the topics ({', '.join(map(str, diff))[:300]}); "
                            "metadata.yaml is damaged or was edited", source=source,
                            hint="restore metadata.yaml, or rebuild it with 'ros2 bag reindex'")


def indexed_counts(path: Path, wanted: Mapping[str, tuple[str, str]]) -> dict[str, int]:
    """Messages of each ``wanted`` role as the file's own message indexes count them (not metadata.yaml)."""
    with path.open("rb") as f:
        summary = _summary(f)
        ids = {role: {cid for cid, ch in summary.channels.items() if ch.topic == topic}
               for role, (topic, _) in wanted.items()}
        counts = dict.fromkeys(wanted, 0)
        for ci in summary.chunk_indexes:
            for role, cids in ids.items():
                for cid in cids:
                    if cid in ci.message_index_offsets:
                        f.seek(ci.message_index_offsets[cid])
                        head = f.read(15)
                        if len(head) < 15:
                            raise _corrupt(path, ci.message_index_offsets[cid], "message index cut short")
                        counts[role] += struct.unpack("<BQHI", head)[3] // 16
    return counts


def _iter_mcap_indexed(path: Path, wanted: Mapping[str, tuple[str, str]], *, axis: Axis,
                       typestore) -> "Iterator[dict[str, _Decoded]]":
    """Per MCAP chunk (in file order): {role: (stamps, values, log_ns)} of the ``wanted`` roles.

    Each chunk is decompressed, its CRC checked when recorded, its messages
    located by the message index (checked against the records: opcode,
    channel, length, log time) and decoded; messages are handed out sorted by
    log time within the chunk, so memory stays about one chunk. Raises
    :class:`_NoUsableIndex` (before yielding) when the file has no usable
    index, :class:`CorruptDataError` naming the byte offset on damage.
    """
    with path.open("rb") as f:
        summary = _summary(f)
        ids = {role: {cid for cid, ch in summary.channels.items() if ch.topic == topic}
               for role, (topic, _) in wanted.items()}
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            present = {role: [c for c in cids if c in ci.message_index_offsets] for role, cids in ids.items()}
            if not any(present.values()):
                continue
            off = ci.chunk_start_offset
            data = _read_chunk(f, path, off)
            if data is None:
                raise _NoUsableIndex(f"cannot decompress {ci.compression!r} chunks")
            buf = np.frombuffer(data, np.uint8)
            out: dict[str, _Decoded] = {}
            for role, cids in present.items():
                parts = []
                for cid in cids:
                    idx = _message_index(f, path, ci.message_index_offsets[cid], cid)
                    o = idx["o"].astype(np.int64)
                    if o.size and (o.min() < 0 or o.max() + 31 > buf.size or (buf[o] != 0x05).any()):
                        raise _corrupt(path, off, "the message index points outside the messages")
                    length = buf[(o + 1)[:, None] + _GATHER8].view("<u8")[:, 0].astype(np.int64)
                    log = buf[(o + 15)[:, None] + _GATHER8].view("<u8")[:, 0]
                    if (buf[(o + 9)[:, None] + np.arange(2)].view("<u2")[:, 0] != cid).any() \
                            or (o + 9 + length > buf.size).any() or (length < 22).any() or (log != idx["t"]).any():
                        raise _corrupt(path, off, "message records do not match their index")
                    stamps, values = _decode_buffer(buf, o + 31, length - 22, msgtype=wanted[role][1], axis=axis,
                                                    typestore=typestore)
                    parts.append((stamps, values, idx["t"].astype(np.uint64)))
                if parts:
                    s, v, t = (np.concatenate([p[k] for p in parts]) for k in range(3))
                    order = np.argsort(t, kind="stable")
                    out[role] = (s[order], v[order], t[order])
            yield out


def _fill_summary_crc(f: BinaryIO, size: int) -> None:
    """Fill in the footer's summary CRC (covers the summary up to the footer's summary_offset_start)."""
    footer = size - 8 - 20 - 9
    f.seek(footer)
    op, length = struct.unpack("<BQ", f.read(9))
    if op != FOOTER_OP or length != 20:
        return
    summary_start, _ = struct.unpack("<QQ", f.read(16))
    if not summary_start:
        return
    f.seek(summary_start)
    crc = zlib.crc32(f.read(footer + 1 + 8 + 16 - summary_start))
    f.seek(footer + 9 + 16)
    f.write(struct.pack("<I", crc))


def write_chunk_crcs(path: Path) -> int:
    """Fill in the CRC-32 of every chunk of the MCAP file ``path`` (in place); returns the chunks done.

    rosbags writes ``uncompressed_crc = 0`` ("not recorded"); the MCAP spec's
    chunk CRC covers the uncompressed records, so any later change of a
    sample is detected on read (:func:`_read_chunk`).
    """
    done = 0
    with path.open("r+b") as f:
        summary = _summary(f)
        for ci in summary.chunk_indexes:
            data = _read_chunk(f, path, ci.chunk_start_offset)
            if data is None:
                continue
            # chunk record: opcode u8, length u64, start u64, end u64, uncompressed_size u64, uncompressed_crc u32
            f.seek(ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8)
            f.write(struct.pack("<I", zlib.crc32(data)))
            done += 1
        _fill_summary_crc(f, path.stat().st_size)
    return done
