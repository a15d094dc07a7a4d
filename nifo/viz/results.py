"""Result directories written by ``nifo characterize``, ``identify``, ``predict`` and ``loop``.

A directory is recognised by the JSON document in it (``characterize.json``,
``identify.json``, ``predict.json``, ``loop.json``). :func:`read_results`
returns them in pipeline order with their figures, so the report and the
recording need not know each command's file layout beyond this module.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from nifo_core.errors import ConfigError, DataFileError

__all__ = ["ResultDir", "read_results", "KINDS", "data_paths", "resolve_data"]

Kind = Literal["characterize", "identify", "predict", "loop"]
#: pipeline order; the document each kind writes
KINDS: dict[str, str] = {"characterize": "characterize.json", "identify": "identify.json",
                         "predict": "predict.json", "loop": "loop.json"}


@dataclass(frozen=True)
class ResultDir:
    """One command's output: its kind, directory, JSON document and PNG figures (in the command's order)."""

    kind: Kind
    path: Path
    doc: dict
    figures: tuple[Path, ...] = field(default_factory=tuple)

    @property
    def name(self) -> str:
        return self.path.name


def _figures(path: Path, doc: dict) -> tuple[Path, ...]:
    listed = [path / f for f in doc.get("figures", []) if isinstance(f, str) and (path / f).is_file()]
    for r in doc.get("records", []) if isinstance(doc.get("records"), list) else []:
        listed += [path / f for f in (r.get("figures") or []) if (path / f).is_file() and path / f not in listed]
    rest = sorted(p for p in path.glob("*.png") if p not in listed)
    return tuple(listed + rest)


def read_result(path: str | os.PathLike) -> ResultDir:
    """The result in ``path`` (a directory, or the JSON file in it)."""
    p = Path(path)
    if p.is_file():
        p = p.parent
    if not p.is_dir():
        raise DataFileError("result directory not found", source=str(p),
                            hint="give a directory written by nifo characterize, identify, predict or loop")
    for kind, fname in KINDS.items():
        f = p / fname
        if f.is_file():
            try:
                doc = json.loads(f.read_text())
            except (OSError, ValueError) as err:
                raise DataFileError(f"cannot read {fname} ({err})", source=str(f)) from err
            if not isinstance(doc, dict):
                raise ConfigError(f"{fname} is not a JSON object", source=str(f))
            return ResultDir(kind, p, doc, _figures(p, doc))  # type: ignore[arg-type]
    raise ConfigError(f"no result document in it (looked for {', '.join(KINDS.values())})", source=str(p),
                      hint="give a directory written by nifo characterize, identify, predict or loop")


def read_results(paths) -> list[ResultDir]:
    """All given results, in pipeline order (characterize, identify, predict, loop), stable otherwise."""
    res = [read_result(p) for p in paths]
    order = list(KINDS)
    return sorted(res, key=lambda r: order.index(r.kind))


def data_paths(result: ResultDir) -> list[str]:
    """The data files a result was computed from, as recorded in its provenance."""
    d = result.doc
    if result.kind == "characterize":
        return [str(p) for p in d.get("inputs", [])]
    if result.kind == "identify":
        data = d.get("data") or []
        if isinstance(data, dict):  # two-step: {"steps": [{"data": [...]}, ...]}
            data = [e for s in data.get("steps", []) for e in s.get("data", [])]
        return [e["path"] for e in data if isinstance(e, dict) and "path" in e]
    if result.kind == "predict":
        return [r["path"] for r in d.get("records", []) if "path" in r]
    if result.kind == "loop":
        data = d.get("data") or d.get("inputs") or []
        return [e["path"] if isinstance(e, dict) else str(e) for e in data if isinstance(e, (dict, str))]
    return []


def resolve_data(path: str, result: ResultDir) -> Path | None:
    """A recorded data path as it is reachable from here (as written, or relative to the result), else None."""
    p = Path(path)
    for cand in (p, result.path / p, result.path.parent / p):
        if cand.exists():
            return cand
    return None
