"""The identification engine: how records are fed into NIFO, the same for every shell.

``nifo identify`` and ``nifo run`` (:mod:`nifo.pipeline.identify`), the fleet's workers
(:mod:`nifo.fleet.tasks`), the identifier node and the viewer's replay (:mod:`nifo.viz.offline`) all
accumulate through this module, as scipy's ``welch`` is ``csd(x, x)``: one set-up decision
(:meth:`IdentifySetup.for_probes`: one rate, a measured force on every record, a fixed or a moving spindle,
the tire patch, the integration band of the shortest record), one accumulator constructor
(:meth:`IdentifySetup.accumulator`: every setting, the conditioning limit included) and one way a chunk enters
it (:meth:`IdentifySetup.push`, :func:`accumulate_record`: the first chunk's acceleration offsets removed from
every chunk, the force and tire patch when the set-up takes them). A shell that skipped a channel here would
identify a force-driven rig without its force, silently: there is no other path to skip it on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Mapping, Sequence

from ..errors import InputError, NifoError, RecordTooShortError, SampleRateError
from ..kinds.describing import Term
from ..signal.integrate import IntegrationBand, default_band
from ..signal.record import Record, acceleration_means
from ..signal.spectral import SpectralSettings
from .result import A1, DEFAULT_ANALYSIS_BAND_HZ, DEFAULT_COND_LIMIT, FORCE, OnIll
from .stream import StreamingNifo, _as_terms

__all__ = ["RecordProbe", "IdentifySetup", "accumulate_record"]


@dataclass(frozen=True)
class RecordProbe:
    """What the set-up needs to know of a record before streaming it: rate, length and channels.

    Read off the first chunk (:meth:`of`); small and JSON-able (:meth:`to_dict`), so the fleet keeps it in a
    note beside its cache.
    """

    fs_hz: float
    n_samples: int
    has_tire_patch: bool = False
    has_force: bool = False
    spindle_fixed: bool = False

    @classmethod
    def of(cls, first: Record, *, whole: bool = False) -> "RecordProbe":
        """The probe of a record from its first chunk (``meta["chunk"]["total_samples"]``: the whole length), or
        of a ``whole`` record (its own length)."""
        n = first.n if whole else first.meta.get("chunk", {}).get("total_samples", first.n)
        return cls(fs_hz=float(first.fs_hz), n_samples=int(n),
                   has_tire_patch=bool(first.has_tire_patch), has_force=bool(first.has_force),
                   spindle_fixed=bool(first.spindle_fixed))

    def to_dict(self) -> dict:
        return {"fs_hz": self.fs_hz, "n_samples": self.n_samples, "has_tire_patch": self.has_tire_patch,
                "has_force": self.has_force, "spindle_fixed": self.spindle_fixed}

    @classmethod
    def from_dict(cls, d: Mapping) -> "RecordProbe":
        return cls(fs_hz=float(d["fs_hz"]), n_samples=int(d["n_samples"]), has_tire_patch=bool(d["has_tire_patch"]),
                   has_force=bool(d["has_force"]), spindle_fixed=bool(d["spindle_fixed"]))


@dataclass(frozen=True)
class IdentifySetup:
    """How every record of one identification is accumulated (one per job, group or node).

    Attributes
    ----------
    fs_hz : float
        The records' common sample rate [Hz].
    terms : tuple of Term
    spectral : SpectralSettings
    band : IntegrationBand
        Integration band for z, ż (validated for the shortest record).
    analysis_band_hz : (float, float)
    cond_limit : float
        Scaled cond(G_UU) above which a line is ill-conditioned.
    with_tire_patch, with_force, spindle_fixed : bool
        The channels taken (:class:`~nifo_core.nifo.stream.StreamingNifo`): the tire patch only without a force.
    """

    fs_hz: float
    terms: tuple[Term, ...]
    spectral: SpectralSettings
    band: IntegrationBand
    analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ
    cond_limit: float = DEFAULT_COND_LIMIT
    with_tire_patch: bool = False
    with_force: bool = False
    spindle_fixed: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "terms", _as_terms(self.terms))
        object.__setattr__(self, "analysis_band_hz", tuple(float(x) for x in self.analysis_band_hz))
        if self.spindle_fixed and not self.with_force:
            raise InputError("records with a fixed spindle need their measured force as the input", channel=FORCE,
                             hint="give the force channel (--columns force=NAME)")

    @classmethod
    def for_probes(cls, probes: Sequence[RecordProbe], terms: Sequence[Term], *,
                   spectral: SpectralSettings | None = None, band: IntegrationBand | None = None,
                   analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ,
                   cond_limit: float = DEFAULT_COND_LIMIT, sources: Sequence[str] = (),
                   input_measured: bool | None = None, use_force: bool | None = None) -> "IdentifySetup":
        """The set-up of records with these probes, as every shell decides it.

        One sample rate (else :class:`SampleRateError` naming each); the force taken when every record has one
        (``use_force``: force it on or off); a fixed spindle for all or none (else :class:`InputError`); the tire
        patch when every record has it and no force is used (``input_measured``: on or off); the integration band
        ``band`` or ``default_band(fs, shortest duration)``, validated for the shortest record (its error names
        that record). ``sources``: the records' names, for the messages.
        """
        if not probes:
            raise InputError("no records to identify", hint="give at least one data file")
        names = list(sources) or [f"record {i}" for i in range(len(probes))]
        rates = sorted({p.fs_hz for p in probes})
        if len(rates) > 1:
            each = ", ".join(f"{n} {p.fs_hz:g} Hz" for n, p in zip(names, probes))
            raise SampleRateError(f"the records have different sample rates ({each})",
                                  hint="resample to one rate first")
        fs = rates[0]
        has_force = all(p.has_force for p in probes)
        if use_force is None:
            use_force = has_force
        if use_force and not has_force:
            missing = [n for n, p in zip(names, probes) if not p.has_force]
            raise InputError(f"NIFO with force needs the force in every record, missing in {missing}", channel=FORCE,
                             hint="give the force channel of every record (--columns force=NAME), or none")
        fixed = {p.spindle_fixed for p in probes}
        if len(fixed) > 1:
            raise InputError("some records have a fixed spindle and some a measured one", channel=A1,
                             hint="identify records of one kind together")
        has_tp = all(p.has_tire_patch for p in probes)
        if input_measured is None:
            input_measured = has_tp
        if input_measured and not has_tp:
            missing = [n for n, p in zip(names, probes) if not p.has_tire_patch]
            raise InputError(f"input-measured NIFO needs the tire patch, missing in {missing}",
                             channel="tire_patch_disp", hint="use records with tire_patch_disp")
        shortest = min(range(len(probes)), key=lambda i: probes[i].n_samples)
        n_min = probes[shortest].n_samples
        try:
            band = (band or default_band(fs, n_min / fs)).validate(fs, n_samples=n_min)
        except NifoError as err:   # name the record that is too short
            if not sources:
                raise
            raise err.with_context(source=names[shortest]) from None
        return cls(fs_hz=fs, terms=tuple(terms), spectral=spectral or SpectralSettings(), band=band,
                   analysis_band_hz=analysis_band_hz, cond_limit=cond_limit,
                   with_tire_patch=bool(input_measured and not use_force), with_force=bool(use_force),
                   spindle_fixed=fixed.pop())

    def accumulator(self, *, fixed=None, spindle_noise_psd: float | None = None,
                    on_ill_conditioned: OnIll = "warn") -> StreamingNifo:
        """A fresh :class:`StreamingNifo` with every setting of this set-up (``fixed``: two-step's step 1)."""
        return StreamingNifo(self.fs_hz, self.terms, settings=self.spectral, band=self.band, fixed=fixed,
                             with_tire_patch=self.with_tire_patch, spindle_noise_psd=spindle_noise_psd,
                             analysis_band_hz=self.analysis_band_hz, on_ill_conditioned=on_ill_conditioned,
                             cond_limit=self.cond_limit, with_force=self.with_force, spindle_fixed=self.spindle_fixed)

    def push(self, acc: StreamingNifo, chunk: Record) -> int:
        """Feed one chunk with the channels this set-up takes; the blocks it completed."""
        return acc.push(chunk.spindle_accel, chunk.body_accel,
                        chunk.tire_patch_disp if self.with_tire_patch else None,
                        chunk.force if self.with_force else None)

    def too_short(self, acc: StreamingNifo, n_samples: int, *, source: str = "") -> RecordTooShortError:
        """The error of a record that gave no spectral block (its length, and what NIFO needs)."""
        return RecordTooShortError(
            f"{n_samples} samples ({n_samples / self.fs_hz:.1f} s) is too short for NIFO (block="
            f"{acc.settings.block} plus {acc.delay_samples} integrator edge samples at each end for "
            f"f_lo={self.band.f_lo_hz:g} Hz), which needs {acc.min_samples}", source=source,
            hint="record longer, or choose a smaller --block")


def accumulate_record(chunks: Iterable[Record], setup: IdentifySetup, *, source: str = "",
                      acc: StreamingNifo | None = None,
                      on_chunk: Callable[[StreamingNifo, Record], None] | None = None) -> tuple[StreamingNifo, int]:
    """One record, chunk by chunk, into a fresh accumulator (or ``acc``): (accumulator, samples pushed).

    The first chunk's acceleration means are removed from every chunk in float64 (an offset of any size gives the
    answer of the record without it: :meth:`Record.centred`); each chunk enters through
    :meth:`IdentifySetup.push`; ``on_chunk(acc, chunk)`` after each (a progress bar, a replay's log). A record
    with no sample or no complete spectral block raises :class:`RecordTooShortError` naming ``source``.
    """
    one = setup.accumulator() if acc is None else acc
    n, means = 0, None
    for chunk in chunks:
        if means is None:
            means = acceleration_means(chunk)
        chunk = chunk.centred(means)
        setup.push(one, chunk)
        n += chunk.n
        if on_chunk is not None:
            on_chunk(one, chunk)
    if means is None:
        raise RecordTooShortError("the file holds no samples", source=source)
    if one.n_avg == 0:
        raise setup.too_short(one, n, source=source)
    return one, n
