"""One writer per output: an advisory lock beside an output, held while a command writes it.

``output_lock(path)`` takes ``.<name>.lock`` in the output's parent folder
(``flock``, exclusive, not waiting) and writes into it who holds it: the
process id, the command line, the host and the time. A second nifo command
given the same output is refused at once with one line naming that process
(:class:`~nifo_core.errors.OutputBusyError`, exit 15): it does not wait, so a
script sees at once that the folder is taken. So is a command whose output
lies inside a folder another command is writing (``--out R/identify`` while
``nifo run --out R`` runs), or that would replace a folder holding an output
being written.

A lock is the kernel's: it goes with the process, whatever ends it (SIGKILL,
a crash, a power cut of the machine), so a lock file left by a dead process is
not held and the next command simply takes it. The holder removes the file
when it is done (checking, on taking a lock, that the file it locked is still
the one at that path, so two commands never hold two files of one name). On a
file system without ``flock`` (some network mounts) the file is created
exclusively instead and one whose process is gone (same host) is taken over.

The lock is reentrant within a process (the ``nifo`` command takes it for the
whole command, :func:`nifo.io.atomic.staged_dir` and friends take it again for
what they write), and a folder this process created for it is removed again
when nothing was written into it.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import fcntl
import json
import os
import socket
import stat
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

from nifo_core.errors import OutputBusyError

from .marker import LOCK, command_line

__all__ = ["output_lock", "lock_path", "holds", "alive"]
#: the errors of a file system that has no flock
_NO_FLOCK = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL}
#: folders below an output searched for a lock held inside it
_DEPTH_BELOW = 3


@dataclass
class _Held:
    fd: int | None
    path: Path
    count: int = 1
    created: list[Path] = field(default_factory=list)


_held: dict[str, _Held] = {}
_mutex = threading.RLock()


def lock_path(final: str | os.PathLike) -> Path:
    """The lock file of output ``final``: ``.<name>.lock`` beside it."""
    final = Path(final)
    return final.with_name(f".{final.name}.lock")


def _key(final: Path) -> str:
    try:
        return os.path.join(os.path.realpath(final.parent), final.name)
    except (OSError, ValueError):
        return str(final.absolute())


def holds(final: str | os.PathLike) -> bool:
    """Whether this process holds the lock of ``final``."""
    with _mutex:
        return _key(Path(final).absolute()) in _held


@contextlib.contextmanager
def output_lock(final: str | os.PathLike | None) -> Iterator[None]:
    """Hold the lock of output ``final`` for the block (module docstring); ``None``: no output, no lock.

    Raises :class:`OutputBusyError` when another process writes ``final``, a
    folder it lies in, or an output inside it. Where no lock file can be made
    (the parent is a regular file, read-only, the name too long, ``final`` a
    device or FIFO) nothing is locked: the command's own check of the output
    then says what is wrong with it.
    """
    if final is None:
        yield
        return
    given = Path(final)
    final = given.absolute()
    key = _key(final)
    with _mutex:
        held = _held.get(key)
        if held is not None:
            held.count += 1
        else:
            held = _acquire(final, given)
            if held is not None:
                _held[key] = held
    try:
        yield
    finally:
        if held is not None:
            with _mutex:
                held.count -= 1
                if held.count == 0:
                    del _held[key]
                    _release(held)


def _holder() -> str:
    return json.dumps({"nifo_lock": 1, "pid": os.getpid(), "host": socket.gethostname(), "command": command_line(),
                       "since": _dt.datetime.now().astimezone().isoformat(timespec="seconds")}) + "\n"


def _lockable(final: Path) -> bool:
    """Whether an output at ``final`` can be locked at all (else the output's own check refuses it)."""
    try:
        st = final.lstat()
    except FileNotFoundError:
        return True
    except OSError:
        return False
    return stat.S_ISDIR(st.st_mode) or stat.S_ISREG(st.st_mode)


def _make_parents(folder: Path) -> list[Path]:
    """``mkdir -p folder``; the folders made (outermost first), to remove again if they stay empty."""
    missing = []
    for p in (folder, *folder.parents):
        if p.exists():
            break
        missing.append(p)
    made: list[Path] = []
    try:
        for p in reversed(missing):
            try:
                p.mkdir()
            except FileExistsError:
                continue
            made.append(p)
    except OSError:
        _remove_made(made)
        raise
    return made


def _acquire(final: Path, given: Path) -> _Held | None:
    if not _lockable(final):
        return None
    try:
        created = _make_parents(final.parent)
    except OSError:
        return None
    try:
        return _take(final, given, created)
    except OSError:         # a path nothing can be written at: the output's own check says why
        _remove_made(created)
        return None
    except BaseException:
        _remove_made(created)
        raise


def _take(final: Path, given: Path, created: list[Path]) -> _Held | None:
    path = lock_path(final)
    _busy_around(final, given)
    for _ in range(20):   # the file may be removed by its last holder between our open and our lock
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise _busy(given, final, final, holder) from None
        except OSError as err:
            os.close(fd)
            if err.errno not in _NO_FLOCK:
                raise
            return _acquire_without_flock(final, given, path, created)
        if _same_file(fd, path):
            os.ftruncate(fd, 0)
            os.pwrite(fd, _holder().encode(), 0)
            return _Held(fd, path, created=created)
        os.close(fd)
    raise OSError(errno.EAGAIN, "the lock file kept changing", str(path))


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path, follow_symlinks=False)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _acquire_without_flock(final: Path, given: Path, path: Path, created: list[Path]) -> _Held | None:
    """Exclusive creation of the lock file; one of a process that is gone (this host) is taken over."""
    for _ in range(20):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
        except FileExistsError:
            holder = _read_holder_path(path)
            if _holder_alive(holder):
                raise _busy(given, final, final, holder) from None
            with contextlib.suppress(OSError):   # stale: its process is gone
                path.unlink()
            continue
        os.write(fd, _holder().encode())
        os.close(fd)
        return _Held(None, path, created=created)
    raise OSError(errno.EAGAIN, "the lock file kept changing", str(path))


def alive(pid: int) -> bool:
    """Whether process ``pid`` of this machine is running (this one is)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _holder_alive(holder: dict) -> bool:
    pid = holder.get("pid")
    if not isinstance(pid, int) or holder.get("host") not in (None, socket.gethostname()):
        return True     # unknown, or another machine's process: it may well be running
    return alive(pid)


def _release(held: _Held) -> None:
    with contextlib.suppress(OSError):
        if held.fd is None or _same_file(held.fd, held.path):
            held.path.unlink()
    if held.fd is not None:
        os.close(held.fd)    # closing releases the flock
    _remove_made(held.created)


def _remove_made(created: list[Path]) -> None:
    for p in reversed(created):    # innermost first; a folder something was written into stays
        try:
            p.rmdir()
        except OSError:
            break


# -----------------------------------------------------------------------------
# who holds it
# -----------------------------------------------------------------------------

def _parse_holder(raw: bytes) -> dict:
    try:
        doc = json.loads(raw[:4096].decode("utf-8", "replace"))
    except ValueError:
        return {}
    return doc if isinstance(doc, dict) else {}


def _read_holder(fd: int) -> dict:
    import time

    for _ in range(5):     # the holder writes its line right after taking the lock
        raw = os.pread(fd, 4096, 0)
        if raw:
            return _parse_holder(raw)
        time.sleep(0.01)
    return {}


def _read_holder_path(path: Path) -> dict:
    try:
        return _parse_holder(path.read_bytes())
    except OSError:
        return {}


def _busy(given: Path, final: Path, locked: Path, holder: dict) -> OutputBusyError:
    """The refusal of output ``given`` (``final`` absolute) because another process holds the lock of ``locked``."""
    pid, cmd, since = holder.get("pid"), holder.get("command"), holder.get("since")
    who = f"process {pid}" if pid else "another process"
    if cmd:
        who += f": {cmd if len(cmd) <= 200 else cmd[:197] + '...'}"
    if since:
        who += f", since {since}"
    if locked == final:
        what = f"is being written by another nifo command ({who})"
    elif locked in final.parents:
        what = f"lies in {locked}, which another nifo command is writing ({who})"
    else:
        what = f"holds {locked}, which another nifo command is writing ({who})"
    return OutputBusyError(what, source=str(given),
                           hint="wait until that command has ended (or stop it), or give another --out")


def _probe(given: Path, final: Path, locked: Path) -> None:
    """Raise OutputBusyError if the lock file of output ``locked`` is held by another process."""
    if holds(locked):
        return
    path = lock_path(locked)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            raise _busy(given, final, locked, _read_holder(fd)) from None
        except OSError as err:
            if err.errno not in _NO_FLOCK:
                raise
            holder = _read_holder(fd)
            if holder and _holder_alive(holder):
                raise _busy(given, final, locked, holder) from None
    finally:
        os.close(fd)


def _busy_around(final: Path, given: Path) -> None:
    """Refuse ``final`` when a folder it lies in, or an output inside it, is being written by another process."""
    for folder in final.parents:
        if folder.parent == folder:
            break
        if lock_path(folder).exists():
            _probe(given, final, folder)
    if not final.is_dir() or final.is_symlink():
        return
    base = len(final.parts)
    for root, dirs, files in os.walk(final):
        if len(Path(root).parts) - base >= _DEPTH_BELOW:
            dirs[:] = []
        for name in files:
            m = LOCK.match(name)
            if m:
                _probe(given, final, Path(root) / m["name"])
