"""Write outputs so that nothing is lost and nothing is half-written.

Every command that writes goes through one of three context managers:

``staged_dir(out)``
    An empty scratch directory ``.<out>.partial-<pid>-*`` beside ``out``; only
    when the block succeeds does it replace ``out``, by an atomic exchange
    (Linux ``renameat2(RENAME_EXCHANGE)``; elsewhere two renames with signals
    held). ``out`` is therefore always all old or all new.
``staged_file(path)``
    The same for one file (or a directory-shaped artefact such as a rosbag2 bag).
``staged_run(out)``
    For ``nifo run``, whose steps write sub-directories and read each other's
    results by path: the old ``out`` is moved aside (``.<out>.old-<pid>``), the
    new one is written in place with an ``INCOMPLETE`` file in it; on success
    the marker and the old tree go, on an error or SIGINT/SIGTERM the new tree
    goes and the old one is put back. After a SIGKILL ``out`` holds the
    ``INCOMPLETE`` marker and the old result is still beside it: the next
    ``nifo run`` into ``out`` puts it back before it starts, so a kill never
    leaves neither. Everything the run writes is :func:`claim`-ed in the marker
    as it is written, so a folder a kill left is still nifo's only where nifo
    wrote (a notebook saved into it afterwards is the user's).

One writer per output: each of the three holds the output's lock
(:mod:`nifo.io.lock`) while it writes, and the ``nifo`` command holds it for the
whole command; a second command on the same output is refused at once, naming
the process that writes it.

Shared rules (:func:`check_output`):

- nifo replaces only what it can tell it wrote (:mod:`nifo.io.ownership`):
  a folder carrying its ``.nifo-output`` marker and nothing beyond what the
  marker lists, each file with the content nifo gave it (or an empty
  folder), a file with nifo's mark (an HTML report's generator <meta>, a bag
  whose metadata names nifo, ...). Anything else — a folder holding a user's
  files or a file nifo wrote that was edited since, a file nifo cannot tell it
  wrote, a path of the other kind, a FIFO or device, a folder holding an input
  of the command — is refused with one line naming it and the fix: nothing a
  user keeps is ever deleted or overwritten;
- every folder :func:`staged_dir` / :func:`staged_run` writes gets the marker
  (the command, nifo's version, the time and the entries written);
- a name too long for the file system (with room for the scratch name) is
  refused before anything is written;
- leftovers of a killed run (``.<name>.partial-<pid>-*``, ``.<name>.old-<pid>``
  whose process is gone) are removed by the next writer of ``<name>``;
- a read-only file system, a full disk, a path under a regular file or a
  permission problem is one :class:`~nifo_core.errors.OutputError` naming the
  path and the fix, never a traceback;
- SIGTERM is turned into :class:`KeyboardInterrupt` while an output is staged,
  so a terminated command cleans up like an interrupted one.

:func:`interrupt_note` tells the command line what an interrupt left behind.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import re
import shutil
import stat
import tempfile
import threading
from pathlib import Path, PurePosixPath
from typing import Iterable, Iterator

from nifo_core.errors import OutputError
from nifo.interrupt import signals_held, term_as_interrupt

from .lock import alive, output_lock
from .marker import read_marker
from .ownership import INCOMPLETE, LEFTOVER as _LEFTOVER, MARKER, nifo_bag_dir, nifo_wrote_file, unowned
from .ownership import why_not_nifos, write_marker

__all__ = ["staged_dir", "staged_file", "staged_run", "check_output", "clean_leftovers", "interrupt_note", "claim",
           "INCOMPLETE", "MARKER", "SCRATCH_CHARS"]

#: characters a scratch or aside name adds to an output's name: ``.<name>.partial-<pid>-XXXXXXXX``
#: (pid up to 7 digits); an output name must leave room for them within the file system's name limit
SCRATCH_CHARS = len(".") + len(".partial-") + 7 + len("-") + 8

#: what this process has committed, and what an interrupted run restored (for :func:`interrupt_note`)
_state: dict[str, list[str]] = {"committed": [], "restored": [], "kept": []}
#: the :func:`staged_run` folders being written (innermost last), each with the step folders written in place
_runs: list["_Run"] = []
#: guards the claims of the folders written in place (steps run on threads)
_claims = threading.RLock()

_OUTPUT_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT, errno.ENOTDIR,
                  errno.EEXIST, errno.EFBIG, errno.EISDIR, errno.ENAMETOOLONG, errno.ELOOP, errno.ENOENT}


# -----------------------------------------------------------------------------
# errors
# -----------------------------------------------------------------------------

def _why(err: OSError) -> str:
    return {errno.ENOSPC: "the disk is full", errno.EDQUOT: "the disk quota is exceeded",
            errno.EROFS: "the file system is read-only", errno.EACCES: "permission denied",
            errno.EPERM: "permission denied", errno.ENOTDIR: "a part of the path is a regular file, not a directory",
            errno.EFBIG: "the file is too large for the file system",
            errno.ENAMETOOLONG: "the name is too long"}.get(err.errno, err.strerror or str(err))


def output_error(err: OSError, final: Path) -> OutputError:
    """One-line :class:`OutputError` for an OSError met while writing ``final``."""
    fix = {errno.ENOSPC: "free some space or write elsewhere (--out)",
           errno.EDQUOT: "free some space or write elsewhere (--out)",
           errno.ENOTDIR: "give an --out path whose parent directories are directories"}.get(
        err.errno, "write to a directory you can write to (--out)")
    return OutputError(f"cannot write the output ({_why(err)})", source=str(final), hint=fix)


# -----------------------------------------------------------------------------
# checks and leftovers
# -----------------------------------------------------------------------------

_FIX_REFUSED = "give another --out, or move or remove it yourself if it may go"


def _what(mode: int) -> str:
    """What a non-directory path is, in words."""
    return ("a regular file" if stat.S_ISREG(mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(mode)
            else "a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")


def _name_max(final: Path) -> int:
    for parent in (final, *final.parents):
        try:
            return int(os.pathconf(parent, "PC_NAME_MAX"))
        except (OSError, ValueError):
            continue
    return 255


def _check_names(final: Path) -> None:
    """Refuse a path with a component longer than the file system holds (ENAMETOOLONG), before any work."""
    limit = _name_max(final)
    parts = [p for p in final.parts if p not in ("/", "")]
    for i, part in enumerate(parts):
        n = len(os.fsencode(part))
        last = i == len(parts) - 1
        room = limit - SCRATCH_CHARS if last else limit
        if n > room:
            shown = part if len(part) <= 24 else part[:20] + "..."
            why = (f"at most {room} fit (the file system holds {limit}, and nifo first writes the output under "
                   f"a scratch name {SCRATCH_CHARS} characters longer)" if last else
                   f"the file system holds at most {limit}")
            raise OutputError(f"the name {shown!r} is {n} bytes long; {why}", source=str(final),
                              hint=f"give an --out path whose names are at most {room} characters")
    if len(os.fsencode(str(final.absolute()))) + SCRATCH_CHARS > 4000:
        raise OutputError("the path is too long for the file system", source=str(final),
                          hint="give a shorter --out path")


def check_output(final: str | os.PathLike, *, kind: str = "dir",
                 reads: Iterable[str | os.PathLike | None] = ()) -> Path:
    """Refuse an output path that would destroy something nifo did not write; returns it as a Path.

    ``kind="dir"``: ``final`` may be absent, an empty directory, or one nifo
    wrote (its ``.nifo-output`` marker lists everything in it, each file with
    the content nifo gave it; see :mod:`nifo.io.ownership`); ``kind="file"``:
    absent or a regular file nifo recognisably wrote; ``kind="bag"``: absent, a
    bag file nifo wrote, an empty directory or a rosbag2 bag directory nifo
    wrote. ``reads``: the command's inputs (data files, its model), none of
    which may be the output or lie inside it (``nifo predict --model DIR --out
    DIR`` would replace the model it reads). Raises :class:`OutputError` (one
    line naming the path and the fix).
    """
    final = Path(final)
    if kind not in ("dir", "file", "bag"):
        raise ValueError(f"{kind=}")
    _check_names(final)
    try:
        _check_reads(final, reads)
        return _check_existing(final, kind)
    except OSError as err:
        raise output_error(err, final) from err


def _check_reads(final: Path, reads: Iterable[str | os.PathLike | None]) -> None:
    """Refuse an output that is, or holds, one of the command's inputs."""
    if not (final.exists() or final.is_symlink()):
        return
    here = final.resolve()
    for r in reads:
        if r is None or str(r) == "":
            continue
        try:
            q = Path(r).resolve()
        except (OSError, RuntimeError):
            continue
        if q == here or here in q.parents:
            what = f"is what this command reads ({r})" if q == here else f"holds {r}, which this command reads"
            raise OutputError(f"{what}: writing the output there would replace it",
                              source=str(final), hint="give another --out (one that holds none of the command's "
                                                      "inputs)")


def _check_existing(final: Path, kind: str) -> Path:
    if not (final.exists() or final.is_symlink()):
        for parent in final.parents:   # a path under a regular file
            if parent.exists():
                if not parent.is_dir():
                    raise OutputError(f"{parent} is {_what(parent.stat().st_mode)}, not a directory",
                                      source=str(final),
                                      hint="give an output path whose parent directories are directories")
                break
        return final
    if final.is_symlink():
        raise OutputError(f"is a symbolic link (to {os.readlink(final)}); it is left untouched", source=str(final),
                          hint="give the real path for the output")
    mode = final.stat().st_mode
    if stat.S_ISDIR(mode):
        if kind == "file":
            raise OutputError("is a directory; a file was to be written there", source=str(final),
                              hint="give a file name (or remove the directory yourself)")
        if kind == "bag":
            if any(final.iterdir()) and not nifo_bag_dir(final):
                names = sorted(p.name for p in final.iterdir())
                raise OutputError(f"exists and is not a bag nifo wrote (it holds {_listing(names)}); it is left "
                                  "untouched", source=str(final), hint=_FIX_REFUSED)
            return final
        problems = unowned(final, limit=4)
        if problems:
            raise _not_nifos(final, problems)
        return final
    if kind == "dir":
        raise OutputError(f"exists and is {_what(mode)}, not a directory; it is left untouched", source=str(final),
                          hint="give a directory name for --out" + (" (or move the file away)"
                                                                     if stat.S_ISREG(mode) else ""))
    if not stat.S_ISREG(mode):
        raise OutputError(f"exists and is {_what(mode)}, not a regular file; it is left untouched",
                          source=str(final), hint="give the path of a new or regular file")
    if not nifo_wrote_file(final):
        raise OutputError(f"exists and nifo cannot tell it wrote this file ({why_not_nifos(final)}); it is left "
                          "untouched", source=str(final), hint=_FIX_REFUSED)
    return final


def _not_nifos(final: Path, problems) -> OutputError:
    """The refusal of a folder holding what nifo may not replace: files it did not write, files it wrote that were
    changed since (the user's now)."""
    foreign = [u.path for u in problems if not u.changed]
    changed = [u.path for u in problems if u.changed]
    parts = []
    if foreign:
        parts.append(f"holds files nifo did not write ({_listing(foreign)})")
    if changed:
        parts.append(f"holds files nifo wrote that were changed since ({_listing(changed)}: yours now)")
    killed = " a nifo run was cut short there and it" if (final / INCOMPLETE).is_file() else ""
    text = f"exists and{killed} " + " and ".join(parts) + "; it is left untouched"
    hint = ("give another --out, or move those files out of it (nifo then replaces only what it wrote)"
            if len(problems) < 4 or read_marker(final) is not None else _FIX_REFUSED)
    return OutputError(text, source=str(final), hint=hint)


def _listing(names: list[str]) -> str:
    shown = [n if len(n) <= 40 else n[:37] + "..." for n in names[:3]]
    return ", ".join(shown) + (", ..." if len(names) > 3 else "")


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def clean_leftovers(final: str | os.PathLike) -> list[Path]:
    """Remove ``.<name>.partial-<pid>-*`` / ``.<name>.old-<pid>`` beside ``final`` whose process is gone.

    Also removes ``INCOMPLETE`` leftovers' old trees; returns what was removed.
    """
    final = Path(final)
    removed = []
    try:
        entries = list(final.parent.iterdir())
    except OSError:
        return removed
    for p in entries:
        m = _LEFTOVER.match(p.name)
        if m and m["name"] == final.name and not alive(int(m["pid"])):
            _remove(p)
            removed.append(p)
    return removed


# -----------------------------------------------------------------------------
# signals and the atomic swap
# -----------------------------------------------------------------------------

_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap ``a`` and ``b`` (both exist); False when the system cannot."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    e = ctypes.get_errno()
    if e in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(e, os.strerror(e), str(b))


def _commit(tmp: Path, final: Path) -> None:
    """Put ``tmp`` at ``final``; the old ``final`` (if any) is removed afterwards."""
    claim(final)     # inside a run written in place: the run's marker lists it before it is there
    with signals_held():
        if final.exists() or final.is_symlink():
            if _exchange(tmp, final):
                old = tmp          # tmp now holds the old content
            else:
                old = final.with_name(f".{final.name}.old-{os.getpid()}")
                _remove(old)
                os.replace(final, old)
                os.replace(tmp, final)
        else:
            old = None
            os.replace(tmp, final)
        _state["committed"].append(str(final))
    if old is not None:
        _remove(old)


def _scratch(final: Path) -> Path:
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        clean_leftovers(final)
        tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.partial-{os.getpid()}-", dir=final.parent))
    except OSError as err:
        raise output_error(err, final) from err
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # mkdtemp makes 0700; results are ordinary directories
    return tmp


def _is_output_oserror(err: BaseException) -> bool:
    return isinstance(err, OSError) and err.errno in _OUTPUT_ERRNOS and not isinstance(err, FileNotFoundError)


# -----------------------------------------------------------------------------
# folders written in place (nifo run): what was written, claimed as it is written
# -----------------------------------------------------------------------------

class _InPlace:
    """A folder written in place — a run's, or a step's inside it — and the entries claimed in it so far; its marker
    (``complete: false`` until sealed) lists them, so a kill leaves a folder that is nifo's only where nifo wrote."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.entries: set[str] = set()

    def claim(self, rel: str) -> None:
        if rel not in self.entries:
            self.entries.add(rel)
            self.mark()

    def mark(self) -> None:
        write_marker(self.path, entries=self.entries, complete=False)

    def seal(self) -> None:
        write_marker(self.path, entries=self.entries, complete=True)


class _Run(_InPlace):
    """A :func:`staged_run` being written, and its steps' folders written in place (innermost last)."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.steps: list[_InPlace] = []


def claim(path: str | os.PathLike) -> None:
    """Record that nifo is about to write ``path``, when it lies in a folder a :func:`staged_run` of this process
    writes in place (elsewhere nothing: a scratch folder is listed whole when it is committed). Every writer of a
    step calls it before it creates a file (:func:`nifo.io.results.write_json`, the figures, the signal tables,
    :func:`staged_file`), so the folder's marker always lists what nifo wrote."""
    p = Path(path).absolute()
    with _claims:
        for run in reversed(_runs):
            if run.path not in p.parents:
                continue
            for folder in (*reversed(run.steps), run):
                if folder.path in p.parents:
                    folder.claim(PurePosixPath(*p.relative_to(folder.path).parts).as_posix())
                    return


def _run_holding(final: Path) -> _Run | None:
    """The :func:`staged_run` of this process that ``final`` lies in, if any."""
    for run in reversed(_runs):
        if run.path in final.absolute().parents:
            return run
    return None


# -----------------------------------------------------------------------------
# the context managers
# -----------------------------------------------------------------------------

@contextlib.contextmanager
def staged_dir(out: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty scratch directory; on success it becomes ``out`` (replacing it atomically).

    Raises :class:`OutputError` when ``out`` is a regular file, a directory
    holding other files, under a regular file, or cannot be written (full
    disk, read-only, permissions) — then nothing at ``out`` changes; and
    :class:`~nifo_core.errors.OutputBusyError` when another process writes it.
    """
    run = _run_holding(Path(out))
    if run is not None:     # a step of nifo run: the run is staged (and locked) as a whole, its steps write in place
        final = check_output(out, kind="dir")
        with _in_run(final, run) as here:
            yield here
        return
    with output_lock(out):
        final = check_output(out, kind="dir")
        with term_as_interrupt():
            tmp = _scratch(final)
            try:
                yield tmp
                write_marker(tmp)
                _commit(tmp, final)
            except BaseException as err:
                _remove(tmp)
                if _is_output_oserror(err):
                    raise output_error(err, final) from err
                raise


@contextlib.contextmanager
def _in_run(final: Path, run: _Run) -> Iterator[Path]:
    """``final`` itself, new, under a run's folder: nobody sees it before the run is complete (its ``INCOMPLETE``
    marker, all old or all new), so the step writes there and the run's figure helpers may still be writing its
    figures after the step (:func:`nifo.plots.writer.deferred_figures`); its marker lists what was claimed in it,
    the figures still rendering included, and is sealed again with their hashes when the run completes. On an
    error the folder goes, as a staged one would."""
    step = _InPlace(final.absolute())
    try:
        with _claims:
            claim(final)
            if final.exists():
                _remove(final)
            final.mkdir(parents=True)
            step.mark()      # the folder is marked (in progress) from its first moment
            run.steps.append(step)
        yield final
        with _claims:
            step.seal()
    except BaseException as err:
        with _claims:
            if step in run.steps:
                run.steps.remove(step)
        _remove(final)
        if _is_output_oserror(err):
            raise output_error(err, final) from err
        raise


@contextlib.contextmanager
def staged_file(path: str | os.PathLike, *, kind: str = "file") -> Iterator[Path]:
    """Yield a not-yet-existing scratch path beside ``path``; on success it is renamed to ``path``.

    ``kind="bag"`` allows a bag directory at ``path`` (see :func:`check_output`).
    """
    in_run = _run_holding(Path(path)) is not None
    with contextlib.nullcontext() if in_run else output_lock(path):
        final = check_output(path, kind=kind)
        with term_as_interrupt():
            tmpdir = _scratch(final)
            tmp = tmpdir / final.name
            try:
                yield tmp
                if not tmp.exists():
                    raise FileNotFoundError(f"staged output {tmp} was not written")
                _commit(tmp, final)
            except BaseException as err:
                if _is_output_oserror(err):
                    raise output_error(err, final) from err
                raise
            finally:
                _remove(tmpdir)


def _writer_pid(final: Path) -> int | None:
    """The process that wrote run folder ``final`` (its marker, or an older nifo's INCOMPLETE line)."""
    doc = read_marker(final)
    if doc is not None and isinstance(doc.get("pid"), int):
        return doc["pid"]
    try:
        m = re.search(r"\(process (\d+)\)", (final / INCOMPLETE).read_text()[:500])
    except OSError:
        return None
    return int(m[1]) if m else None


def _put_back_old(final: Path) -> bool:
    """A run cut short by a kill left ``final`` incomplete and its previous result beside it
    (``.<final>.old-<pid>``): put that back (``final`` holds only what the killed run wrote: checked before).
    Only under the output's lock, so the run that left it is not running."""
    if not (final / INCOMPLETE).is_file():
        return False
    pid = _writer_pid(final)
    old = final.with_name(f".{final.name}.old-{pid}") if pid else None
    if old is None or pid == os.getpid() or alive(pid) or not old.is_dir() or old.is_symlink():
        return False
    with signals_held():
        _remove(final)
        os.replace(old, final)
    return True


def _incomplete_note(old: Path | None) -> str:
    kept = (f" The previous result is kept beside it, in {old.name}, until the next run, which puts it back before "
            "it starts if this one did not finish.") if old is not None else ""
    return (f"nifo run (process {os.getpid()}) is writing this directory, or was killed while it did: its content "
            f"is incomplete. Run nifo run again.{kept}\n")


@contextlib.contextmanager
def staged_run(out: str | os.PathLike) -> Iterator[Path]:
    """Yield ``out`` itself, new and empty but for an ``INCOMPLETE`` marker; see the module docstring.

    On success the marker and the previous content (kept aside as
    ``.<out>.old-<pid>``) are removed; on any exception, SIGINT or SIGTERM the
    new content is removed and the previous one restored.
    """
    with output_lock(out):
        final = check_output(out, kind="dir")
        with term_as_interrupt():
            yield from _run_in_place(final)


def _run_in_place(final: Path) -> Iterator[Path]:
    old = final.with_name(f".{final.name}.old-{os.getpid()}")
    had_old = False
    run = _Run(final.absolute())
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        _put_back_old(final)
        clean_leftovers(final)
        with signals_held():
            had_old = final.exists()
            if had_old:
                os.replace(final, old)
            final.mkdir()
            run.mark()
            (final / INCOMPLETE).write_text(_incomplete_note(old if had_old else None))
    except OSError as err:
        with signals_held():
            if had_old and old.exists():
                _remove(final)
                os.replace(old, final)
        raise output_error(err, final) from err
    start = len(_state["committed"])
    with _claims:
        _runs.append(run)
    try:
        yield final
        with signals_held(), _claims:
            for step in run.steps:      # the steps' folders, their figures rendered since each step ended included
                if step.path.is_dir():
                    step.seal()
            if not (final / INCOMPLETE).is_file():
                raise FileNotFoundError(errno.ENOENT, "the run's folder is gone", str(final / INCOMPLETE))
            run.seal()
            (final / INCOMPLETE).unlink()
            _state["committed"][start:] = [str(final)]
    except BaseException as err:
        gone = isinstance(err, FileNotFoundError) and not (final / INCOMPLETE).is_file()
        with signals_held():
            _drop_new(final)
            if had_old and old.is_dir():
                os.replace(old, final)
                _state["restored"].append(str(final))
            del _state["committed"][start:]
        if gone:      # something else removed the folder while the run wrote into it: not a bug of nifo's
            raise OutputError("the output folder was removed or replaced while nifo run wrote it", source=str(final),
                              hint="run again, and leave the folder to nifo until it is done") from err
        if _is_output_oserror(err):
            raise output_error(err, final) from err
        raise
    finally:
        with _claims:
            _runs.remove(run)     # by identity: another thread's run may have started since
    _remove(old)


def _drop_new(final: Path) -> None:
    """A failed run's new folder goes — unless something nifo did not claim was put into it while it ran (a user's
    file): then the folder is kept whole beside, as ``<final>.kept-<pid>``, with what nifo wrote listed in its
    marker, rather than deleted with it."""
    try:
        mine = final.is_dir() and bool(unowned(final, contents=False))     # an interrupt waits for no hashing
    except OSError:
        mine = False
    if not mine:
        _remove(final)
        return
    kept = final.with_name(f"{final.name}.kept-{os.getpid()}")
    os.replace(final, kept)
    _state["kept"].append(str(kept))


def interrupt_note() -> str:
    """What an interrupted command left on disk, for its one-line message."""
    done, restored, kept = _state["committed"], _state["restored"], _state.get("kept", [])
    also = ("; files put into the new folder while it was written are kept in " + ", ".join(kept)) if kept else ""
    if done:
        return "interrupted after writing " + ", ".join(done) + "; nothing else was written" + also
    if restored:
        return ("interrupted; nothing was written (the earlier results in " + ", ".join(restored) + " were kept)"
                + also)
    return "interrupted; nothing was written" + also
