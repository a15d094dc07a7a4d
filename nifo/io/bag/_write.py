"""Writing rosbag2 MCAP bags (layout in :mod:`nifo.io.bag`): :func:`write_bag`, :func:`write_channels`."""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from nifo_core.errors import ConfigError, DataFileError, NifoError
from nifo_core.signal.record import Record

from ..atomic import staged_file
from ._topics import _DEFAULT_TOPICS, BagTopics
from .cdr import AXES as _AXES, IMU, LAYOUT as _LAYOUT, POINT_STAMPED, WRENCH_STAMPED, Axis
from .cdr import payloads as _payloads  # the message layout lives in nifo.io.bag.cdr
from ._mcap import write_chunk_crcs

__all__ = ["TopicData", "write_bag", "write_channels", "BAG_VERSION"]

#: rosbag2 metadata version written: 8 is read by Humble and Jazzy (9 is not read by Humble)
BAG_VERSION = 8


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
    log_ns: np.ndarray | None = None  #: bag receive time [ns, int64 or uint64]; default: the header stamps


def _topic_data(record: Record, topics: BagTopics) -> list[TopicData]:
    stamps = record.t0_ns + np.rint(np.arange(record.n) * (1e9 / record.fs_hz)).astype(np.int64)
    if record.spindle_accel is None:
        raise ConfigError("the record has a fixed spindle (no spindle acceleration); a bag needs both Imu topics",
                          channel="spindle", hint="write it as CSV or MAT instead")
    out = [TopicData(topics.spindle, IMU, "spindle", stamps, record.spindle_accel),
           TopicData(topics.body, IMU, "body", stamps, record.body_accel)]
    if record.tire_patch_disp is not None:
        if not topics.tire_patch:
            raise ConfigError("the record has a tire-patch displacement but no topic was given for it",
                              channel="tire_patch",
                              hint="name a tire-patch topic (--topics ...,tire_patch=/topic) or drop the tire patch")
        out.append(TopicData(topics.tire_patch, POINT_STAMPED, "tire_patch", stamps, record.tire_patch_disp))
    if record.force is not None:
        out.append(TopicData(topics.force or "/nifo/force", WRENCH_STAMPED, "force", stamps, record.force))
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
            log_ns = stamps if td.log_ns is None else np.asarray(td.log_ns)   # int64, or uint64 as MCAP holds
            streams.append(_stream(log_ns, k, conn, raw, size))
        write = writer.write
        for t, _, i, conn, raw, size in heapq.merge(*streams, key=lambda m: (m[0], m[1], m[2])):
            write(conn, t, raw[i * size:(i + 1) * size])
    mcap = bagdir / f"{bagdir.name}.mcap"
    write_chunk_crcs(mcap)
    _honest_distro(bagdir / "metadata.yaml", mcap)


#: the ROS distro whose message definitions (and type hashes) the bag embeds: rosbags' Jazzy typestore
ROS_DISTRO = "jazzy"


def _honest_distro(metadata: Path, mcap: Path) -> None:
    """``ros_distro: rosbags`` (what rosbags writes) → the distro of the embedded message definitions.

    In metadata.yaml it is rewritten; in the copy inside the MCAP file's
    ``rosbag2`` metadata record it is replaced by the same number of bytes
    (trailing blanks, which YAML drops) so no record offset moves.
    """
    old, new = b"ros_distro: rosbags", f"ros_distro: {ROS_DISTRO}".encode()
    new = new.ljust(len(old))
    metadata.write_bytes(metadata.read_bytes().replace(old, new.rstrip()))
    blob = mcap.read_bytes()
    at = blob.rfind(old)
    if at >= 0:
        with mcap.open("r+b") as f:
            f.seek(at)
            f.write(new)


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
        with staged_file(final, kind="file" if final.suffix == ".mcap" else "bag") as tmp:
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
              axis: Axis = "z", start_ns: int | None = None) -> Path:
    """Write ``record`` as a rosbag2 MCAP bag; atomic (nothing is left behind on failure).

    ``path`` ending in ``.mcap`` gives a single MCAP file (``ros2 bag info/play``
    read those directly); any other path gives a bag directory with
    ``metadata.yaml`` and ``<name>.mcap``. An existing bag at ``path`` is replaced.
    Returns ``path``.

    ``start_ns`` is the stamp of the first sample [ns since the epoch]; by
    default the record's ``t0_ns``, or the current time when the record has
    none (``t0_ns == 0``, e.g. simulated data), so that a bag never claims to
    start in 1970.
    """
    if start_ns is None:
        start_ns = record.t0_ns or time.time_ns()
    if start_ns != record.t0_ns:
        record = replace(record, t0_ns=int(start_ns))
    try:
        data = _topic_data(record, topics or _DEFAULT_TOPICS)
    except NifoError as err:
        raise err.with_context(source=str(path)) from None
    return write_channels(path, data, axis=axis)
