"""The typed options of each pipeline step: what its command line gives, with the command line's defaults.

A command parses its arguments and hands the step its options (``XOptions.from_args(args)``); ``nifo run``, the
fleet and the benchmarks build the same objects directly, so no step is ever driven by re-parsing an argument
list. Every option object carries the input and settings options of :class:`Inputs`
(:func:`nifo.io.loader.add_input_arguments`, :func:`nifo.settings.add_settings_arguments`,
:func:`nifo.io.provenance.add_system_argument`), which :func:`nifo.settings.resolve` merges once with the model
file and the data into the one :class:`~nifo_core.settings.AnalysisSettings`.

``tests/test_pipeline_options.py`` checks that the fields and defaults here are the commands' own.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Sequence

__all__ = ["Inputs", "CharacterizeOptions", "IdentifyOptions", "LoopOptions", "PredictOptions", "RunOptions",
           "ExportOptions"]

#: NIFO's default streaming chunk [samples] (7.3 min at 600 Hz): memory stays ~0.1 GB whatever the record's length
CHUNK_SAMPLES = 2 ** 18


class _FromArgs:
    @classmethod
    def from_args(cls, args: argparse.Namespace, **given):
        """The options of parsed arguments (attributes the parser did not define keep their defaults), ``given``
        overriding them."""
        return cls(**{**{f.name: getattr(args, f.name) for f in fields(cls) if hasattr(args, f.name)}, **given})


@dataclass(frozen=True)
class Inputs(_FromArgs):
    """The input and settings options every data step takes (None: not given — the model file, the data or the
    default decide)."""

    topics: str | None = None
    columns: str | None = None
    fs_hz: float | None = None
    axis: str = "z"
    skip_seconds: float | None = None
    skip_periods: int | None = None
    period_samples: int | None = None
    block: int | None = None
    overlap: float | None = None
    window: str | None = None
    analysis_band_hz: Sequence[float] | None = None
    no_settings_from_data: bool = False
    system: str | None = None
    #: the CLI's ``--quiet`` (no settings printout)
    quiet: bool = False

    def taking(self, given: Inputs):
        """These options with the input and settings options of ``given`` that this step also has (``nifo run``
        passes its own --columns, --block, ... on to every step)."""
        mine = {f.name for f in fields(self)}
        return replace(self, **{f.name: getattr(given, f.name) for f in fields(given)
                                if f.name in mine and f.name in INPUT_FIELDS})


@dataclass(frozen=True)
class CharacterizeOptions(Inputs):
    """``nifo characterize``: restoring-force plots and the suggested model."""

    data: Sequence[str] = ()
    out: Path | None = None
    integration_band_hz: Sequence[float] | None = None
    m2: float | None = None
    top: int = 5
    max_terms: int = 3
    kinds: str | None = None
    freq_window: Sequence[float] | None = None
    grid: int = 24
    min_err: float = 0.02
    slices_hz: Sequence[float] | None = None
    amplitude_bins: int = 4


@dataclass(frozen=True)
class IdentifyOptions(Inputs):
    """``nifo identify``: NIFO on the records, optionally refined by output error."""

    data: Sequence[Path] = ()
    model: Path | None = None
    out: Path | None = None
    integration_band_hz: Sequence[float] | None = None
    cond_limit: float | None = None
    step_data: Sequence[Sequence[Path]] | None = None
    chunk_samples: int = CHUNK_SAMPLES
    no_plots: bool = False
    refine: bool = False
    refine_linear: bool = False
    feedback_paths: bool = False
    refine_seconds: float = 120.0


@dataclass(frozen=True)
class LoopOptions(Inputs):
    """``nifo loop``: from the declared (or linear) model, what the data need."""

    data: Sequence[str] = ()
    model: Path | None = None
    out: Path | None = None
    integration_band_hz: Sequence[float] | None = None
    cond_limit: float | None = None
    max_rounds: int = 4
    m2: float | None = None
    fit_fraction: float = 2 / 3
    kinds: str | None = None
    grid: int = 24
    prediction: str = "model"
    structure: str = "auto"
    no_retune: bool = False
    no_refine: bool = False
    refine_seconds: float = 60.0


@dataclass(frozen=True)
class PredictOptions(Inputs):
    """``nifo predict``: an identified model applied to records."""

    data: Sequence[Path] = ()
    model: Path | None = None
    out: Path | None = None
    method: str = "parametric"
    no_plots: bool = False


@dataclass(frozen=True)
class RunOptions(Inputs):
    """``nifo run``: the whole job."""

    data: Sequence[Path] = ()
    out: Path = Path("results")
    integration_band_hz: Sequence[float] | None = None
    cond_limit: float | None = None
    no_loop: bool = False
    no_refine: bool = False
    no_recording: bool = False


@dataclass(frozen=True)
class ExportOptions(_FromArgs):
    """``nifo export``: an identified model's strut force law as tables, its linear part, a figure."""

    model: Path | None = None
    out: Path | None = None
    m2: float | None = None
    points: int = 201
    #: the CLI's ``--quiet``
    quiet: bool = False


#: the fields of the options that no flag gives (the command's --quiet; what nifo run tells its steps)
NOT_FLAGS = frozenset({"quiet"})
#: the options ``nifo run`` passes on to every step that has them (the flags of the input and settings groups; the
#: settings themselves travel resolved, as one AnalysisSettings)
INPUT_FIELDS = frozenset({f.name for f in fields(Inputs)} - {"quiet"} | {"integration_band_hz", "cond_limit"})

