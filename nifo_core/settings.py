"""One settings object for every step, with one merge: given > model file > chosen from the data > default.

Every spectral and band setting an identification needs is here, once:

- ``spectral``: block, window, overlap (:class:`~nifo_core.signal.spectral.SpectralSettings`);
- ``band``: the integration band of z, ż (:class:`~nifo_core.signal.integrate.IntegrationBand`);
- ``analysis_band_hz``: where NIFO pools, the linear part is fitted and predictions are scored;
- ``period_samples`` / ``skip_periods`` / ``skip_seconds``: a periodic excitation and the transient to drop;
- ``cond_limit``: the conditioning that counts as ill-conditioned.

:func:`resolve_settings` merges what the user gave on the command line, what
the model file's ``settings:`` say, what :mod:`nifo_core.signal.excitation` read off
the data, and the defaults, in that order, validates the result once, and
records for each setting its value, where it came from and why
(:attr:`AnalysisSettings.choices`), so a command prints each choice once and a
result carries them.

Chosen from the data (docs/method.md §8), where not given:

- periodic excitation: one period per block, boxcar window, no overlap
  (leakage-free), the transient periods dropped;
- random excitation: the paper's blocks (Table 2: flattop, 52 % overlap,
  6144 samples at 600 Hz: 10.24 s), shortened when the record would give
  fewer than 8 averages, never below 4 cycles of the lowest analysed line;
- the analysis band: the excited band (random excitation: from 2 Hz at the
  lowest, see :data:`RANDOM_LOWEST_HZ`);
- the integration band: periodic data from 2/3 of the lowest analysed line
  (the integrator is exact from 1.5× its lower edge), random data from where
  z rises 10 dB out of the integrated accelerometer noise (its lowest modes
  inside, though the input may be weak there), never lower than the record's
  length allows; to 3× the top of the excited band (the harmonics of a
  clearance or play), at most fs/2.5.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Mapping, Sequence

import numpy as np

from .defaults import DEFAULT_ANALYSIS_BAND_HZ, DEFAULT_COND_LIMIT
from .errors import ConfigError
from .setting_rules import check_timing
from .signal.excitation import Excitation
from .signal.integrate import IntegrationBand, default_band, lowest_edge_hz
from .signal.spectral import SpectralSettings

__all__ = ["Choice", "GivenSettings", "AnalysisSettings", "DEFAULT_ANALYSIS_BAND_HZ", "DEFAULT_COND_LIMIT",
           "PAPER_BLOCK_S", "resolve_settings", "merge_given", "period_and_transient", "Timing",
           "shortest_after_transient"]

#: random data: at least this many spectral averages before the paper's block is shortened
MIN_AVERAGES = 8
#: the paper's spectral block for random data [s] (Table 2: 6144 samples at 600 Hz)
PAPER_BLOCK_S = 6144 / 600.0
#: the integrator is exact (within 0.2 %) from this multiple of its lower edge
EXACT_FROM = 1.5
#: the integration band reaches this multiple of the top of the excited band (a play's or clearance's harmonics)
HARMONICS = 3.0
#: random excitation: the analysis band starts no lower (the paper's 2 Hz, Table 2 and its figures). Below it the
#: relative motion carries the integrated accelerometer noise and the window's leakage around the body mode: on the
#: bundled sample (2 % noise) NIFO's pooled play coefficient is +20 % from 2 Hz, +42 % from the excited band's 0.9 Hz
RANDOM_LOWEST_HZ = 2.0


@dataclass(frozen=True)
class Choice:
    """One setting's value, where it came from ('command line', 'model file', 'data', 'default') and why."""

    value: object
    source: str
    reason: str = ""

    def to_dict(self) -> dict:
        v = self.value
        if isinstance(v, IntegrationBand):
            v = [v.f_lo_hz, v.f_hi_hz]
        elif isinstance(v, tuple):
            v = list(v)
        return {"value": v, "source": self.source, "reason": self.reason}


@dataclass(frozen=True)
class GivenSettings:
    """Settings given by the user (command line) or a model file: None where not given."""

    block: int | None = None
    overlap: float | None = None
    window: str | None = None
    integration_band_hz: tuple[float, float] | None = None
    analysis_band_hz: tuple[float, float] | None = None
    period_samples: int | None = None
    skip_periods: int | None = None
    skip_seconds: float | None = None
    cond_limit: float | None = None

    def __post_init__(self) -> None:
        for name in ("integration_band_hz", "analysis_band_hz"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _pair(v, name))
        check_timing(period_samples=self.period_samples, skip_periods=self.skip_periods, skip_seconds=self.skip_seconds)
        if self.cond_limit is not None and not (np.isfinite(self.cond_limit) and self.cond_limit > 1):
            raise ConfigError(f"cond_limit={self.cond_limit!r} must be a number > 1", channel="--cond-limit")
        if self.integration_band_hz is not None and self.integration_band_hz[0] <= 0:
            lo, hi = self.integration_band_hz
            raise ConfigError(f"integration band {lo:g}-{hi:g} Hz needs LO > 0",
                              channel="--integration-band", hint="e.g. --integration-band 0.5 200")
        spectral = {k: getattr(self, k) for k in ("block", "overlap", "window") if getattr(self, k) is not None}
        if spectral:    # the spectral engine's own rules, checked here once for every caller
            replace(SpectralSettings(), **spectral)

    def items(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


#: a band setting's flag and its name in words (the messages of every source: flag, model file, node parameter)
_BANDS = {"integration_band_hz": ("--integration-band", "integration band"),
          "analysis_band_hz": ("--analysis-band", "analysis band")}


def _pair(value, name: str) -> tuple[float, float]:
    flag, words = _BANDS[name]
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(f"{words} {value!r} must be two numbers [Hz]", channel=flag, hint="e.g. 2 30") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi):
        raise ConfigError(f"{words} {lo:g}-{hi:g} Hz must satisfy 0 <= LO < HI", channel=flag, hint="e.g. 2 30")
    return lo, hi


def merge_given(*layers: GivenSettings) -> tuple[GivenSettings, dict[str, str]]:
    """The first layer that gives a setting wins; (merged, setting → index of the layer that gave it)."""
    out: dict = {}
    origin: dict[str, str] = {}
    for i, layer in enumerate(layers):
        for k, v in layer.items().items():
            if k not in out:
                out[k] = v
                origin[k] = i
    return GivenSettings(**out), origin


@dataclass(frozen=True)
class AnalysisSettings:
    """The settings every step uses (module docstring); ``choices`` says where each came from and why."""

    spectral: SpectralSettings
    band: IntegrationBand | None        # None: not resolvable without the data (the default for each record)
    analysis_band_hz: tuple[float, float]
    period_samples: int | None = None
    skip_periods: int | None = None
    skip_seconds: float | None = None
    cond_limit: float = DEFAULT_COND_LIMIT
    excitation: Excitation | None = None
    choices: Mapping[str, Choice] = field(default_factory=dict)
    #: what was found in each record before any setting was chosen (constant offsets removed, clipping), by file
    inputs: Mapping[str, Mapping] = field(default_factory=dict)
    #: one line each about the records (an offset removed, a channel that clipped a little), printed with the settings
    notes: tuple[str, ...] = ()

    def describe(self) -> list[str]:
        """One line per setting: value, source and reason (what a command prints once); then the notes."""
        out = []
        for name, c in self.choices.items():
            out.append(f"{_LABELS.get(name, name)}: {_fmt(c.value)} ({c.source}{': ' + c.reason if c.reason else ''})")
        return out + list(self.notes)

    def source_of(self, name: str) -> str:
        """Where setting ``name`` came from, in words ("command line", "model file", "chosen from the data", ...)."""
        c = self.choices.get(name)
        if c is None:
            return "default"
        return {"data": "chosen from the data", "default": "the default"}.get(c.source, c.source)

    def to_dict(self) -> dict:
        band = None if self.band is None else [self.band.f_lo_hz, self.band.f_hi_hz]
        return {"spectral": self.spectral.to_dict(), "integration_band_hz": band,
                "analysis_band_hz": list(self.analysis_band_hz), "period_samples": self.period_samples,
                "skip_periods": self.skip_periods, "skip_seconds": self.skip_seconds, "cond_limit": self.cond_limit,
                "excitation": None if self.excitation is None else self.excitation.to_dict(),
                "choices": {k: c.to_dict() for k, c in self.choices.items()},
                "inputs": {k: dict(v) for k, v in self.inputs.items()}, "notes": list(self.notes)}

    def skip_samples(self, fs_hz: float) -> int:
        """Samples dropped from the start of a record (the transient)."""
        if self.period_samples and self.skip_periods:
            return int(self.period_samples) * int(self.skip_periods)
        return int(round(float(self.skip_seconds or 0.0) * fs_hz))


_LABELS = {"period_samples": "period", "skip_periods": "transient", "skip_seconds": "transient",
           "spectral": "blocks", "analysis_band_hz": "analysis band", "band": "integration band",
           "cond_limit": "ill-conditioned above"}


def _fmt(v) -> str:
    if isinstance(v, IntegrationBand):
        return f"{v.f_lo_hz:.4g}-{v.f_hi_hz:.4g} Hz"
    if isinstance(v, tuple) and len(v) == 2 and all(isinstance(x, float) for x in v):
        return f"{v[0]:.4g}-{v[1]:.4g} Hz"
    if isinstance(v, SpectralSettings):
        return f"{v.block} samples, {v.window} window, {100 * v.overlap:g} % overlap"
    return str(v)


def _random_block(fs_hz: float, n_samples: int, lowest_hz: float, overlap: float) -> tuple[int, str]:
    """The paper's 10.24 s block, shortened for ≥ MIN_AVERAGES averages, never below 4 cycles of ``lowest_hz``."""
    block = int(round(PAPER_BLOCK_S * fs_hz))
    need = int(np.ceil(4 * fs_hz / max(lowest_hz, 1e-9)))
    step = 1.0 - overlap

    def averages(b: int) -> int:
        return int((n_samples - b) // max(int(round(b * step)), 1)) + 1 if n_samples >= b else 0

    why = f"the paper's {block / fs_hz:.4g} s blocks"
    if block < need:     # a slow system sampled slowly (a 1 Hz record): the paper's seconds resolve none of its lines
        block = 1 << int(np.ceil(np.log2(need)))
        why = f"blocks of {block / fs_hz:.4g} s for 4 cycles of the lowest line"
    while averages(block) < MIN_AVERAGES and block // 2 >= max(need, 64):
        block //= 2
        why = f"blocks shortened to {block / fs_hz:.4g} s for {MIN_AVERAGES} averages"
    return block, f"{why}: {averages(block)} averages, {block / fs_hz * lowest_hz:.3g} cycles of the lowest line"


@dataclass(frozen=True)
class Timing:
    """A periodic excitation's period and the transient dropped before any block (None: none)."""

    period_samples: int | None
    skip_periods: int | None
    skip_seconds: float | None


def period_and_transient(given: GivenSettings, excitation: Excitation | None, choices: dict[str, Choice],
                         given_choice) -> Timing:
    """The period and the transient: as given, else read off ``excitation``; their :class:`Choice` entered in
    ``choices`` (``given_choice(value, name)``: the choice of a given
    value). The one place both are decided: :func:`resolve_settings` for a job, and the job's settings on some of its
    records (:func:`nifo.settings.for_records`: a level, a file) where the job left them to the data."""
    ex = excitation
    period = given.period_samples
    if period is not None:
        choices["period_samples"] = given_choice(int(period), "period_samples")
    elif ex is not None and ex.periodic:
        period = ex.period_samples
        choices["period_samples"] = Choice(int(period), "data", ex.reasons.get("period", ""))
    elif ex is not None:
        choices["period_samples"] = Choice(None, "data", ex.reasons.get("period", ""))
    skip_periods, skip_seconds = given.skip_periods, given.skip_seconds
    if skip_periods is not None:
        choices["skip_periods"] = given_choice(int(skip_periods), "skip_periods")
    elif skip_seconds is not None:
        choices["skip_seconds"] = given_choice(float(skip_seconds), "skip_seconds")
    elif ex is not None and ex.periodic and ex.period_samples == period:
        skip_periods = int(ex.transient_periods)
        choices["skip_periods"] = Choice(skip_periods, "data", ex.reasons.get("transient", ""))
    if skip_periods and not period:
        raise ConfigError("--skip-periods needs the period: give --period-samples too", channel="--skip-periods")
    return Timing(period, skip_periods, skip_seconds)


def shortest_after_transient(durations_s: Sequence[float], fs_hz: float | None, period_samples: int | None,
                             skip_periods: int | None, skip_seconds: float | None) -> float | None:
    """The shortest record's duration once its transient is dropped [s] (None without records): what bounds the
    blocks and the integration band's lower edge."""
    shortest = min(durations_s) if durations_s else None
    if shortest is not None and period_samples and skip_periods:
        shortest = shortest - skip_periods * period_samples / fs_hz
    elif shortest is not None and skip_seconds:
        shortest = shortest - skip_seconds
    return shortest


def resolve_settings(given: GivenSettings, *, fs_hz: float | None, durations_s: Sequence[float] = (),
                     excitation: Excitation | None = None, snr_lo_hz: float | None = None,
                     origins: Mapping[str, str] | None = None,
                     reasons: Mapping[str, str] | None = None) -> AnalysisSettings:
    """Merge ``given`` (already command line > model file, :func:`merge_given`) with the choices from the data.

    Long because it is the one place every setting is decided, each with the reason it is printed with: one
    short stanza per setting, read top to bottom, rather than nine helpers each passed the same context.

    Parameters
    ----------
    given : GivenSettings
        What the user and the model file gave.
    fs_hz : float or None
        The records' rate; None (no data yet, e.g. a node before its first sample): an integration band not
        given stays None, the default of each record (:func:`~nifo_core.signal.integrate.default_band`).
    durations_s : sequence of float
        The records' durations after the transient [s] (the shortest bounds the integration band).
    excitation : Excitation, optional
        :func:`~nifo_core.signal.excitation.analyse_excitation` of the records (combined); None: the defaults.
    snr_lo_hz : float, optional
        Random data: where z rises out of the integrated accelerometer noise
        (:func:`nifo_core.characterize.restoring.suggest_band`): the integration band starts no lower.
    origins : mapping, optional
        Setting name → 'command line' / 'model file' (for the record of choices); or 'data' for a setting chosen
        from the data by a caller that chose it once for several steps (``nifo run``), with its reason in ``reasons``.
    """
    origins = dict(origins or {})
    reasons = dict(reasons or {})
    choices: dict[str, Choice] = {}
    g = given

    def from_user(name: str) -> str:
        return origins.get(name, "command line")

    def given_choice(value, name: str) -> Choice:
        return Choice(value, from_user(name), reasons.get(name, ""))

    ex = excitation
    timing = period_and_transient(g, ex, choices, given_choice)
    period, skip_periods, skip_seconds = timing.period_samples, timing.skip_periods, timing.skip_seconds
    periodic = period is not None or (ex is not None and ex.periodic)
    shortest = shortest_after_transient(durations_s, fs_hz, period, skip_periods, skip_seconds)
    # blocks
    if periodic and period:
        auto = SpectralSettings(block=int(period), overlap=0.0, window="boxcar")
        why = "periodic excitation: one period per block, boxcar, no overlap (leakage-free)"
    else:
        base = SpectralSettings()
        lowest = ex.band_hz[0] if ex is not None else DEFAULT_ANALYSIS_BAND_HZ[0]
        if ex is not None and fs_hz:
            n = int(shortest * fs_hz) if shortest else 10 ** 9
            block, why = _random_block(fs_hz, n, lowest, base.overlap)
            auto = replace(base, block=block)
            why = f"random excitation: flattop, {100 * base.overlap:g} % overlap (nearly independent blocks), {why}"
        else:
            auto, why = base, "paper Table 2"
    spec = SpectralSettings(block=int(g.block) if g.block is not None else auto.block,
                            overlap=float(g.overlap) if g.overlap is not None else auto.overlap,
                            window=g.window if g.window is not None else auto.window)
    given_spec = [k for k in ("block", "overlap", "window") if getattr(g, k) is not None]
    if given_spec:
        src = from_user(given_spec[0])
        choices["spectral"] = Choice(spec, src if len(given_spec) == 3 else f"{src} ({', '.join(given_spec)}), "
                                     f"data (the rest)", reasons.get(given_spec[0], "") if len(given_spec) == 3
                                     else why)
    else:
        choices["spectral"] = Choice(spec, "data" if ex is not None else "default", why if ex is not None else
                                     "paper Table 2")
    # bands
    top = fs_hz / 2.5 if fs_hz else float("inf")
    if g.analysis_band_hz is not None:
        analysis = g.analysis_band_hz
        choices["analysis_band_hz"] = given_choice(analysis, "analysis_band_hz")
    elif ex is not None:
        analysis = (float(ex.band_hz[0]), float(min(ex.band_hz[1], top)))
    else:
        analysis = DEFAULT_ANALYSIS_BAND_HZ
        choices["analysis_band_hz"] = Choice(analysis, "default", "paper Table 2's figures")
    floor = lowest_edge_hz(shortest) if shortest else 0.0
    if g.integration_band_hz is not None:
        band = IntegrationBand(*g.integration_band_hz)
        choices["band"] = given_choice(band, "integration_band_hz")
    elif ex is not None:
        lo = analysis[0] / EXACT_FROM
        why = [f"from 1/{EXACT_FROM:g} of the lowest analysed line"]
        if snr_lo_hz is not None and not periodic:   # random data: z is trusted from where it leaves the noise
            lo, why = snr_lo_hz, ["from where z rises 10 dB out of the integrated accelerometer noise"]
        if floor > lo:
            lo, why = floor, [f"from what the record's length allows ({shortest:.0f} s)"]
        hi = min(HARMONICS * ex.band_hz[1], top)
        why.append(f"to {'fs/2.5' if hi == top else f'{HARMONICS:g}× the top of the excited band'}")
        band = IntegrationBand(round(lo, 4), round(hi, 4))
        choices["band"] = Choice(band, "data", " ".join(why))
    elif fs_hz:
        band = default_band(fs_hz, shortest)
        choices["band"] = Choice(band, "default", "0.5 Hz (body bounce inside), raised for short records; "
                                 "min(200 Hz, fs/2.5)")
    else:
        band = None
        choices["band"] = Choice(None, "default", "default_band(fs, duration) of each record")
    if band is not None and fs_hz:   # an edge the shortest record cannot resolve is refused here, before any work
        band = band.validate(fs_hz, n_samples=int(shortest * fs_hz) if shortest else None)
    if g.analysis_band_hz is None and ex is not None and band is not None:
        lo = max(analysis[0], band.f_lo_hz)
        hi = min(analysis[1], band.f_hi_hz)
        if not lo < hi:
            raise ConfigError(f"the excited band {analysis[0]:.4g}-{analysis[1]:.4g} Hz lies outside what the "
                              f"record can integrate ({band.f_lo_hz:.4g}-{band.f_hi_hz:.4g} Hz)",
                              hint="record longer, or give --analysis-band and --integration-band")
        note = ex.reasons.get("band", "the excited band")
        if lo > analysis[0]:
            note += f"; from {lo:.4g} Hz, the integration band's lower edge"
        if not ex.periodic and lo < RANDOM_LOWEST_HZ < hi:
            lo = RANDOM_LOWEST_HZ
            note += (f"; from {RANDOM_LOWEST_HZ:g} Hz for random excitation (below it z carries the integrated "
                     f"noise and the window's leakage around the body mode)")
        analysis = (float(lo), float(hi))
        choices["analysis_band_hz"] = Choice(analysis, "data", note)
    cond = float(g.cond_limit) if g.cond_limit is not None else DEFAULT_COND_LIMIT
    if g.cond_limit is not None:
        choices["cond_limit"] = given_choice(cond, "cond_limit")
    return AnalysisSettings(spectral=spec, band=band, analysis_band_hz=(float(analysis[0]), float(analysis[1])),
                            period_samples=int(period) if period else None,
                            skip_periods=int(skip_periods) if skip_periods is not None else None,
                            skip_seconds=float(skip_seconds) if skip_seconds is not None else None,
                            cond_limit=cond, excitation=ex, choices=choices)
