"""Reading rosbag2 bags (any storage rosbags reads) into a :class:`~nifo_core.signal.record.Record`: :func:`read_bag`."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from nifo_core.errors import ConfigError, DataFileError, NifoError
from nifo_core.signal.record import Record

from ..assemble import assemble_record
from ._topics import BagTopics, _topic_table, resolve_topics
from .cdr import AXES as _AXES, Axis
from ..inputs import regular_input
from ._mcap import (_decode, _Decoded, _iter_mcap_indexed, _NoUsableIndex, check_metadata_topics,
                          check_structure, chunk_crc_status, crc_note, receive_stamps)

if TYPE_CHECKING:
    from rosbags.interfaces import Connection

__all__ = ["read_bag"]

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
                                  for k, dt in enumerate((np.int64, np.float64, np.uint64)))
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
        out[role] = (stamps, values, np.asarray(logs[role], np.uint64))
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
    regular_input(path)
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
    meta.update(integrity_meta(storage))
    return assemble_record(
        {_CHANNEL_OF_ROLE[r]: (receive_stamps(ch.log_ns, source=src, channel=ch.topic) if use_log_time else ch.stamp_ns,
                               ch.values) for r, ch in chans.items()},
        labels={_CHANNEL_OF_ROLE[r]: ch.topic for r, ch in chans.items()}, path=path, meta=meta, stamp_tol_ns=1.0)


def integrity_meta(storage: Path) -> dict:
    """``{"chunk_crc": {...}, "integrity_note": ...}`` of a bag's MCAP file (say once when chunks have no CRC)."""
    try:
        mcap = _mcap_file(storage)
    except Exception:  # noqa: BLE001 - unreadable metadata was reported by the reader already
        mcap = None
    status = chunk_crc_status(mcap) if mcap is not None else None
    if status is None:
        return {}
    note = crc_note(status)
    return {"chunk_crc": status, **({"integrity_note": note} if note else {})}


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
            for mcap in ([storage] if storage.suffix == ".mcap" else sorted(storage.glob("*.mcap"))
                         if storage.is_dir() else []):
                check_structure(mcap)   # before any library trusts its lengths and offsets
            with Reader(storage) as reader:  # validates metadata and gives the topics
                conns = list(reader.connections)
                if not conns or reader.message_count == 0:
                    raise DataFileError("the bag holds no messages", source=src,
                                        hint="record again and check that the sensor topics were published")
                available = _topic_table(conns)
                if mcap_file is not None and storage.is_dir():
                    check_metadata_topics(available, mcap_file, source=src)
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
