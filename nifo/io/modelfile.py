"""Model files: which nonlinearities to identify (YAML, written by hand or by ``nifo characterize``).

Format (``nifo_model: 1``)::

    nifo_model: 1
    nonlinearities:               # describing functions; kinds in nifo_core/kinds/describing.py
      - kind: velocity_deadzone
        params: {knee: 0.03}      # m/s
      - {kind: coulomb, params: {eps: 0.005}}
      - {clearance: {gap: 1.0e-4}}          # short form
    settings:                     # optional; command-line options override
      block: 6144                 # samples per spectral block
      overlap: 0.52
      window: flattop
      integration_band_hz: [0.5, 200]   # integration band for z, ż (also read as band_hz)
      analysis_band_hz: [2, 30]         # analysis band (also read as freq_range_hz)

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

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, Mapping

import yaml
from pydantic import AliasChoices, BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from nifo_core.kinds.describing import Term, kind as _kind, make_term
from nifo_core.errors import ConfigError, DataFileError, NifoError
from nifo_core.settings import GivenSettings
from nifo_core.signal.spectral import MAX_BLOCK

from .atomic import staged_file
from .ownership import YAML_MARK_PREFIX

__all__ = ["ModelSpec", "Step", "load_model_spec", "parse_model_spec", "write_model_spec", "SETTINGS_KEYS",
           "MAX_MODEL_BYTES", "MAX_BLOCK"]

SETTINGS_KEYS = ("block", "overlap", "window", "integration_band_hz", "analysis_band_hz")
#: the settings' old names, still read (docs/CONTRACTS.md, "One name per setting")
SETTINGS_ALIASES = {"band_hz": "integration_band_hz", "freq_range_hz": "analysis_band_hz"}

#: a model file is a few hundred bytes; anything above this is not one
MAX_MODEL_BYTES = 1 << 20
#: YAML nodes (scalars, lists, maps) a model file may hold
MAX_NODES = 20_000
#: the most nonlinearities per step / steps per file
MAX_TERMS = 64

_Text = Annotated[str, Field(max_length=10_000)]
_Name = Annotated[str, Field(min_length=1, max_length=200)]


# -----------------------------------------------------------------------------
# the one schema (pydantic 2, strict: a boolean is not a number, a string not a list)
# -----------------------------------------------------------------------------

class _Strict(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)


class Settings(_Strict):
    """``settings:`` of a model file; the command line overrides each. The types are checked here (strict); the
    values by the settings' own rules, one validator per field for every source
    (:class:`nifo_core.settings.GivenSettings`: the command line, a model file, the identifier node)."""

    block: int | None = None
    overlap: float | None = None
    window: Annotated[str, Field(max_length=100)] | None = None
    integration_band_hz: tuple[float, float] | None = Field(
        None, validation_alias=AliasChoices("integration_band_hz", "band_hz"))
    analysis_band_hz: tuple[float, float] | None = Field(
        None, validation_alias=AliasChoices("analysis_band_hz", "freq_range_hz"))

    @model_validator(mode="before")
    @classmethod
    def _one_name(cls, v: Any) -> Any:
        if isinstance(v, dict):
            for old, new in SETTINGS_ALIASES.items():
                if old in v and new in v:
                    raise ValueError(f"{new} and {old} are one setting (the old name): give it once, as {new}")
        return v

    @field_validator("integration_band_hz", "analysis_band_hz", mode="before")
    @classmethod
    def _list_pair(cls, v: Any) -> Any:
        return tuple(v) if isinstance(v, list) else v

    @model_validator(mode="after")
    def _values(self) -> "Settings":
        try:
            GivenSettings(block=self.block, overlap=self.overlap, window=self.window,
                          integration_band_hz=self.integration_band_hz, analysis_band_hz=self.analysis_band_hz)
        except ConfigError as err:
            raise ValueError(err.message) from None
        return self


_Param = Any   # checked against the kind in TermSpec._typed_params (a boolean is not a number)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _short(v: Any) -> str:
    r = repr(v)
    return r if len(r) <= 40 else r[:37] + "..."


def text_number_note(value: Any) -> str:
    """For a string that reads as a number (YAML 1.1 takes ``1e-4`` without a decimal point for text):
    what happened and how to write it; '' otherwise."""
    if not isinstance(value, str) or len(value) > 40:
        return ""
    try:
        x = float(value)
    except ValueError:
        return ""
    if not math.isfinite(x) or not any(c.isdigit() for c in value):
        return ""
    mant, _, exp = value.strip().lower().partition("e")
    if not exp or "." in mant:
        return f" ({value!r} is text, not a number: write {value.strip()} without quotes)"
    return (f" ({value!r} was read as text: YAML reads a number like 1e-4 without a decimal point as a string; "
            f"write {mant}.0e{exp})")


class TermSpec(_Strict):
    """One nonlinearity: ``{kind: NAME, params: {...}}`` (short forms are normalised to this)."""

    kind: _Name
    params: Annotated[dict[Annotated[str, Field(max_length=100)], _Param], Field(max_length=16)] = \
        Field(default_factory=dict)
    coefficient: _Param | None = None
    name: _Text | None = None
    note: _Text | None = None

    @model_validator(mode="before")
    @classmethod
    def _short_forms(cls, v: Any) -> Any:
        if isinstance(v, str):
            return {"kind": v}
        if isinstance(v, dict) and "kind" not in v and len(v) == 1:
            (name, params), = v.items()
            return {"kind": name, "params": {} if params is None else params}
        if isinstance(v, dict) and v.get("params", {}) is None:
            return {**v, "params": {}}
        return v

    @model_validator(mode="after")
    def _typed_params(self) -> "TermSpec":
        try:
            k = _kind(self.kind)
        except ConfigError as err:
            raise ValueError(f"{err.message}; {err.hint}") from None
        if self.coefficient is not None and not _is_number(self.coefficient):
            raise ValueError(f"{k.name} coefficient={_short(self.coefficient)} must be a number")
        note = ""
        try:    # the kind's own rule (Kind.check), the one every caller of the core goes through
            for name, value in self.params.items():
                note = text_number_note(value)
                k.check_value(name, value)
            note = ""
            k.check(self.params)
        except ConfigError as err:
            raise ValueError(err.message + note + (f", {err.hint}" if err.hint else "")) from None
        return self


class StepSpec(_Strict):
    name: _Name | None = None
    nonlinearities: Annotated[list[TermSpec], Field(max_length=MAX_TERMS)] | None = None
    data: Annotated[list[Annotated[str, Field(min_length=1, max_length=4096)]], Field(max_length=1000)] = \
        Field(default_factory=list)

    @field_validator("data", mode="before")
    @classmethod
    def _one_path(cls, v: Any) -> Any:
        if v is None:
            return []
        return [v] if isinstance(v, str) else v


class ModelFile(_Strict):
    """The whole document (``nifo_model: 1``)."""

    nifo_model: Literal[1] = 1
    nonlinearities: Annotated[list[TermSpec], Field(max_length=MAX_TERMS)] | None = None
    steps: Annotated[list[StepSpec], Field(min_length=1, max_length=MAX_TERMS)] | None = None
    settings: Settings | None = None
    note: _Text | None = None
    suggested_by: _Text | None = None

    @field_validator("nifo_model", mode="before")
    @classmethod
    def _version(cls, v: Any) -> Any:
        if type(v) is not int or v != 1:   # strict: true, 1.0 and "1" are not the format version 1
            raise ValueError(f"must be the integer 1 (the format version), got {_short(v)}")
        return v

    @model_validator(mode="after")
    def _either(self) -> "ModelFile":
        if self.steps is not None and self.nonlinearities is not None:
            raise ValueError("give either 'nonlinearities' or 'steps', not both")
        return self


# -----------------------------------------------------------------------------
# the parsed form the commands use
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Step:
    name: str
    terms: tuple[Term, ...]
    data: tuple[Path, ...] = ()


@dataclass(frozen=True)
class ModelSpec:
    """A parsed, validated model file."""

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


_FIX = "see the model file format in 'nifo identify --help' (nifo_model: 1, nonlinearities: or steps:, settings:)"


def _where(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part not in ("function-after[_typed_params(), TermSpec]",) and not str(part).startswith(
                ("function-", "tagged-union", "constrained-")):
            out += ("." if out else "") + str(part)
    return out


def validation_error(err: ValidationError, src: str, *, hint: str = _FIX, yaml: bool = True) -> ConfigError:
    """One :class:`ConfigError` line for the first problem pydantic found: where (dotted path), what, the value
    (``yaml``: and, for a number YAML read as text, how to write it)."""
    first = err.errors(include_url=False)[0]
    where = _where(first["loc"])
    msg = first["msg"].removeprefix("Value error, ")
    value = first.get("input")
    shown = repr(value) if isinstance(value, (bool, int, float)) or (isinstance(value, str) and len(value) < 60) \
        else type(value).__name__
    more = f" (and {err.error_count() - 1} more problem(s))" if err.error_count() > 1 else ""
    text = f"{where}: {msg}" if where else msg
    if first["type"] not in ("value_error", "assertion_error"):
        if value is None and first["type"] != "missing":
            text += ", got null"
        elif value is not None and first["type"] != "missing":
            text += f", got {shown}" + (text_number_note(value) if yaml else "")
    return ConfigError(text + more, source=src, hint=hint)


_validation_error = validation_error


def _terms(items: list[TermSpec] | None, where: str, src: str) -> tuple[Term, ...]:
    out = []
    for i, t in enumerate(items or ()):
        try:
            out.append(make_term({"kind": t.kind, "params": dict(t.params)}))
        except ConfigError as err:
            raise ConfigError(f"{where}[{i}]: {err.message}", source=src, hint=err.hint) from None
    return tuple(out)


class _NoAliasLoader(yaml.SafeLoader):
    """SafeLoader that refuses aliases (``*name``: a billion-laughs bomb expands them) and huge documents."""

    def compose_node(self, parent, index):  # noqa: D102
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(None, None, "YAML aliases (*name) are not accepted in a model file",
                                              event.start_mark)
        self._nodes = getattr(self, "_nodes", 0) + 1
        if self._nodes > MAX_NODES:
            raise yaml.composer.ComposerError(None, None, f"more than {MAX_NODES} YAML nodes",
                                              self.peek_event().start_mark)
        return super().compose_node(parent, index)


def parse_model_spec(text: str, *, source: str = "model", base: Path | None = None) -> ModelSpec:
    """Validate a model file's text against the schema; ``base`` resolves step data paths."""
    src = source
    try:
        doc = yaml.load(text, Loader=_NoAliasLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as err:
        first = str(err).replace("\n", " ")
        raise ConfigError(f"not a valid model file ({first[:300]})", source=src,
                          hint="check indentation and brackets; write values out instead of YAML aliases") from None
    except RecursionError:
        raise ConfigError("the YAML nests too deeply", source=src, hint=_FIX) from None
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise ConfigError(f"a model file must be a mapping with 'nonlinearities:' or 'steps:', got a "
                          f"{type(doc).__name__}", source=src, hint=_FIX)
    try:
        model = ModelFile.model_validate(doc)
    except ValidationError as err:
        raise _validation_error(err, src) from None
    except RecursionError:
        raise ConfigError("the YAML nests too deeply", source=src, hint=_FIX) from None
    settings = model.settings.model_dump(exclude_none=True) if model.settings else {}
    for k in ("integration_band_hz", "analysis_band_hz"):
        if k in settings:
            settings[k] = [float(v) for v in settings[k]]
    base = base or Path(".")
    if model.steps is not None:
        steps = tuple(Step(s.name or f"step {i + 1}", _terms(s.nonlinearities, f"steps[{i}].nonlinearities", src),
                           tuple(base / d for d in s.data)) for i, s in enumerate(model.steps))
        return ModelSpec(steps, settings, src)
    return ModelSpec((Step("all", _terms(model.nonlinearities, "nonlinearities", src)),), settings, src)


def load_model_spec(path: str | Path) -> ModelSpec:
    """Read and validate a model file (every command calls this); errors name the file and the entry.

    The file must be a regular file of at most :data:`MAX_MODEL_BYTES`;
    YAML aliases are refused; the document is checked against one schema
    (:class:`ModelFile`): types (a boolean is not a number), ranges, known
    kinds and parameters, ``nifo_model: 1``.
    """
    p = Path(path)
    src = str(p)
    try:
        if not p.exists():
            raise DataFileError("model file not found", source=src, hint="check the --model path")
        if not p.is_file():
            raise DataFileError("the model file is not a regular file (a directory, FIFO or device)", source=src,
                                hint="give the path of a .yaml model file")
        size = p.stat().st_size
        if size > MAX_MODEL_BYTES:
            raise ConfigError(f"the model file is {size} bytes; a model file is at most {MAX_MODEL_BYTES}",
                              source=src, hint="give the .yaml model file, not a data file")
        with p.open("rb") as f:
            raw = f.read(MAX_MODEL_BYTES + 1)
        text = raw.decode("utf-8-sig")
    except NifoError:
        raise
    except UnicodeDecodeError:
        raise ConfigError("the model file is not UTF-8 text", source=src,
                          hint="give the .yaml model file, not a data file") from None
    except OSError as err:
        raise DataFileError(f"cannot read the model file ({err.strerror or err})", source=src,
                            hint="check the path and the file's permissions") from err
    return parse_model_spec(text, source=src, base=p.parent)


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
    from nifo_core import __version__

    with staged_file(path) as tmp:   # the first line marks it as nifo's (it may replace it: nifo.io.ownership)
        tmp.write_text(f"{YAML_MARK_PREFIX}{__version__}\n" + yaml.safe_dump(doc, sort_keys=False))
    return Path(path)
