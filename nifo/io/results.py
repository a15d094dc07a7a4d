"""Result files of ``nifo identify`` and ``nifo predict`` (JSON), written atomically.

``identify.json`` (``nifo_identify: 1``)
    ``result``: the whole :meth:`NifoResult.to_dict` (frequency lines; the
    per-line paper-Eq. 9 estimate ``t21``, ``b``, ``mu_over_k2``, ``c_over_m2``;
    the pooled constant-coefficient fit under ``static`` with its own T21,
    B_i, μ_i/K2 and the pooled c_i/M2; plain ``t21_h1`` and its coherence;
    multiple and partial coherences; ``cond``; ``random_error``; settings,
    integration band, analysis band; ``input_measured`` when the tire patch
    was recorded). Complex arrays are ``{"re": [...], "im": [...]}``.
    ``bounds``: about-95 % random-error bounds |T21|·(1 ∓ 2ε) of both T21s.
    ``summary``: the numbers the command prints (pooled c_i/M2 with units,
    T21 vs plain H1, conditioning). ``warnings``: plain sentences.
    ``data``: every file read (path, name, size in bytes, sample rate,
    samples, duration, the reader's ``meta``), per step for two-step models.
    ``model_file``: the model file and its steps. ``settings``: as run.

``model.json`` (``nifo_identified_model: 1``; read through :class:`ModelDocument`)
    :meth:`IdentifiedModel.to_dict` (T21, B_i, terms, pooled c_i/M2, the
    one-mass body model or null, ``offsets`` (the static part the prediction adds),
    ``prediction_band`` (the band the prediction covers, chosen by held-out whole-signal
    error), ``periodic_response`` (for a periodic input: the model's periodic response or its simulation as it
    comes, chosen the same way) and ``validity`` (the band and input amplitudes identified on;
    :mod:`nifo_core.predict.scope`), ``linear_part``: the linear part predictions
    use — ``kind`` body or rational, ``order``, ``fit_rms``, ``stable``,
    ``physical``, ``reason`` it was chosen, the ``candidates`` tried, and for a
    rational one its ``poles``/``residues`` —, ``force_gain`` 1/M2, settings,
    provenance: data files, model file, identify settings; files without
    ``linear_part`` are read with the body as linear part), plus ``linear_h1``: the plain-H1 model at the
    identification level (the equivalent linearisation) that ``nifo predict``
    compares against. :func:`read_model` returns both. ``validity.strut_range``: the lowest and highest deflection
    [m] and velocity [m/s] of the identification records (the force law's measured range).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Annotated, Any, Literal, Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from nifo_core import __version__
from nifo_core.errors import ConfigError, DataFileError
from nifo_core.predict.model import IdentifiedModel
from nifo_core.nifo.identify import NifoResult
from nifo_core.signal.record import Record

from .atomic import claim, staged_file
from .modelfile import TermSpec, validation_error

__all__ = ["data_entry", "identify_document", "write_json", "read_json", "read_identify", "model_document",
           "write_model", "read_model", "ModelDocument", "IDENTIFY_JSON", "MODEL_JSON", "PREDICT_JSON"]

IDENTIFY_JSON = "identify.json"
MODEL_JSON = "model.json"
PREDICT_JSON = "predict.json"


def _default(o: Any):
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, np.ndarray):
        if o.dtype.kind == "f" and not np.isfinite(o).all():   # null where not finite, in one pass
            return np.where(np.isfinite(o), o, None).tolist()
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    if isinstance(o, complex):
        return {"re": o.real, "im": o.imag}
    return str(o)


def _nan_to_none(o):
    """JSON has no NaN/inf: null instead (strict parsers reject NaN); arrays through :func:`_default` at once."""
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, np.ndarray):
        return _default(o) if o.dtype.kind in "biuf" else _nan_to_none(o.tolist())
    if isinstance(o, complex):
        return _nan_to_none(_default(o))
    if isinstance(o, Mapping):
        return {k: _nan_to_none(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        if all(type(v) is float for v in o):     # a plain list of numbers (most of a document): no call per value
            return [v if math.isfinite(v) else None for v in o]
        return [_nan_to_none(v) for v in o]
    return o


def write_json(path: str | os.PathLike, doc: Mapping, *, atomic: bool = True, indent: int | None = None) -> Path:
    """Write ``doc`` as JSON (numpy values converted, NaN/inf as null); atomically unless
    inside an already staged directory. ``indent`` for files people read."""
    seps = None if indent else (",", ":")
    try:   # one pass: arrays' non-finite values are null already (_default)
        text = json.dumps(doc, default=_default, allow_nan=False, indent=indent, separators=seps) + "\n"
    except ValueError:   # a NaN/inf float outside an array: every value checked
        text = json.dumps(_nan_to_none(doc), default=_default, allow_nan=False, indent=indent, separators=seps) + "\n"
    p = Path(path)
    if not atomic:
        claim(p)     # inside nifo run's folder: listed in its marker before it is written
        p.write_text(text)
        return p
    with staged_file(p) as tmp:
        tmp.write_text(text)
    return p


def _nan(x):
    """null -> NaN in numeric lists read back from JSON (other None values stay None).

    A list of numbers alone (most of a document: spectra, time series) is returned as it is, and one of numbers and
    nulls mapped in one pass, without a call per value. Measured: the sample's ``nifo run`` made 400 822 calls of it,
    the top of its profile by own time (0.9 s, 2.2 s with what it called, of 33 s under cProfile), but that is the
    profiler's cost per call: the eight JSON documents of the run, each read back whole, take 26.8 ms the old way and
    8.1 ms this way (best of 5)."""
    if isinstance(x, list):
        kinds = set(map(type, x))
        if kinds <= {float, int}:
            return x
        if kinds <= {float, int, type(None)}:
            return [float("nan") if v is None else v for v in x]
        if type(None) in kinds:
            return [float("nan") if v is None else _nan(v) for v in x]
        return [_nan(v) for v in x]
    if isinstance(x, dict):
        return {k: _nan(v) for k, v in x.items()}
    return x


def read_json(path: str | os.PathLike, *, what: str) -> dict:
    """A JSON document, or :class:`DataFileError` / :class:`ConfigError` naming the file."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except FileNotFoundError:
        raise DataFileError(f"{what} not found", source=str(p), hint="check the path") from None
    except (OSError, UnicodeDecodeError) as err:
        raise DataFileError(f"cannot read {what} ({err})", source=str(p)) from err
    except json.JSONDecodeError as err:
        raise ConfigError(f"{what} is not valid JSON ({err.msg} at line {err.lineno})", source=str(p),
                          hint="write it again with nifo identify") from None
    if not isinstance(doc, dict):
        raise ConfigError(f"{what} must be a JSON object", source=str(p))
    return doc


def data_entry(path: str | os.PathLike, record: Record | None = None, *, fs_hz: float | None = None,
               n_samples: int | None = None, meta: Mapping | None = None) -> dict:
    """Provenance of one data file: path, name, size in bytes, rate, samples, duration, reader meta."""
    p = Path(path)
    size = sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) if p.is_dir() else p.stat().st_size
    if record is not None:
        fs_hz, n_samples, meta = record.fs_hz, record.n, record.meta
    return {"path": str(p), "name": p.name, "size_bytes": int(size), "fs_hz": fs_hz, "n_samples": n_samples,
            "duration_s": None if not (fs_hz and n_samples) else n_samples / fs_hz, "meta": dict(meta or {})}


def identify_document(result: NifoResult, *, data: Any, summary: Mapping, warnings: list[str],
                      settings: Mapping, model_file: Mapping, figures: list[str]) -> dict:
    """The ``identify.json`` document (see the module docstring)."""
    k_free, k_static = result.bound_factor(), result.bound_factor(static=True)
    lo, hi = result.bounds("t21", k=k_free)
    st = result.static
    eps = np.asarray(st.random_error)
    mag = np.abs(st.t21)
    return {
        "nifo_identify": 1, "nifo_version": __version__,
        "model_file": dict(model_file), "data": data, "settings": dict(settings),
        "summary": dict(summary), "warnings": list(warnings), "figures": list(figures),
        "bounds": {"note": "95 % random-error bounds |T|(1 -/+ k eps), k the Student-t quantile of the fit's "
                           "2(n_avg - inputs) degrees of freedom; random error only",
                   "t21_free": {"lower": lo, "upper": hi, "k": k_free},
                   "t21_static": {"lower": mag * np.maximum(1 - k_static * eps, 0), "upper": mag * (1 + k_static * eps),
                                  "k": k_static}},
        "result": result.to_dict(),
    }


def read_identify(path: str | os.PathLike) -> tuple[NifoResult, dict]:
    """The :class:`NifoResult` and the whole document of an ``identify.json`` (or its directory)."""
    p = Path(path)
    if p.is_dir():
        p = p / IDENTIFY_JSON
    doc = read_json(p, what="identify result")
    if doc.get("nifo_identify") != 1 or "result" not in doc:
        raise ConfigError("not an identify.json (no 'nifo_identify: 1' and 'result')", source=str(p),
                          hint="give the file nifo identify wrote")
    try:
        return NifoResult.from_dict(_nan(doc["result"])), doc
    except ConfigError as err:
        raise err.with_context(source=str(p)) from None


def model_document(model: IdentifiedModel, *, linear: IdentifiedModel | None = None) -> dict:
    """``model.json``: the model's dict plus the plain-H1 ``linear_h1`` model to compare against."""
    doc = model.to_dict()
    doc["nifo_version"] = __version__
    if linear is not None:
        doc["linear_h1"] = linear.to_dict()
    return doc


def write_model(path: str | os.PathLike, model: IdentifiedModel, *, linear: IdentifiedModel | None = None,
                atomic: bool = True) -> Path:
    """Write ``model.json`` (see :func:`model_document`)."""
    return write_json(path, model_document(model, linear=linear), atomic=atomic)


# -----------------------------------------------------------------------------
# model.json's schema: the same discipline as model files (pydantic, strict types), on what is read back
# -----------------------------------------------------------------------------

_Finite = Annotated[float, Field(allow_inf_nan=False)]
_Nullable = Annotated[float, Field(allow_inf_nan=False)] | None       # JSON writes NaN as null
_Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
_Pair = Annotated[list[_Finite], Field(min_length=2, max_length=2)]
_NullablePair = Annotated[list[_Nullable], Field(min_length=2, max_length=2)]
_MODEL_FIX = ("give the model.json nifo identify or nifo loop wrote (this one was edited or damaged); "
              "run nifo identify again to write it anew")


class _Doc(BaseModel):
    """A part of a document nifo wrote: strict types; keys it does not read are ignored."""

    model_config = ConfigDict(strict=True, extra="ignore", frozen=True)


class _Complex(_Doc):
    re: list[_Nullable]
    im: list[_Nullable]

    @model_validator(mode="after")
    def _same_length(self) -> "_Complex":
        if len(self.re) != len(self.im):
            raise ValueError(f"re has {len(self.re)} values, im {len(self.im)}")
        return self


class _FiniteComplex(_Complex):
    re: list[_Finite]
    im: list[_Finite]


class _BodyDoc(_Doc):
    k: _Finite
    c: _Finite
    k3: _Finite = 0.0
    fit_rms: _Nullable = None


class _LinearDoc(_Doc):
    kind: Literal["body", "rational"]
    body: _BodyDoc | None = None
    poles: _FiniteComplex | None = None
    residues: _FiniteComplex | None = None
    paths: list[_FiniteComplex] | None = None
    fit_rms: _Nullable = None
    band_hz: _NullablePair | None = None
    reason: str = ""
    candidates: dict[str, Any] | None = None
    absorbed: _Pair | None = None

    @model_validator(mode="after")
    def _parts(self) -> "_LinearDoc":
        if self.kind == "body" and self.body is None:
            raise ValueError("a linear part of kind 'body' needs 'body' (k, c)")
        if self.kind == "rational":
            if self.poles is None or self.residues is None:
                raise ValueError("a rational linear part needs 'poles' and 'residues'")
            if len(self.poles.re) != len(self.residues.re):
                raise ValueError(f"{len(self.poles.re)} poles but {len(self.residues.re)} residues")
        return self


class _BandDoc(_Doc):
    f_lo_hz: _Positive
    f_hi_hz: _Positive


class _SpectralDoc(_Doc):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    block: Annotated[int, Field(ge=8)]
    overlap: Annotated[float, Field(ge=0.0, lt=1.0, allow_inf_nan=False)]
    window: str
    detrend: str = "constant"


class _OffsetsDoc(_Doc):
    force: _Nullable = None
    output: _Finite = 0.0
    output_name: Literal["body_accel", "body_disp"] = "body_accel"
    how: str = ""


class _Banded(_Doc):
    band_hz: _Pair

    @field_validator("band_hz")
    @classmethod
    def _band(cls, v: list[float]) -> list[float]:
        if not v[0] < v[1]:
            raise ValueError(f"band_hz {v[0]:g}-{v[1]:g} must have its lower value first")
        return v


class _PredictionBandDoc(_Banded):
    policy: Literal["whole", "band"]
    reason: str = ""
    held_out: dict[str, Any] | None = None


class _PeriodicResponseDoc(_Doc):
    policy: Literal["periodic", "simulated"]
    reason: str = ""
    held_out: dict[str, Any] | None = None
    distortion: Literal["model", "linear"] = "model"


class _ValidityDoc(_Banded):
    input: Literal["spindle_accel", "force"]
    unit: str = ""
    rms: _Pair
    peak: _Pair
    outside_band_fraction: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.0
    n_records: Annotated[int, Field(ge=0)] = 0
    strut_range: dict[str, Any] | None = None


class ModelDocument(_Doc):
    """``model.json`` as :func:`read_model` accepts it: every field prediction uses, of the right type and
    finite (null only where NaN is a value nifo writes: T21 and B lines, fit errors)."""

    nifo_identified_model: int
    freq_hz: list[_Finite]
    t21: _Complex
    b: list[_Complex]
    terms: list[TermSpec]
    c_over_m2: list[_Finite]
    body: _BodyDoc | None
    linear_part: _LinearDoc | None = None
    force_gain: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] | None = None
    analysis_band_hz: _Pair
    fs_hz: _Positive
    settings: _SpectralDoc
    band: _BandDoc
    source: str = "static"
    provenance: dict[str, Any] | None = None
    offsets: _OffsetsDoc | None = None
    prediction_band: _PredictionBandDoc | None = None
    periodic_response: _PeriodicResponseDoc | None = None
    validity: _ValidityDoc | None = None
    linear_h1: "ModelDocument | None" = None

    @field_validator("nifo_identified_model", mode="before")
    @classmethod
    def _version(cls, v: Any) -> Any:
        if type(v) is not int or v != 1:
            raise ValueError(f"must be the integer 1, got {v!r}")
        return v

    @model_validator(mode="after")
    def _shapes(self) -> "ModelDocument":
        nf, nt = len(self.freq_hz), len(self.terms)
        if len(self.t21.re) != nf:
            raise ValueError(f"t21 has {len(self.t21.re)} lines but freq_hz {nf}")
        if len(self.b) != nt or any(len(x.re) != nf for x in self.b):
            raise ValueError(f"b must hold {nt} term(s) of {nf} lines each")
        if len(self.c_over_m2) != nt:
            raise ValueError(f"c_over_m2 has {len(self.c_over_m2)} value(s) for {nt} term(s)")
        if self.body is None and self.linear_part is None:
            raise ValueError("the model has no linear part: neither 'body' nor 'linear_part'")
        return self


def check_model_document(doc: Mapping, source: str) -> None:
    """Raise :class:`ConfigError` naming the file and the first field that is missing, null or of a wrong type."""
    try:
        ModelDocument.model_validate(dict(doc))
    except ValidationError as err:
        raise validation_error(err, source, hint=_MODEL_FIX, yaml=False) from None
    except RecursionError:
        raise ConfigError("the document nests too deeply", source=source, hint=_MODEL_FIX) from None


def read_model(path: str | os.PathLike) -> tuple[IdentifiedModel, IdentifiedModel | None]:
    """The identified model and (when stored) its plain-H1 linear counterpart from a ``model.json``.

    ``path`` may also be a directory holding ``model.json`` (what ``nifo identify``
    or ``nifo loop`` wrote). A missing file is named, with what writes it.
    """
    p = Path(path)
    if p.is_dir():
        if not (p / MODEL_JSON).is_file():
            raise DataFileError(f"the directory has no {MODEL_JSON}", source=str(p),
                                hint=f"give the output directory of nifo identify or nifo loop, or the {MODEL_JSON} "
                                     "file itself (identify.json alone cannot predict)")
        p = p / MODEL_JSON
    elif not p.exists():
        raise DataFileError(f"identified model file {p.name} does not exist", source=str(p),
                            hint=f"give the {MODEL_JSON} (or its directory) that nifo identify or nifo loop wrote")
    doc = read_json(p, what="identified model")
    if "nifo_identified_model" not in doc:
        raise ConfigError("not an identified model file (no 'nifo_identified_model: 1')", source=str(p),
                          hint="give the model.json that nifo identify wrote")
    check_model_document(doc, str(p))
    try:
        model = IdentifiedModel.from_dict(_nan(doc))
        lin = doc.get("linear_h1")
        linear = None if lin is None else IdentifiedModel.from_dict(_nan(lin))
    except ConfigError as err:
        raise err.with_context(source=str(p)) from None
    for m, where in ((model, ""), (linear, "linear_h1: ")):
        if m is not None:
            _check_model(m, str(p), where)
    return model, linear


def _check_model(model: IdentifiedModel, source: str, where: str) -> None:
    """What the schema cannot say about a model.json: its analysis band ordered, its linear part stable (a model
    that cannot be simulated is the file's fault, named as such rather than after the data it was given)."""
    lo, hi = model.analysis_band_hz
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi):
        raise ConfigError(f"{where}analysis_band_hz {lo:g} {hi:g} must satisfy 0 <= LO < HI", source=source,
                          channel="analysis_band_hz", hint=_MODEL_FIX)
    if not model.linear.stable:
        poles = np.round(model.linear.all_poles(), 4).tolist()
        raise ConfigError(f"{where}the linear part is not stable (poles {poles} 1/s): it cannot be simulated",
                          source=source, channel="linear_part", hint=_MODEL_FIX)

