"""One entry point from data files to :class:`~nifo_core.record.Record` and back.

``load_record(path)`` picks the reader from the path: a directory, ``*.mcap``
or ``*.db3`` is a rosbag2 bag (:mod:`nifo.io.bag`), ``*.csv``/``*.tsv``/``*.txt``
a CSV table (:mod:`nifo.io.tabular`), ``*.mat`` a MATLAB file
(:mod:`nifo.io.matfile`); other names are recognised by their first bytes.
``save_record(path, record)`` writes by suffix, atomically.

The readers share :func:`assemble_record`: per-channel time stamps in, one
uniformly sampled :class:`Record` out, or a :class:`~nifo_core.errors.NifoError`
naming file, channel and fix (timestamps not increasing or gapped, channels at
different rates or on different clocks, NaN/inf samples).

For commands: :func:`add_input_arguments` adds ``--topics``, ``--columns``,
``--fs`` and ``--axis`` to a parser and :func:`input_options` turns the parsed
arguments into keyword arguments for :func:`load_record`.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from nifo_core.errors import ConfigError, DataFileError
from nifo_core.record import CHANNELS, Record

from .assemble import _check_declared_rate, assemble_record  # noqa: F401  (assemble_record: public here too)
from .inputs import regular_input

if TYPE_CHECKING:
    from .bag import BagTopics

__all__ = ["load_record", "save_record", "load_records", "iter_record_chunks", "detect_format", "assemble_record",
           "parse_columns", "add_input_arguments", "input_options", "COLUMN_KEYS"]

Format = Literal["bag", "csv", "mat"]
Axis = Literal["x", "y", "z"]

#: keys of a ``columns`` mapping (CSV column names / MAT keys), with accepted aliases
COLUMN_KEYS = ("time", *CHANNELS, "fs", "t0_ns")
_COLUMN_ALIASES = {"t": "time", "spindle": "spindle_accel", "body": "body_accel",
                   "tire_patch": "tire_patch_disp", "fs_hz": "fs"}

_BAG_SUFFIXES = {".mcap", ".db3"}
_CSV_SUFFIXES = {".csv", ".tsv", ".txt"}
_MAT_SUFFIXES = {".mat"}


# =============================================================================
# public API
# =============================================================================

def detect_format(path: str | os.PathLike) -> Format:
    """``"bag"``, ``"csv"`` or ``"mat"`` for an existing ``path``, else :class:`DataFileError`."""
    p = Path(path)
    regular_input(p)   # missing, FIFO, device: one line, never a reader blocked forever
    if p.is_dir():
        return "bag"
    suffix = p.suffix.lower()
    if suffix in _BAG_SUFFIXES:
        return "bag"
    if suffix in _CSV_SUFFIXES:
        return "csv"
    if suffix in _MAT_SUFFIXES:
        return "mat"
    try:
        with p.open("rb") as f:
            head = f.read(128)
    except OSError as err:
        raise DataFileError(f"cannot read the file ({err.strerror or err})", source=str(p),
                            hint="check the path and the file's permissions") from err
    if head.startswith(b"\x89MCAP"):
        return "bag"
    if head.startswith(b"MATLAB") or head[:8] == b"\x89HDF\r\n\x1a\n":
        return "mat"
    if head and all(32 <= c < 127 or c in b"\t\r\n" for c in head.lstrip(b"\xef\xbb\xbf")):
        return "csv"
    raise DataFileError("unknown data format", source=str(p),
                        hint="give a rosbag2 bag (directory or .mcap), a .csv or a .mat file")


def load_record(path: str | os.PathLike, *, topics: "BagTopics | None" = None,
                columns: Mapping[str, str] | None = None, fs_hz: float | None = None,
                axis: Axis = "z") -> Record:
    """Read one data file into a :class:`Record`.

    Parameters
    ----------
    path : path-like
        A rosbag2 bag (directory or ``.mcap``), a ``.csv`` or a ``.mat`` file.
    topics : BagTopics, optional
        Bag topics for the roles; found by name when not given (bags only).
    columns : mapping, optional
        CSV column / MAT key for each of ``time``, ``spindle_accel``,
        ``body_accel``, ``tire_patch_disp``, ``fs`` (CSV and MAT only). MAT
        keys may pick a row of a 2-D array: ``"Acceleration[1]"``.
    fs_hz : float, optional
        Sample rate [Hz] for files without time stamps; when the file has
        stamps it must agree with them.
    axis : {"x", "y", "z"}
        The vector component read from Imu / PointStamped messages (bags only).

    Raises
    ------
    NifoError
        A subclass with its own exit code: :class:`DataFileError`,
        :class:`MissingChannelError`, :class:`NonFiniteError`,
        :class:`TimestampError`, :class:`SampleRateError`,
        :class:`RecordTooShortError`, :class:`ConfigError`.
    """
    fmt = detect_format(path)
    if fmt == "bag":
        from .bag import read_bag
        rec = read_bag(path, topics=topics, axis=axis)
        if fs_hz is not None:
            _check_declared_rate(rec.fs_hz, fs_hz, source=str(path))
        return rec
    cols = _normalise_columns(columns)
    if fmt == "csv":
        from .tabular import read_csv
        return read_csv(path, columns=cols, fs_hz=fs_hz)
    from .matfile import read_mat
    return read_mat(path, columns=cols, fs_hz=fs_hz)


def iter_record_chunks(path: str | os.PathLike, *, chunk_samples: int, topics: "BagTopics | None" = None,
                       columns: Mapping[str, str] | None = None, fs_hz: float | None = None,
                       axis: Axis = "z") -> Iterator[Record]:
    """:func:`load_record`, handed out as consecutive chunks of ``chunk_samples`` samples.

    Bags (single indexed MCAP) are decoded chunk by chunk with the same numpy
    decoder (:func:`nifo.io.bag.iter_bag_chunks`), so memory does not grow
    with the recording's length; CSV and MAT files are read whole and sliced.
    Every chunk's ``meta["chunk"]`` holds ``index``, ``start`` (sample) and
    ``total_samples`` (expected for the whole file). Pushing the chunks in
    order into a streaming estimator gives what the whole record would.
    """
    fmt = detect_format(path)
    if fmt != "bag":
        from .bag import _record_chunks
        yield from _record_chunks(load_record(path, topics=topics, columns=columns, fs_hz=fs_hz, axis=axis),
                                  int(chunk_samples))
        return
    from .bag import iter_bag_chunks
    first = True
    for rec in iter_bag_chunks(path, chunk_samples=chunk_samples, topics=topics, axis=axis):
        if first and fs_hz is not None:
            _check_declared_rate(rec.fs_hz, fs_hz, source=str(path))
        first = False
        yield rec


def load_records(paths: Iterable[str | os.PathLike], **kw) -> list[Record]:
    """:func:`load_record` for each path (same options), in order."""
    return [load_record(p, **kw) for p in paths]


def save_record(path: str | os.PathLike, record: Record, *, topics: "BagTopics | None" = None,
                axis: Axis = "z") -> Path:
    """Write ``record`` in the format given by the suffix; returns the path written.

    ``.csv`` → CSV (``time,spindle_accel,body_accel[,tire_patch_disp]``, '%.17g');
    ``.mat`` → MAT v5; ``.mcap`` → one rosbag2 MCAP file; a directory name
    (no suffix, or an existing directory) → a rosbag2 bag directory.
    Atomic: on any failure nothing is left at ``path`` (an existing file is kept).
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in _CSV_SUFFIXES:
        from .tabular import write_csv
        return write_csv(p, record)
    if suffix in _MAT_SUFFIXES:
        from .matfile import write_mat
        return write_mat(p, record)
    if suffix == ".mcap" or not suffix or p.is_dir():
        from .bag import write_bag
        return write_bag(p, record, topics=topics, axis=axis)
    raise DataFileError(f"cannot tell the output format from the suffix {p.suffix!r}", source=str(p),
                        hint="name the output *.mcap, *.csv, *.mat, or a directory (rosbag2 bag)")


# =============================================================================
# options shared by the commands that read data
# =============================================================================

def _normalise_columns(columns: Mapping[str, str] | None) -> dict[str, str]:
    out: dict[str, str] = {}
    for key, name in (columns or {}).items():
        k = _COLUMN_ALIASES.get(key, key)
        if k not in COLUMN_KEYS:
            raise ConfigError(f"unknown column role {key!r}", channel="--columns",
                              hint=f"use roles {', '.join(COLUMN_KEYS)}")
        out[k] = str(name)
    return out


def parse_columns(text: str) -> dict[str, str]:
    """``"time=t,spindle_accel=a_wheel,body_accel=a_body"`` (the ``--columns`` option) to a dict.

    Names may contain brackets (``Acceleration[1]``) but not commas.
    """
    out: dict[str, str] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        key, sep, name = item.partition("=")
        if not sep or not key.strip() or not name.strip():
            raise ConfigError(f"cannot read --columns item {item!r}", channel="--columns",
                              hint="write --columns time=t,spindle_accel=a_wheel,body_accel=a_body")
        out[key.strip()] = name.strip()
    return _normalise_columns(out)


def add_input_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options every data-reading command shares: --topics, --columns, --fs, --axis."""
    g = parser.add_argument_group("input data")
    g.add_argument("--topics", metavar="ROLE=TOPIC,...",
                   help="bag topics, e.g. spindle=/a/imu,body=/b/imu[,tire_patch=/c] "
                        "(default: /nifo/... or found by name)")
    g.add_argument("--columns", metavar="ROLE=NAME,...",
                   help="CSV columns / MAT keys, e.g. time=t,spindle_accel=a_wheel,body_accel=a_body; "
                        "MAT rows as KEY[i], fs=KEY (default: time,spindle_accel,body_accel,tire_patch_disp)")
    g.add_argument("--fs", type=float, metavar="HZ", dest="fs_hz",
                   help="sample rate for files without a time column")
    g.add_argument("--axis", choices=("x", "y", "z"), default="z",
                   help="vector component read from Imu/PointStamped messages (default: z)")


def input_options(args: argparse.Namespace) -> dict:
    """Keyword arguments for :func:`load_record` from arguments added by :func:`add_input_arguments`."""
    from .bag import BagTopics

    topics = getattr(args, "topics", None)
    columns = getattr(args, "columns", None)
    return {"topics": BagTopics.parse(topics) if topics else None,
            "columns": parse_columns(columns) if columns else None,
            "fs_hz": getattr(args, "fs_hz", None),
            "axis": getattr(args, "axis", "z") or "z"}
