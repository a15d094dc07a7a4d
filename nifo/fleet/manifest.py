"""What a fleet run processes: a manifest (CSV or YAML) or a folder tree, as validated bag entries.

Manifest columns (CSV header / YAML keys), one row per bag:

=========  ======================================================================
vehicle    vehicle id (required)
corner     corner, e.g. FL, FR, RL, RR (default ``-``)
date       recording date, free text (default empty)
path       the bag (rosbag2 directory or .mcap, .csv, .mat); relative to the manifest
model      model file (nonlinearities, settings) of the group; default ``--model``
m2_kg      sprung mass of the corner [kg] (weighed), optional: coefficients then
           also in SI (K2 [N/m], C2 [N·s/m], c_i), and strut health compares those,
           so differences in loading do not pass for differences in the strut
=========  ======================================================================

A YAML manifest is a list of such mappings, or ``{bags: [...]}``. A folder tree
is ``ROOT/<vehicle>/<corner>/<bag>`` (or ``ROOT/<vehicle>/<bag>``, corner ``-``).
A missing bag is not a manifest error: it is recorded as a failed bag later,
so the rest of the fleet runs.
"""

from __future__ import annotations

import csv
from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from nifo_core.errors import ConfigError

__all__ = ["BagEntry", "load_manifest", "scan_tree", "load_fleet_input", "MANIFEST_FIELDS"]

MANIFEST_FIELDS = ("vehicle", "corner", "date", "path", "model", "m2_kg")
_DATA_SUFFIXES = {".mcap", ".db3", ".csv", ".tsv", ".mat"}


class BagEntry(BaseModel):
    """One bag of the fleet (validated manifest row)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    vehicle: str
    corner: str = "-"
    date: str = ""
    path: Path
    model: Path | None = None
    m2_kg: float | None = None

    @field_validator("m2_kg")
    @classmethod
    def _mass(cls, v: float | None) -> float | None:
        if v is not None and not (v > 0 and v < 1e5):
            raise ValueError(f"{v!r} must be a sprung mass in kg (> 0)")
        return v

    @field_validator("vehicle", "corner")
    @classmethod
    def _name(cls, v: str) -> str:
        v = str(v).strip()
        if not v:
            raise ValueError("must not be empty")
        if "/" in v:
            raise ValueError(f"{v!r} must not contain '/'")
        return v

    @property
    def group(self) -> tuple[str, str]:
        """(vehicle, corner): one model per group."""
        return (self.vehicle, self.corner)


def _entry(raw: dict, *, where: str, base: Path, src: str) -> BagEntry:
    unknown = set(raw) - set(MANIFEST_FIELDS)
    if unknown:
        raise ConfigError(f"{where}: unknown column(s) {sorted(unknown)}", source=src,
                          hint=f"columns are {', '.join(MANIFEST_FIELDS)}")
    d = {k: v for k, v in raw.items() if v not in (None, "")}
    try:
        e = BagEntry(**d)
    except ValidationError as err:
        first = err.errors()[0]
        loc = ".".join(str(x) for x in first["loc"]) or "row"
        raise ConfigError(f"{where}: {loc}: {first['msg']}", source=src,
                          hint="every row needs vehicle and path (corner, date, model, m2_kg optional)") from None
    path = e.path if e.path.is_absolute() else base / e.path
    model = None if e.model is None else (e.model if e.model.is_absolute() else base / e.model)
    return e.model_copy(update={"path": path, "model": model})


def load_manifest(path: str | Path) -> list[BagEntry]:
    """Bag entries of a CSV or YAML manifest; relative paths are taken from the manifest's folder."""
    p = Path(path)
    src = str(p)
    if not p.is_file():
        raise ConfigError("no such manifest file", source=src, hint="give a .csv/.yaml manifest or a folder")
    base = p.parent
    if p.suffix.lower() in (".yaml", ".yml"):
        try:
            doc = yaml.safe_load(p.read_text())
        except yaml.YAMLError as err:
            raise ConfigError(f"not valid YAML ({str(err).splitlines()[0]})", source=src) from None
        rows = doc.get("bags") if isinstance(doc, dict) else doc
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise ConfigError("a YAML manifest is a list of {vehicle, corner, date, path, model} mappings "
                              "(or {bags: [...]})", source=src)
        entries = [_entry(r, where=f"entry {i + 1}", base=base, src=src) for i, r in enumerate(rows)]
    else:
        with p.open(newline="") as f:
            reader = csv.DictReader(f)
            if reader.fieldnames is None:
                raise ConfigError("the manifest is empty", source=src, hint=f"header: {','.join(MANIFEST_FIELDS)}")
            reader.fieldnames = [h.strip().lower() for h in reader.fieldnames]
            entries = [_entry({k: (v or "").strip() for k, v in r.items()}, where=f"line {i + 2}", base=base,
                              src=src) for i, r in enumerate(reader)]
    if not entries:
        raise ConfigError("the manifest lists no bags", source=src)
    _unique(entries, src)
    return entries


def _is_bag(p: Path) -> bool:
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix.lower() in _DATA_SUFFIXES


def _bags_in(folder: Path) -> list[Path]:
    return sorted(q for q in folder.iterdir() if not q.name.startswith(".") and _is_bag(q))


def scan_tree(root: str | Path) -> list[BagEntry]:
    """Bag entries of a folder tree ``ROOT/<vehicle>/<corner>/<bag>`` or ``ROOT/<vehicle>/<bag>``."""
    r = Path(root)
    if not r.is_dir():
        raise ConfigError("no such folder", source=str(r), hint="give a fleet folder or a manifest")
    entries = []
    for v in sorted(q for q in r.iterdir() if q.is_dir() and not q.name.startswith(".") and not _is_bag(q)):
        entries += [BagEntry(vehicle=v.name, path=b) for b in _bags_in(v)]
        for c in sorted(q for q in v.iterdir() if q.is_dir() and not q.name.startswith(".") and not _is_bag(q)):
            entries += [BagEntry(vehicle=v.name, corner=c.name, path=b) for b in _bags_in(c)]
    if not entries:
        raise ConfigError("no bags found under ROOT/<vehicle>/[<corner>/]<bag>", source=str(r),
                          hint="bags are rosbag2 folders, .mcap, .csv or .mat files; or give a manifest")
    return entries


def _unique(entries: list[BagEntry], src: str) -> None:
    seen: dict[Path, int] = {}
    for i, e in enumerate(entries):
        key = e.path.resolve()
        if key in seen:
            raise ConfigError(f"bag {e.path} is listed twice (entries {seen[key] + 1} and {i + 1})", source=src,
                              hint="list every bag once: it would count twice in its group's average")
        seen[key] = i


def load_fleet_input(path: str | Path, *, default_model: Path | None = None) -> list[BagEntry]:
    """Entries of a manifest file or folder tree, each with its model file resolved (row > ``default_model``)."""
    p = Path(path)
    entries = scan_tree(p) if p.is_dir() else load_manifest(p)
    out = []
    for e in entries:
        model = e.model or default_model
        if model is None:
            raise ConfigError(f"bag {e.path} (vehicle {e.vehicle}, corner {e.corner}) has no model file",
                              source=str(p), hint="give --model MODEL.yaml or a model column in the manifest")
        out.append(e.model_copy(update={"model": Path(model)}))
    models: dict[tuple[str, str], tuple] = {}
    for e in out:
        first = models.setdefault(e.group, (e.model, e.m2_kg))
        if first[0] != e.model:
            raise ConfigError(f"vehicle {e.vehicle} corner {e.corner} lists two model files ({first[0]} "
                              f"and {e.model})", source=str(p), hint="one model file per vehicle and corner")
        if first[1] != e.m2_kg:
            raise ConfigError(f"vehicle {e.vehicle} corner {e.corner} lists two sprung masses ({first[1]} and "
                              f"{e.m2_kg} kg)", source=str(p), hint="give one m2_kg per vehicle and corner (or none)")
    return out
