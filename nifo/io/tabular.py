"""CSV tables to and from :class:`~nifo_core.signal.record.Record`.

Layout: one header row, then one row per sample::

    time,spindle_accel,body_accel,tire_patch_disp
    0,0.0123,-0.0045,1.2e-05
    0.0016666666666666668,...

``time`` in seconds (absolute: ``t0_ns·1e-9 + i/fs``), accelerations in m/s²,
displacement in m; ``tire_patch_disp`` is optional. Other column names are
mapped with ``columns={"time": "t", "spindle_accel": "a_wheel", ...}``; a
table without a time column needs ``fs_hz``. The delimiter (``,``, ``;`` or
tab) is taken from the header row; lines starting with ``#`` are comments.
Values are written with ``%.17g`` so a write/read round trip is bit-exact.
"""

from __future__ import annotations

import csv
import os
import re
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from nifo_core.errors import ConfigError, DataFileError, MissingChannelError, NifoError
from nifo_core.signal.record import Record

from .assemble import READ_ROLES, Assembly, assemble_record, seconds_to_ns
from .atomic import staged_file
from .inputs import regular_input

__all__ = ["read_csv", "write_csv"]

_FIX_COLUMNS = ("name the columns, e.g. --columns time=t,spindle_accel=a_wheel,body_accel=a_body "
                "(columns={...} in Python)")


def _delimiter(header: str) -> str:
    counts = {d: header.count(d) for d in (",", ";", "\t")}
    best = max(counts, key=counts.get)
    return best if counts[best] else ","


#: what np.loadtxt reads as a number: ASCII digits, optional sign, point and exponent; inf, infinity, nan
_PLAIN_NUMBER = re.compile(r"^[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf(?:inity)?|nan)$", re.I)
_FIX_CELL = "write plain numbers with the digits 0-9 (e.g. 1000, -0.5, 1.5e-3), without quotes or digit separators"


def _why_not_a_number(cell: str) -> str:
    """Why ``cell`` is not a number np.loadtxt reads, in words (empty when it is one)."""
    c = cell.strip()
    if _PLAIN_NUMBER.match(c):
        return ""
    if len(c) >= 2 and c[0] == c[-1] and c[0] in "\"'":
        return "it is quoted"
    plain = c.replace("_", "")
    try:
        float(plain)
        readable = True
    except ValueError:
        readable = False
    if readable and "_" in c:
        return "digit-group underscores are not read"
    if readable and not c.isascii():
        return "digits other than 0-9"
    if not c:
        return "the cell is empty"
    return "not a number"


def _bad_cell(path: Path, delim: str, header: list[str], wanted: Mapping[str, int]) -> DataFileError:
    """Find the first cell np.loadtxt could not read (split as loadtxt splits: no quoting), to say where it is."""
    with path.open(newline="", encoding="utf-8-sig") as f:
        seen_header = False
        for line_no, line in enumerate(f, start=1):
            text = line.split("#", 1)[0].rstrip("\r\n")
            if not text.strip():
                continue
            if not seen_header:
                seen_header = True
                continue
            row = text.split(delim)
            if len(row) != len(header):
                return DataFileError(f"row {line_no} has {len(row)} cells but the header has {len(header)}",
                                     source=str(path), hint=f"fix or delete row {line_no}")
            for name, j in wanted.items():
                why = _why_not_a_number(row[j])
                if why:
                    return DataFileError(f"row {line_no}, column {j + 1}: cell {row[j].strip()!r} is not a number"
                                         + ("" if why == "not a number" else f" ({why})"), source=str(path),
                                         channel=f"column {name}", hint=f"fix or delete row {line_no}: {_FIX_CELL}")
    return DataFileError("cannot read the table", source=str(path), hint="check the file is a CSV table")


def _not_utf8(path: Path, err: UnicodeDecodeError) -> DataFileError:
    """A CSV that is not UTF-8: say which encoding it looks like and how to convert it."""
    with path.open("rb") as f:
        head = f.read(1 << 16)
    looks_text = b"\x00" not in head and sum(32 <= b < 127 or b in b"\t\r\n" for b in head) > 0.9 * len(head)
    at = f"byte 0x{err.object[err.start]:02x} at offset {err.start}" if err.object else "an undecodable byte"
    if looks_text:
        return DataFileError(f"the file is not UTF-8 text ({at}); it looks like Latin-1 (ISO-8859-1) or "
                             "Windows-1252, and nifo reads CSV tables as UTF-8", source=str(path),
                             hint=f"convert it, e.g. iconv -f latin1 -t utf-8 {path.name} > {path.stem}.utf8.csv "
                                  "(use -f cp1252 for a Windows export)")
    return DataFileError(f"the file is not text ({at}; nifo reads CSV tables as UTF-8): is it a CSV table?",
                         source=str(path), hint="give a CSV table with a header row, saved as UTF-8")


def _ragged_row(path: Path, delim: str, width: int) -> DataFileError | None:
    """The first data row whose cell count differs from the header's (np.loadtxt ignores extra cells)."""
    with path.open("rb") as f:
        raw = f.read()
    d = delim.encode()
    lines = raw.splitlines()
    counts = np.fromiter((ln.count(d) for ln in lines), np.int64, count=len(lines))
    if not (counts != width - 1).any():
        return None
    # a closer look (comments, blank lines, quoted cells) only when the quick count disagrees
    with path.open(newline="", encoding="utf-8-sig") as f:
        seen_header = False
        for line_no, row in enumerate(csv.reader(f, delimiter=delim), start=1):
            if not row or row[0].lstrip().startswith("#") or not any(c.strip() for c in row):
                continue
            if not seen_header:
                seen_header = True
                continue
            if len(row) != width:
                return DataFileError(f"row {line_no} has {len(row)} cells but the header has {width}",
                                     source=str(path), hint=f"fix or delete row {line_no}")
    return None


def read_csv(path: str | os.PathLike, *, columns: Mapping[str, str] | None = None,
             fs_hz: float | None = None, assembly=None) -> Record:
    """Read a CSV table (layout in the module docstring) into a :class:`Record`.

    ``assembly`` (:class:`nifo.io.assemble.Assembly`, set by ``load_record``):
    the roles required and what is added besides the file's columns.
    """
    path = regular_input(path)
    src = str(path)
    asm = assembly or Assembly()
    names = {"time": "time", **{c: c for c in READ_ROLES}, **dict(columns or {})}
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            header_line = f.readline()
            while header_line.lstrip().startswith("#"):
                header_line = f.readline()
            if not header_line.strip():
                raise DataFileError("the file is empty", source=src, hint="give a CSV table with a header row")
            delim = _delimiter(header_line)
            header = [h.strip() for h in next(csv.reader([header_line], delimiter=delim))]
            index = {h: j for j, h in enumerate(header)}
            wanted: dict[str, int] = {}
            explicit = set(columns or {})
            for role in ("time", *READ_ROLES):
                name = names.get(role)
                if name in index and header.count(name) > 1:
                    cols = [str(j + 1) for j, h in enumerate(header) if h == name]
                    raise DataFileError(f"column {name!r} appears {len(cols)} times in the header (columns "
                                        f"{', '.join(cols)}): nifo cannot tell which one to read", source=src,
                                        channel=role, hint=f"rename all but one {name!r} column in the header, or "
                                                           f"read another column with --columns {role}=NAME")
                if name in index:
                    wanted[role] = index[name]
                elif role in asm.required or role in explicit:
                    if role == "time" and fs_hz is not None:
                        continue
                    raise MissingChannelError(
                        f"no column {name!r}; the header has {', '.join(map(repr, header))}", source=src,
                        channel=role, hint=_FIX_COLUMNS)
            shared = [r for r in wanted if list(wanted.values()).count(wanted[r]) > 1]
            if shared:
                raise ConfigError(f"roles {', '.join(shared)} all read column {header[wanted[shared[0]]]!r}",
                                  source=src, channel="--columns", hint="give each role its own column")
            if "time" not in wanted and fs_hz is None and not asm.collect:
                raise MissingChannelError(
                    f"no time column {names['time']!r} and no sample rate; the header has "
                    f"{', '.join(map(repr, header))}", source=src, channel="time",
                    hint="map the time column with --columns time=NAME, or pass --fs HZ")
            try:
                with warnings.catch_warnings():   # "input contained no data": reported below as an error
                    warnings.simplefilter("ignore", UserWarning)
                    data = np.loadtxt(f, delimiter=delim, usecols=list(wanted.values()), ndmin=2,
                                      dtype=np.float64, comments="#")
            except UnicodeDecodeError:
                raise
            except ValueError as err:
                raise _bad_cell(path, delim, header,
                                {header[j]: j for j in wanted.values()}) from err
    except NifoError:
        raise
    except UnicodeDecodeError as err:
        raise _not_utf8(path, err) from err
    except OSError as err:
        raise DataFileError(f"cannot read the file ({err.strerror or err})", source=src,
                            hint="check the path and the file's permissions") from err
    ragged = _ragged_row(path, delim, len(header))
    if ragged is not None:
        raise ragged
    if data.shape[0] == 0:
        raise DataFileError("the table has a header but no data rows", source=src,
                            hint="check that the export finished")
    col = {role: data[:, k] for k, role in enumerate(wanted)}
    stamps = None
    if "time" in col:
        t = col["time"]
        if not np.isfinite(t).all():
            i = int(np.argmax(~np.isfinite(t)))
            raise DataFileError(f"time at data row {i + 1} is not finite", source=src, channel=names["time"],
                                hint="repair or delete that row")
        stamps = seconds_to_ns(t, source=src, channel=f"column {names['time']}")
        # seconds in a float: allow the rounding of t*1e9 to whole ns
        tol = 1.0 + 4 * float(np.spacing(np.max(np.abs(t)))) * 1e9
    chans = {c: (stamps, col[c]) for c in READ_ROLES if c in col}
    labels = {c: f"column {names[c]}" for c in chans}
    meta = {"format": "csv", "path": src, "columns": {r: header[j] for r, j in wanted.items()},
            "delimiter": delim}
    return assemble_record(chans, labels=labels, path=path, meta=meta, fs_hz=fs_hz,
                           stamp_tol_ns=tol if stamps is not None else 1.0, assembly=asm)


def write_csv(path: str | os.PathLike, record: Record) -> Path:
    """Write ``record`` as CSV (``time,spindle_accel,body_accel[,tire_patch_disp][,force]``); atomic."""
    final = Path(path)
    cols = [record.t0_ns * 1e-9 + np.arange(record.n) / record.fs_hz, record.spindle_accel, record.body_accel]
    header = ["time", "spindle_accel", "body_accel"]
    for name in ("tire_patch_disp", "force"):
        if getattr(record, name) is not None:
            cols.append(getattr(record, name))
            header.append(name)
    try:
        with staged_file(final) as tmp:
            np.savetxt(tmp, np.column_stack(cols), fmt="%.17g", delimiter=",", header=",".join(header),
                       comments="")
    except OSError as err:
        raise DataFileError(f"cannot write the file ({err.strerror or err})", source=str(final),
                            hint="check that the directory exists and is writable") from err
    return final
