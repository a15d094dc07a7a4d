"""Model files: which nonlinearities to identify (YAML, written by hand or by ``nifo characterize``).

Format (``nifo_model: 1``)::

    nifo_model: 1
    nonlinearities:               # describing functions; kinds in nifo_core/describing.py
      - kind: velocity_deadzone
        params: {knee: 0.03}      # m/s
      - {kind: coulomb, params: {eps: 0.005}}
      - {clearance: {gap: 1.0e-4}}          # short form
    settings:                     # optional; command-line options override
      block: 6144                 # samples per spectral block
      overlap: 0.52
      window: flattop
      band_hz: [0.5, 200]         # integration band for z, ż

Two-step identification (paper §3.3): list ``steps`` instead of
``nonlinearities``; each step names its nonlinearities and the data it is
identified on (paths relative to the model file, or given on the command line
with ``--step-data``). Later steps keep the earlier steps' terms fixed at their
identified coefficient functions::

    nifo_model: 1
    steps:
      - name: backlash on low-level data
        nonlinearities: [{kind: backlash, params: {deadband: 0.00043}}]
        data: [road_1.0mm.mcap]
      - name: damper knee on high-level data
        nonlinearities: [{kind: velocity_deadzone, params: {knee: 0.03}}]
        data: [road_2.5mm.mcap]
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import yaml

from nifo_core.describing import Term, make_term
from nifo_core.errors import ConfigError, DataFileError

from .atomic import staged_file

__all__ = ["ModelSpec", "Step", "load_model_spec", "write_model_spec", "SETTINGS_KEYS"]

SETTINGS_KEYS = ("block", "overlap", "window", "band_hz", "freq_range_hz")


@dataclass(frozen=True)
class Step:
    name: str
    terms: tuple[Term, ...]
    data: tuple[Path, ...] = ()


@dataclass(frozen=True)
class ModelSpec:
    """A parsed model file."""

    steps: tuple[Step, ...]
    settings: Mapping = field(default_factory=dict)
    source: str = ""

    @property
    def terms(self) -> tuple[Term, ...]:
        """All terms of all steps, in order."""
        return tuple(t for s in self.steps for t in s.terms)

    @property
    def two_step(self) -> bool:
        return len(self.steps) > 1


def _terms(items, where: str, src: str) -> tuple[Term, ...]:
    if items is None:
        return ()
    if not isinstance(items, list):
        raise ConfigError(f"{where} must be a list of nonlinearities", source=src,
                          hint="write '- kind: NAME' entries (see nifo identify --help)")
    out = []
    for i, it in enumerate(items):
        try:
            out.append(make_term(it))
        except ConfigError as err:
            raise ConfigError(f"{where}[{i}]: {err.message}", source=src, hint=err.hint) from None
    return tuple(out)


def load_model_spec(path: str | Path) -> ModelSpec:
    """Read and validate a model file; errors name the file and the entry."""
    p = Path(path)
    src = str(p)
    try:
        doc = yaml.safe_load(p.read_text())
    except FileNotFoundError:
        raise DataFileError("model file not found", source=src, hint="check the --model path") from None
    except (OSError, UnicodeDecodeError) as err:
        raise DataFileError(f"cannot read model file ({err})", source=src) from err
    except yaml.YAMLError as err:
        raise ConfigError(f"not valid YAML ({str(err).splitlines()[0]})", source=src,
                          hint="check indentation and brackets") from err
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise ConfigError("a model file must be a mapping with 'nonlinearities:' or 'steps:'", source=src)
    unknown = set(doc) - {"nifo_model", "nonlinearities", "steps", "settings", "note", "suggested_by"}
    if unknown:
        raise ConfigError(f"unknown key(s) {sorted(unknown)}", source=src,
                          hint="use nifo_model, nonlinearities or steps, settings, note")
    settings = doc.get("settings") or {}
    if not isinstance(settings, dict) or set(settings) - set(SETTINGS_KEYS):
        raise ConfigError(f"settings may only hold {', '.join(SETTINGS_KEYS)}", source=src)
    if "steps" in doc and "nonlinearities" in doc:
        raise ConfigError("give either 'nonlinearities' or 'steps', not both", source=src)
    if "steps" in doc:
        steps = []
        if not isinstance(doc["steps"], list) or not doc["steps"]:
            raise ConfigError("'steps' must be a non-empty list", source=src)
        for i, s in enumerate(doc["steps"]):
            if not isinstance(s, dict):
                raise ConfigError(f"steps[{i}] must be a mapping", source=src)
            data = s.get("data") or []
            if isinstance(data, str):
                data = [data]
            steps.append(Step(str(s.get("name") or f"step {i + 1}"),
                              _terms(s.get("nonlinearities"), f"steps[{i}].nonlinearities", src),
                              tuple((p.parent / d) for d in data)))
        return ModelSpec(tuple(steps), dict(settings), src)
    return ModelSpec((Step("all", _terms(doc.get("nonlinearities"), "nonlinearities", src)),), dict(settings), src)


def write_model_spec(path: str | Path, terms: list[Term] | tuple[Term, ...], *, settings: Mapping | None = None,
                     note: str | None = None, suggested_by: str | None = None) -> Path:
    """Write a single-step model file (atomically)."""
    doc: dict = {"nifo_model": 1}
    if note:
        doc["note"] = note
    if suggested_by:
        doc["suggested_by"] = suggested_by
    doc["nonlinearities"] = [t.to_dict() for t in terms]
    if settings:
        doc["settings"] = dict(settings)
    with staged_file(path) as tmp:
        tmp.write_text(yaml.safe_dump(doc, sort_keys=False))
    return Path(path)
