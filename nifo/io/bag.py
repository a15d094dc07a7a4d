"""rosbag2 bags (MCAP storage) to and from :class:`~nifo_core.record.Record`.

Layout of the bags nifo writes (and expects by default)
-------------------------------------------------------
- ``/nifo/spindle/imu``: ``sensor_msgs/msg/Imu``, spindle (unsprung) acceleration
  in ``linear_acceleration.<axis>`` [m/s²];
- ``/nifo/body/imu``: ``sensor_msgs/msg/Imu``, body (sprung) acceleration, likewise;
- ``/nifo/tire_patch/displacement`` (optional): ``geometry_msgs/msg/PointStamped``,
  tire-patch displacement in ``point.<axis>`` [m];
- ``/nifo/force`` (optional): ``geometry_msgs/msg/WrenchStamped``, a measured
  force on the body (a shaker rig's load cell) in ``wrench.force.<axis>`` [N];
  the standard stamped message for a force (what ROS force/torque sensor
  drivers publish), frame_id ``"force"``.

* One message per sample; ``header.stamp`` is the sample time
  ``t0_ns + round(i · 1e9 / fs_hz)`` and is also the bag's log time.
  ``header.frame_id`` is ``"spindle"``, ``"body"`` or ``"tire_patch"``.
* Imu: only ``linear_acceleration.<axis>`` (default ``z``, vertical) carries
  data; everything else is zero. Per REP-145, ``orientation_covariance[0]``
  and ``angular_velocity_covariance[0]`` are -1 ("not provided");
  ``linear_acceleration_covariance`` is all zero ("unknown").
  Values are stored exactly as in the Record: gravity is *not* added, so a
  write/read round trip is bit-exact.
* Tire-patch displacement is a ``geometry_msgs/msg/PointStamped`` (the point's
  ``<axis>`` component, metres). It is a position, not a vector quantity or a
  pose; PointStamped is the smallest standard stamped message that carries a
  position and is understood by every ROS tool (plotjuggler, rviz, ros2 topic
  echo). A bare ``std_msgs/Float64`` has no stamp and was therefore ruled out.
* rosbag2 metadata version 8 with ``storage_identifier: mcap``: the newest
  version that ``ros2 bag`` on Humble (which cannot parse version 9's QoS
  lists) and Jazzy both read. Message definitions are embedded in the MCAP
  schemas, and every topic records its offered QoS profile: the sensor-data
  profile (best effort, volatile, keep last 5), like ``qos_profile_sensor_data``.
  ``custom_data`` holds ``generator: nifo <version>``.

Reading
-------
:func:`read_bag` accepts a bag directory (with ``metadata.yaml``), a single
``.mcap`` file (rosbags reads lone storage files), a directory holding one
``.mcap`` file without metadata, or a ``.db3`` (sqlite3) bag. Topic roles come
from :class:`BagTopics` or, when the default names are absent, from topic
names (see :func:`resolve_topics`).

rosbags opens the bag (metadata, topics, message counts). The messages are
then decoded without a Python object per message: for a single MCAP file
(uncompressed or with zstd/lz4 chunks) the chunk and message indexes locate
every message record and numpy gathers from the decompressed chunks; other
bags (sqlite3, file/message compression, unindexed MCAP) yield their raw CDR
bytes through rosbags' reader, which are concatenated. In both cases the
fixed-layout fields (stamp, one float64) are gathered per group of equally
sized messages, after checking the encapsulation header and the ``frame_id``
length that sets the offsets; a message that does not fit (big-endian, odd
layout) goes through rosbags' generic ``deserialize_cdr``. See
``benchmarks/bench_bag_read.py`` for the speed against the generic path.

Stamps come from ``header.stamp``; only when those are all zero is the bag's
receive (log) time used, and ``meta["stamps"]`` says so.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from nifo_core.errors import (ConfigError, DataFileError, MissingChannelError, NifoError,
                              RecordTooShortError, TimestampError)
from nifo_core.record import Record

from .atomic import staged_file
from .cdr import AXES as _AXES, CDR_LE as _CDR_LE, IMU
from .cdr import LAYOUT as _LAYOUT, POINT_STAMPED, WRENCH_STAMPED, Axis
from .cdr import payloads as _payloads  # the message layout lives in nifo.io.cdr

if TYPE_CHECKING:
    from rosbags.interfaces import Connection

__all__ = ["BagTopics", "TopicData", "read_bag", "iter_bag_chunks", "write_bag", "write_channels",
           "resolve_topics", "IMU", "POINT_STAMPED", "WRENCH_STAMPED"]


#: rosbag2 metadata version written: 8 is read by Humble and Jazzy (9 is not read by Humble)
BAG_VERSION = 8

_SPINDLE_WORDS = ("spindle", "wheel", "unsprung")
_BODY_WORDS = ("body", "sprung", "chassis")
_TIRE_WORDS = ("tire", "tyre", "patch", "road")
_FORCE_WORDS = ("force", "load", "wrench")
_FORCE_TOPIC = "/nifo/force"

_ROLE_ALIASES = {"spindle": "spindle", "spindle_accel": "spindle", "body": "body", "body_accel": "body",
                 "tire_patch": "tire_patch", "tire_patch_disp": "tire_patch", "force": "force"}


@dataclass(frozen=True)
class BagTopics:
    """Which topic plays which role.

    Reading with topics other than the defaults requires them to exist (the
    default tire-patch topic may be absent: no tire patch then);
    ``tire_patch=None`` ignores any tire-patch topic. Writing a record with a
    tire patch needs a ``tire_patch`` topic.
    """

    spindle: str = "/nifo/spindle/imu"
    body: str = "/nifo/body/imu"
    tire_patch: str | None = "/nifo/tire_patch/displacement"
    #: None: ``/nifo/force`` when the bag has it (a force is optional)
    force: str | None = None

    @classmethod
    def parse(cls, text: str) -> "BagTopics":
        """``"spindle=/a,body=/b[,tire_patch=/c]"`` (the ``--topics`` option) to :class:`BagTopics`."""
        given: dict[str, str] = {}
        for item in filter(None, (s.strip() for s in text.split(","))):
            key, sep, topic = item.partition("=")
            role = _ROLE_ALIASES.get(key.strip())
            if not sep or role is None or not topic.strip():
                raise ConfigError(f"cannot read --topics item {item!r}", channel="--topics",
                                  hint="write --topics spindle=/a,body=/b[,tire_patch=/c]")
            given[role] = topic.strip()
        return cls(**given)

    def as_dict(self) -> dict[str, str | None]:
        """Topic per role (``force`` only when set)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "force" or self.force}


_DEFAULT_TOPICS = BagTopics()


# =============================================================================
# writing
# =============================================================================

def _sensor_qos():
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    zero = QosTime(0, 0)  # RMW_DURATION_UNSPECIFIED, as in qos_profile_sensor_data
    return Qos(QosHistory.KEEP_LAST, 5, QosReliability.BEST_EFFORT, QosDurability.VOLATILE,
               zero, zero, QosLiveliness.AUTOMATIC, zero, False)


@dataclass(frozen=True)
class TopicData:
    """One topic to write: per-message stamps [ns] and values (``msgtype`` Imu or PointStamped)."""

    topic: str
    msgtype: str
    frame_id: str
    stamp_ns: np.ndarray
    values: np.ndarray
    log_ns: np.ndarray | None = None  #: bag receive time; default: the header stamps


def _topic_data(record: Record, topics: BagTopics) -> list[TopicData]:
    stamps = record.t0_ns + np.rint(np.arange(record.n) * (1e9 / record.fs_hz)).astype(np.int64)
    out = [TopicData(topics.spindle, IMU, "spindle", stamps, record.spindle_accel),
           TopicData(topics.body, IMU, "body", stamps, record.body_accel)]
    if record.tire_patch_disp is not None:
        if not topics.tire_patch:
            raise ConfigError("the record has a tire-patch displacement but no topic was given for it",
                              channel="tire_patch", hint="set BagTopics(tire_patch=...)")
        out.append(TopicData(topics.tire_patch, POINT_STAMPED, "tire_patch", stamps, record.tire_patch_disp))
    if record.force is not None:
        out.append(TopicData(topics.force or _FORCE_TOPIC, WRENCH_STAMPED, "force", stamps, record.force))
    return out


def _stream(log_ns: np.ndarray, k: int, conn, raw: bytes, size: int):
    return ((t, k, i, conn, raw, size) for i, t in enumerate(log_ns.tolist()))


def _write_bag_dir(bagdir: Path, data: Sequence[TopicData], axis: Axis) -> None:
    import heapq

    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    qos = [_sensor_qos()]
    from nifo_core import __version__

    writer = Writer(bagdir, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
    # zstd MCAP chunk compression (storage-level: ros2 bag, Foxglove and mcap read it natively);
    # Imu messages are mostly constant fields, so bags shrink several-fold
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        # a map, never null: yaml-cpp in ros2 bag cannot convert a null custom_data
        writer.set_custom_data("generator", f"nifo {__version__}")
        streams = []
        for k, td in enumerate(data):
            conn = writer.add_connection(td.topic, td.msgtype, typestore=typestore, offered_qos_profiles=qos)
            stamps = np.asarray(td.stamp_ns, np.int64)
            rows = _payloads(stamps, np.asarray(td.values, np.float64), frame_id=td.frame_id,
                             msgtype=td.msgtype, axis=axis)
            raw, size = rows.tobytes(), rows.shape[1]
            # (log time, topic order, message index, connection, bytes): interleaved as a recorder logs them
            log_ns = stamps if td.log_ns is None else np.asarray(td.log_ns, np.int64)
            streams.append(_stream(log_ns, k, conn, raw, size))
        write = writer.write
        for t, _, i, conn, raw, size in heapq.merge(*streams, key=lambda m: (m[0], m[1], m[2])):
            write(conn, t, raw[i * size:(i + 1) * size])


def write_channels(path: str | os.PathLike, data: Sequence[TopicData], *, axis: Axis = "z") -> Path:
    """Write topics with their own stamps as a rosbag2 MCAP bag (layout as :func:`write_bag`); atomic.

    For tools and tests that need channels :class:`Record` cannot hold
    (uneven stamps, offsets, other topic sets). Log time = header stamp.
    """
    if axis not in _AXES:
        raise ConfigError(f"{axis=} is not one of x, y, z", channel="--axis", hint="use --axis x, y or z")
    for td in data:
        if (td.msgtype not in _LAYOUT or np.shape(td.stamp_ns) != np.shape(td.values)
                or (td.log_ns is not None and np.shape(td.log_ns) != np.shape(td.values))):
            raise ConfigError(f"topic {td.topic}: {td.msgtype} with {np.size(td.stamp_ns)} stamps and "
                              f"{np.size(td.values)} values", channel=td.topic,
                              hint=f"give {IMU}, {POINT_STAMPED} or {WRENCH_STAMPED} and one stamp per value")
    names = [td.topic for td in data]
    if len(set(names)) != len(names):
        raise ConfigError(f"two roles share one topic: {names}", channel="--topics",
                          hint="give each channel its own topic")
    final = Path(path)
    try:
        with staged_file(final) as tmp:
            if final.suffix == ".mcap":
                bagdir = tmp.parent / "bag" / final.stem
                bagdir.parent.mkdir()
                _write_bag_dir(bagdir, data, axis)
                os.replace(bagdir / f"{final.stem}.mcap", tmp)
            else:
                _write_bag_dir(tmp, data, axis)
    except NifoError as err:
        raise err.with_context(source=str(final)) from None
    except OSError as err:
        raise DataFileError(f"cannot write the bag ({err.strerror or err})", source=str(final),
                            hint="check that the directory exists and is writable") from err
    return final


def write_bag(path: str | os.PathLike, record: Record, *, topics: BagTopics | None = None,
              axis: Axis = "z") -> Path:
    """Write ``record`` as a rosbag2 MCAP bag; atomic (nothing is left behind on failure).

    ``path`` ending in ``.mcap`` gives a single MCAP file (``ros2 bag info/play``
    read those directly); any other path gives a bag directory with
    ``metadata.yaml`` and ``<name>.mcap``. An existing bag at ``path`` is replaced.
    Returns ``path``.
    """
    try:
        data = _topic_data(record, topics or _DEFAULT_TOPICS)
    except NifoError as err:
        raise err.with_context(source=str(path)) from None
    return write_channels(path, data, axis=axis)


# =============================================================================
# reading
# =============================================================================

def _storage_path(path: Path) -> Path:
    """The path rosbags' Reader should open, or raise :class:`DataFileError`."""
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return path
        mcaps = sorted(path.glob("*.mcap"))
        if len(mcaps) == 1:
            return mcaps[0]
        raise DataFileError("directory is not a rosbag2 bag (no metadata.yaml"
                            + (f", {len(mcaps)} .mcap files)" if mcaps else ", no .mcap file)"),
                            source=str(path), hint="pass the bag directory or one .mcap file")
    return path


def _topic_table(conns: Sequence["Connection"]) -> dict[str, str]:
    return {c.topic: c.msgtype for c in conns}


def _matching(names: Sequence[str], words: Sequence[str], exclude: Sequence[str] = ()) -> list[str]:
    def has(name: str, ws: Sequence[str]) -> bool:
        parts = re.split(r"[^a-z0-9]+", name.lower())
        return any(w in p for p in parts for w in ws)
    return [n for n in names if has(n, words) and not (exclude and has(n, exclude))]


def resolve_topics(available: Mapping[str, str], topics: BagTopics | None, *,
                   source: str) -> dict[str, str | None]:
    """Topic for each role (``spindle``, ``body``, ``tire_patch``) among ``available`` {topic: msgtype}.

    Explicit ``topics`` must exist. Without them the defaults are used when
    present; otherwise Imu topics are matched by name: spindle
    ("spindle", "wheel", "unsprung") and body ("body", "sprung", "chassis",
    but not a spindle word); a PointStamped with "tire", "tyre", "patch" or
    "road" in its name is the tire patch, a WrenchStamped ``/nifo/force`` or
    the one with "force", "load" or "wrench" in its name the measured force
    (the ``force`` role is listed only when found). Raises :class:`MissingChannelError`
    listing the Imu topics when a role is absent or ambiguous.
    """
    imus = sorted(t for t, ty in available.items() if ty == IMU)
    points = sorted(t for t, ty in available.items() if ty == POINT_STAMPED)
    listing = ", ".join(imus) or "none"
    fix = "name the topics, e.g. --topics spindle=/a,body=/b (topics=BagTopics(spindle=..., body=...))"

    def missing(role: str, what: str) -> MissingChannelError:
        return MissingChannelError(f"{what}; Imu topics in the bag: {listing}", source=source,
                                   channel=role, hint=fix)

    if topics is not None and topics != _DEFAULT_TOPICS:
        out: dict[str, str | None] = {}
        for role, want, types in (("spindle", topics.spindle, (IMU,)), ("body", topics.body, (IMU,)),
                                  ("tire_patch", topics.tire_patch, (POINT_STAMPED,)),
                                  ("force", topics.force or _FORCE_TOPIC, (WRENCH_STAMPED,))):
            if want is None:
                out[role] = None
            elif want not in available:
                if (role, want) in (("tire_patch", _DEFAULT_TOPICS.tire_patch), ("force", _FORCE_TOPIC)):
                    out[role] = None  # the optional default
                    continue
                raise missing(role, f"topic {want} is not in the bag")
            elif available[want] not in types:
                raise MissingChannelError(f"topic {want} is {available[want]}, expected {' or '.join(types)}",
                                          source=source, channel=role, hint=fix)
            else:
                out[role] = want
        if out.get("force", 0) is None:
            del out["force"]
        return out

    d = _DEFAULT_TOPICS
    out = {}
    for role, default, words, exclude in (("spindle", d.spindle, _SPINDLE_WORDS, ()),
                                          ("body", d.body, _BODY_WORDS, _SPINDLE_WORDS)):
        if available.get(default) == IMU:
            out[role] = default
            continue
        found = _matching(imus, words, exclude)
        if len(found) != 1:
            raise missing(role, f"no Imu topic for the {role}" if not found
                          else f"several Imu topics could be the {role} ({', '.join(found)})")
        out[role] = found[0]
    if available.get(d.tire_patch) == POINT_STAMPED:
        out["tire_patch"] = d.tire_patch
    else:
        found = _matching(points, _TIRE_WORDS)
        out["tire_patch"] = found[0] if len(found) == 1 else None
    wrenches = sorted(t for t, ty in available.items() if ty == WRENCH_STAMPED)
    found = [_FORCE_TOPIC] if available.get(_FORCE_TOPIC) == WRENCH_STAMPED else _matching(wrenches, _FORCE_WORDS)
    if len(found) == 1:   # the force role is listed only when present
        out["force"] = found[0]
    if out["spindle"] == out["body"]:
        raise missing("body", f"spindle and body resolve to the same topic {out['spindle']}")
    return out


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


def _mcap_file(storage: Path) -> Path | None:
    """The one uncompressed-mode MCAP file of a bag, or None (then rosbags reads it)."""
    if storage.is_file():
        return storage if storage.suffix == ".mcap" else None
    import yaml

    info = yaml.safe_load((storage / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    files = info.get("relative_file_paths") or []
    if info.get("storage_identifier") != "mcap" or len(files) != 1 or info.get("compression_mode"):
        return None
    return storage / Path(files[0]).name


#: one topic's messages, decoded: (header stamp [ns], value, log time [ns]) per message
_Decoded = tuple[np.ndarray, np.ndarray, np.ndarray]


class _NoUsableIndex(Exception):
    """The MCAP file has no chunk/message index nifo can use: read it with rosbags instead."""


def _read_mcap_indexed(path: Path, wanted: Mapping[str, tuple[str, str]], *, expected: Mapping[str, int],
                       axis: Axis, typestore) -> dict[str, _Decoded] | None:
    """Messages of the ``wanted`` {role: (topic, msgtype)} via the MCAP chunk and message indexes.

    Each chunk is decompressed, its messages located by the message index and
    decoded by :func:`_decode_buffer`, then dropped (memory stays about one
    chunk). Returns {role: (stamps, values, log_ns)} in log-time order, as
    rosbags yields them, or None when the file has no usable index or the
    index does not hold the ``expected`` message count of every role (the
    caller then iterates with rosbags). Raises on damaged data.
    """
    parts: dict[str, list[_Decoded]] = {role: [] for role in wanted}
    try:
        for chunk in _iter_mcap_indexed(path, wanted, axis=axis, typestore=typestore):
            for role, decoded in chunk.items():
                parts[role].append(decoded)
    except _NoUsableIndex:
        return None
    for role, ps in parts.items():
        if sum(p[0].size for p in ps) != expected[role]:
            return None  # an incomplete index: let rosbags scan the file
    out = {}
    for role, ps in parts.items():
        stamps, values, log_ns = (np.concatenate([p[k] for p in ps]) if ps else np.zeros(0, dt)
                                  for k, dt in enumerate((np.int64, np.float64, np.int64)))
        order = np.argsort(log_ns, kind="stable")  # log-time order; ties in file order
        out[role] = (stamps[order], values[order], log_ns[order])
    return out


def _iterate(reader, conns: Sequence["Connection"], wanted: Mapping[str, tuple[str, str]], *, axis: Axis,
             typestore) -> dict[str, _Decoded]:
    """Messages of each role through rosbags' reader (any storage, compression, unindexed files)."""
    by_id = {c.id: role for c in conns for role, (t, _) in wanted.items() if c.topic == t}
    datas: dict[str, list[bytes]] = {role: [] for role in wanted}
    logs: dict[str, list[int]] = {role: [] for role in wanted}
    sinks = {cid: (datas[role].append, logs[role].append) for cid, role in by_id.items()}
    for conn, t, d in reader.messages(connections=[c for c in conns if c.id in by_id]):
        add_data, add_t = sinks[conn.id]
        add_data(d)
        add_t(t)
    out = {}
    for role, (_, msgtype) in wanted.items():
        stamps, values = _decode(datas[role], msgtype=msgtype, axis=axis, typestore=typestore)
        out[role] = (stamps, values, np.asarray(logs[role], np.int64))
    return out


@dataclass
class _Channel:
    """One topic's decoded messages."""

    topic: str
    msgtype: str
    stamp_ns: np.ndarray
    values: np.ndarray
    log_ns: np.ndarray


_CHANNEL_OF_ROLE = {"spindle": "spindle_accel", "body": "body_accel", "tire_patch": "tire_patch_disp",
                    "force": "force"}


def _open_checked(path: str | os.PathLike, axis: Axis) -> tuple[Path, str, Path]:
    """(path, source name, storage path) of a bag that exists and is not empty, or a clear error."""
    if axis not in _AXES:
        raise ConfigError(f"{axis=} is not one of x, y, z", channel="--axis", hint="use --axis x, y or z")
    path = Path(path)
    src = str(path)
    if not path.exists():
        raise DataFileError("no such file or directory", source=src, hint="check the path")
    if path.is_file() and path.stat().st_size == 0:
        raise DataFileError("the file is empty (0 bytes)", source=src,
                            hint="re-copy the bag; the recording may not have started")
    return path, src, _storage_path(path)


def read_bag(path: str | os.PathLike, *, topics: BagTopics | None = None, axis: Axis = "z") -> Record:
    """Read a rosbag2 bag (directory, lone ``.mcap`` or ``.db3``) into a :class:`Record`.

    Raises :class:`DataFileError` (unreadable, truncated, empty),
    :class:`MissingChannelError`, :class:`NonFiniteError`,
    :class:`TimestampError` or :class:`SampleRateError`, naming file and topic.
    """
    from .loader import assemble_record  # shared with the CSV and MAT readers

    path, src, storage = _open_checked(path, axis)
    chans = _read_channels(storage, topics, axis, src)
    # header stamps, unless a recorder left them all zero: then the receive (log) time
    use_log_time = not any(ch.stamp_ns.any() for ch in chans.values())
    meta = {"format": "rosbag2", "storage": "sqlite3" if _is_sqlite(storage) else "mcap", "path": src,
            "topics": {role: chans[role].topic if role in chans else None for role in _CHANNEL_OF_ROLE
                       if role != "force" or role in chans},   # a force only when there is one
            "axis": axis, "stamps": "receive_time" if use_log_time else "header"}
    if use_log_time:
        meta["stamps_note"] = "header stamps are all zero; the bag's receive (log) time was used"
    return assemble_record(
        {_CHANNEL_OF_ROLE[r]: (ch.log_ns if use_log_time else ch.stamp_ns, ch.values) for r, ch in chans.items()},
        labels={_CHANNEL_OF_ROLE[r]: ch.topic for r, ch in chans.items()}, path=path, meta=meta, stamp_tol_ns=1.0)


def _is_sqlite(storage: Path) -> bool:
    if storage.is_dir():
        return not any(storage.glob("*.mcap")) and any(storage.glob("*.db3*"))
    return storage.suffix == ".db3"


def _read_channels(storage: Path, topics: BagTopics | None, axis: Axis, src: str) -> dict[str, _Channel]:
    """_Decoded messages of each role present; every reader error becomes a :class:`DataFileError`."""
    import contextlib
    import tempfile

    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    try:
        with contextlib.ExitStack() as stack:
            mcap_file = _mcap_file(storage)
            if storage.is_file() and storage.suffix not in (".mcap", ".db3"):
                # an MCAP file under another name: rosbags picks the storage by suffix
                alias = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="nifo-bag-"))) / "bag.mcap"
                alias.symlink_to(storage.resolve())
                storage = mcap_file = alias
            with Reader(storage) as reader:  # validates metadata and gives the topics
                conns = list(reader.connections)
                if not conns or reader.message_count == 0:
                    raise DataFileError("the bag holds no messages", source=src,
                                        hint="record again and check that the sensor topics were published")
                available = _topic_table(conns)
                wanted = {r: (t, available[t]) for r, t in resolve_topics(available, topics, source=src).items()
                          if t}
                decoded = None
                if mcap_file is not None:
                    expected = {r: sum(c.msgcount for c in conns if c.topic == t) for r, (t, _) in wanted.items()}
                    decoded = _read_mcap_indexed(mcap_file, wanted, expected=expected, axis=axis,
                                                 typestore=typestore)
                if decoded is None:
                    decoded = _iterate(reader, conns, wanted, axis=axis, typestore=typestore)
            out = {role: _Channel(wanted[role][0], wanted[role][1], *d) for role, d in decoded.items()}
    except NifoError:
        raise
    except FileNotFoundError as err:
        raise DataFileError(f"cannot open the bag ({err})", source=src, hint="check the path") from err
    except PermissionError as err:
        raise DataFileError("permission denied", source=src, hint="check the file's permissions") from err
    except Exception as err:  # rosbags ReaderError, mcap/struct/zstd/lz4 errors on damaged files, ...
        detail = str(err).rstrip(".") or type(err).__name__
        raise DataFileError(f"cannot read the bag ({detail}); the file is damaged or truncated", source=src,
                            hint="re-copy the bag; a recording cut short can often be repaired with "
                                 "'ros2 bag reindex' (directory) or 'mcap recover' (.mcap file)") from err
    for role in list(out):
        if not out[role].values.size:
            if role in ("tire_patch", "force"):
                del out[role]
                continue
            raise DataFileError("the topic holds no messages", source=src, channel=out[role].topic,
                                hint="record again and check that the sensor published")
    return out


# =============================================================================
# reading chunk by chunk (memory bounded by the chunk, not the recording)
# =============================================================================

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


class _ChunkAssembler:
    """Turns per-role message streams into aligned, uniformly sampled :class:`Record` chunks.

    The checks of :func:`nifo.io.loader.assemble_record`, applied as the data
    arrive: the rate comes from the first chunk's stamps (snapped to its short
    decimal form); later stamps must continue it without gaps or reversals;
    roles must share sample instants (within a quarter period). Leading
    samples of a role that started earlier are trimmed, as are trailing ones.
    """

    def __init__(self, roles: Sequence[str], *, chunk_samples: int, src: str, name: str, labels: Mapping[str, str],
                 meta: Mapping, total: int) -> None:
        self.roles, self.chunk, self.src, self.name, self.labels = list(roles), int(chunk_samples), src, name, labels
        self.meta, self.total = dict(meta), int(total)
        self.pending: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {r: [] for r in self.roles}
        self.count = {r: 0 for r in self.roles}
        self.fs: float | None = None
        self.last: int | None = None
        self.emitted = 0
        self.index = 0
        self.aligned = False

    def add(self, role: str, stamps: np.ndarray, values: np.ndarray) -> None:
        if stamps.size:
            self.pending[role].append((stamps, values))
            self.count[role] += stamps.size

    def _take(self, role: str, k: int) -> tuple[np.ndarray, np.ndarray]:
        parts = self.pending[role]
        s = np.concatenate([p[0] for p in parts]) if len(parts) > 1 else parts[0][0]
        v = np.concatenate([p[1] for p in parts]) if len(parts) > 1 else parts[0][1]
        self.pending[role] = [(s[k:], v[k:])] if s.size > k else []
        self.count[role] = s.size - k
        return s[:k], v[:k]

    def _align_start(self) -> None:
        firsts = {r: self.pending[r][0][0][0] for r in self.roles}
        start = max(firsts.values())
        for r in self.roles:
            s = np.concatenate([p[0] for p in self.pending[r]])
            period_guess = float(np.median(np.diff(s[:64]))) if s.size > 1 else 0.0
            drop = int(np.searchsorted(s, start - 0.25 * period_guess, "left"))
            if drop:
                self._take(r, drop)
                self.meta.setdefault("trimmed", {})[self.labels[r]] = [drop, 0]
        self.aligned = True

    def ready(self, final: bool = False) -> "Iterator[Record]":
        from nifo_core.timebase import sample_rate_from_stamps

        from .loader import _nominal_rate

        if not all(self.count.values()):
            return
        if not self.aligned:
            self._align_start()
        while True:
            n = min(self.count.values())
            if n == 0 or (n < self.chunk and not final):
                return
            k = min(n, self.chunk)
            taken = {r: self._take(r, k) for r in self.roles}
            ref_role = self.roles[0]
            ref = taken[ref_role][0]
            if self.fs is None:
                if ref.size < 2:
                    raise RecordTooShortError(f"{ref.size} sample(s): cannot tell the sample rate", source=self.src,
                                              channel=self.labels[ref_role], hint="record at least a few seconds")
                rate = sample_rate_from_stamps(ref, source=self.src, channel=self.labels[ref_role])
                self.fs = _nominal_rate(ref, rate, 1.0)
            period = 1e9 / self.fs
            for r in self.roles:
                s = taken[r][0]
                seq = s if self.last is None else np.concatenate([[self.last], s])
                dt = np.diff(seq)
                bad = (dt <= 0) | (np.abs(dt - period) > 0.5 * period)
                if bad.any():
                    i = int(np.argmax(bad))
                    raise TimestampError(
                        f"time stamps are not uniform or not increasing at "
                        f"t={(seq[i + 1] - seq[0]) / 1e9 + self.emitted / self.fs:.3f} s "
                        f"(interval {dt[i] / 1e6:.3f} ms, sample period {period / 1e6:.3f} ms)",
                        source=self.src, channel=self.labels[r],
                        hint="split the record at the gap (or fill dropped samples) and analyse the pieces")
                if r != ref_role:
                    dev = np.abs(s - ref) > 0.25 * period
                    if dev.any():
                        i = int(np.argmax(dev))
                        raise TimestampError(
                            f"the channels are not sampled at the same instants: at sample {self.emitted + i} "
                            f"{self.labels[r]} is {(s[i] - ref[i]) / 1e6:+.3f} ms off {self.labels[ref_role]}",
                            source=self.src, channel=f"{self.labels[ref_role]}, {self.labels[r]}",
                            hint="resample the channels onto one clock so that each sample has one stamp for all")
            meta = dict(self.meta)
            meta["chunk"] = {"index": self.index, "start": self.emitted, "total_samples": self.total}
            vals = {r: taken[r][1] for r in self.roles}
            try:
                rec = Record(self.fs, vals["spindle"], vals["body"], vals.get("tire_patch"), force=vals.get("force"),
                             t0_ns=int(ref[0]),
                             source=self.name, meta=meta)
            except NifoError as err:
                raise err.with_context(source=self.src) from None
            self.last = int(ref[-1])
            self.emitted += k
            self.index += 1
            yield rec


def _record_chunks(rec: Record, chunk_samples: int) -> "Iterator[Record]":
    """Slices of a whole record, with the chunk metadata of :func:`iter_bag_chunks`."""
    from dataclasses import replace

    for i, start in enumerate(range(0, rec.n, chunk_samples)):
        part = rec.slice(start, start + chunk_samples)
        yield replace(part, meta={**dict(rec.meta), "chunk": {"index": i, "start": start, "total_samples": rec.n}})


def iter_bag_chunks(path: str | os.PathLike, *, chunk_samples: int, topics: BagTopics | None = None,
                    axis: Axis = "z") -> "Iterator[Record]":
    """Read a bag as consecutive :class:`Record` chunks of ``chunk_samples`` samples (the last may be shorter).

    For a single indexed MCAP file (what nifo and ``ros2 bag record`` write)
    the MCAP chunks are decoded one at a time with the numpy decoder of
    :func:`read_bag`, so memory is bounded by ``chunk_samples`` whatever the
    recording's length; other bags are read whole and sliced. Chunks carry
    ``meta["chunk"] = {"index", "start", "total_samples"}`` (the expected
    total from the bag's message counts). The same checks as :func:`read_bag`
    apply (rate, gaps, common instants, finiteness), chunk by chunk.
    """
    if isinstance(chunk_samples, bool) or int(chunk_samples) < 2:
        raise ConfigError(f"chunk_samples={chunk_samples!r} must be an integer >= 2")
    chunk_samples = int(chunk_samples)
    path, src, storage = _open_checked(path, axis)
    mcap_file = None
    if not _is_sqlite(storage) and (storage.is_dir() or storage.suffix == ".mcap"):
        try:
            mcap_file = _mcap_file(storage)
        except Exception:  # unreadable metadata: read_bag reports it properly
            mcap_file = None
    if mcap_file is None:
        yield from _record_chunks(read_bag(path, topics=topics, axis=axis), chunk_samples)
        return
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    try:
        with Reader(storage) as reader:
            conns = list(reader.connections)
            if not conns or reader.message_count == 0:
                raise DataFileError("the bag holds no messages", source=src,
                                    hint="record again and check that the sensor topics were published")
            available = _topic_table(conns)
            wanted = {r: (t, available[t]) for r, t in resolve_topics(available, topics, source=src).items() if t}
            expected = {r: sum(c.msgcount for c in conns if c.topic == t) for r, (t, _) in wanted.items()}
    except NifoError:
        raise
    except Exception as err:
        raise DataFileError(f"cannot read the bag ({str(err).rstrip('.') or type(err).__name__}); the file is "
                            "damaged or truncated", source=src, hint="re-copy the bag") from err
    for opt in ("tire_patch", "force"):
        if expected.get(opt, 1) == 0:
            del wanted[opt], expected[opt]
    for role in ("spindle", "body"):
        if expected[role] == 0:
            raise DataFileError("the topic holds no messages", source=src, channel=wanted[role][0],
                                hint="record again and check that the sensor published")
    roles = [r for r in ("spindle", "body", "tire_patch", "force") if r in wanted]
    meta = {"format": "rosbag2", "storage": "mcap", "path": src,
            "topics": {role: wanted[role][0] if role in wanted else None for role in _CHANNEL_OF_ROLE
                       if role != "force" or role in wanted},
            "axis": axis, "stamps": "header", "streamed": True}
    asm = _ChunkAssembler(roles, chunk_samples=chunk_samples, src=src, name=path.name,
                          labels={r: wanted[r][0] for r in roles}, meta=meta, total=min(expected.values()))
    use_log: bool | None = None
    it = _iter_mcap_indexed(mcap_file, wanted, axis=axis, typestore=typestore)
    while True:
        try:
            part = next(it)
        except StopIteration:
            break
        except _NoUsableIndex as err:   # no usable index: the whole-bag reader, if nothing was handed out yet
            if asm.index or asm.emitted:
                raise DataFileError(f"cannot read the bag chunk by chunk ({err})", source=src,
                                    hint="read it whole (nifo.io.loader.load_record)") from err
            yield from _record_chunks(read_bag(path, topics=topics, axis=axis), chunk_samples)
            return
        except NifoError:
            raise
        except Exception as err:
            raise DataFileError(f"cannot read the bag ({str(err).rstrip('.') or type(err).__name__}); the file is "
                                "damaged or truncated", source=src,
                                hint="re-copy the bag; 'mcap recover' can often repair a cut recording") from err
        if use_log is None and any(p[0].size for p in part.values()):
            use_log = not any(p[0].any() for p in part.values())
            if use_log:
                asm.meta["stamps"] = "receive_time"
        for role, (s, v, t) in part.items():
            asm.add(role, t if use_log else s, v)
        yield from asm.ready()
    yield from asm.ready(final=True)
