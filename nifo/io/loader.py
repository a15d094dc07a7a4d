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
``--fs``, ``--axis``, ``--skip-seconds``, ``--skip-periods`` and
``--period-samples`` to a parser and :func:`input_options` turns the parsed
arguments into keyword arguments for :func:`load_record`.

Channel roles (``--columns ROLE=NAME``, CSV and MAT): ``spindle_accel``,
``body_accel`` [m/s²], ``tire_patch_disp`` [m], ``force`` [N] (on the body) and
``body_disp`` (a displacement recorded instead of ``body_accel``: it is
differentiated twice, exactly for periodic data — see
:func:`nifo_core.record.acceleration_from_displacement`). Two forms extend a
NAME: ``NAME@FILE`` reads that channel from another file (CSV column or MAT
key; FILE relative to the data file's directory, or absolute), e.g. the
Silverbox's input and output::

    --columns force=um@SNJP_um_full_FNSI_50.mat,body_disp=ym,spindle_accel=fixed,fs=fs

and ``spindle_accel=fixed`` declares a spindle that does not move (a single
mass driven by the measured force). So that one ``--columns`` serves many
files, FILE may name the other file after the data file: ``{name}`` and
``{stem}`` are the data file's name and stem, ``{name:OLD=NEW}`` its name with
OLD replaced by NEW — for every Silverbox level at once::

    --columns body_disp=ym,force=um@{name:_ym_=_um_},spindle_accel=fixed
 The channel from the other file must have
the same number of samples (and rate, when that file gives one).

Transient start: ``skip_seconds`` drops that much from the start,
``skip_periods`` drops whole periods of ``period_samples`` (multisine data:
the periods before the steady state). Both are applied after channels are
combined and before a displacement is differentiated.
"""

from __future__ import annotations

import argparse
import os
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from nifo_core.errors import (ConfigError, DataFileError, NifoError, NonFiniteError, RecordTooShortError,
                              SampleRateError, TimestampError)
from nifo_core.record import Record, acceleration_from_displacement
from nifo_core.timebase import check_common_rate, sample_rate_from_stamps

if TYPE_CHECKING:
    from .bag import BagTopics

__all__ = ["load_record", "save_record", "load_records", "iter_record_chunks", "detect_format", "assemble_record",
           "parse_columns", "add_input_arguments", "input_options", "COLUMN_KEYS", "READ_ROLES", "Assembly", "Skip"]

Format = Literal["bag", "csv", "mat"]
Axis = Literal["x", "y", "z"]

#: channel roles a CSV/MAT reader looks for (``body_disp`` becomes ``body_accel``)
READ_ROLES = ("spindle_accel", "body_accel", "body_disp", "tire_patch_disp", "force")
#: keys of a ``columns`` mapping (CSV column names / MAT keys), with accepted aliases
COLUMN_KEYS = ("time", *READ_ROLES, "fs", "t0_ns")
_COLUMN_ALIASES = {"t": "time", "spindle": "spindle_accel", "body": "body_accel",
                   "tire_patch": "tire_patch_disp", "fs_hz": "fs"}
#: ``spindle_accel=fixed``: the spindle does not move
FIXED = "fixed"


@dataclass(frozen=True)
class Skip:
    """Samples to drop from the start of a record (a transient): seconds, or whole periods."""

    seconds: float | None = None
    periods: int | None = None
    period_samples: int | None = None

    def samples(self, fs_hz: float, n: int, *, source: str) -> int:
        """Samples to drop from a record of ``n`` samples at ``fs_hz``; a clear error if nothing would be left."""
        k = 0
        if self.seconds is not None:
            k += int(round(self.seconds * fs_hz))
        if self.periods is not None:
            k += int(self.periods) * int(self.period_samples)
        if k >= n:
            raise RecordTooShortError(f"skipping {k} samples ({k / fs_hz:.3g} s) leaves nothing of {n}",
                                      source=source, channel="--skip-seconds/--skip-periods",
                                      hint="skip less than the record's length")
        return k

    @property
    def active(self) -> bool:
        return bool(self.seconds) or bool(self.periods)


@dataclass(frozen=True)
class Assembly:
    """What :func:`assemble_record` does besides stamps → Record (set by :func:`load_record`).

    extra : {role: (values, label, rate in Hz or None)}
        Channels read from other files (``NAME@FILE``), appended as they are.
    spindle_fixed : bool
        ``spindle_accel=fixed``: build the record with a fixed spindle.
    skip : Skip
        Transient start to drop.
    required : frozenset
        Roles the reader must find in the file.
    collect : bool
        Return ``{role: values}`` and the rate instead of a Record (reading one channel of another file).
    """

    extra: Mapping[str, tuple[np.ndarray, str, float | None]] = field(default_factory=dict)
    spindle_fixed: bool = False
    skip: Skip = Skip()
    required: frozenset = frozenset({"spindle_accel", "body_accel"})
    collect: bool = False

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
                axis: Axis = "z", skip_seconds: float | None = None, skip_periods: int | None = None,
                period_samples: int | None = None) -> Record:
    """Read one data file into a :class:`Record`.

    Parameters
    ----------
    path : path-like
        A rosbag2 bag (directory or ``.mcap``), a ``.csv`` or a ``.mat`` file.
    topics : BagTopics, optional
        Bag topics for the roles; found by name when not given (bags only).
    columns : mapping, optional
        CSV column / MAT key for each of ``time``, ``spindle_accel``,
        ``body_accel``, ``body_disp``, ``tire_patch_disp``, ``force``, ``fs``
        (CSV and MAT only). MAT keys may pick a row of a 2-D array:
        ``"Acceleration[1]"``; ``NAME@FILE`` reads from another file and
        ``spindle_accel="fixed"`` declares a fixed spindle (module docstring).
    fs_hz : float, optional
        Sample rate [Hz] for files without time stamps; when the file has
        stamps it must agree with them.
    axis : {"x", "y", "z"}
        The vector component read from Imu / PointStamped messages (bags only).
    skip_seconds : float, optional
        Drop this much from the start (a transient) [s].
    skip_periods, period_samples : int, optional
        Drop ``skip_periods`` whole periods of ``period_samples`` samples from
        the start (periodic data); ``period_samples`` alone makes a
        displacement channel's derivative exact when the record is whole periods.

    Raises
    ------
    NifoError
        A subclass with its own exit code: :class:`DataFileError`,
        :class:`MissingChannelError`, :class:`NonFiniteError`,
        :class:`TimestampError`, :class:`SampleRateError`,
        :class:`RecordTooShortError`, :class:`ConfigError`.
    """
    fmt = detect_format(path)
    skip = _skip(skip_seconds, skip_periods, period_samples, source=str(path))
    if fmt == "bag":
        from .bag import read_bag
        rec = read_bag(path, topics=topics, axis=axis)
        if fs_hz is not None:
            _check_declared_rate(rec.fs_hz, fs_hz, source=str(path))
        if skip.active:
            k = skip.samples(rec.fs_hz, rec.n, source=str(path))
            rec = rec.slice(k, rec.n)
            rec = _with_meta(rec, skipped_samples=k)
        return rec
    cols, asm = _plan(path, _normalise_columns(columns), fs_hz=fs_hz, skip=skip)
    if fs_hz is None:   # a file without a rate takes the rate of a channel combined from another file
        fs_hz = next((f for _, _, f in asm.extra.values() if f is not None), None)
    return _read_tabular(fmt, path, cols, fs_hz, asm)


def _read_tabular(fmt: str, path, cols: Mapping[str, str], fs_hz: float | None, asm: Assembly):
    if fmt == "csv":
        from .tabular import read_csv
        return read_csv(path, columns=cols, fs_hz=fs_hz, assembly=asm)
    if fmt == "mat":
        from .matfile import read_mat
        return read_mat(path, columns=cols, fs_hz=fs_hz, assembly=asm)
    raise DataFileError("a channel from another file must come from a CSV or MAT file", source=str(path),
                        hint="give NAME@FILE with a .csv or .mat file")


def _with_meta(rec: Record, **items) -> Record:
    from dataclasses import replace
    return replace(rec, meta={**dict(rec.meta), **items})


def _skip(seconds, periods, period_samples, *, source: str) -> Skip:
    if seconds is not None and not (np.isfinite(seconds) and seconds >= 0):
        raise ConfigError(f"--skip-seconds {seconds!r} must be a time >= 0 [s]", source=source,
                          channel="--skip-seconds", hint="e.g. --skip-seconds 2")
    if period_samples is not None and int(period_samples) < 1:
        raise ConfigError(f"--period-samples {period_samples!r} must be a positive number of samples",
                          source=source, channel="--period-samples", hint="e.g. --period-samples 8192")
    if periods is not None:
        if int(periods) < 0:
            raise ConfigError(f"--skip-periods {periods!r} must be >= 0", source=source, channel="--skip-periods",
                              hint="e.g. --skip-periods 1")
        if period_samples is None:
            raise ConfigError("--skip-periods needs the period's length", source=source, channel="--skip-periods",
                              hint="add --period-samples N (samples per period, e.g. 8192)")
    return Skip(seconds, None if periods is None else int(periods),
                None if period_samples is None else int(period_samples))


_TEMPLATE = re.compile(r"\{(name|stem)(?::([^=}]*)=([^}]*))?\}")


def _external_path(base: str | os.PathLike, name: str) -> Path:
    b = Path(base)

    def sub(m: re.Match) -> str:
        out = b.name if m[1] == "name" else b.stem
        if m[2] is not None:
            if m[2] not in out:
                raise ConfigError(f"{{{m[1]}:{m[2]}={m[3]}}}: {m[2]!r} does not occur in {out!r}", source=str(base),
                                  channel="--columns", hint="give the part of the data file's name to replace")
            out = out.replace(m[2], m[3])
        return out
    name = _TEMPLATE.sub(sub, name)
    p = Path(name).expanduser()
    if not p.is_absolute():
        near = Path(base).parent / p
        p = near if near.exists() or not p.exists() else p
    if not p.exists():
        raise DataFileError(f"no such file {name!r} (looked beside {Path(base).name} and in the working directory)",
                            source=str(base), channel="--columns",
                            hint="give NAME@FILE with FILE relative to the data file's directory, or absolute")
    return p


def _plan(path, cols: dict[str, str], *, fs_hz: float | None, skip: Skip) -> tuple[dict[str, str], Assembly]:
    """Split ``columns`` into what the reader reads from ``path`` and what the loader adds (module docstring)."""
    local: dict[str, str] = {}
    extra: dict[str, tuple[np.ndarray, str, float | None]] = {}
    spindle_fixed = False
    for role, name in cols.items():
        if role == "spindle_accel" and name.strip().lower() == FIXED:
            spindle_fixed = True
        elif role in READ_ROLES and "@" in name:
            key, _, other = name.rpartition("@")
            if not key.strip() or not other.strip():
                raise ConfigError(f"cannot read --columns {role}={name!r}", source=str(path), channel="--columns",
                                  hint="write ROLE=NAME@FILE, e.g. force=um@SNJP_um_full_FNSI_50.mat")
            extra[role] = _read_external(path, _external_path(path, other.strip()), key.strip(), role, fs_hz)
        else:
            local[role] = name
    if "body_disp" in cols and "body_accel" in cols:
        raise ConfigError("both body_accel and body_disp are given", source=str(path), channel="--columns",
                          hint="give the body's acceleration or its displacement, not both")
    if spindle_fixed and "force" not in cols:
        raise ConfigError("a fixed spindle needs a measured force", source=str(path), channel="--columns",
                          hint="add force=NAME (or NAME@FILE) to --columns, or name the spindle column")
    required = {"spindle_accel", "body_accel"} - set(extra)
    if spindle_fixed:
        required.discard("spindle_accel")
    if "body_disp" in cols:
        required.discard("body_accel")
        if "body_disp" not in extra:
            required.add("body_disp")
    return local, Assembly(extra=extra, spindle_fixed=spindle_fixed, skip=skip, required=frozenset(required))


def _read_external(base, path: Path, key: str, role: str,
                   fs_hz: float | None) -> tuple[np.ndarray, str, float | None]:
    """One channel (CSV column or MAT key ``key``) of another file, for ``role``."""
    fmt = detect_format(path)
    if fmt == "bag":
        raise DataFileError("a channel from another file must come from a CSV or MAT file", source=str(base),
                            channel=role, hint=f"convert {path.name} to CSV or MAT, or use a bag with all topics")
    cols = {role: key}
    got = _read_tabular(fmt, path, cols, fs_hz, Assembly(required=frozenset({role}), collect=True))
    values, fs_file = got
    return values, f"{key}@{path.name}", fs_file


def iter_record_chunks(path: str | os.PathLike, *, chunk_samples: int, topics: "BagTopics | None" = None,
                       columns: Mapping[str, str] | None = None, fs_hz: float | None = None,
                       axis: Axis = "z", skip_seconds: float | None = None, skip_periods: int | None = None,
                       period_samples: int | None = None) -> Iterator[Record]:
    """:func:`load_record`, handed out as consecutive chunks of ``chunk_samples`` samples.

    Bags (single indexed MCAP) are decoded chunk by chunk with the same numpy
    decoder (:func:`nifo.io.bag.iter_bag_chunks`), so memory does not grow
    with the recording's length; CSV and MAT files are read whole and sliced.
    Every chunk's ``meta["chunk"]`` holds ``index``, ``start`` (sample) and
    ``total_samples`` (expected for the whole file). Pushing the chunks in
    order into a streaming estimator gives what the whole record would.
    A skipped start (``skip_*``, see :func:`load_record`) is dropped before the first chunk.
    """
    fmt = detect_format(path)
    if fmt != "bag":
        from .bag import _record_chunks
        yield from _record_chunks(load_record(path, topics=topics, columns=columns, fs_hz=fs_hz, axis=axis,
                                              skip_seconds=skip_seconds, skip_periods=skip_periods,
                                              period_samples=period_samples), int(chunk_samples))
        return
    from dataclasses import replace

    from .bag import iter_bag_chunks
    skip = _skip(skip_seconds, skip_periods, period_samples, source=str(path))
    first, left = True, 0
    for rec in iter_bag_chunks(path, chunk_samples=chunk_samples, topics=topics, axis=axis):
        if first:
            if fs_hz is not None:
                _check_declared_rate(rec.fs_hz, fs_hz, source=str(path))
            total = int(rec.meta.get("chunk", {}).get("total_samples", rec.n))
            left = skip.samples(rec.fs_hz, total, source=str(path)) if skip.active else 0
        first = False
        if left:
            if left >= rec.n:
                left -= rec.n
                continue
            rec, left = rec.slice(left, rec.n), 0
        if skip.active and "chunk" in rec.meta:
            k = skip.samples(rec.fs_hz, int(rec.meta["chunk"]["total_samples"]), source=str(path))
            ch = dict(rec.meta["chunk"], total_samples=int(rec.meta["chunk"]["total_samples"]) - k)
            rec = replace(rec, meta={**dict(rec.meta), "chunk": ch, "skipped_samples": k})
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
    """Add the options every data-reading command shares: --topics, --columns, --fs, --axis, --skip-*."""
    g = parser.add_argument_group("input data")
    g.add_argument("--topics", metavar="ROLE=TOPIC,...",
                   help="bag topics, e.g. spindle=/a/imu,body=/b/imu[,tire_patch=/c] "
                        "(default: /nifo/... or found by name)")
    g.add_argument("--columns", metavar="ROLE=NAME,...",
                   help="CSV columns / MAT keys, e.g. time=t,spindle_accel=a_wheel,body_accel=a_body; "
                        "MAT rows as KEY[i], fs=KEY; also force=NAME [N], body_disp=NAME (displacement instead "
                        "of body_accel), NAME@FILE (from another file), spindle_accel=fixed "
                        "(default: time,spindle_accel,body_accel,tire_patch_disp,force)")
    g.add_argument("--fs", type=float, metavar="HZ", dest="fs_hz",
                   help="sample rate for files without a time column")
    g.add_argument("--axis", choices=("x", "y", "z"), default="z",
                   help="vector component read from Imu/PointStamped messages (default: z)")
    g.add_argument("--skip-seconds", type=float, metavar="S", dest="skip_seconds",
                   help="drop the first S seconds of every record (a transient start)")
    g.add_argument("--skip-periods", type=int, metavar="P", dest="skip_periods",
                   help="drop the first P periods of periodic (multisine) data; needs --period-samples")
    g.add_argument("--period-samples", type=int, metavar="N", dest="period_samples",
                   help="samples per period of periodic data (e.g. 8192); also makes body_disp's derivative exact")


def input_options(args: argparse.Namespace) -> dict:
    """Keyword arguments for :func:`load_record` from arguments added by :func:`add_input_arguments`."""
    from .bag import BagTopics

    topics = getattr(args, "topics", None)
    columns = getattr(args, "columns", None)
    return {"topics": BagTopics.parse(topics) if topics else None,
            "columns": parse_columns(columns) if columns else None,
            "fs_hz": getattr(args, "fs_hz", None),
            "axis": getattr(args, "axis", "z") or "z",
            "skip_seconds": getattr(args, "skip_seconds", None),
            "skip_periods": getattr(args, "skip_periods", None),
            "period_samples": getattr(args, "period_samples", None)}


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
                    fs_hz: float | None = None, t0_ns: int = 0, stamp_tol_ns: float = 1.0,
                    assembly: Assembly | None = None) -> Record:
    """Build a :class:`Record` from ``{channel: (stamp_ns or None, values)}``.

    With stamps: each channel's rate comes from its stamps
    (:func:`~nifo_core.timebase.sample_rate_from_stamps`: increasing, no gaps),
    the rates must agree (:func:`~nifo_core.timebase.check_common_rate`), and
    the channels are trimmed to their common samples (stamps equal within a
    quarter period, else :class:`TimestampError`); ``meta["trimmed"]`` says how
    many samples were cut. The rate is snapped to its short decimal form when
    that reproduces every stamp within ``stamp_tol_ns``. Without stamps
    ``fs_hz`` is required. ``labels`` name channels in messages (topic, column or key).
    ``assembly`` (from :func:`load_record`) adds channels of other files, a
    fixed spindle, a skipped start and a displacement's derivative, in that order.
    """
    src = str(path)
    meta = dict(meta)
    asm = assembly or Assembly()
    names = [c for c in READ_ROLES if c in channels]
    values = {c: np.asarray(channels[c][1], dtype=np.float64).ravel() for c in names}
    stamps = {c: channels[c][0] for c in names}
    if all(s is None for s in stamps.values()):
        if fs_hz is None and asm.collect:
            return values[names[0]], None
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
    if asm.collect:
        return values[names[0]], fs
    labels = dict(labels)
    for role, (v, label, f_other) in asm.extra.items():            # NAME@FILE channels
        n_here = next(iter(values.values())).size if values else v.size
        if v.size != n_here:
            raise TimestampError(f"{label} has {v.size} samples but the record has {n_here}", source=src,
                                 channel=role, hint="combine channels recorded together (same length and rate)")
        if f_other is not None and abs(f_other - fs) > 1e-6 * fs:
            raise SampleRateError(f"{label} is sampled at {f_other:.10g} Hz, the record at {fs:.10g} Hz",
                                  source=src, channel=role, hint="combine channels sampled at one rate")
        values[role], labels[role] = np.asarray(v, np.float64), label
        meta.setdefault("columns", {})[role] = label
    if asm.skip.active:                                             # transient start
        k = asm.skip.samples(fs, next(iter(values.values())).size, source=src)
        values = {c: v[k:] for c, v in values.items()}
        t0 += int(round(k * 1e9 / fs))
        meta["skipped_samples"] = k
    if "body_disp" in values:                                       # displacement -> acceleration
        values["body_accel"], how = acceleration_from_displacement(values.pop("body_disp"), fs,
                                                                   period_samples=asm.skip.period_samples)
        meta["body_from_displacement"] = how
    if asm.spindle_fixed:
        meta["spindle"] = "fixed"
    try:
        return Record(fs, None if asm.spindle_fixed else values["spindle_accel"], values["body_accel"],
                      values.get("tire_patch_disp"), t0_ns=t0, source=Path(path).name, meta=meta,
                      force=values.get("force"))
    except NifoError as err:
        raise err.with_context(source=src) from None
