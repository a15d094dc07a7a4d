"""Names of records in what nifo writes: the file's name where it is unique, never the same name twice.

Users read these names (tables, figures, legends, the report), so a record keeps
its plain file name (``rec.csv``) when no other record of the command has it.
Records of the same name from different folders are told apart by as many of
their folders as it takes (``day1/rec.csv``, ``day2/rec.csv``); the same file
given twice by its index (``rec.csv #2``). File names made from them keep
letters, digits, ``_ . -`` only, and where two still come out alike — ``rec
1.csv`` and ``rec_1.csv``, or ``Rec.csv`` and ``rec.csv`` on a file system that
ignores case — the later one gets ``-2``, ``-3``, ... (issue 56: the second
record's predicted signals overwrote the first's, both listed in predict.json).
"""

from __future__ import annotations

import os
import re
from collections import Counter, defaultdict
from pathlib import Path
from typing import Sequence

__all__ = ["record_labels", "file_stems", "safe_stem"]


def _parts(p: str | os.PathLike) -> tuple[str, ...]:
    try:
        return Path(p).resolve().parts
    except (OSError, RuntimeError):
        return Path(os.path.abspath(p)).parts


def record_labels(paths: Sequence[str | os.PathLike]) -> list[str]:
    """One label per record (module docstring): the file name, qualified by folders or an index only where names
    would repeat."""
    names = [Path(p).name or str(p) for p in paths]
    groups: dict[str, list[int]] = defaultdict(list)
    for i, n in enumerate(names):
        groups[n].append(i)
    labels = list(names)
    for members in groups.values():
        if len(members) < 2:
            continue
        parts = {i: _parts(paths[i]) for i in members}
        distinct = sorted(set(parts.values()))      # the same file given twice is one path, told apart by index
        k = 1
        if len(distinct) > 1:
            longest = max(len(v) for v in distinct)
            for k in range(2, longest + 1):       # the fewest trailing folders that tell them apart
                if len({"/".join(v[-k:]) for v in distinct}) == len(distinct):
                    break
        seen: Counter = Counter()
        for i in members:
            label = "/".join(parts[i][-k:]).lstrip("/") if k > 1 else names[i]
            seen[parts[i]] += 1
            labels[i] = label if seen[parts[i]] == 1 else f"{label} #{seen[parts[i]]}"
    return labels


def safe_stem(label: str) -> str:
    """``label`` as a file-name stem: letters, digits and ``_ . -`` (a folder's ``/`` becomes ``_``)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label).strip("._") or "record"


def file_stems(labels: Sequence[str]) -> list[str]:
    """File-name stems for ``labels`` (:func:`safe_stem`), unique even where two come out alike, case ignored."""
    out: list[str] = []
    used: set[str] = set()
    for label in labels:
        stem = safe_stem(label)
        k = 1
        while (stem if k == 1 else f"{stem}-{k}").casefold() in used:
            k += 1
        stem = stem if k == 1 else f"{stem}-{k}"
        used.add(stem.casefold())
        out.append(stem)
    return out
