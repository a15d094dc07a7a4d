"""What every step of the loop works on (:mod:`nifo_core.loop.closing`): the records checked and centred, the
integration band (:func:`loop_band`), the held-out split, the evaluator, the linear part's predictor, the frame of
the static position and the declared model fitted as declared (:class:`_Setup`, made by :func:`_set_up`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from ..kinds.describing import Term, make_term
from ..errors import ConfigError, InputError, RecordTooShortError
from ..signal.integrate import IntegrationBand
from ..predict.heldout import HeldOut, split_records
from .residual import _Evaluator
from ..settings import AnalysisSettings
from .results import DeclaredTerm
from .round_results import Errors
from .settings import LoopSettings
from .ambiguity import Explanation
from .frame import Frame
from .predictor import _errors, _Predictor
from ..signal.record import Record
from ..characterize.restoring import suggest_band

__all__ = ["loop_band"]


#: a record must span this many periods of the integration band's lower edge: the integrator takes 16
#: (its edges are dropped), and the held-out third must keep ≈ 4 periods once its band-pass has settled
LOOP_PERIODS_PER_RECORD = 48.0


def loop_band(records: Sequence[Record], band: IntegrationBand | None = None) -> tuple[IntegrationBand, str | None]:
    """The integration band for the loop on these records, and what was adapted (None: nothing).

    Default: :func:`~nifo_core.characterize.restoring.suggest_band` of the records together. Its lower edge is raised
    where the shortest record spans fewer than ``LOOP_PERIODS_PER_RECORD`` periods of it (30 s → 1.6 Hz,
    60 s → 0.8 Hz): every column of the equation error is band-limited alike, so a higher edge costs
    the loop only the motion below it, while a too-low one leaves no held-out part.
    """
    fs = float(records[0].fs_hz)
    band = (band or suggest_band(records).band).validate(fs)
    shortest = min(r.duration_s for r in records)
    need = LOOP_PERIODS_PER_RECORD / shortest if shortest > 0 else float("inf")
    if band.f_lo_hz >= need:
        return band, None
    new = IntegrationBand(round(float(np.ceil(need * 100) / 100), 2), band.f_hi_hz)
    if new.f_lo_hz >= new.f_hi_hz:
        raise RecordTooShortError(f"a {shortest:.1f} s record is too short for the loop",
                                  hint=f"record at least {LOOP_PERIODS_PER_RECORD / band.f_lo_hz:.0f} s")
    new.validate(fs)
    return new, (f"integration band's lower edge raised {band.f_lo_hz:g} → {new.f_lo_hz:g} Hz: the shortest record "
                 f"({shortest:.0f} s) must span {LOOP_PERIODS_PER_RECORD:g} periods of it to keep a held-out part "
                 f"after the integrator's edges (records of {LOOP_PERIODS_PER_RECORD / band.f_lo_hz:.0f} s keep "
                 f"{band.f_lo_hz:g} Hz)")


def _data_settings(recs: Sequence[Record], band: IntegrationBand | None, s: LoopSettings) -> AnalysisSettings:
    """Without explicit data settings: the loop's spectral settings and analysis band, its integration band."""
    return AnalysisSettings(spectral=s.spectral, band=band, analysis_band_hz=s.analysis_band_hz)


@dataclass(frozen=True)
class _Setup:
    """What every round of :func:`close_loop` works on: the records (as measured and centred), the declared model
    fitted as declared, the settings, the held-out split, the evaluator and the linear part's predictor."""

    raw: tuple[Record, ...]
    recs: tuple[Record, ...]
    declared_terms: tuple[Term, ...]
    decl_theta: Sequence[float]
    m2_kg: float | None
    s: LoopSettings
    band: IntegrationBand
    band_note: str | None
    adapted: str | None
    held: HeldOut
    ev: _Evaluator
    pred: _Predictor
    floor: object
    initial: Errors
    frame: Frame
    # re-tuning by the one-mass equation error: on the body the loop is on *now* (taken back once a term is in)
    retune_ok = property(lambda self: self.s.retune and not self.pred.flexible)

    @property
    def n_decl(self) -> int:
        return len(self.declared_terms)

    def keeps(self, errs: Errors) -> tuple[bool, str]:
        """Whether the model of ``errs`` keeps the declared physics (every declared term within the stated factor of
        its declared parameter, its coefficient with the sign of the declared fit), and how it changes it."""
        fates = [DeclaredTerm(d, float(t0), t, float(t1), self.m2_kg)
                 for d, t0, t, t1 in zip(self.declared_terms, self.decl_theta, errs.terms, errs.theta_per_kg)]
        changed = [f for f in fates if f.changed_meaning]
        return not changed, " ".join(f.text() for f in changed)

    def explanation(self, what: str, errs: Errors) -> Explanation:
        return Explanation(what, tuple(errs.terms), tuple(errs.theta_per_kg), errs.prediction_nmse_pct, self.m2_kg)


def _set_up(records: Record | Sequence[Record], declared: Sequence[Term | Mapping | str], m2_kg: float | None,
            band: IntegrationBand | None, settings: LoopSettings, data: AnalysisSettings | None,
            say: Callable[[float, str], None]) -> _Setup:
    """The records checked and centred, the band, the held-out split, the evaluator and the predictor, the declared
    model fitted as declared (:func:`close_loop`'s arguments)."""
    raw = [records] if isinstance(records, Record) else list(records)
    if not raw:
        raise InputError("no records to run the loop on")
    # every analysis on the records without their accelerations' constant offsets (removed in float64: offsets of
    # any size give the same loop); the model's static part is fitted on the records as measured (fit_scope)
    recs = [r.centred() for r in raw]
    if m2_kg is not None and not (np.isfinite(m2_kg) and m2_kg > 0):
        raise ConfigError(f"m2_kg={m2_kg!r} must be a positive mass [kg]")
    rates = sorted({r.fs_hz for r in recs})
    if len(rates) > 1:
        raise InputError(f"records have different sample rates {rates} Hz", hint="resample to one rate first")
    terms = [make_term(t) for t in declared]
    s = settings
    data = data or _data_settings(recs, band, s)
    fs = float(recs[0].fs_hz)
    skip = data.skip_samples(fs)
    band, band_note = loop_band([r.slice(min(skip, r.n - 1), r.n) for r in recs], band or data.band)
    data = replace(data, band=band)
    if data.period_samples is None:
        s = replace(s, spectral=data.spectral, analysis_band_hz=data.analysis_band_hz)
    held = split_records(recs, skip_samples=skip, period_samples=data.period_samples, fit_fraction=s.fit_fraction,
                         band_hz=data.analysis_band_hz)
    adapted = None
    if data.period_samples is None:     # NIFO on the fit parts: blocks short enough for their length
        shortest = min(k - sk for k, sk in zip(held.split, held.skip))
        block = data.spectral.block
        while block > 256 and 2 * block > shortest:
            block //= 2
        if block != data.spectral.block:
            adapted = (f"spectral block {data.spectral.block} → {block} samples for the models fitted on the fit "
                       f"parts and the per-band residual: the shortest fit part is {shortest / fs:.1f} s")
            data = replace(data, spectral=replace(data.spectral, block=block))
    say(0.0, "restoring force and the declared model")
    ev = _Evaluator(held, band, s, spectral=data.spectral if data.period_samples is None else None)
    say(0.02, "the linear part: one-mass body or rational, by held-out prediction")
    pred = _Predictor(held, data, s, ev)
    floor = held.noise_floor()
    declared_terms = tuple(terms)
    frame = Frame()     # every form of z from the static position the declared model implies, when it is material
    frame.place(ev, declared_terms)
    # the declared model fitted as declared: the signs its terms mean (a falling knee, a hardening spring...). The
    # declared parameters are not re-tuned before the rounds: with effects still missing the re-tune takes them up
    # (measured, a hidden quadratic damping beside the paper's knee: the knee walked from 0.03 to 0.055 m/s)
    decl_theta = ev.equation(declared_terms)["theta_per_kg"] if terms else ()
    return _Setup(raw=tuple(raw), recs=tuple(recs), declared_terms=declared_terms, decl_theta=decl_theta, m2_kg=m2_kg,
                  s=s, band=band, band_note=band_note, adapted=adapted, held=held, ev=ev, pred=pred, floor=floor,
                  initial=_errors(ev, pred, terms), frame=frame)


def _placed(u: _Setup, terms: Sequence[Term]) -> bool:
    """The frame ``terms`` imply placed (:class:`~nifo_core.loop.frame.Frame`); True when a column changed, the
    predictor's fits forgotten then."""
    if not u.frame.place(u.ev, terms):
        return False
    u.pred.forget()
    return True
