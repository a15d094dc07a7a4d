"""One entry point from data files to :class:`~nifo_core.signal.record.Record` and back.

``load_record(path)`` picks the reader from the path through one table, :data:`READERS` (suffix → format, as
rosbags' ``STORAGE_PLUGINS``): a directory, ``*.mcap`` or ``*.db3`` is a rosbag2 bag (:mod:`nifo.io.bag`),
``*.csv``/``*.tsv``/``*.txt`` a CSV table (:mod:`nifo.io.tabular`), ``*.mat`` a MATLAB file
(:mod:`nifo.io.matfile`); other names are recognised by their first bytes (each format's ``magic``).
``save_record(path, record)`` writes by suffix, atomically. A new format is a reader module and a row of
:data:`READERS`.

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
:func:`nifo_core.signal.record.acceleration_from_displacement`). Two forms extend a
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
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np

from nifo_core.errors import ConfigError, DataFileError
from nifo_core.setting_rules import check_timing
from nifo_core.signal.record import Record

from . import bag   # a lazy front door: rosbags and mcap are imported when a bag is first read or written
from .assemble import FIXED, READ_ROLES, Assembly, Skip, check_declared_rate, assemble_record  # noqa: F401
from .atomic import check_output
from .inputs import regular_input
from .matfile import read_mat, write_mat
from .memo import known, remembered
from .tabular import read_csv, write_csv

__all__ = ["load_record", "seed_whole_bag", "save_record", "check_record_output", "load_records", "iter_record_chunks",
           "detect_format", "assemble_record", "parse_columns", "add_input_arguments", "input_options", "COLUMN_KEYS",
           "READ_ROLES", "Assembly", "Skip", "FileFormat", "READERS"]

Axis = Literal["x", "y", "z"]

#: keys of a ``columns`` mapping (CSV column names / MAT keys), with accepted aliases
COLUMN_KEYS = ("time", *READ_ROLES, "fs", "t0_ns")
_COLUMN_ALIASES = {"t": "time", "spindle": "spindle_accel", "body": "body_accel",
                   "tire_patch": "tire_patch_disp", "fs_hz": "fs"}


# =============================================================================
# the reader table
# =============================================================================

@dataclass(frozen=True)
class FileFormat:
    """One data format: how nifo reads it, writes it and tells it by its first bytes (a row of :data:`READERS`).

    ``tables``: read through ``--columns`` (CSV columns, MAT keys: a channel may come from another such file);
    otherwise a bag, read through ``--topics``/``--axis``. ``read_table(path, columns=, fs_hz=, assembly=)`` reads a
    table format; ``write(path, record, topics=, axis=)`` writes one (None: nifo reads the format, does not write
    it); ``output``: what :func:`nifo.io.atomic.check_output` guards, a file or a bag directory.
    """

    name: Literal["bag", "csv", "mat"]
    tables: bool
    magic: tuple[bytes, ...] = ()
    read_table: Callable[..., Record] | None = None
    write: Callable[..., Path] | None = None
    output: Literal["file", "bag"] = "file"


def _write_bag(path, record, *, topics=None, axis="z") -> Path:
    return bag.write_bag(path, record, topics=topics, axis=axis)


BAG = FileFormat("bag", tables=False, magic=(b"\x89MCAP",), write=_write_bag, output="file")
SQLITE_BAG = FileFormat("bag", tables=False)
CSV = FileFormat("csv", tables=True, read_table=read_csv, write=lambda path, record, **_: write_csv(path, record))
MAT = FileFormat("mat", tables=True, magic=(b"MATLAB", b"\x89HDF\r\n\x1a\n"), read_table=read_mat,
                 write=lambda path, record, **_: write_mat(path, record))
#: suffix → format, as rosbags' ``STORAGE_PLUGINS``: a new format is a row here (and its reader module), nothing else
READERS: dict[str, FileFormat] = {".mcap": BAG, ".db3": SQLITE_BAG, ".csv": CSV, ".tsv": CSV, ".txt": CSV,
                                  ".mat": MAT}
#: a directory (or a name without a suffix, to write) is a rosbag2 bag directory
BAG_DIRECTORY = FileFormat("bag", tables=False, write=_write_bag, output="bag")
Format = Literal["bag", "csv", "mat"]


# =============================================================================
# public API
# =============================================================================

def detect_format(path: str | os.PathLike) -> Format:
    """``"bag"``, ``"csv"`` or ``"mat"`` for an existing ``path``, else :class:`DataFileError`."""
    return file_format(path).name


def file_format(path: str | os.PathLike) -> FileFormat:
    """The row of :data:`READERS` for an existing ``path``: a directory is a bag, else by suffix, else by the
    first bytes (any printable text is a CSV table); else :class:`DataFileError`."""
    p = Path(path)
    regular_input(p)   # missing, FIFO, device: one line, never a reader blocked forever
    if p.is_dir():
        return BAG_DIRECTORY
    if p.suffix.lower() in READERS:
        return READERS[p.suffix.lower()]
    try:
        with p.open("rb") as f:
            head = f.read(128)
    except OSError as err:
        raise DataFileError(f"cannot read the file ({err.strerror or err})", source=str(p),
                            hint="check the path and the file's permissions") from err
    for fmt in dict.fromkeys(READERS.values()):
        if any(head.startswith(m) for m in fmt.magic):
            return fmt
    if head and all(32 <= c < 127 or c in b"\t\r\n" for c in head.lstrip(b"\xef\xbb\xbf")):
        return CSV
    raise DataFileError("unknown data format", source=str(p),
                        hint="give a rosbag2 bag (directory or .mcap), a .csv or a .mat file")


def load_record(path: str | os.PathLike, *, topics: "bag.BagTopics | None" = None,
                columns: Mapping[str, str] | None = None, fs_hz: float | None = None,
                axis: Axis = "z", skip_seconds: float | None = None, skip_periods: int | None = None,
                period_samples: int | None = None, centred: bool = False) -> Record:
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
    centred : bool
        The accelerations' constant offsets removed (:meth:`Record.centred`): what the analysis steps read.

    Raises
    ------
    NifoError
        A subclass with its own exit code: :class:`DataFileError`,
        :class:`MissingChannelError`, :class:`NonFiniteError`,
        :class:`TimestampError`, :class:`SampleRateError`,
        :class:`RecordTooShortError`, :class:`ConfigError`.
    """
    options = dict(topics=topics, columns=columns, fs_hz=fs_hz, axis=axis, skip_seconds=skip_seconds,
                   skip_periods=skip_periods, period_samples=period_samples)
    # the record names its file as given: the same file given another way is read for its own name
    rec = remembered(Path(path), {**options, "as_given": str(path)}, lambda: _load(path, **options))
    return rec.centred() if centred else rec


def _load(path, *, topics, columns, fs_hz, axis, skip_seconds, skip_periods, period_samples) -> Record:
    fmt = file_format(path)
    skip = _skip(skip_seconds, skip_periods, period_samples, source=str(path))
    if not fmt.tables:
        rec = _whole_bag(path, topics, axis)
        if fs_hz is not None:
            check_declared_rate(rec.fs_hz, fs_hz, source=str(path))
        if skip.active:
            k = skip.samples(rec.fs_hz, rec.n, source=str(path))
            rec = rec.slice(k, rec.n)
            rec = _with_meta(rec, skipped_samples=k)
        return rec
    cols, asm = _plan(path, _normalise_columns(columns), fs_hz=fs_hz, skip=skip)
    if fs_hz is None:   # a file without a rate takes the rate of a channel combined from another file
        fs_hz = next((f for _, _, f in asm.extra.values() if f is not None), None)
    return fmt.read_table(path, columns=cols, fs_hz=fs_hz, assembly=asm)


def _bag_key(topics, axis) -> dict:
    return {"topics": repr(topics), "axis": axis}


def _whole_bag(path, topics, axis) -> Record:
    """A bag decoded whole once per job (:func:`nifo.io.memo.reuse_reads`), whatever is skipped of it: here, or by
    the settings' probe when it read the file to its end (:func:`seed_whole_bag`)."""
    return remembered(Path(path), _bag_key(topics, axis), lambda: bag.read_bag(path, topics=topics, axis=axis),
                      kind="bag-whole")


def seed_whole_bag(path, record: Record, *, topics, axis) -> None:
    """``record``, a file's chunks read in order from its first sample (:func:`iter_record_chunks`, concatenated),
    kept as the job's whole read of the file when it is a bag read to its last sample: the same channels and rate as
    :func:`bag.read_bag` gives (measured on the bundled sample's and the loop benchmark's bags, bit for bit), without
    the chunks' own marks. Anything else (a table, a bag read in part) is left to be read when first loaded.
    Measured: ``nifo run`` decoded each bag twice, once to choose its settings and once to analyse it (0.35-0.8 s
    per 120-300 s bag)."""
    if not record.meta.get("streamed") or record.n != record.meta.get("chunk", {}).get("total_samples"):
        return
    meta = {k: v for k, v in record.meta.items() if k not in ("chunk", "streamed")}
    remembered(Path(path), _bag_key(topics, axis), lambda: replace(record, meta=meta), kind="bag-whole")


def _bag_chunks(path, chunk_samples: int, topics, axis) -> Iterator[Record]:
    """A bag's chunks: decoded one by one (memory bounded by a chunk), or, when this job already holds the bag
    decoded whole (:func:`_whole_bag`, :func:`seed_whole_bag`), sliced from it: the same samples, rate and meta
    (measured: ``nifo identify`` on one bag decoded it twice, in chunks by the settings' probe and again in chunks
    for its streaming estimator)."""
    whole = known(Path(path), _bag_key(topics, axis), kind="bag-whole")
    if whole is None:
        yield from bag.iter_bag_chunks(path, chunk_samples=chunk_samples, topics=topics, axis=axis)
        return
    for part in whole.chunks(int(chunk_samples)):
        yield replace(part, meta={**dict(part.meta), "streamed": True})


def _with_meta(rec: Record, **items) -> Record:
    return replace(rec, meta={**dict(rec.meta), **items})


def _skip(seconds, periods, period_samples, *, source: str) -> Skip:
    try:    # the values by the settings' own rules (one validator per field, every caller alike)
        check_timing(skip_seconds=seconds, skip_periods=periods, period_samples=period_samples)
    except ConfigError as err:
        raise err.with_context(source=source) from None
    if periods is not None and period_samples is None:     # the loader cuts whole periods: it needs their length
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
    fmt = file_format(path)
    if not fmt.tables:
        raise DataFileError("a channel from another file must come from a CSV or MAT file", source=str(base),
                            channel=role, hint=f"convert {path.name} to CSV or MAT, or use a bag with all topics")
    got = fmt.read_table(path, columns={role: key}, fs_hz=fs_hz,
                         assembly=Assembly(required=frozenset({role}), collect=True))
    values, fs_file = got
    return values, f"{key}@{path.name}", fs_file


def iter_record_chunks(path: str | os.PathLike, *, chunk_samples: int, topics: "bag.BagTopics | None" = None,
                       columns: Mapping[str, str] | None = None, fs_hz: float | None = None,
                       axis: Axis = "z", skip_seconds: float | None = None, skip_periods: int | None = None,
                       period_samples: int | None = None) -> Iterator[Record]:
    """:func:`load_record`, handed out as consecutive chunks of ``chunk_samples`` samples.

    Bags (single indexed MCAP) are decoded chunk by chunk with the same numpy
    decoder (:func:`nifo.io.bag.iter_bag_chunks`), so memory does not grow
    with the recording's length; CSV and MAT files are read whole and sliced (:meth:`Record.chunks`).
    Every chunk's ``meta["chunk"]`` holds ``index``, ``start`` (sample) and
    ``total_samples`` (expected for the whole file). Pushing the chunks in
    order into a streaming estimator gives what the whole record would.
    A skipped start (``skip_*``, see :func:`load_record`) is dropped before the first chunk.
    """
    if file_format(path).tables:
        yield from load_record(path, topics=topics, columns=columns, fs_hz=fs_hz, axis=axis,
                               skip_seconds=skip_seconds, skip_periods=skip_periods,
                               period_samples=period_samples).chunks(int(chunk_samples))
        return
    skip = _skip(skip_seconds, skip_periods, period_samples, source=str(path))
    first, left = True, 0
    for rec in _bag_chunks(path, chunk_samples, topics, axis):
        if first:
            if fs_hz is not None:
                check_declared_rate(rec.fs_hz, fs_hz, source=str(path))
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


def _output_format(path: Path) -> FileFormat:
    """The row of :data:`READERS` that writes ``path`` (a directory or a name without a suffix: a bag directory)."""
    if not path.suffix or path.is_dir():
        return BAG_DIRECTORY
    fmt = READERS.get(path.suffix.lower())
    if fmt is None or fmt.write is None:
        raise DataFileError(f"cannot tell the output format from the suffix {path.suffix!r}", source=str(path),
                            hint="name the output *.mcap, *.csv, *.mat, or a directory (rosbag2 bag)")
    return fmt


def check_record_output(path: str | os.PathLike) -> Path:
    """Refuse ``path`` before any work when :func:`save_record` would refuse to write there.

    A CSV or MAT file that exists is never replaced (nifo cannot tell it wrote
    it); an existing ``.mcap`` file or bag directory only when nifo wrote it
    (:mod:`nifo.io.ownership`).
    """
    p = Path(path)
    return check_output(p, kind=_output_format(p).output)


def save_record(path: str | os.PathLike, record: Record, *, topics: "bag.BagTopics | None" = None,
                axis: Axis = "z") -> Path:
    """Write ``record`` in the format given by the suffix (:data:`READERS`); returns the path written.

    ``.csv`` → CSV (``time,spindle_accel,body_accel[,tire_patch_disp]``, '%.17g');
    ``.mat`` → MAT v5; ``.mcap`` → one rosbag2 MCAP file; a directory name
    (no suffix, or an existing directory) → a rosbag2 bag directory.
    Atomic: on any failure nothing is left at ``path`` (an existing file is kept).
    """
    p = Path(path)
    return _output_format(p).write(p, record, topics=topics, axis=axis)


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
    topics = getattr(args, "topics", None)
    columns = getattr(args, "columns", None)
    return {"topics": bag.BagTopics.parse(topics) if topics else None,
            "columns": parse_columns(columns) if columns else None,
            "fs_hz": getattr(args, "fs_hz", None),
            "axis": getattr(args, "axis", "z") or "z",
            "skip_seconds": getattr(args, "skip_seconds", None),
            "skip_periods": getattr(args, "skip_periods", None),
            "period_samples": getattr(args, "period_samples", None)}
