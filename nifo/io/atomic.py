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
    results by path: the old ``out`` is moved aside, the new one is written in
    place with an ``INCOMPLETE`` file in it; on success the marker and the old
    tree go, on an error or SIGINT/SIGTERM the new tree goes and the old one is
    put back. After a SIGKILL ``out`` holds the ``INCOMPLETE`` marker.

Shared rules (:func:`check_output`):

- nifo replaces only what it can tell it wrote (:mod:`nifo.io.ownership`):
  a folder carrying its ``.nifo-output`` marker and nothing beyond what the
  marker lists (or an empty one), a file with nifo's mark (an HTML report's
  generator <meta>, a bag whose metadata names nifo, ...). Anything else —
  a folder holding a user's files, a file nifo cannot tell it wrote, a path
  of the other kind, a FIFO or device — is refused with one line naming it
  and the fix: nothing a user keeps is ever deleted or overwritten;
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
import shutil
import stat
import tempfile
from pathlib import Path
from typing import Iterator

from nifo_core.errors import OutputError
from nifo.interrupt import signals_held, term_as_interrupt

from .ownership import INCOMPLETE, LEFTOVER as _LEFTOVER, MARKER, foreign_entries, nifo_bag_dir, nifo_wrote_file
from .ownership import why_not_nifos, write_marker

__all__ = ["staged_dir", "staged_file", "staged_run", "check_output", "clean_leftovers", "interrupt_note",
           "INCOMPLETE", "MARKER", "SCRATCH_CHARS"]

#: characters a scratch or aside name adds to an output's name: ``.<name>.partial-<pid>-XXXXXXXX``
#: (pid up to 7 digits); an output name must leave room for them within the file system's name limit
SCRATCH_CHARS = len(".") + len(".partial-") + 7 + len("-") + 8

#: what this process has committed, and what an interrupted run restored (for :func:`interrupt_note`)
_state: dict[str, list[str]] = {"committed": [], "restored": []}
#: the :func:`staged_run` folders being written (innermost last), each with the step folders written in place
_runs: list[tuple[Path, list[Path]]] = []

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


def check_output(final: str | os.PathLike, *, kind: str = "dir") -> Path:
    """Refuse an output path that would destroy something nifo did not write; returns it as a Path.

    ``kind="dir"``: ``final`` may be absent, an empty directory, or one nifo
    wrote (its ``.nifo-output`` marker lists everything in it; see
    :mod:`nifo.io.ownership`); ``kind="file"``: absent or a regular file nifo
    recognisably wrote; ``kind="bag"``: absent, a bag file nifo wrote, an
    empty directory or a rosbag2 bag directory nifo wrote. Raises
    :class:`OutputError` (one line naming the path and the fix).
    """
    final = Path(final)
    if kind not in ("dir", "file", "bag"):
        raise ValueError(f"{kind=}")
    _check_names(final)
    try:
        return _check_existing(final, kind)
    except OSError as err:
        raise output_error(err, final) from err


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
        foreign = foreign_entries(final)
        if foreign:
            raise OutputError(f"exists and holds files nifo did not write ({_listing(foreign)}); it is left "
                              "untouched", source=str(final), hint=_FIX_REFUSED)
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


def _listing(names: list[str]) -> str:
    shown = [n if len(n) <= 40 else n[:37] + "..." for n in names[:3]]
    return ", ".join(shown) + (", ..." if len(names) > 3 else "")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


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
        if m and m["name"] == final.name and not _alive(int(m["pid"])):
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
# the context managers
# -----------------------------------------------------------------------------

@contextlib.contextmanager
def staged_dir(out: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty scratch directory; on success it becomes ``out`` (replacing it atomically).

    Raises :class:`OutputError` when ``out`` is a regular file, a directory
    holding other files, under a regular file, or cannot be written (full
    disk, read-only, permissions) — then nothing at ``out`` changes.
    """
    final = check_output(out, kind="dir")
    run = _run_holding(final)
    if run is not None:     # a step of nifo run: the run is staged as a whole, its steps write in place
        with _in_run(final, run) as here:
            yield here
        return
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


def _run_holding(final: Path) -> list[Path] | None:
    """The folders written in place so far by the :func:`staged_run` this process is writing ``final`` into."""
    for run, written in reversed(_runs):
        if run in final.absolute().parents:
            return written
    return None


@contextlib.contextmanager
def _in_run(final: Path, written: list[Path]) -> Iterator[Path]:
    """``final`` itself, new, under a run's folder: nobody sees it before the run is complete (its ``INCOMPLETE``
    marker, all old or all new), so the step writes there and the run's figure helpers may still be writing its
    figures after the step (:func:`nifo.plots.writer.deferred_figures`); its marker is written again, listing
    them, when the run completes. On an error the folder goes, as a staged one would."""
    try:
        if final.exists():
            _remove(final)
        final.mkdir(parents=True)
        yield final
        write_marker(final)
        written.append(final)
    except BaseException as err:
        _remove(final)
        if _is_output_oserror(err):
            raise output_error(err, final) from err
        raise


@contextlib.contextmanager
def staged_file(path: str | os.PathLike, *, kind: str = "file") -> Iterator[Path]:
    """Yield a not-yet-existing scratch path beside ``path``; on success it is renamed to ``path``.

    ``kind="bag"`` allows a bag directory at ``path`` (see :func:`check_output`).
    """
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


@contextlib.contextmanager
def staged_run(out: str | os.PathLike) -> Iterator[Path]:
    """Yield ``out`` itself, new and empty but for an ``INCOMPLETE`` marker; see the module docstring.

    On success the marker and the previous content (kept aside as
    ``.<out>.old-<pid>``) are removed; on any exception, SIGINT or SIGTERM the
    new content is removed and the previous one restored.
    """
    final = check_output(out, kind="dir")
    with term_as_interrupt():
        old = final.with_name(f".{final.name}.old-{os.getpid()}")
        had_old = False
        try:
            final.parent.mkdir(parents=True, exist_ok=True)
            clean_leftovers(final)
            with signals_held():
                had_old = final.exists()
                if had_old:
                    os.replace(final, old)
                final.mkdir()
                write_marker(final, complete=False)
                (final / INCOMPLETE).write_text(
                    f"nifo run (process {os.getpid()}) is writing this directory, or was killed while it did: "
                    "its content is incomplete. Run nifo run again.\n")
        except OSError as err:
            with signals_held():
                if had_old and old.exists():
                    _remove(final)
                    os.replace(old, final)
            raise output_error(err, final) from err
        start = len(_state["committed"])
        entry: tuple[Path, list[Path]] = (final.absolute(), [])
        written = entry[1]
        _runs.append(entry)
        try:
            yield final
            with signals_held():
                for d in written:      # the steps' folders, with what was written after each step (its figures)
                    if d.is_dir():
                        write_marker(d)
                write_marker(final)
                (final / INCOMPLETE).unlink()
                _state["committed"][start:] = [str(final)]
        except BaseException as err:
            with signals_held():
                _remove(final)
                if had_old:
                    os.replace(old, final)
                    _state["restored"].append(str(final))
                del _state["committed"][start:]
            if _is_output_oserror(err):
                raise output_error(err, final) from err
            raise
        finally:
            _runs.remove(entry)     # by identity: another thread's run may have started since
        _remove(old)


def interrupt_note() -> str:
    """What an interrupted command left on disk, for its one-line message."""
    done, restored = _state["committed"], _state["restored"]
    if done:
        return "interrupted after writing " + ", ".join(done) + "; nothing else was written"
    if restored:
        return "interrupted; nothing was written (the earlier results in " + ", ".join(restored) + " were kept)"
    return "interrupted; nothing was written"
