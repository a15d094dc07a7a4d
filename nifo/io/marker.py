"""The ``.nifo-output`` marker: what nifo wrote into a folder, file by file, so that it replaces nothing else.

Every output folder nifo writes carries :data:`MARKER`, a JSON document
(format 2)::

    {"nifo_output": 2, "nifo_version": "0.9.0", "command": "nifo identify ...", "written": "2026-12-06T...",
     "pid": 4242, "complete": true, "note": "...",
     "entries": ["figures", "figures/a.png", "identify.json", ...],
     "content": {"figures/a.png": [20481, "<XXH3-128>"], "identify.json": [5120, "<XXH3-128>"], ...},
     "digest": "<XXH3-128 of the document without this key>"}

``entries`` lists every path nifo wrote (folders too), ``content`` each file's
size and content hash — or ``null`` for a file that was being written when the
folder's writer was cut short (``complete: false``: a ``nifo run`` killed by
SIGKILL keeps its marker up to date as it writes, :func:`nifo.io.atomic.claim`).
A folder is nifo's to replace when everything in it is listed and every listed
file still has the content nifo gave it (:func:`unowned` names the rest: files
nifo did not write, and files it wrote that were changed since — those are the
user's now). A sub-folder with its own marker answers for itself. A marker
whose digest does not match (edited, damaged, forged by hand) is no marker.

Format 1 (an older nifo: ``entries`` only, no sizes or hashes) is read but does
not answer for a folder: such a folder is recognised by its result documents
alone (:mod:`nifo.io.ownership`), so a copied or hand-written marker never
makes a user's file nifo's.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import shlex
import stat
import sys
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Iterable

import xxhash

from nifo_core import __version__

__all__ = ["MARKER", "INCOMPLETE", "LEFTOVER", "LOCK", "MARKER_FORMAT", "write_marker", "read_marker", "file_hash",
           "Unowned", "unowned_in_marked", "tree", "set_invocation", "command_line"]

#: the marker file of every output folder nifo writes
MARKER = ".nifo-output"
#: the marker file of a ``nifo run`` output that is being written (or was cut short by a kill)
INCOMPLETE = "INCOMPLETE"
#: leftovers of a killed writer beside an output (``.<name>.partial-<pid>-*``, ``.<name>.old-<pid>``)
LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?:partial|old)-(?P<pid>\d+)(?:-.*)?$")
#: the lock file of output ``<name>`` (:mod:`nifo.io.lock`), beside it
LOCK = re.compile(r"^\.(?P<name>.+)\.lock$")

#: the marker's format: 2 records each file's size and content hash and the document's own digest
MARKER_FORMAT = 2
_MAX_MARKER_BYTES = 16 << 20
_NOTE = ("nifo wrote this folder and may replace it; it refuses to replace a folder holding anything not listed "
         "here or a listed file whose content changed since")


@dataclass(frozen=True)
class Unowned:
    """An entry of an output folder that is not nifo's to replace: ``path`` relative to the folder; ``changed``:
    nifo wrote it, but its content has changed since (the user's now), else nifo never wrote it."""

    path: str
    changed: bool = False


def file_hash(p: str | os.PathLike) -> str:
    """XXH3-128 of a file's content (hex)."""
    h = xxhash.xxh3_128()
    with open(p, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def _digest(doc: dict) -> str:
    body = {k: v for k, v in doc.items() if k != "digest"}
    return xxhash.xxh3_128(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _marked(p: Path) -> bool:
    """Whether folder ``p`` answers for itself (a marker of this format)."""
    doc = read_marker(p)
    return doc is not None and doc.get("nifo_output") == MARKER_FORMAT


def tree(d: Path) -> list[str]:
    """Relative POSIX paths of every entry under ``d`` (folders too): the marker, INCOMPLETE, leftovers and lock
    files left out, and nothing below a sub-folder with its own marker (it answers for itself)."""
    out = []
    for root, dirs, files in os.walk(d):
        rel = Path(root).relative_to(d)
        keep = []
        for name in dirs:
            r = (rel / name).as_posix()
            if LEFTOVER.match(name):
                continue
            out.append(r)
            if not _marked(Path(root) / name):
                keep.append(name)
        dirs[:] = keep
        for name in files:
            r = (rel / name).as_posix()
            if r in (MARKER, INCOMPLETE) or LEFTOVER.match(name) or LOCK.match(name):
                continue
            out.append(r)
    return sorted(out)


def _with_parents(entries: Iterable[str]) -> list[str]:
    out = set()
    for e in entries:
        parts = PurePosixPath(e).parts
        for k in range(1, len(parts) + 1):
            out.add("/".join(parts[:k]))
    return sorted(out)


_invocation: list[str] = []


def set_invocation(argv: list[str]) -> None:
    """The command line the marker records (the ``nifo`` command sets it; else ``sys.argv``)."""
    _invocation[:] = ["nifo", *map(str, argv)]


def command_line() -> str:
    """The command line of this process as the marker and the output lock record it."""
    return shlex.join(_invocation or [Path(sys.argv[0]).name, *sys.argv[1:]])


def write_marker(d: str | os.PathLike, *, entries: Iterable[str] | None = None, complete: bool = True) -> Path:
    """Write ``d/.nifo-output`` (replacing it whole): ``entries`` (relative paths nifo wrote into ``d``; None:
    everything now in it, :func:`tree`) with each file's size and content hash; ``complete`` False while a run is
    still writing: then every file is ``null`` (being written; hashed once, when the folder is sealed)."""
    d = Path(d)
    listed = tree(d) if entries is None else _with_parents(entries)
    content: dict[str, list | None] = {}
    for r in listed:
        p = d / r
        try:
            st = p.lstat()
        except FileNotFoundError:
            content[r] = None
            continue
        if stat.S_ISREG(st.st_mode):
            content[r] = [int(st.st_size), file_hash(p)] if complete else None
    doc = {"nifo_output": MARKER_FORMAT, "nifo_version": __version__, "command": command_line(),
           "written": _dt.datetime.now().astimezone().isoformat(timespec="seconds"), "pid": os.getpid(),
           "complete": bool(complete), "note": _NOTE, "entries": listed, "content": content}
    doc["digest"] = _digest(doc)
    path = d / MARKER
    tmp = d / f".{MARKER}.partial-{os.getpid()}-w"   # replaced whole: a kill never leaves half a marker
    text = re.sub(r'\[\n\s+(\d+),\n\s+("[0-9a-f]+")\n\s+\]', r"[\1, \2]", json.dumps(doc, indent=1))
    tmp.write_text(text + "\n")
    os.replace(tmp, path)
    return path


def _rel_ok(r) -> bool:
    if not isinstance(r, str) or not r or "\x00" in r or r.startswith("/") or "\\" in r:
        return False
    return all(part not in ("", ".", "..") for part in r.split("/"))


def read_marker(d: str | os.PathLike) -> dict | None:
    """The marker document of folder ``d``, or None when it has no valid one (absent, unreadable, not nifo's, a
    digest that does not match, an entry that leaves the folder)."""
    p = Path(d) / MARKER
    try:
        st = p.lstat()
        if not stat.S_ISREG(st.st_mode) or st.st_size > _MAX_MARKER_BYTES:
            return None
        doc = json.loads(p.read_bytes())
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(doc, dict):
        return None
    entries = doc.get("entries")
    if doc.get("nifo_output") == 1:      # an older nifo's: read, but it answers for nothing (module docstring)
        return doc
    if doc.get("nifo_output") != MARKER_FORMAT or doc.get("digest") != _digest(doc):
        return None
    content = doc.get("content")
    if not (isinstance(entries, list) and all(map(_rel_ok, entries)) and isinstance(content, dict)):
        return None
    listed = set(entries)
    for r, c in content.items():
        if r not in listed or not (c is None or (isinstance(c, list) and len(c) == 2 and isinstance(c[0], int)
                                                and isinstance(c[1], str))):
            return None
    return doc


def _scan(d: Path) -> list[os.DirEntry]:
    return sorted(os.scandir(d), key=lambda e: e.name)


def _skipped(name: str, top: bool) -> bool:
    return (top and name in (MARKER, INCOMPLETE)) or bool(LEFTOVER.match(name)) or bool(LOCK.match(name))


def unowned_in_marked(d: Path, doc: dict, limit: int, *, contents: bool = True) -> list[Unowned]:
    """Entries of folder ``d``, marked with ``doc`` (:func:`read_marker`, this format), that are not nifo's to
    replace (at most ``limit``): not listed, or listed and changed since (``contents=False``: not read)."""
    listed, content = set(doc["entries"]), doc["content"]
    found: list[Unowned] = []

    def walk(cur: Path, rel: str) -> None:
        for e in _scan(cur):
            if len(found) >= limit:
                return
            r = rel + e.name
            if _skipped(e.name, not rel):
                continue
            if r not in listed or e.is_symlink():
                found.append(Unowned(r))
            elif e.is_dir():
                sub = read_marker(e.path)
                if sub is not None and sub.get("nifo_output") == MARKER_FORMAT:
                    found.extend(Unowned(f"{r}/{x.path}", x.changed)
                                 for x in unowned_in_marked(Path(e.path), sub, limit - len(found), contents=contents))
                else:
                    walk(Path(e.path), r + "/")
            elif not e.is_file(follow_symlinks=False):
                found.append(Unowned(r))
            elif contents and content.get(r) is not None and not _same_content(Path(e.path), content[r]):
                found.append(Unowned(r, changed=True))

    walk(d, "")
    return found


def _same_content(p: Path, recorded: list) -> bool:
    try:
        return p.stat().st_size == recorded[0] and file_hash(p) == recorded[1]
    except OSError:
        return False
