"""Input paths: refuse what would block or mislead a reader before it opens anything.

A FIFO, socket or device given as a data file blocks a reader forever (or
reads an endless stream); :func:`regular_input` refuses those, also inside a
bag directory, with one line naming the path.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from nifo_core.errors import DataFileError

__all__ = ["regular_input"]

_BAG_MEMBERS = ("metadata.yaml", "*.mcap", "*.db3", "*.db3.*", "*.mcap.*")


def _kind(mode: int) -> str:
    return ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "not a regular file")


def regular_input(path: str | os.PathLike) -> Path:
    """``path`` if it is a regular file, or a directory whose bag files are regular; else DataFileError."""
    p = Path(path)
    try:
        mode = p.stat().st_mode
    except FileNotFoundError:
        raise DataFileError("no such file or directory", source=str(p), hint="check the path") from None
    except OSError as err:
        raise DataFileError(f"cannot open it ({err.strerror or err})", source=str(p),
                            hint="check the path and its permissions") from err
    if stat.S_ISDIR(mode):
        for pattern in _BAG_MEMBERS:
            for member in p.glob(pattern):
                m = member.stat().st_mode
                if not stat.S_ISREG(m):
                    raise DataFileError(f"{member.name} in the bag is {_kind(m)}", source=str(member),
                                        hint="give the bag's files as regular files (copy the recording)")
        return p
    if not stat.S_ISREG(mode):
        raise DataFileError(f"the input is {_kind(mode)}, which would be read forever", source=str(p),
                            hint="save the data to a regular file and give that path")
    return p
