"""Our standard-message conventions, and conversions between them and numpy.

Samples travel in standard types; the identifier's results are the typed
``nifo_msgs`` messages (:mod:`nifo_nodes.results`).

Per-sample input (acquisition, replay, ``ros2 bag play``)
---------------------------------------------------------
``sensor_msgs/msg/Imu``, one message per sample, ``header.stamp`` = sample
time from the source, value in ``linear_acceleration.z`` [m/s²] (the bag
layout of :mod:`nifo.io.bag`: orientation/angular velocity flagged "not
provided" per REP-145). Tire patch: ``geometry_msgs/msg/PointStamped``,
``point.z`` [m]. Decoding goes through :func:`decode_imu`, a fixed-offset read
of the serialized CDR bytes (subscriptions are ``raw=True``): a Python
subscriber that deserializes each Imu spends ≈250 µs per message.

Sample blocks between our nodes (``std_msgs/msg/Float64MultiArray``)
--------------------------------------------------------------------
======================  ==============================================================
field                   meaning
======================  ==============================================================
``layout.dim[0]``       ``label="sample"``, ``size=n``, ``stride=n·c``
``layout.dim[1]``       ``label="<ch0>|<ch1>|..."`` (channel names), ``size=c``, ``stride=c``
``layout.data_offset``  ``5``: the preamble length
``data[0:5]``           preamble ``[stamp_sec, stamp_nanosec, fs_hz, seq, segment]``
``data[5:]``            samples, row-major ``(n, c)``
======================  ==============================================================

``stamp`` is the first sample's source stamp (sec/nanosec held exactly in
float64); sample i is at ``stamp + round(i·1e9/fs_hz)`` ns. ``seq`` counts
blocks from 0 per publisher (a gap in seq = a lost block). ``segment`` counts
stream discontinuities: a new segment starts after a gap, a NaN burst or a
restarted publisher, and a receiver must not join samples across it.

Results: see :mod:`nifo_nodes.results` (``nifo_msgs``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from nifo.io.bag.cdr import CDR_LE as _CDR_LE, IMU, IMU_BODY as _IMU_BODY
from nifo.io.bag.cdr import POINT_BODY as _POINT_BODY, POINT_STAMPED, header_size, payloads, value_offset
from nifo_core.errors import InputError

__all__ = ["Block", "block_to_msg", "block_from_msg", "decode_imu", "decode_imu_batch", "decode_point", "ImuEncoder",
           "PointEncoder", "stamp_ns_of", "BLOCK_PREAMBLE"]

BLOCK_PREAMBLE = 5
_NS = 1_000_000_000


def stamp_ns_of(stamp) -> int:
    """``builtin_interfaces/Time`` to int nanoseconds."""
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def _split(stamp_ns: int) -> tuple[int, int]:
    sec, nsec = divmod(int(stamp_ns), _NS)
    return sec, nsec


# ----------------------------------------------------------------------------- per-sample messages
def _header_end(raw: bytes) -> int:
    """Offset of the first byte after the (8-aligned) std_msgs/Header, or raise InputError."""
    if len(raw) < 16 or raw[:4] != _CDR_LE:
        raise InputError(f"not a little-endian CDR message ({len(raw)} bytes, header {raw[:4].hex()})")
    (name_len,) = struct.unpack_from("<I", raw, 12)
    return 4 + -(-(12 + name_len) // 8) * 8


def _decode(raw: bytes, body: int, value: int) -> tuple[int, float]:
    end = _header_end(raw)
    if len(raw) != end + body:
        raise InputError(f"message of {len(raw)} bytes does not have the expected layout ({end + body} bytes)")
    sec, nsec = struct.unpack_from("<iI", raw, 4)
    if nsec >= _NS:
        raise InputError(f"stamp nanosec={nsec} is out of range")
    (v,) = struct.unpack_from("<d", raw, end + value)
    return sec * _NS + nsec, v


def decode_imu(raw: bytes, axis: str = "z") -> tuple[int, float]:
    """``(stamp_ns, linear_acceleration.<axis>)`` of a serialized ``sensor_msgs/msg/Imu``.

    Raises :class:`InputError` for bytes that are not a little-endian Imu
    (the caller logs and skips them).
    """
    return _decode(raw, _IMU_BODY, value_offset(IMU, axis))


def decode_imu_batch(raws: list[bytes], axis: str = "z") -> tuple[np.ndarray, np.ndarray, list[tuple[int, str]]]:
    """:func:`decode_imu` of many messages at once, vectorized: ``(stamp_ns, values, bad)``.

    ``stamp_ns`` (int64) and ``values`` (float64) hold the decodable messages in
    their input order; ``bad`` lists ``(index, reason)`` of the others (the
    reason is :func:`decode_imu`'s error), for the caller to log and skip.
    Same checks and results as :func:`decode_imu` message by message.
    """
    n = len(raws)
    if n == 0:
        return np.empty(0, np.int64), np.empty(0, np.float64), []
    lens = np.fromiter(map(len, raws), np.int64, n)
    starts = np.zeros(n, np.int64)
    np.cumsum(lens[:-1], out=starts[1:])
    buf = np.frombuffer(b"".join(raws) + bytes(16), np.uint8)  # padded: fixed-offset reads stay in bounds

    def read(offsets: np.ndarray, dtype: str) -> np.ndarray:
        size = np.dtype(dtype).itemsize
        idx = np.clip(offsets, 0, buf.size - size)[:, None] + np.arange(size)
        return np.ascontiguousarray(buf[idx]).view(dtype).ravel()

    ok = (lens >= 16) & (read(starts, "<u4") == int.from_bytes(_CDR_LE, "little"))
    name_len = read(starts + 12, "<u4").astype(np.int64)
    end = 4 + -(-(12 + name_len) // 8) * 8
    nsec = read(starts + 8, "<u4").astype(np.int64)
    ok &= (lens == end + _IMU_BODY) & (nsec < _NS)
    stamps = read(starts + 4, "<i4").astype(np.int64) * _NS + nsec
    values = read(starts + end + value_offset(IMU, axis), "<f8")
    bad = []
    for i in np.flatnonzero(~ok).tolist():
        try:
            decode_imu(raws[i], axis)
            raise AssertionError("decode_imu_batch and decode_imu disagree")  # pragma: no cover
        except InputError as err:
            bad.append((i, str(err)))
    return stamps[ok], values[ok], bad


def decode_point(raw: bytes, axis: str = "z") -> tuple[int, float]:
    """``(stamp_ns, point.<axis>)`` of a serialized ``geometry_msgs/msg/PointStamped``."""
    return _decode(raw, _POINT_BODY, value_offset(POINT_STAMPED, axis))


class _Encoder:
    """Serialized messages from a template (:func:`nifo.io.bag.cdr.payloads` of one message): patch stamp
    and value into their fixed offsets (≈1 µs, vs ≈20 µs for the numpy encoder on one message)."""

    def __init__(self, frame_id: str, msgtype: str, axis: str) -> None:
        self._template = payloads(np.zeros(1, np.int64), np.zeros(1), frame_id=frame_id, msgtype=msgtype,
                                  axis=axis)[0].tobytes()
        self._value = header_size(frame_id) + value_offset(msgtype, axis)

    def encode(self, stamp_ns: int, value: float) -> bytes:
        buf = bytearray(self._template)
        sec, nsec = _split(stamp_ns)
        struct.pack_into("<iI", buf, 4, sec, nsec)
        struct.pack_into("<d", buf, self._value, value)
        return bytes(buf)


class ImuEncoder(_Encoder):
    """Serialized ``sensor_msgs/msg/Imu`` with ``linear_acceleration.<axis>`` = value (REP-145 flags set)."""

    def __init__(self, frame_id: str, axis: str = "z") -> None:
        super().__init__(frame_id, IMU, axis)


class PointEncoder(_Encoder):
    """Serialized ``geometry_msgs/msg/PointStamped`` with ``point.<axis>`` = value."""

    def __init__(self, frame_id: str, axis: str = "z") -> None:
        super().__init__(frame_id, POINT_STAMPED, axis)


# ----------------------------------------------------------------------------- sample blocks
@dataclass(frozen=True)
class Block:
    """A block of uniformly sampled multi-channel data with its first sample's source stamp."""

    stamp_ns: int
    fs_hz: float
    channels: tuple[str, ...]
    data: np.ndarray  # (n, c)
    seq: int = 0
    segment: int = 0

    @property
    def n(self) -> int:
        return int(self.data.shape[0])

    def end_stamp_ns(self) -> int:
        """Stamp the sample after the last one would have."""
        return self.stamp_ns + int(round(self.n * 1e9 / self.fs_hz))

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.channels.index(name)]


def block_to_msg(block: Block):
    """:class:`Block` to ``std_msgs/msg/Float64MultiArray`` (layout in the module docstring)."""
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    n, c = block.data.shape
    sec, nsec = _split(block.stamp_ns)
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label="sample", size=n, stride=n * c),
                      MultiArrayDimension(label="|".join(block.channels), size=c, stride=c)]
    msg.layout.data_offset = BLOCK_PREAMBLE
    pre = np.array([sec, nsec, block.fs_hz, block.seq, block.segment], np.float64)
    msg.data = np.concatenate([pre, np.ascontiguousarray(block.data, np.float64).ravel()])
    return msg


def block_from_msg(msg) -> Block:
    """Inverse of :func:`block_to_msg`; raises :class:`InputError` for a message that breaks the layout."""
    dims = msg.layout.dim
    if len(dims) != 2 or dims[0].label != "sample" or msg.layout.data_offset != BLOCK_PREAMBLE:
        raise InputError(f"not a nifo sample block (dims {[d.label for d in dims]}, "
                         f"data_offset={msg.layout.data_offset})")
    n, c = int(dims[0].size), int(dims[1].size)
    data = np.asarray(msg.data, np.float64)
    if data.size != BLOCK_PREAMBLE + n * c:
        raise InputError(f"sample block holds {data.size} values, layout says {BLOCK_PREAMBLE}+{n}x{c}")
    channels = tuple(dims[1].label.split("|"))
    if len(channels) != c:
        raise InputError(f"sample block names {len(channels)} channels, layout says {c}")
    sec, nsec, fs, seq, seg = data[:BLOCK_PREAMBLE]
    if not (np.isfinite(fs) and fs > 0 and 0 <= nsec < _NS and sec == int(sec) and nsec == int(nsec)):
        raise InputError(f"sample block preamble is invalid (stamp {sec}/{nsec}, fs {fs})")
    return Block(int(sec) * _NS + int(nsec), float(fs), channels, data[BLOCK_PREAMBLE:].reshape(n, c),
                 int(seq), int(seg))
