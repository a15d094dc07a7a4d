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

- an existing path of the other kind (a regular file where a directory is to
  be written, a directory where a file is) is refused, as is an existing
  directory that does not look like nifo output (it holds data or other
  files): nothing a user keeps there is ever deleted;
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
import signal
import tempfile
import threading
from pathlib import Path
from typing import Iterator

from nifo_core.errors import OutputError

__all__ = ["staged_dir", "staged_file", "staged_run", "check_output", "clean_leftovers", "interrupt_note",
           "INCOMPLETE", "NIFO_SUFFIXES"]

#: the marker file of a ``nifo run`` output that is being written (or was cut short by a kill)
INCOMPLETE = "INCOMPLETE"

#: file suffixes nifo writes into its output directories (a directory of only these may be replaced)
NIFO_SUFFIXES = frozenset({".json", ".png", ".svg", ".pdf", ".yaml", ".yml", ".html", ".rrd", ".npz", ".txt",
                           ".parquet", ".arrow", ".feather", ".log", ".md", ".tex"})

_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?:partial|old)-(?P<pid>\d+)(?:-.*)?$")

#: what this process has committed, and what an interrupted run restored (for :func:`interrupt_note`)
_state: dict[str, list[str]] = {"committed": [], "restored": []}

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

def _looks_like_output(d: Path, depth: int = 0) -> bool:
    """Whether directory ``d`` holds only what nifo writes (so replacing it loses nothing of the user's)."""
    try:
        entries = list(os.scandir(d))
    except OSError:
        return False
    for e in entries:
        if e.name == INCOMPLETE or _LEFTOVER.match(e.name):
            continue
        if e.is_dir(follow_symlinks=False):
            if depth >= 2 or not _looks_like_output(Path(e.path), depth + 1):
                return False
        elif not (e.is_file(follow_symlinks=False) and Path(e.name).suffix.lower() in NIFO_SUFFIXES):
            return False
    return True


def check_output(final: str | os.PathLike, *, kind: str = "dir") -> Path:
    """Refuse an output path that would destroy something; returns it as a Path.

    ``kind="dir"``: ``final`` may be absent, an empty directory, or one that
    holds only nifo output (:data:`NIFO_SUFFIXES`, sub-directories of the
    same); ``kind="file"``: absent or a regular file; ``kind="bag"``: absent,
    a file, an empty directory or a rosbag2 bag directory. Raises
    :class:`OutputError`.
    """
    final = Path(final)
    if kind not in ("dir", "file", "bag"):
        raise ValueError(f"{kind=}")
    if not (final.exists() or final.is_symlink()):
        for parent in final.parents:   # a path under a regular file
            if parent.exists():
                if not parent.is_dir():
                    raise OutputError(f"{parent} is a regular file, not a directory", source=str(final),
                                      hint="give an output path whose parent directories are directories")
                break
        return final
    if final.is_symlink():
        raise OutputError(f"is a symbolic link (to {os.readlink(final)}); it is left untouched", source=str(final),
                          hint="give the real path for the output")
    if final.is_dir():
        if kind == "file":
            raise OutputError("is a directory; a file was to be written there", source=str(final),
                              hint="give a file name (or remove the directory yourself)")
        if kind == "bag":
            if any(final.iterdir()) and not ((final / "metadata.yaml").is_file() or any(final.glob("*.mcap"))):
                raise OutputError("is a directory that is not a rosbag2 bag; it is left untouched",
                                  source=str(final), hint="give a new path for the bag")
        elif not _looks_like_output(final):
            raise OutputError("exists and holds files nifo did not write (data, other files); it is left "
                              "untouched", source=str(final),
                              hint="give a new or empty output directory (--out), or empty this one yourself")
        return final
    if kind == "dir":
        raise OutputError("exists and is a regular file, not a directory; it is left untouched", source=str(final),
                          hint="give a directory name for --out (or move the file away)")
    if not final.is_file():
        raise OutputError("exists and is not a regular file (FIFO, device or socket)", source=str(final),
                          hint="give the path of a regular file")
    return final


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

def _on_term(signum, frame):  # noqa: ARG001
    raise KeyboardInterrupt(f"signal {signum}")


@contextlib.contextmanager
def _term_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt inside the block (main thread, default handler only)."""
    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return
    signal.signal(signal.SIGTERM, _on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT/SIGTERM wait until the block is done (a rename pair is not cut in the middle)."""
    sigs = {signal.SIGINT, signal.SIGTERM}
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


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
    with _signals_held():
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
    with _term_as_interrupt():
        tmp = _scratch(final)
        try:
            yield tmp
            _commit(tmp, final)
        except BaseException as err:
            _remove(tmp)
            if _is_output_oserror(err):
                raise output_error(err, final) from err
            raise


@contextlib.contextmanager
def staged_file(path: str | os.PathLike, *, kind: str = "file") -> Iterator[Path]:
    """Yield a not-yet-existing scratch path beside ``path``; on success it is renamed to ``path``.

    ``kind="bag"`` allows a bag directory at ``path`` (see :func:`check_output`).
    """
    final = check_output(path, kind=kind)
    with _term_as_interrupt():
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
    with _term_as_interrupt():
        old = final.with_name(f".{final.name}.old-{os.getpid()}")
        had_old = False
        try:
            final.parent.mkdir(parents=True, exist_ok=True)
            clean_leftovers(final)
            with _signals_held():
                had_old = final.exists()
                if had_old:
                    os.replace(final, old)
                final.mkdir()
                (final / INCOMPLETE).write_text(
                    f"nifo run (process {os.getpid()}) is writing this directory, or was killed while it did: "
                    "its content is incomplete. Run nifo run again.\n")
        except OSError as err:
            with _signals_held():
                if had_old and old.exists():
                    _remove(final)
                    os.replace(old, final)
            raise output_error(err, final) from err
        start = len(_state["committed"])
        try:
            yield final
            with _signals_held():
                (final / INCOMPLETE).unlink()
                _state["committed"][start:] = [str(final)]
        except BaseException as err:
            with _signals_held():
                _remove(final)
                if had_old:
                    os.replace(old, final)
                    _state["restored"].append(str(final))
                del _state["committed"][start:]
            if _is_output_oserror(err):
                raise output_error(err, final) from err
            raise
        _remove(old)


def interrupt_note() -> str:
    """What an interrupted command left on disk, for its one-line message."""
    done, restored = _state["committed"], _state["restored"]
    if done:
        return "interrupted after writing " + ", ".join(done) + "; nothing else was written"
    if restored:
        return "interrupted; nothing was written (the earlier results in " + ", ".join(restored) + " were kept)"
    return "interrupted; nothing was written"
