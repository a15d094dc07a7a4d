"""Whether nifo wrote a path: the output marker, and recognising nifo's own files and bags.

nifo replaces an existing output only when it can tell that it wrote it;
whatever it cannot tell is refused (:mod:`nifo.io.atomic`), so nothing a user
keeps is ever deleted or overwritten.

Folders
    Every output folder nifo creates carries the marker ``.nifo-output``
    (:mod:`nifo.io.marker`): what nifo wrote, each file with its size and
    content hash. A folder is nifo's to replace when it is empty, or when
    everything in it is listed there with the content nifo gave it (a
    sub-folder with its own marker answers for itself; a ``nifo run`` cut
    short by a kill keeps its marker up to date as it writes); :func:`unowned`
    names the rest. Result folders of a nifo from before the marker are
    recognised only exactly (:func:`_legacy_result`): one result document nifo
    writes (``identify.json`` with ``nifo_identify: 1``, ...) and no entry but
    the files that document and its command name; a ``nifo run`` folder only
    when every sub-folder is one of those.
Files
    An HTML report with nifo's ``<meta name="generator" content="nifo ...">``;
    a JSON document with one of nifo's own keys (``nifo_truth``,
    ``nifo_identified_model``, ``nifo_version``, ...); a YAML model file whose
    first line is ``# written by nifo ...``; an identifier node's ``.npz``
    checkpoint; an MCAP file whose rosbag2 metadata names
    ``generator: nifo ...``; a bag folder holding only its ``metadata.yaml``
    (naming nifo) and the MCAP files it lists; a Rerun recording whose
    application id is nifo's; a MAT file with a ``nifo_writer`` key. CSV
    tables (which carry no writer's mark) and anything else are never
    recognised.
"""

from __future__ import annotations

import json
import os
import re
import stat
from pathlib import Path

from .marker import INCOMPLETE, LEFTOVER, LOCK, MARKER, MARKER_FORMAT, Unowned, command_line, read_marker
from .marker import set_invocation, unowned_in_marked, write_marker

__all__ = ["MARKER", "INCOMPLETE", "LEFTOVER", "LOCK", "set_invocation", "command_line", "write_marker", "read_marker",
           "foreign_entries", "unowned", "Unowned", "nifo_wrote_file", "why_not_nifos", "nifo_bag_dir",
           "GENERATOR_META", "MAT_WRITER_KEY", "YAML_MARK_PREFIX"]

#: what an HTML page nifo writes carries in its <head> (``{version}`` filled in)
GENERATOR_META = '<meta name="generator" content="nifo {version}">'

_MAX_MARKER_BYTES = 4 << 20
_MAX_JSON_BYTES = 64 << 20
_NIFO_JSON_KEYS = frozenset({"nifo_output", "nifo_truth", "nifo_identified_model", "nifo_identify", "nifo_predict",
                             "nifo_characterize", "nifo_fleet"})
_GENERATOR = re.compile(rb'<meta\s+name="generator"\s+content="nifo[ "]')
_RRD_APP_ID = b"\n\x04nifo"   # protobuf: StoreInfo.application_id = "nifo" (nifo.viz.rerun_log.APP_ID)


def _scan(d: Path) -> list[os.DirEntry]:
    return sorted(os.scandir(d), key=lambda e: e.name)


def unowned(d: str | os.PathLike, *, limit: int = 3, contents: bool = True) -> list[Unowned]:
    """Entries of folder ``d`` that are not nifo's to replace (at most ``limit``): what it did not write, and what
    it wrote that was changed since (:mod:`nifo.io.marker`; ``contents=False``: what it did not write only, no file
    read); ``[]``: nifo may replace ``d``."""
    d = Path(d)
    entries = [e for e in _scan(d) if not (LEFTOVER.match(e.name) or LOCK.match(e.name))]
    if not entries:
        return []
    doc = _marker(d)
    if doc is not None:
        return unowned_in_marked(d, doc, limit, contents=contents)
    # an old nifo result (none, or an older nifo's marker, which lists no contents: recognised by its result
    # documents alone, so a copied or hand-written marker never makes a user's file nifo's): name what is extra
    for recognise in (_legacy_unexpected, _legacy_run_unexpected):
        kind, unexpected = recognise(d)
        if kind is not None:
            return [Unowned(x) for x in unexpected[:limit]]
    return [Unowned(e.name) for e in entries][:limit]


def _marker(d: Path) -> dict | None:
    """The marker of folder ``d`` when it is one that answers for the folder (this format: sizes, hashes, digest)."""
    doc = read_marker(d)
    return doc if doc is not None and doc.get("nifo_output") == MARKER_FORMAT else None


def foreign_entries(d: str | os.PathLike, *, limit: int = 3) -> list[str]:
    """The paths of :func:`unowned` (``[]``: nifo may replace ``d``)."""
    return [u.path for u in unowned(d, limit=limit)]


# -----------------------------------------------------------------------------
# result folders of a nifo from before the marker: recognised exactly, or not at all
# -----------------------------------------------------------------------------

#: result document -> (its nifo key, the other files its command writes by fixed name)
_LEGACY = {"characterize.json": ("nifo_characterize", {"suggested_model.yaml"}),
           "identify.json": ("nifo_identify", {"model.json"}),
           "predict.json": ("nifo_predict", set()),
           "loop.json": (None, {"model.json", "refined_model.yaml"})}
#: what ``nifo run`` writes into its --out
_RUN_DIRS = {"characterize", "characterize_levels", "identify", "predict", "loop", "report", "recording"}


def _small_json(p: Path):
    try:
        st = p.lstat()
        if not stat.S_ISREG(st.st_mode) or st.st_size > _MAX_JSON_BYTES:
            return None
        return json.loads(p.read_bytes())
    except (OSError, ValueError, RecursionError):
        return None


def _figure_names(doc, depth: int = 0) -> set[str]:
    """Every name in a ``figures`` or ``signals`` list anywhere in a result document (predict lists them per
    record)."""
    out: set[str] = set()
    if depth > 4:
        return out
    if isinstance(doc, dict):
        for k, v in doc.items():
            if k in ("figures", "signals") and isinstance(v, list):
                out |= {f for f in v if isinstance(f, str) and "/" not in f}
            elif isinstance(v, (dict, list)):
                out |= _figure_names(v, depth + 1)
    elif isinstance(doc, list):
        for v in doc[:10_000]:
            out |= _figure_names(v, depth + 1)
    return out


def _legacy_unexpected(d: Path) -> tuple[str | None, list[str]]:
    """(kind, entries beyond what it wrote) of an old nifo result folder (no marker, or an older nifo's); (None,
    []): not one. A folder with this nifo's marker is "marked": its marker names what is not nifo's."""
    doc = _marker(d)
    if doc is not None:
        return "marked", [u.path for u in unowned_in_marked(d, doc, 3)]
    names = {e.name: e for e in _scan(d) if e.name != MARKER and not LEFTOVER.match(e.name)}
    docs = [n for n in _LEGACY if n in names]
    if len(docs) != 1:
        return None, []
    name = docs[0]
    key, fixed = _LEGACY[name]
    doc = _small_json(d / name)
    if not isinstance(doc, dict) or not (doc.get(key) == 1 if key else isinstance(doc.get("nifo_version"), str)):
        return None, []
    figures = _figure_names(doc)
    vectors = {str(Path(f).with_suffix(".svg")) for f in figures if f.endswith(".png")}   # nifo.plots.save_figure
    allowed = {name, *fixed, *figures, *vectors}
    unexpected = [n for n, e in names.items() if n not in allowed or e.is_symlink() or not e.is_file()]
    marked_ns = _older_marker_ns(d)     # an older nifo's marker, written after its files: a file newer is edited
    if marked_ns is not None:
        unexpected += [n for n, e in names.items() if n not in unexpected and e.stat().st_mtime_ns > marked_ns]
    return name.removesuffix(".json"), unexpected


def _older_marker_ns(d: Path) -> int | None:
    """The modification time of an older nifo's marker in ``d`` (format 1), if there is one."""
    doc = read_marker(d)
    if doc is None or doc.get("nifo_output") != 1:
        return None
    try:
        return (d / MARKER).stat().st_mtime_ns
    except OSError:
        return None


def _legacy_result(d: Path) -> str | None:
    """The kind of an old nifo result folder ``d`` (no marker), recognised exactly; else None."""
    kind, unexpected = _legacy_unexpected(d)
    return kind if kind is not None and not unexpected else None


def _legacy_run(d: Path) -> bool:
    """An old ``nifo run`` folder: only its sub-folders, each an old (or marked) result of the right kind."""
    kind, unexpected = _legacy_run_unexpected(d)
    return kind is not None and not unexpected


def _legacy_run_unexpected(d: Path) -> tuple[str | None, list[str]]:
    """("run", entries beyond what it wrote) of an old ``nifo run`` folder; (None, []): not one."""
    names = {e.name: e for e in _scan(d) if not LEFTOVER.match(e.name) and e.name != MARKER}
    incomplete = names.pop(INCOMPLETE, None)
    if incomplete is not None:
        if not _head(Path(incomplete.path), 64).startswith(b"nifo run (process "):
            return None, []
    elif "characterize" not in names or _legacy_result(Path(names["characterize"].path)) not in ("characterize",
                                                                                               "marked"):
        return None, []
    unexpected = [n for n in names if n not in _RUN_DIRS]
    for n, e in names.items():
        if n not in _RUN_DIRS:
            continue
        if e.is_symlink() or not e.is_dir():
            unexpected.append(n)
            continue
        p = Path(e.path)
        if n in ("characterize", "identify", "predict", "loop"):
            kind, extra = _legacy_unexpected(p)
            if kind not in (n, "marked"):
                unexpected.append(n)
            unexpected += [f"{n}/{x}" for x in extra]
        elif n == "characterize_levels":
            for sub in _scan(p):
                if sub.name in ("lowest", "highest") and sub.is_dir() and not sub.is_symlink():
                    if _legacy_result(Path(sub.path)) not in ("characterize", "marked"):
                        unexpected.append(f"{n}/{sub.name}")
                elif sub.name == "two_step_model.yaml" and sub.is_file() and not sub.is_symlink():
                    if b"suggested_by: nifo run" not in _head(Path(sub.path), 1 << 16):
                        unexpected.append(f"{n}/{sub.name}")
                elif not LEFTOVER.match(sub.name):
                    unexpected.append(f"{n}/{sub.name}")
        else:   # report/report.html, recording/nifo.rrd
            want = {"report": "report.html", "recording": "nifo.rrd"}[n]
            for s_ in _scan(p):
                if LEFTOVER.match(s_.name):
                    continue
                ok = s_.name == want and not s_.is_symlink() and s_.is_file() and (
                    nifo_wrote_file(Path(s_.path)) if n == "recording" else _old_report(Path(s_.path)))
                if not ok:
                    unexpected.append(f"{n}/{s_.name}")
    return "run", unexpected


def _old_report(p: Path) -> bool:
    """A report an older nifo wrote inside its run folder (before the generator <meta>)."""
    head = _head(p, 4096)
    return nifo_wrote_file(p) or (head.lstrip().lower().startswith(b"<!doctype html") and b"<title>nifo" in head)


# -----------------------------------------------------------------------------
# single files and bag folders
# -----------------------------------------------------------------------------

def _head(p: Path, n: int) -> bytes:
    try:
        with open(p, "rb") as f:
            return f.read(n)
    except OSError:
        return b""


def _mcap_generator(p: Path) -> str | None:
    """``custom_data.generator`` of the rosbag2 metadata inside MCAP file ``p`` (None if absent or unreadable)."""
    import yaml

    from .mcap_chunks import check_structure

    try:
        check_structure(p)   # lengths and offsets sane before a reader trusts them
        from mcap.reader import make_reader

        with open(p, "rb") as f:
            for m in make_reader(f).iter_metadata():
                if m.name == "rosbag2":
                    doc = yaml.safe_load(m.metadata.get("serialized_metadata", ""))
                    gen = (doc or {}).get("custom_data", {}).get("generator")
                    return gen if isinstance(gen, str) else None
    except Exception:  # noqa: BLE001 - anything unreadable is simply not recognised as nifo's
        return None
    return None


def why_not_nifos(p: str | os.PathLike) -> str:
    """Why nifo cannot tell it wrote file ``p`` (for the refusal's message)."""
    suffix = Path(p).suffix.lower()
    return {".html": 'it has no <meta name="generator" content="nifo ..."> tag',
            ".htm": 'it has no <meta name="generator" content="nifo ..."> tag',
            ".json": "it holds none of nifo's document keys",
            ".yaml": f"its first line is not '{YAML_MARK_PREFIX}...'",
            ".yml": f"its first line is not '{YAML_MARK_PREFIX}...'",
            ".npz": "it is not a nifo identifier checkpoint",
            ".mcap": "its rosbag2 metadata does not name nifo as the generator",
            ".rrd": "it is not a Rerun recording of nifo's",
            ".mat": "it holds no nifo_writer key",
            ".csv": "a CSV table carries no mark of its writer", ".tsv": "a table carries no mark of its writer",
            ".txt": "a text table carries no mark of its writer"}.get(suffix, "nifo writes no such file")


def nifo_wrote_file(p: str | os.PathLike) -> bool:
    """Whether regular file ``p`` is recognisably one nifo wrote (module docstring); False when unsure."""
    p = Path(p)
    try:
        if not stat.S_ISREG(p.lstat().st_mode):
            return False
    except OSError:
        return False
    suffix = p.suffix.lower()
    if suffix in (".html", ".htm"):
        return _GENERATOR.search(_head(p, 1 << 16)) is not None
    if suffix == ".json":
        doc = _small_json(p)
        return isinstance(doc, dict) and (bool(_NIFO_JSON_KEYS & doc.keys())
                                          or isinstance(doc.get("nifo_version"), str))
    if suffix in (".yaml", ".yml"):
        return _head(p, 256).startswith(YAML_MARK_PREFIX.encode())
    if suffix == ".npz":
        return _npz_checkpoint(p)
    if suffix == ".mcap":
        return (_mcap_generator(p) or "").startswith("nifo ")
    if suffix == ".rrd":
        head = _head(p, 1 << 13)
        return head.startswith(b"RRF") and _RRD_APP_ID in head
    if suffix == ".mat":
        return _mat_writer(p).startswith("nifo ")
    return False


#: the first line of a YAML file nifo writes (``nifo.io.modelfile.write_model_spec``)
YAML_MARK_PREFIX = "# written by nifo "


def _npz_checkpoint(p: Path) -> bool:
    """An identifier node's checkpoint (``nifo_nodes.identifier.save_checkpoint``): its own member names."""
    import zipfile

    try:
        with zipfile.ZipFile(p) as z:
            names = set(z.namelist())
    except (OSError, zipfile.BadZipFile, ValueError):
        return False
    return {"node.version.npy", "node.next_ns.npy"} <= names


#: the key of a MAT file nifo writes that names it (``nifo.io.matfile.write_mat``)
MAT_WRITER_KEY = "nifo_writer"


def _mat_writer(p: Path) -> str:
    """The ``nifo_writer`` string of a MAT file ('' when absent or unreadable)."""
    try:
        import scipy.io

        if not any(name == MAT_WRITER_KEY for name, _, _ in scipy.io.whosmat(str(p))):
            return ""
        v = scipy.io.loadmat(str(p), variable_names=[MAT_WRITER_KEY])[MAT_WRITER_KEY]
        return str(v.ravel()[0]) if v.size else ""
    except Exception:  # noqa: BLE001 - unreadable: not recognised
        return ""


def nifo_bag_dir(d: str | os.PathLike) -> bool:
    """Whether folder ``d`` is a rosbag2 bag nifo wrote: metadata.yaml naming nifo and only the MCAP files it lists."""
    import yaml

    d = Path(d)
    meta = d / "metadata.yaml"
    try:
        if not stat.S_ISREG(meta.lstat().st_mode) or meta.stat().st_size > _MAX_MARKER_BYTES:
            return False
        info = yaml.safe_load(meta.read_bytes())["rosbag2_bagfile_information"]
        gen = info.get("custom_data", {}).get("generator")
        files = [Path(f).name for f in info.get("relative_file_paths") or []]
    except Exception:  # noqa: BLE001 - unreadable metadata: not recognised
        return False
    if not (isinstance(gen, str) and gen.startswith("nifo ")) or not files:
        return False
    present = {e.name for e in _scan(d) if not LEFTOVER.match(e.name)}
    return present == {"metadata.yaml", *files} and all(nifo_wrote_file(d / f) for f in files)
