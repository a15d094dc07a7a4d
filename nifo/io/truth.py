"""The simulator's truth file beside a data file (``<name>.truth.json``): where ``nifo simulate`` puts it."""

from __future__ import annotations

from pathlib import Path

__all__ = ["truth_for"]


def truth_for(path: Path) -> Path | None:
    """The simulator's truth file beside ``path`` (``<name>.truth.json``), if any."""
    p = Path(path)
    cand = p.with_name(p.name + ".truth.json")
    if cand.is_file():
        return cand
    if p.suffix:  # also road.truth.json beside road.mcap
        cand = p.with_name(p.stem + ".truth.json")
        if cand.is_file():
            return cand
    return None
