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

import numpy as np

from nifo_core.errors import (ConfigError, DataFileError, NifoError, NonFiniteError, SampleRateError,
                              TimestampError)
from nifo_core.record import CHANNELS, Record
from nifo_core.timebase import check_common_rate, sample_rate_from_stamps

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
    if not p.exists():
        raise DataFileError("no such file or directory", source=str(p), hint="check the path")
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


# =============================================================================
# shared by the readers: stamps + values per channel → Record
# =============================================================================

def _check_declared_rate(rate: float, fs_hz: float, *, source: str) -> None:
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise ConfigError(f"sample rate must be positive, got {fs_hz!r} Hz", source=source, channel="--fs",
                          hint="give the sample rate in Hz")
    if abs(rate - fs_hz) > 1e-3 * fs_hz:
        raise SampleRateError(f"the time stamps give {rate:.6g} Hz but the sample rate was given as "
                              f"{fs_hz:.6g} Hz", source=source, channel="--fs",
                              hint="drop --fs (the stamps set the rate) or correct it")


def _nominal_rate(stamp_ns: np.ndarray, rate: float, tol_ns: float) -> float:
    """``rate`` rounded to the fewest decimals (0..9) that still reproduces every stamp within ``tol_ns``.

    Stamps written as ``t0 + round(i·1e9/fs)`` give back ``fs`` exactly; jittery
    real stamps keep the least-squares rate.
    """
    rel = (stamp_ns - stamp_ns[0]).astype(np.float64)
    i = np.arange(stamp_ns.size, dtype=np.float64)
    for digits in range(10):
        r = round(rate, digits)
        if r > 0 and abs(r - rate) <= 1e-6 * rate and np.max(np.abs(rel - np.rint(i * (1e9 / r)))) <= tol_ns:
            return r
    return rate


def _align(stamps: dict[str, np.ndarray], fs: float, *, labels: Mapping[str, str],
           source: str) -> dict[str, slice]:
    """The slice of each channel that covers the samples common to all (stamps equal within fs/4)."""
    tol = 0.25e9 / fs
    start = max(int(s[0]) for s in stamps.values())
    stop = min(int(s[-1]) for s in stamps.values())
    ref_name = next(iter(stamps))
    if stop < start - tol:
        spans = ", ".join(f"{labels[k]} {s[0] / 1e9:.3f}–{s[-1] / 1e9:.3f} s" for k, s in stamps.items())
        raise TimestampError(f"channels do not overlap in time ({spans})", source=source,
                             channel=", ".join(labels[k] for k in stamps),
                             hint="give channels recorded at the same time")
    cuts = {k: slice(int(np.searchsorted(s, start - tol, "left")), int(np.searchsorted(s, stop + tol, "right")))
            for k, s in stamps.items()}
    ref = stamps[ref_name][cuts[ref_name]]
    for k, s in stamps.items():
        part = s[cuts[k]]
        m = min(part.size, ref.size)
        if m == 0:
            raise TimestampError("the channels share no sample instants", source=source,
                                 channel=f"{labels[ref_name]}, {labels[k]}",
                                 hint="give channels recorded at the same time on one clock")
        dev = np.abs(part[:m] - ref[:m]) > tol
        if part.size != ref.size or dev.any():
            i = int(np.argmax(dev)) if dev.any() else 0
            period = 1e9 / fs
            lag = (float(part[i] - ref[i]) + period / 2) % period - period / 2  # nearest-sample offset
            raise TimestampError(
                f"the channels are not sampled at the same instants: at t={(ref[i] - ref[0]) / 1e9:.3f} s "
                f"{labels[k]} is {lag / 1e6:+.3f} ms off {labels[ref_name]} (sample period {period / 1e6:.3f} ms)",
                source=source, channel=f"{labels[ref_name]}, {labels[k]}",
                hint="resample the channels onto one clock so that each sample has one stamp for all")
    return cuts


def assemble_record(channels: Mapping[str, tuple[np.ndarray | None, np.ndarray]], *,
                    labels: Mapping[str, str], path: str | os.PathLike, meta: Mapping,
                    fs_hz: float | None = None, t0_ns: int = 0, stamp_tol_ns: float = 1.0) -> Record:
    """Build a :class:`Record` from ``{channel: (stamp_ns or None, values)}``.

    With stamps: each channel's rate comes from its stamps
    (:func:`~nifo_core.timebase.sample_rate_from_stamps`: increasing, no gaps),
    the rates must agree (:func:`~nifo_core.timebase.check_common_rate`), and
    the channels are trimmed to their common samples (stamps equal within a
    quarter period, else :class:`TimestampError`); ``meta["trimmed"]`` says how
    many samples were cut. The rate is snapped to its short decimal form when
    that reproduces every stamp within ``stamp_tol_ns``. Without stamps
    ``fs_hz`` is required. ``labels`` name channels in messages (topic, column or key).
    """
    src = str(path)
    meta = dict(meta)
    names = [c for c in CHANNELS if c in channels]
    values = {c: np.asarray(channels[c][1], dtype=np.float64).ravel() for c in names}
    stamps = {c: channels[c][0] for c in names}
    if all(s is None for s in stamps.values()):
        if fs_hz is None:
            raise ConfigError("the file has no time stamps and no sample rate was given", source=src,
                              channel="fs", hint="pass --fs HZ (fs_hz=...) or add a time column/key")
        _check_declared_rate(fs_hz, fs_hz, source=src)
        fs = float(fs_hz)
        lengths = {labels[c]: v.size for c, v in values.items()}
        if len(set(lengths.values())) != 1:
            raise TimestampError(f"channels have different lengths {lengths} and no time stamps to align them",
                                 source=src, channel=", ".join(lengths),
                                 hint="trim the channels to the same samples")
        t0 = int(t0_ns)
    else:
        st = {c: np.asarray(s, dtype=np.int64).ravel() for c, s in stamps.items()}
        rates = {labels[c]: sample_rate_from_stamps(s, source=src, channel=labels[c]) for c, s in st.items()}
        fs = check_common_rate(rates, source=src)
        cuts = _align(st, fs, labels=labels, source=src)
        trimmed = {labels[c]: [cuts[c].start, st[c].size - cuts[c].stop] for c in names
                   if cuts[c].start or cuts[c].stop != st[c].size}
        if trimmed:
            meta["trimmed"] = trimmed  # samples cut at [start, end] to cover the same instants
        values = {c: v[cuts[c]] for c, v in values.items()}
        common = st[names[0]][cuts[names[0]]]
        if common.size < 2:
            fs = float(np.mean(list(rates.values())))
        else:
            fs = _nominal_rate(common, float((common.size - 1) * 1e9 / (common[-1] - common[0])), stamp_tol_ns)
        if fs_hz is not None:
            _check_declared_rate(fs, fs_hz, source=src)
        t0 = int(common[0]) if common.size else 0
    for c, v in values.items():
        bad = ~np.isfinite(v)
        if bad.any():
            i = int(np.argmax(bad))
            raise NonFiniteError(f"{int(bad.sum())} of {v.size} samples are NaN or infinite "
                                 f"(first at t={i / fs:.3f} s, sample {i})", source=src, channel=labels[c],
                                 hint="cut the record before/after the bad stretch or repair the sensor data")
    try:
        return Record(fs, values["spindle_accel"], values["body_accel"], values.get("tire_patch_disp"),
                      t0_ns=t0, source=Path(path).name, meta=meta)
    except NifoError as err:
        raise err.with_context(source=src) from None
