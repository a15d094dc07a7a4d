"""Write outputs so that a failure leaves nothing half-written.

``staged_dir(out)`` gives a scratch directory beside ``out``; only when the
block succeeds does it replace ``out`` (by rename). ``staged_file(path)`` does
the same for one file (or a directory-shaped artefact such as a rosbag2 bag).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

__all__ = ["staged_dir", "staged_file"]


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def _commit(tmp: Path, final: Path) -> None:
    old = None
    if final.exists() or final.is_symlink():
        old = final.with_name(f".{final.name}.old-{os.getpid()}")
        _remove(old)
        os.replace(final, old)
    os.replace(tmp, final)
    if old is not None:
        _remove(old)


@contextlib.contextmanager
def staged_dir(out: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty scratch directory; on success it becomes ``out`` (replacing it)."""
    final = Path(out)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.partial-", dir=final.parent))
    _umask = os.umask(0)
    os.umask(_umask)
    tmp.chmod(0o777 & ~_umask)  # mkdtemp makes 0700; results are ordinary directories
    try:
        yield tmp
    except BaseException:
        _remove(tmp)
        raise
    _commit(tmp, final)


@contextlib.contextmanager
def staged_file(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a not-yet-existing scratch path beside ``path``; on success it is renamed to ``path``."""
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{final.name}.partial-", dir=final.parent))
    tmp = tmpdir / final.name
    try:
        yield tmp
        if not tmp.exists():
            raise FileNotFoundError(f"staged output {tmp} was not written")
        _commit(tmp, final)
    finally:
        _remove(tmpdir)
