"""Whether an error is a Ctrl-C (or SIGTERM) in disguise: imported by ``python -m nifo`` before anything else.

An interrupt that lands inside a library can surface as another error raised from it: matplotlib's savefig
(AttributeError in restore_bbox), or a class being created during an import (dataclasses' ``__set_name__``:
RuntimeError, with the KeyboardInterrupt as its cause; measured in ``tests/test_kill.py``, SIGINT 2.3 s into
``nifo identify``, while the command's parser imported scipy.stats). Those are interruptions, not bugs.
"""

from __future__ import annotations

__all__ = ["by_interrupt"]


def by_interrupt(exc: BaseException | None) -> bool:
    """Whether ``exc`` is a KeyboardInterrupt or was raised from or while handling one (its cause/context chain)."""
    seen: set[int] = set()
    todo = [exc]
    while todo:
        e = todo.pop()
        if e is None or id(e) in seen:
            continue
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        todo += [e.__cause__, e.__context__]
    return False
