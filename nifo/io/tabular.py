"""CSV tables to and from :class:`~nifo_core.record.Record`.

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
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from nifo_core.errors import DataFileError, MissingChannelError
from nifo_core.record import Record

from .atomic import staged_file

__all__ = ["read_csv", "write_csv"]

_FIX_COLUMNS = ("name the columns, e.g. --columns time=t,spindle_accel=a_wheel,body_accel=a_body "
                "(columns={...} in Python)")


def _delimiter(header: str) -> str:
    counts = {d: header.count(d) for d in (",", ";", "\t")}
    best = max(counts, key=counts.get)
    return best if counts[best] else ","


def _bad_cell(path: Path, delim: str, header: list[str], wanted: Mapping[str, int]) -> DataFileError:
    """Find the first cell np.loadtxt could not read, to say where it is."""
    with path.open(newline="", encoding="utf-8-sig") as f:
        seen_header = False
        for line_no, row in enumerate(csv.reader(f, delimiter=delim), start=1):
            if not row or row[0].lstrip().startswith("#"):
                continue
            if not seen_header:
                seen_header = True
                continue
            if len(row) != len(header):
                return DataFileError(f"row {line_no} has {len(row)} cells but the header has {len(header)}",
                                     source=str(path), hint=f"fix or delete row {line_no}")
            for name, j in wanted.items():
                try:
                    float(row[j])
                except ValueError:
                    return DataFileError(f"row {line_no}: cell {row[j]!r} is not a number", source=str(path),
                                         channel=f"column {name}",
                                         hint=f"fix or delete row {line_no}; write missing values as nan "
                                              "only if you then cut them out")
    return DataFileError("cannot read the table", source=str(path), hint="check the file is a CSV table")


def read_csv(path: str | os.PathLike, *, columns: Mapping[str, str] | None = None,
             fs_hz: float | None = None, assembly=None) -> Record:
    """Read a CSV table (layout in the module docstring) into a :class:`Record`.

    ``assembly`` (:class:`nifo.io.loader.Assembly`, set by ``load_record``):
    the roles required and what is added besides the file's columns.
    """
    from .loader import READ_ROLES, Assembly, assemble_record

    path = Path(path)
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
                if name in index:
                    wanted[role] = index[name]
                elif role in asm.required or role in explicit:
                    if role == "time" and fs_hz is not None:
                        continue
                    raise MissingChannelError(
                        f"no column {name!r}; the header has {', '.join(map(repr, header))}", source=src,
                        channel=role, hint=_FIX_COLUMNS)
            if "time" not in wanted and fs_hz is None and not asm.collect:
                raise MissingChannelError(
                    f"no time column {names['time']!r} and no sample rate; the header has "
                    f"{', '.join(map(repr, header))}", source=src, channel="time",
                    hint="map the time column with --columns time=NAME, or pass --fs HZ")
            try:
                data = np.loadtxt(f, delimiter=delim, usecols=list(wanted.values()), ndmin=2,
                                  dtype=np.float64, comments="#")
            except ValueError as err:
                raise _bad_cell(path, delim, header,
                                {header[j]: j for j in wanted.values()}) from err
    except (DataFileError, MissingChannelError):
        raise
    except UnicodeDecodeError as err:
        raise DataFileError("the file is not text (is it a CSV table?)", source=src,
                            hint="give a CSV table with a header row") from err
    except OSError as err:
        raise DataFileError(f"cannot read the file ({err.strerror or err})", source=src,
                            hint="check the path and the file's permissions") from err
    if data.shape[0] == 0:
        raise DataFileError("the table has a header but no data rows", source=src,
                            hint="check that the export finished")
    col = {role: data[:, k] for k, role in enumerate(wanted)}
    stamps = None
    if "time" in col:
        t = col["time"]
        if not np.isfinite(t).all():
            i = int(np.argmax(~np.isfinite(t)))
            raise DataFileError(f"time at row {i + 2} is not finite", source=src, channel=names["time"],
                                hint="repair or delete that row")
        stamps = np.rint(t * 1e9).astype(np.int64)
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
