"""The loop's equation error (:mod:`nifo_core.loop.closing`): fit a term set on the fit parts, score it on the held-out parts.

The force-balance equation error of the body (paper Eq. 2 per unit sprung
mass, every column band-passed after the nonlinear map; a measured force on
the body is one more linear column, coefficient -1/M2) traces what the model
lacks (docs/method.md §5 step 1). The other residual, the held-out prediction
error of the model class ``nifo identify`` writes, is :mod:`nifo_core.predict.heldout`
and :mod:`nifo_core.predict.model_fit`. Also here: the tire check, the evidence behind
an added effect, the re-tuning of the terms' parameters and the per-band
numbers of a held-out prediction.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from ..characterize.automatic import candidate_grid
from ..characterize.data import RegressionData
from ..characterize.result import Candidate
from ..characterize.score import score_candidate
from ..characterize.static import shifted_offsets, static_bump_stops
from ..kinds.describing import Term
from ..errors import InputError
from ..signal.integrate import IntegrationBand
from ..predict.heldout import HeldOut
from ..predict.linear_part import BodyModel
from .round_results import Evidence
from .settings import RESIDUAL_BANDS_HZ, RETUNE_FACTOR, LoopSettings
from .stops import placed_beyond
from ..predict.model import IdentifiedModel
from ..characterize.restoring import RestoringForce, bandpass, bandpass_settle_samples, restoring_force
from ..signal.frf import h1, partial_coherence
from ..signal.spectral import SpectralSettings, auto_spectrum, cross_spectra
from ..signal.noise import estimate_noise
from ..signal.record import Record
from ..signal.bias_correction import Correction, LinearFit, simulated_correction
from ..signal.least_squares import lstsq
from ..errors import NifoError
from ..predict.model import fine_factor, predict_records
from ..predict.timesim import lookahead_samples
from ..signal.uncertainty import CoefficientBounds, coefficient_bounds

#: the seed of the noise the bias correction adds (fixed: the same data give the same model)
BIAS_SEED = 28
#: the bias correction's iterations in the loop (each one simulation and 2·BIAS_PAIRS + 1 equation-error fits,
#: cheap); measured on a bump stop (2e5 N/m, 4 mm gap, 2 % noise): two steps and the geometric tail stopped 1-2 %
#: short of the fixed point (their contraction 0.41-0.46 rises to 0.49-0.55 in later steps), five steps within 0.2 %
BIAS_ITERATIONS = 5
#: antithetic pairs of noise draws per step of the bias correction (their scatter: θ₀'s random error, errors in
#: variables included: :attr:`~nifo_core.signal.bias_correction.Correction.fit_sd`)
BIAS_PAIRS = 4

@dataclass(frozen=True)
class _Part:
    """Regression columns of one record part: every column band-passed once more (as characterize does)."""

    y: np.ndarray           # band-passed -ẍ2 [m/s²]
    z: np.ndarray           # band-passed z [m]
    zdot: np.ndarray        # band-passed ż [m/s]
    rf: RestoringForce
    keep: np.ndarray        # indices into rf of the rows
    index: int = 0          # which record (per-record offsets of bump stops)
    applied: np.ndarray | None = None   # band-passed measured force on the body [N] (coefficient -1/M2)

    @property
    def linear(self) -> list[np.ndarray]:
        """The linear columns: z, ż and, when measured, the force on the body."""
        return [self.z, self.zdot] + ([] if self.applied is None else [self.applied])


def _part(rf: RestoringForce, index: int = 0) -> _Part:
    s = bandpass_settle_samples(rf.fs_hz, rf.band)
    if rf.n - 2 * s < max(64, int(4 * rf.fs_hz / rf.band.f_lo_hz)):
        raise InputError(f"{rf.n / rf.fs_hz:.1f} s of data is too short for the loop (the band-pass settles over "
                         f"{s / rf.fs_hz:.1f} s at each end)", source=rf.source or "record",
                         hint="record longer, or raise the band's lower edge")
    keep = np.arange(s, rf.n - s)
    cols = [rf.force, rf.z, rf.zdot] + ([] if rf.applied is None else [rf.applied])
    b = bandpass(np.vstack(cols), rf.fs_hz, rf.band)[:, keep]
    return _Part(b[0], b[1], b[2], rf, keep, index, None if rf.applied is None else b[3])


def _parts_sum(a: Sequence[_Part], b: Sequence[_Part], sign: float) -> list[_Part]:
    """Record by record, the parts of ``a`` plus ``sign`` × those of ``b``: what the parts of the summed records are
    (every column is linear in the record's channels: integrated, band-passed), cut the same way."""
    def add(u, v):
        return None if u is None else u + sign * v

    out = []
    for p, q in zip(a, b, strict=True):
        rf, rq = p.rf, q.rf
        rf = replace(rf, force=rf.force + sign * rq.force, z=rf.z + sign * rq.z, zdot=rf.zdot + sign * rq.zdot,
                     spindle_accel=rf.spindle_accel + sign * rq.spindle_accel, x2=add(rf.x2, rq.x2),
                     applied=add(rf.applied, rq.applied))
        out.append(_Part(p.y + sign * q.y, p.z + sign * q.z, p.zdot + sign * q.zdot, rf, p.keep, p.index,
                         add(p.applied, q.applied)))
    return out


def _g(part: _Part, term: Term, offsets: Mapping[str, Sequence[float]] | None = None) -> np.ndarray:
    """g(z, ż) on the part's motion, band-passed AFTER the map (docs/method.md §5 step 3).

    ``offsets``: term label → one ``offset`` [m] per record (a bump stop measured from the static
    position, which sits elsewhere in each record: :mod:`nifo_core.characterize.static`; an even stiffness
    evaluated on z from the static position, ``z - offset``).
    """
    rf = part.rf
    z = rf.z
    if offsets and term.label in offsets:
        off = float(offsets[term.label][part.index])
        if "offset" in term.spec.params:
            term = Term(term.kind, {**term.params, "offset": off})
        else:        # an even stiffness: evaluated on z measured from the static position (.characterize.static)
            z = z - off
    return bandpass(term.evaluate(z, rf.zdot), rf.fs_hz, rf.band)[part.keep]


def _design(parts: Sequence[_Part], terms: Sequence[Term],
            offsets: Mapping[str, Sequence[float]] | None = None) -> tuple[np.ndarray, np.ndarray]:
    ys, xs = [], []
    for p in parts:
        ys.append(p.y)
        xs.append(np.column_stack([*p.linear, *[_g(p, t, offsets) for t in terms]]))
    return np.concatenate(ys), np.vstack(xs)


def _nmse_pct(y: np.ndarray, e: np.ndarray) -> float:
    """Worden & Tomlinson: 100·Σe²/(N·σ_y²)."""
    v = float(np.var(y))
    return 100.0 * float(np.mean(e ** 2)) / v if v > 0 else float("nan")


def _band_db(spec_pairs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> dict[str, float]:
    """10·log10(ΣG_ee/ΣG_yy) per band, PSDs summed over records: [(freq, G_yy, G_ee), ...]."""
    out = {}
    for lo, hi in RESIDUAL_BANDS_HZ:
        num = den = 0.0
        for f, gyy, gee in spec_pairs:
            m = (f >= lo) & (f < hi)
            num += float(gee[m].sum())
            den += float(gyy[m].sum())
        out[f"{lo:g}-{hi:g}"] = float(10 * np.log10(num / den)) if num > 0 and den > 0 else float("nan")
    return out


class _Evaluator:
    """The force-balance equation error of a term set: fitted on the fit parts, scored on the held-out parts.

    Each record after its transient (:class:`~nifo_core.predict.heldout.HeldOut`) is integrated whole, then its restoring
    force is split at ``fit_fraction`` of what the integrator leaves (its edges are lost once per record, not at the
    split too): the same fraction as the held-out prediction's split, give or take the edges.
    """

    def __init__(self, held: HeldOut, band: IntegrationBand, settings: LoopSettings,
                 spectral: SpectralSettings | None = None) -> None:
        self.band, self.settings = band, settings
        self.held = held
        self.fit_recs, self.test_recs, self.fit_rfs, self.test_rfs = [], [], [], []
        for rec, skip in zip(held.records, held.skip):
            rec = rec.slice(skip, rec.n)
            rf = restoring_force(rec, band=band)
            k = int(round(settings.fit_fraction * rf.n))      # of what the integrator leaves, as the prediction's
            self.fit_rfs.append(rf.select(slice(0, k)))
            self.test_rfs.append(replace(rf.select(slice(k, rf.n)), start=rf.start + k))
            self.fit_recs.append(rec.slice(0, rf.start + k))
            self.test_recs.append(rec.slice(rf.start + k, rec.n))
        self.fit_parts = [_part(rf, i) for i, rf in enumerate(self.fit_rfs)]
        #: each record's sensor noise (:mod:`nifo_core.signal.noise`), whole record after its transient
        self.noise = tuple(estimate_noise(r.slice(k, r.n)) for r, k in zip(held.records, held.skip))
        self.test_parts = [_part(rf, i) for i, rf in enumerate(self.test_rfs)]
        #: linear columns of the equation error: z, ż and the measured force when there is one
        self.n_lin = len(self.fit_parts[0].linear)
        #: bump stops measured from the static position: term label → offset -m_i per record [m]
        self.static: dict[str, tuple[float, ...]] = {}
        self._regression: RegressionData | None = None   # characterize's rows of the fit parts (made on demand)
        self._regression_lock = threading.Lock()         # the loop's candidates ask for it side by side
        spec = spectral or settings.spectral
        self.notes: list[str] = []
        shortest = min(r.n for r in self.test_recs)
        self.spec = spec if shortest >= 2 * spec.block else replace(
            spec, block=int(2 ** np.floor(np.log2(max(shortest // 8, 256)))), overlap=0.5, window="hann")
        if self.spec.block != spec.block:
            self.notes.append(f"spectral block {spec.block} → {self.spec.block} samples for the per-band residual: "
                              f"the shortest held-out part is {shortest / held.records[0].fs_hz:.1f} s")
        self._cache: dict = {}

    def regression(self) -> RegressionData:
        """characterize's regression rows of the fit parts, made at the first call (safe on several threads)."""
        with self._regression_lock:
            if self._regression is None:
                self._regression = RegressionData(self.fit_rfs, n_groups=4, body_stiffness=False)
            return self._regression

    def forget_equations(self) -> None:
        """The remembered equation-error fits dropped: they are kept by the terms' labels, and a label's column
        changes with its frame (:mod:`nifo_core.loop.frame`); a fit with the bias removed is kept with its offsets,
        and stays."""
        for key in [k for k in self._cache if not (k and k[0] == "corrected")]:
            del self._cache[key]

    def _reads(self) -> list[int]:
        """Per held record, the samples its fit part is made of (:meth:`_fit_parts_of`): up to the fit part's end, the
        integrator's reach beyond it and the simulation's look-ahead. The rest of the record, its held-out part,
        is neither fitted nor needed by the simulated fit (measured on the bundled sample's three records: the fit
        parts' force the same to 1e-13 of its peak, z and ż to 2e-15)."""
        out = []
        for rec, skip, part, rf in zip(self.held.records, self.held.skip, self.fit_recs, self.fit_rfs):
            ahead = lookahead_samples(fine_factor(rec.fs_hz, rec.fs_hz))
            out.append(skip + part.n + rf.start + ahead)     # rf.start: the integrator's half-length (its edge)
        return out

    def _fit_parts_of(self, records: Sequence[Record]) -> list[_Part]:
        """The fit parts of ``records`` (the held records, renoised), cut exactly as :attr:`fit_parts`."""
        out = []
        for i, (rec, skip) in enumerate(zip(records, self.held.skip)):
            rf = restoring_force(rec.slice(skip, rec.n), band=self.band)
            out.append(_part(rf.select(slice(0, self.fit_rfs[i].n)), i))
        return out

    @property
    def corrects(self) -> bool:
        """Whether coefficients are reported with the fit's bias removed (:mod:`nifo_core.signal.bias_correction`)."""
        return bool(self.settings.noise_correction) and not any(r.spindle_fixed for r in self.held.records)

    def _lstsq(self, parts: Sequence[_Part], terms: Sequence[Term]) -> np.ndarray:
        y, x = _design(parts, terms, self.static)
        return lstsq(x, y)

    def corrected(self, terms: Sequence[Term]) -> Correction | None:
        """The equation-error coefficients with the fit's bias (noise on both sensors, processing) removed by
        simulating the fit (:func:`nifo_core.signal.bias_correction.simulated_correction`); None when it cannot."""
        if not self.corrects:
            return None
        terms = tuple(terms)
        key = ("corrected", tuple(t.label for t in terms), tuple(sorted(self.static.items())))
        if key not in self._cache:
            recs = list(self.held.records)
            spectral, band_hz = self.settings.spectral, self.settings.analysis_band_hz

            def simulate_records(theta: np.ndarray, some: Sequence[Record]) -> list[np.ndarray | None]:
                """Each record's body acceleration at θ (None where it cannot be simulated), the records of one
                length marched together (predict_body's bits)."""
                model = self._model_of(terms, theta, spectral, band_hz)
                if model is None:
                    return [None] * len(some)
                try:
                    got = predict_records(model, [np.asarray(r.spindle_accel) for r in some], [r.fs_hz for r in some],
                                          forces=[r.force if self.n_lin == 3 else None for r in some])
                except (NifoError, np.linalg.LinAlgError, FloatingPointError):
                    return [None] * len(some)     # any None refuses the correction, whichever record it is
                return [None if isinstance(p, NifoError) else p.body_accel for p in got]

            def simulate(theta: np.ndarray, rec: Record) -> np.ndarray | None:
                return simulate_records(theta, [rec])[0]

            t0 = self._lstsq(self.fit_parts, terms)
            fit = LinearFit(self._fit_parts_of, _parts_sum, lambda parts: self._lstsq(parts, terms))
            self._cache[key] = simulated_correction(fit, simulate, recs, self.noise, t0, seed=BIAS_SEED,
                                                    iterations=BIAS_ITERATIONS, drive_noise=True,
                                                    pairs=BIAS_PAIRS, side_by_side=True, reads=self._reads(),
                                                    simulate_records=simulate_records)
        return self._cache[key]

    def joint(self, terms: Sequence[Term]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(θ = [k, c, θ_i...], fit rows y, X) of the equation-error fit on the fit part."""
        y, x = _design(self.fit_parts, terms, self.static)
        return lstsq(x, y), y, x

    def bounds(self, terms: Sequence[Term], *, level: float = 0.95, corrected: bool = True) -> CoefficientBounds:
        """θ with bounds: random error (:func:`coefficient_bounds`) and, when the bias is removed
        (:meth:`corrected`; ``corrected=False``: not asked), the corrected θ with what the correction adds to the
        bound (:meth:`~nifo_core.signal.bias_correction.Correction.half_width`)."""
        y, x = _design(self.fit_parts, terms, self.static)
        b = coefficient_bounds(x, y, self.fit_parts[0].rf.fs_hz, level=level,
                               segments=[p.y.size for p in self.fit_parts])
        cor = self.corrected(terms) if corrected else None
        if cor is None:
            return b
        return replace(b, theta=cor.theta,
                       half_width=cor.half_width(b.half_width, b.n_eff - x.shape[1], level=level))

    def equation(self, terms: Sequence[Term]) -> dict:
        """The equation-error numbers of ``terms`` (fit on the fit parts, NMSE on the held-out parts)."""
        key = tuple(t.label for t in terms)
        if key in self._cache:
            return self._cache[key]
        terms = tuple(terms)
        theta, y, x = self.joint(terms)
        fit_nmse = _nmse_pct(y, y - x @ theta)
        yt, xt = _design(self.test_parts, terms, self.static)
        eq_nmse = _nmse_pct(yt, yt - xt @ theta)
        eq_pairs = []  # per-band residual of the equation error (always: the gate compares like with like)
        for p in self.test_parts:
            e = p.y - np.column_stack([*p.linear, *[_g(p, t, self.static) for t in terms]]) @ theta
            if e.size >= self.spec.block:
                sp = cross_spectra(np.stack([p.y, e]), p.rf.fs_hz, self.spec)
                eq_pairs.append((sp.freq_hz, auto_spectrum(sp, 0), auto_spectrum(sp, 1)))
        n = self.n_lin
        out = {"terms": terms, "theta_per_kg": tuple(float(v) for v in theta[n:n + len(terms)]),
               "k_per_kg": float(theta[0]), "c_per_kg": float(theta[1]), "equation_nmse_pct": eq_nmse,
               "equation_nmse_fit_pct": fit_nmse, "equation_band_residual_db": _band_db(eq_pairs)}
        self._cache[key] = out
        return out

    def equation_model(self, terms: Sequence[Term], spectral: SpectralSettings,
                       analysis_band_hz: tuple[float, float]) -> IdentifiedModel | None:
        """The equation-error fit of ``terms`` as a model: a one-mass body (k, c), constant coefficients θ_i and,
        with a measured force, its gain 1/M2 (the force column's coefficient is -1/M2). None when the body is not
        physical (a multi-mode structure read as one mass)."""
        terms = tuple(terms)
        return self._model_of(terms, self.joint(terms)[0], spectral, analysis_band_hz)

    def _model_of(self, terms: tuple[Term, ...], theta: np.ndarray, spectral: SpectralSettings,
                  analysis_band_hz: tuple[float, float]) -> IdentifiedModel | None:
        n = self.n_lin
        gain = -float(theta[2]) if n == 3 else 0.0
        if not (theta[0] > 0 and theta[1] > 0 and gain >= 0):
            return None
        fs = self.fit_recs[0].fs_hz
        f = spectral.freq_hz(fs)
        body = BodyModel(float(theta[0]), float(theta[1]))
        t21 = body.t21(f)
        gam = np.asarray(theta[n:n + len(terms)], float)
        w2 = (2 * np.pi * f) ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            b = gam[:, None] * ((1 - t21) / np.where(w2 > 0, w2, np.inf))[None, :]
        return IdentifiedModel(freq_hz=f, t21=t21, b=b, terms=terms, c_over_m2=gam, body=body,
                               analysis_band_hz=analysis_band_hz, fs_hz=fs, settings=spectral, band=self.band,
                               source="static" if terms else "h1", force_gain=gain,
                               provenance={"from": "nifo loop: the force-balance equation-error fit on the fit parts"})

    def band_numbers(self, preds: Sequence[np.ndarray]) -> tuple[dict, tuple]:
        """Per-band residual of the held-out prediction error (records pooled) and the transmissibility error per
        record, from whole-record predictions (:meth:`HeldOut.predictions`)."""
        lo, hi = self.held.band_hz
        pairs, trans = [], []
        for rec, yhat, k in zip(self.held.records, preds, self.held.split):
            y = np.asarray(rec.body_accel)[k:]
            e = y - np.asarray(yhat)[k:]
            if y.size < self.spec.block:
                continue
            sp = cross_spectra(np.stack([y, e]), rec.fs_hz, self.spec)
            pairs.append((sp.freq_hz, auto_spectrum(sp, 0), auto_spectrum(sp, 1)))
            drive = np.asarray(rec.force if rec.spindle_fixed else rec.spindle_accel)[k:]
            sv = cross_spectra(np.stack([drive, y, np.asarray(yhat)[k:]]), rec.fs_hz, self.spec)
            m = (sv.freq_hz >= lo) & (sv.freq_hz <= hi)
            t_meas, t_pred = h1(sv, 0, 1), h1(sv, 0, 2)
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = np.abs(t_pred[m] - t_meas[m]) / np.abs(t_meas[m])
            rel = rel[~np.isnan(rel)]      # lines where the measured H1 is undefined say nothing (no all-NaN warning)
            trans.append((rec.source, 100.0 * float(np.median(rel)) if rel.size else float("nan")))
        return _band_db(pairs), tuple(trans)


# --------------------------------------------------------------------------------------------
# checks and evidence
# --------------------------------------------------------------------------------------------
def _tire_events(part: _Part, quantile: float, guard_s: float) -> np.ndarray:
    """Rows near the spindle's impacts: |ẍ1| above its quantile, dilated by ± guard."""
    a = np.abs(np.asarray(part.rf.spindle_accel)[part.keep])
    hit = a > np.quantile(a, quantile)
    g = max(1, int(round(guard_s * part.rf.fs_hz)))
    k = np.convolve(hit.astype(float), np.ones(2 * g + 1), mode="same") > 0
    return k


def _tire_check(ev: _Evaluator, terms: Sequence[Term], cand: Term, s: LoopSettings) -> tuple[float, float]:
    """(relative coefficient shift when the rows near spindle impacts are left out, fraction left out)."""
    theta, y, x = ev.joint([*terms, cand])
    events = np.concatenate([_tire_events(p, s.tire_quantile, s.tire_guard_s) for p in ev.fit_parts])
    keep = ~events
    th2 = np.linalg.lstsq(x[keep], y[keep], rcond=None)[0]
    shift = abs(th2[-1] - theta[-1]) / abs(theta[-1]) if theta[-1] != 0 else float("inf")
    return float(shift), float(events.mean())


def _static_candidate(ev: _Evaluator, terms: Sequence[Term], cand: Candidate, s: LoopSettings,
                      m2_kg: float | None) -> Candidate:
    """A bump-stop or even-stiffness candidate re-measured from the static position
    (:mod:`nifo_core.characterize.static`).

    The ranking measures z from each record's mean position, which a one-sided stop (or an even stiffness, whose
    mean force θ·mean z² is not zero) pushes away from the static one, the more the harder the excitation. A stop's
    gap from the static position and one offset -m_i per record come from the balance of the mean force (an even
    stiffness: the offsets alone, :func:`~nifo_core.characterize.static.shifted_offsets`); the candidate is
    re-scored with them and its offsets registered in ``ev.static`` (the loop's columns use them from then on).
    Measured without it: a hidden even stiffness beside a clearance (the fleet of issue 54) had its level-dependent
    linear part taken up by two spurious bump stops.
    """
    frame = cand.term.spec.static_frame
    if not frame:
        return cand
    data = ev.regression()
    # the other terms keep their own (already static) frame; only the candidate is re-measured
    if frame == "threshold":
        new, offs = static_bump_stops(data, [*terms, cand.term])
        term, off = new[-1], offs[-1]
        key = term.spec.key_param
        if off is not None and term.params[key] > cand.term.params[key]:   # the mean pushed towards the stop
            term, off = placed_beyond(data, ev.static, terms, term, off)
    else:
        term, off = cand.term, shifted_offsets(data, [*terms, cand.term])[-1]
    if off is None:
        return cand
    base = [data.regressor(t, offsets=ev.static.get(t.label)) for t in terms]
    out = score_candidate(data, base, term, thresholds=s.thresholds, n_grid=2 * s.grid_points, m2=m2_kg,
                          names=tuple(t.label for t in terms), offsets=off)
    ev.static[term.label] = tuple(off)
    return out


def _evidence(ev: _Evaluator, terms: Sequence[Term], cand: Term, s: LoopSettings, n_bins: int = 30) -> Evidence:
    th0, y, x0 = ev.joint(terms)
    th1, _, x1 = ev.joint([*terms, cand])
    e0, e1 = y - x0 @ th0, y - x1 @ th1
    effect = e0 - e1  # what adding the term explains (its linear part re-absorbed by the refit)
    var = np.concatenate([p.zdot if cand.variable == "zdot" else p.z for p in ev.fit_parts])
    lo, hi = np.quantile(var, [0.005, 0.995])
    edges = np.linspace(lo, hi, n_bins + 1)
    idx = np.clip(np.digitize(var, edges) - 1, 0, n_bins - 1)
    inside = (var >= lo) & (var <= hi)
    cnt = np.bincount(idx[inside], minlength=n_bins).astype(float)

    def mean(a):
        return tuple(float(v) for v in np.where(cnt > 0, np.bincount(idx[inside], a[inside], n_bins) /
                                                np.maximum(cnt, 1), np.nan))

    # partial coherence of the residual with the candidate, given z, ż and the declared terms (one engine)
    pcs, n_avg = [], 0
    for p in ev.fit_parts:
        if p.y.size < ev.spec.block:
            continue
        chans = np.vstack([p.y, *p.linear, *[_g(p, t, ev.static) for t in [*terms, cand]]])
        sp = cross_spectra(chans, p.rf.fs_hz, ev.spec)
        m = (sp.freq_hz >= s.analysis_band_hz[0]) & (sp.freq_hz <= s.analysis_band_hz[1])
        pc = partial_coherence(sp, 0, list(range(1, chans.shape[0])))[-1][m]
        pcs.append(pc)
        n_avg = max(n_avg, sp.n_avg)
    q = ev.n_lin + len(terms) + 1
    level = 1 - 0.05 ** (1 / max(n_avg - q - 1, 1)) if n_avg else float("nan")
    pc_all = np.concatenate(pcs) if pcs else np.array([np.nan])
    finite = pc_all[np.isfinite(pc_all)]       # no all-NaN mean (numpy's warning reached the user): NaN said plainly
    centres = 0.5 * (edges[1:] + edges[:-1])
    return Evidence(variable=cand.variable, bins=tuple(float(c) for c in centres), before=mean(e0), after=mean(e1),
                    effect=mean(effect),
                    partial_coherence_mean=float(np.mean(finite)) if finite.size else float("nan"),
                    partial_coherence_level=float(level),
                    fraction_lines_above_level=float(np.mean(pc_all > level)) if pcs else float("nan"))


def _retune(ev: "_Evaluator", terms: Sequence[Term], s: LoopSettings, *, which: Sequence[int] | None = None,
            declared: Sequence[Term] = ()) -> tuple[list[Term], list[str]]:
    """Each term's varying parameter re-tuned over its grid (then refined), the others held: best ERR.

    ``which``: the indices of the terms to re-tune (default all). A declared term (``declared[i]`` for the i-th
    term) stays within :data:`~nifo_core.loop.settings.RETUNE_FACTOR` of its *declared* key parameter (a gap, knee
    or deadband is the engineer's statement: re-tuning round after round must not walk it away); a term the loop
    added within a factor 2 of its current one.
    """
    z = np.concatenate([p.z for p in ev.fit_parts])
    v = np.concatenate([p.zdot for p in ev.fit_parts])
    rng = dict(z_range=float(np.quantile(np.abs(z), 0.995)), zdot_range=float(np.quantile(np.abs(v), 0.995)),
               z_neg=float(np.quantile(-z, 0.998)), z_pos=float(np.quantile(z, 0.998)))
    out, notes = list(terms), []
    for i, t in enumerate(terms):
        if which is not None and i not in which:
            continue
        if t.label in ev.static:  # a bump stop from the static position: its gap was fitted with its offsets
            continue
        grid = [g for g in candidate_grid(t.kind, points=s.grid_points, **rng)
                if g.params.get("side") == t.params.get("side")]
        vary = [k for k in t.params if k not in ("side", "offset") and len({g.params[k] for g in grid}) > 1]
        if not vary:
            continue
        key = vary[0]
        y, x0 = _design(ev.fit_parts, out[:i] + out[i + 1:], ev.static)
        q, _ = np.linalg.qr(x0)
        r = y - q @ (q.T @ y)

        def err(term: Term) -> float:
            g = np.concatenate([_g(p, term, ev.static) for p in ev.fit_parts])
            g = g - q @ (q.T @ g)
            d = float(g @ g)
            return float(g @ r) ** 2 / d if d > 0 else 0.0

        vals = sorted({float(g.params[key]) for g in grid})
        if key == t.spec.key_param:  # a declared gap/knee/deadband is the engineer's statement
            v0 = float(t.params[key])
            lo, hi = 0.5 * v0, 2.0 * v0
            if i < len(declared) and declared[i].kind == t.kind and key in declared[i].params:
                d0 = float(declared[i].params[key])
                lo, hi = d0 / RETUNE_FACTOR, d0 * RETUNE_FACTOR
            vals = [x for x in vals if lo <= x <= hi] or [v0]
        else:
            lo, hi = -np.inf, np.inf
        scores = [err(Term(t.kind, {**t.params, key: x})) for x in vals]
        j = int(np.argmax(scores))
        a, b = vals[max(j - 1, 0)], vals[min(j + 1, len(vals) - 1)]
        fine = [x for x in np.linspace(a, b, 9)[1:-1] if t.spec.may_be(key, x) and lo <= x <= hi]
        cands = [(scores[j], vals[j])] + [(err(Term(t.kind, {**t.params, key: x})), x) for x in fine]
        cands.append((err(t), float(t.params[key])))
        best_score, best = max(cands)
        old = float(t.params[key])
        if best != old and best_score > 1.001 * cands[-1][0]:
            out[i] = Term(t.kind, {**t.params, key: best})
            notes.append(f"{t.label} re-tuned to {key}={best:.4g} on these data")
    return out, notes
