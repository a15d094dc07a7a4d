"""MATLAB ``.mat`` files (v4–v7; read with scipy) to and from :class:`~nifo_core.signal.record.Record`.

Keys read by default: ``spindle_accel``, ``body_accel``, optional
``tire_patch_disp`` (vectors, SI units), and the sample rate as ``fs`` (or
``Fs``/``fs_hz``) or per-sample ``time`` in seconds; ``t0_ns`` when present.
Other names are mapped with ``columns``; a key may pick one row of a 2-D
array with ``KEY[i]`` (the index runs along the shorter dimension, so it works
for 3×N and N×3 alike). ``fs`` may name a key or be a number; ``fs_hz``
gives the rate when the file holds none. The F-16 ground-vibration files::

    load_record("F16Data_SineSw_Level3.mat",
                columns={"spindle_accel": "Acceleration[1]", "body_accel": "Acceleration[2]", "fs": "Fs"})

MATLAB v7.3 files are HDF5, which scipy cannot read (and h5py is not a
dependency): re-save them with ``save(name, ..., '-v7')``.

:func:`write_mat` writes MAT v5 with ``spindle_accel``, ``body_accel``
(N×1 columns), ``tire_patch_disp`` when present, ``fs``, ``t0_ns`` and
``nifo_writer`` (``"nifo VERSION"``: nifo replaces only a file it wrote).
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from nifo_core.errors import ConfigError, DataFileError, MissingChannelError
from nifo_core.signal.record import Record

from .assemble import READ_ROLES, Assembly, assemble_record, check_declared_rate, seconds_to_ns
from .atomic import staged_file
from .inputs import regular_input
from .ownership import MAT_WRITER_KEY

__all__ = ["read_mat", "write_mat"]

_KEY = re.compile(r"^\s*(?P<key>[^\[\]]+?)\s*(?:\[\s*(?P<idx>-?\d+)\s*\])?\s*$")
_FS_KEYS = ("fs", "Fs", "fs_hz", "FS")
_LOGICAL = "__nifo_logical__"   # the keys MATLAB stored as logical (set by _load)
_FIX_KEYS = ("name the keys, e.g. --columns spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs "
             "(columns={...} in Python)")


def _key_name(spec: str) -> str | None:
    m = _KEY.match(spec)
    return m["key"] if m else None


def _listing(data: Mapping[str, object]) -> str:
    items = [f"{k} {'×'.join(map(str, np.shape(v)))}" for k, v in data.items()
             if not k.startswith("__") and isinstance(v, np.ndarray)]
    return ", ".join(items) or "none"


def _pick(data: Mapping[str, object], spec: str, *, role: str, src: str) -> np.ndarray:
    """The 1-D float array named by ``spec`` (``KEY`` or ``KEY[i]``)."""
    m = _KEY.match(spec)
    if not m:
        raise MissingChannelError(f"cannot read the key {spec!r}", source=src, channel=role, hint=_FIX_KEYS)
    key, idx = m["key"], m["idx"]
    if key not in data or key.startswith("__"):
        raise MissingChannelError(f"no key {key!r}; the file holds {_listing(data)}", source=src,
                                  channel=role, hint=_FIX_KEYS)
    arr = data[key]
    if isinstance(arr, np.ndarray) and (arr.dtype.kind == "b" or key in data.get(_LOGICAL, ())):
        # a MATLAB logical: true would read as 1
        what = "the sample rate" if role == "fs" else "time" if role == "time" else "a signal"
        raise DataFileError(f"key {key!r} is a logical (true/false) array, not {what}", source=src, channel=role,
                            hint="store it as a double (e.g. fs = 600, not fs = true)"
                                 + (", or give the rate with --fs HZ" if role == "fs" else ""))
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "iuf":
        raise DataFileError(f"key {key!r} is not a numeric array ({type(arr).__name__} "
                            f"{getattr(arr, 'dtype', '')})", source=src, channel=role,
                            hint="store the signal as a real double vector")
    arr = np.squeeze(arr)
    if idx is not None:
        if arr.ndim > 2:   # e.g. several realisations of a multisine, each its own experiment
            raise MissingChannelError(f"{key!r} is a {arr.ndim}-D array (shape {np.shape(data[key])}): several "
                                      f"experiments in one key; nifo reads a vector or a row of a 2-D array",
                                      source=src, channel=role,
                                      hint=f"save each experiment as its own file, e.g. in Python scipy.io.savemat("
                                           f"'r0.mat', {{'{key}': d['{key}'][..., 0], ...}}) with the other keys")
        if arr.ndim != 2:
            raise MissingChannelError(f"{key!r} has shape {np.shape(data[key])}; [i] picks a row of a 2-D array",
                                      source=src, channel=role, hint=f"use {key} without [i]")
        axis = int(np.argmin(arr.shape))
        i = int(idx)
        if not -arr.shape[axis] <= i < arr.shape[axis]:
            raise MissingChannelError(f"{key!r} has {arr.shape[axis]} rows (shape {arr.shape}); "
                                      f"row {i} does not exist", source=src, channel=role,
                                      hint=f"use {key}[0] .. {key}[{arr.shape[axis] - 1}]")
        arr = np.take(arr, i, axis=axis)
    elif arr.ndim > 1:
        raise MissingChannelError(f"{key!r} is a {'×'.join(map(str, arr.shape))} array, not a vector",
                                  source=src, channel=role,
                                  hint=f"pick one row with {key}[i], e.g. --columns {role}={key}[0]")
    return np.atleast_1d(arr).astype(np.float64)


def _load(path: Path) -> dict:
    import scipy.io

    src = str(path)
    try:
        major, _ = scipy.io.matlab.matfile_version(str(path))
    except OSError as err:
        raise DataFileError(f"cannot read the file ({err.strerror or err})", source=src,
                            hint="check the path and the file's permissions") from err
    except Exception as err:  # scipy's MatReadError, ValueError on garbage
        raise DataFileError(f"not a MATLAB file ({err})", source=src,
                            hint="give a .mat file saved by MATLAB/Octave/scipy") from err
    if major == 2:
        raise DataFileError("MATLAB v7.3 (HDF5) files cannot be read", source=src,
                            hint="re-save it in MATLAB with save(name, vars..., '-v7')")
    try:
        data = scipy.io.loadmat(str(path), squeeze_me=False, appendmat=False)
        # loadmat gives a MATLAB logical as uint8 (true reads as 1): remember which keys are logical
        try:
            data[_LOGICAL] = frozenset(name for name, _, cls in scipy.io.whosmat(str(path)) if cls == "logical")
        except Exception:  # noqa: BLE001 - the data were read; only the logical flags are unknown
            data[_LOGICAL] = frozenset()
        return data
    except NotImplementedError as err:  # v7.3 that slipped past the version probe
        raise DataFileError("MATLAB v7.3 (HDF5) files cannot be read", source=src,
                            hint="re-save it in MATLAB with save(name, vars..., '-v7')") from err
    except Exception as err:  # truncated or corrupt
        raise DataFileError(f"cannot read the MAT file ({err}); it may be truncated or damaged", source=src,
                            hint="re-copy or re-export the file") from err


def _scalar(arr: np.ndarray, key: str, src: str) -> float:
    """The one number a key such as ``fs`` holds."""
    if arr.size != 1 or not np.isfinite(arr.ravel()[0]):
        raise DataFileError(f"key {key!r} should hold one finite number, it holds {arr.size} value(s)"
                            + (f" ({arr.ravel()[0]!r})" if arr.size == 1 else ""), source=src, channel="fs",
                            hint="store the sample rate as one number in Hz, or give it with --fs HZ")
    return float(arr.ravel()[0])


def read_mat(path: str | os.PathLike, *, columns: Mapping[str, str] | None = None,
             fs_hz: float | None = None, assembly=None) -> Record:
    """Read a ``.mat`` file (layout in the module docstring) into a :class:`Record`.

    ``assembly`` (:class:`nifo.io.assemble.Assembly`, set by ``load_record``):
    the roles required and what is added besides the file's keys.
    """
    path = regular_input(path)
    src = str(path)
    asm = assembly or Assembly()
    data = _load(path)
    cols = dict(columns or {})
    used: dict[str, str] = {}
    chans: dict[str, np.ndarray] = {}
    for role in READ_ROLES:
        spec = cols.get(role, role)
        if role not in asm.required and role not in cols and _key_name(spec) not in data:
            continue
        chans[role] = _pick(data, spec, role=role, src=src)
        used[role] = spec
    specs = [(r, used[r].replace(" ", "")) for r in used]
    for i, (r, sp) in enumerate(specs):
        for r2, sp2 in specs[i + 1:]:
            if sp == sp2:
                raise ConfigError(f"{r} and {r2} both read key {used[r]!r}", source=src, channel="--columns",
                                  hint="give each role its own key (or row KEY[i])")
    fs_file: float | None = None
    fs_spec = cols.get("fs")
    if fs_spec is not None:
        try:
            fs_file = float(fs_spec)
            used["fs"] = fs_spec
        except ValueError:
            fs_file = _scalar(_pick(data, fs_spec, role="fs", src=src), fs_spec, src)
            used["fs"] = fs_spec
    else:
        key = next((k for k in _FS_KEYS if k in data), None)
        if key is not None:
            fs_file = _scalar(_pick(data, key, role="fs", src=src), key, src)
            used["fs"] = key
    stamps = None
    time_spec = cols.get("time", "time")
    if "time" in cols or _key_name(time_spec) in data:
        t = _pick(data, time_spec, role="time", src=src)
        if not np.isfinite(t).all():
            raise DataFileError("the time vector holds NaN or infinite values", source=src, channel=time_spec,
                                hint="repair the time vector or drop it and give fs")
        stamps = seconds_to_ns(t, source=src, channel=f"key {time_spec}")
        used["time"] = time_spec
    t0_ns = 0
    t0_spec = cols.get("t0_ns", "t0_ns")
    if _key_name(t0_spec) in data:
        raw_t0 = np.asarray(data[_key_name(t0_spec)]).ravel()
        if raw_t0.size != 1 or raw_t0.dtype.kind not in "iuf" or _key_name(t0_spec) in data.get(_LOGICAL, ()):
            raise DataFileError(f"key {t0_spec!r} is not one number", source=src, channel="t0_ns",
                                hint="store t0_ns as an int64 scalar, or drop it")
        if not (np.isfinite(raw_t0[0]) and abs(float(raw_t0[0])) < 4e18):   # NaN, or past year 2096
            raise DataFileError(f"key {t0_spec!r} is {raw_t0[0]!r}, not a time in ns", source=src, channel="t0_ns",
                                hint="store t0_ns as an int64 scalar (ns since the epoch), or drop it")
        t0_ns = int(raw_t0[0])  # int64 kept exact (no float round trip)
    if stamps is None and fs_hz is None and fs_file is None and not asm.collect:
        raise MissingChannelError(f"no sample rate: no key fs/Fs/time; the file holds {_listing(data)}",
                                  source=src, channel="fs",
                                  hint="name the rate key with --columns fs=KEY, or give it with --fs HZ")
    if fs_hz is not None and fs_file is not None and stamps is None:
        check_declared_rate(fs_file, fs_hz, source=src)
    labels = {c: f"key {used[c]}" for c in chans}
    meta = {"format": "mat", "path": src, "columns": used}
    if stamps is not None:
        tol = 1.0 + 4 * float(np.spacing(np.max(np.abs(t)))) * 1e9
        return assemble_record({c: (stamps, v) for c, v in chans.items()}, labels=labels, path=path, meta=meta,
                               fs_hz=fs_hz if fs_hz is not None else fs_file, stamp_tol_ns=tol, assembly=asm)
    return assemble_record({c: (None, v) for c, v in chans.items()}, labels=labels, path=path, meta=meta,
                           fs_hz=fs_hz if fs_hz is not None else fs_file, t0_ns=t0_ns, assembly=asm)


def write_mat(path: str | os.PathLike, record: Record) -> Path:
    """Write ``record`` as MAT v5 (keys in the module docstring); atomic."""
    import scipy.io

    final = Path(path)
    from nifo_core import __version__

    out = {"spindle_accel": np.asarray(record.spindle_accel), "body_accel": np.asarray(record.body_accel),
           "fs": np.float64(record.fs_hz), "t0_ns": np.int64(record.t0_ns),
           MAT_WRITER_KEY: f"nifo {__version__}"}   # nifo may replace a file that names it (nifo.io.ownership)
    for name in ("tire_patch_disp", "force"):
        if getattr(record, name) is not None:
            out[name] = np.asarray(getattr(record, name))
    try:
        with staged_file(final) as tmp:
            scipy.io.savemat(str(tmp), out, appendmat=False, oned_as="column", do_compression=False)
    except OSError as err:
        raise DataFileError(f"cannot write the file ({err.strerror or err})", source=str(final),
                            hint="check that the directory exists and is writable") from err
    return final
