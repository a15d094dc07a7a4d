"""Per-bag partials on disk, keyed by the bag's content and the settings (restart-safe).

Key = SHA-256 (first 40 hex digits) of two hashes: the bag's content hash,
:func:`content_hash` — XXH3-128 (``xxhash``, a required dependency) of every
file of a rosbag2 folder by relative path, or of the file — and
:func:`settings_hash`, the SHA-256 of the JSON of everything that changes the
partial (terms, spectral settings, integration band, tire patch, analysis
band, chunk length, input options, :data:`CACHE_FORMAT`). Beside the partials, small JSON notes keep the bags'
rates, lengths and channels (one note per vehicle whose bags were all in one
task, key: their content hashes and the input options; else one per bag), so
a rerun fixes every group's set-up, and so finds the partials' keys, without
opening a finished bag. Renaming or moving a bag keeps its
key; touching one byte or a setting makes a new one. An entry is one ``.npz``
written to a temporary name and renamed into place, so a run killed at any
instant (SIGKILL included) leaves whole entries or none: the next run reuses
the finished bags and recomputes the rest. Entries are not fsync'ed (a
process kill cannot tear a renamed file; after a power loss a torn entry
fails to load and is recomputed).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from pathlib import Path
from typing import Mapping

import numpy as np
import xxhash

__all__ = ["content_hash", "settings_hash", "cache_key", "load_partial", "store_partial", "load_note", "store_note",
           "CACHE_FORMAT"]

#: bump when the content of a cached partial changes meaning
CACHE_FORMAT = 3
_CHUNK = 1 << 22


def _hasher():
    """XXH3-128 (xxhash, ~20 GB/s): (name, hash object)."""
    return "xxh3-128", xxhash.xxh3_128()


def content_hash(path: str | os.PathLike) -> str:
    """Hash of a file's bytes, or of a folder's files (relative names and bytes, sorted): ``"ALGO:HEX"``.

    XXH3-128, a non-cryptographic 128-bit hash: it names a bag in the user's own
    cache (accidental collisions ~2⁻⁶⁴), not proof against a forger. It costs
    ~1 ms per 5-MB bag (SHA-256: ~4 ms, 5 % of the bag's whole accumulation).
    """
    p = Path(path)
    algo, h = _hasher()
    files = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
    buf = bytearray(_CHUNK)
    view = memoryview(buf)
    for q in files:
        if p.is_dir():
            h.update(q.relative_to(p).as_posix().encode() + b"\0")
        with q.open("rb", buffering=0) as f:
            while n := f.readinto(buf):
                h.update(view[:n])
        h.update(b"\0\0")
    return f"{algo}:{h.hexdigest()}"


def settings_hash(settings: Mapping) -> str:
    """SHA-256 of the canonical JSON of the settings that shape a partial."""
    doc = json.dumps({"cache_format": CACHE_FORMAT, **settings}, sort_keys=True, default=str)
    return hashlib.sha256(doc.encode()).hexdigest()


def cache_key(bag_hash: str, settings_digest: str) -> str:
    return hashlib.sha256(f"{bag_hash}:{settings_digest}".encode()).hexdigest()[:40]


def _entry(cache_dir: Path, key: str) -> Path:
    """One folder for all entries: a folder per key prefix cost a mkdir (~0.3 ms) per bag of a first run."""
    return cache_dir / f"{key}.npz"


def _temporary(path: Path) -> tuple[int, str]:
    """(descriptor, name) of a new file beside ``path`` named after this process and thread (``mkstemp``'s
    random names cost ~0.25 ms per entry); a leftover of a killed process of the same pid is overwritten."""
    tmp = str(path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp"))
    return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), tmp


#: arrays of at most this many elements (not complex) go into one JSON entry: an .npz entry costs ~0.07 ms
_SMALL = 64


def _pack(state: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Arrays to store: a stack of exactly Hermitian matrices (the accumulated cross-spectra) as its upper
    triangles; the small ones (counters, names, settings) together as one JSON entry (exact: JSON floats
    round-trip bit for bit; dtype and shape kept); the rest as they are."""
    out, small = {}, {}
    for k, v in state.items():
        a = np.asarray(v)
        if a.dtype.kind == "c" and a.ndim == 3 and a.shape[1] == a.shape[2] > 1 and \
                np.array_equal(a, np.conj(np.swapaxes(a, 1, 2))):
            iu = np.triu_indices(a.shape[1])
            out[f"triu.{a.shape[1]}.{k}"] = a[:, iu[0], iu[1]]      # 10 of 16 entries for 4 channels
        elif a.size <= _SMALL and a.dtype.kind in "biufU":
            small[k] = {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.ravel().tolist()}
        else:
            out[f"state.{k}"] = a
    if small:
        out["__small__"] = np.array(json.dumps(small))
    return out


def _unpack(z) -> dict[str, np.ndarray]:
    state = {}
    for name in z.files:
        if name.startswith("state."):
            state[name[6:]] = z[name]
        elif name == "__small__":
            for k, d in json.loads(str(z[name])).items():
                state[k] = np.array(d["data"], dtype=np.dtype(d["dtype"])).reshape(d["shape"])
        elif name.startswith("triu."):
            _, n, k = name.split(".", 2)
            n = int(n)
            t = z[name]
            iu = np.triu_indices(n)
            a = np.empty((t.shape[0], n, n), t.dtype)
            a[:, iu[1], iu[0]] = np.conj(t)
            a[:, iu[0], iu[1]] = t           # the diagonal (real) last: as stored
            state[k] = a
    return state


_MADE: set[Path] = set()


def _folder(folder: Path) -> None:
    """Create a cache folder once per process (a mkdir per entry cost ~0.2 ms); made again if removed since."""
    if folder not in _MADE or not folder.is_dir():
        folder.mkdir(parents=True, exist_ok=True)
        _MADE.add(folder)


def load_partial(cache_dir: str | os.PathLike | None, key: str) -> dict | None:
    """The cached partial (``{"state": {...}, "info": {...}}``) or None (absent or unreadable: recompute)."""
    if cache_dir is None:
        return None
    path = _entry(Path(cache_dir), key)
    try:
        with np.load(path, allow_pickle=False) as z:
            info = json.loads(str(z["__info__"]))
            state = _unpack(z)
    except FileNotFoundError:
        return None
    except Exception:  # noqa: BLE001 - a torn or foreign entry is recomputed, never trusted
        return None
    return {"state": state, "info": info}


def store_partial(cache_dir: str | os.PathLike | None, key: str, state: Mapping[str, np.ndarray],
                  info: Mapping) -> None:
    """Write one entry atomically (temporary file in the same folder, then rename).

    A Hermitian stack (the partial's cross-spectral sums, exactly Hermitian as
    accumulated) is stored as its upper triangles: 0.49 instead of 0.79 MB for
    four channels, read back bit for bit.
    """
    if cache_dir is None:
        return
    path = _entry(Path(cache_dir), key)
    _folder(path.parent)
    fd, tmp = _temporary(path)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, __info__=np.array(json.dumps(info, default=str)), **_pack(state))
        os.replace(tmp, path)   # no fsync: a killed process leaves whole files; a torn one (power loss) reads as absent
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_note(cache_dir: str | os.PathLike | None, key: str) -> dict | None:
    """A small cached JSON note (a bag's rate, length and channels) or None."""
    if cache_dir is None:
        return None
    try:
        return json.loads((Path(cache_dir) / "notes" / f"{key}.json").read_text())
    except FileNotFoundError:
        return None
    except Exception:  # noqa: BLE001 - torn or foreign: recomputed
        return None


def store_note(cache_dir: str | os.PathLike | None, key: str, note: Mapping) -> None:
    """Write a small JSON note atomically."""
    if cache_dir is None:
        return
    folder = Path(cache_dir) / "notes"
    _folder(folder)
    fd, tmp = _temporary(folder / f"{key}.json")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(note, f)
        os.replace(tmp, folder / f"{key}.json")
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
