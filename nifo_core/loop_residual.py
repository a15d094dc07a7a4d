"""Residuals of the loop (:mod:`nifo_core.loop`): fit a term set on the fit parts, score it on the held-out parts.

Two residuals (METHOD.md §5 step 1): the force-balance equation error of the
body (paper Eq. 2 per unit sprung mass, every column band-passed after the
nonlinear map) and the prediction error of the body acceleration simulated
from the measured spindle acceleration. Also the tire check, the evidence
behind an added effect and the re-tuning of the terms' parameters.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from .characterize import candidate_grid
from .characterize_data import RegressionData
from .characterize_result import Candidate
from .characterize_score import score_candidate
from .characterize_static import STATIC_KINDS, static_bump_stops
from .describing import Term
from .errors import ConfigError, InputError, NifoError
from .integrate import IntegrationBand
from .loop_results import RESIDUAL_BANDS_HZ, Errors, Evidence, LoopSettings
from .model import BodyModel, IdentifiedModel, predict_transmissibility
from .nifo import identify_nifo
from .record import Record
from .restoring import RestoringForce, bandpass, bandpass_settle_samples, restoring_force
from .frf import h1, partial_coherence
from .spectral import auto_spectrum, cross_spectra

@dataclass(frozen=True)
class _Part:
    """Regression columns of one record part: every column band-passed once more (as characterize does)."""

    y: np.ndarray           # band-passed -ẍ2 [m/s²]
    z: np.ndarray           # band-passed z [m]
    zdot: np.ndarray        # band-passed ż [m/s]
    rf: RestoringForce
    keep: np.ndarray        # indices into rf of the rows
    index: int = 0          # which record (per-record offsets of bump stops)


def _part(rf: RestoringForce, index: int = 0) -> _Part:
    s = bandpass_settle_samples(rf.fs_hz, rf.band)
    if rf.n - 2 * s < max(64, int(4 * rf.fs_hz / rf.band.f_lo_hz)):
        raise InputError(f"{rf.n / rf.fs_hz:.1f} s of data is too short for the loop (the band-pass settles over "
                         f"{s / rf.fs_hz:.1f} s at each end)", source=rf.source or "record",
                         hint="record longer, or raise the band's lower edge")
    keep = np.arange(s, rf.n - s)
    b = bandpass(np.vstack([rf.force, rf.z, rf.zdot]), rf.fs_hz, rf.band)[:, keep]
    return _Part(b[0], b[1], b[2], rf, keep, index)


def _g(part: _Part, term: Term, offsets: Mapping[str, Sequence[float]] | None = None) -> np.ndarray:
    """g(z, ż) on the part's motion, band-passed AFTER the map (METHOD.md §5 step 3).

    ``offsets``: term label → one ``offset`` [m] per record (a bump stop measured from the static
    position, which sits elsewhere in each record: :mod:`nifo_core.characterize_static`).
    """
    rf = part.rf
    if offsets and term.label in offsets:
        term = Term(term.kind, {**term.params, "offset": float(offsets[term.label][part.index])})
    return bandpass(term.evaluate(rf.z, rf.zdot), rf.fs_hz, rf.band)[part.keep]


def _design(parts: Sequence[_Part], terms: Sequence[Term],
            offsets: Mapping[str, Sequence[float]] | None = None) -> tuple[np.ndarray, np.ndarray]:
    ys, xs = [], []
    for p in parts:
        ys.append(p.y)
        xs.append(np.column_stack([p.z, p.zdot, *[_g(p, t, offsets) for t in terms]]))
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
    """Fits a term set on the fit parts and scores it on the held-out parts (both residuals)."""

    def __init__(self, records: Sequence[Record], band: IntegrationBand, settings: LoopSettings) -> None:
        # integrate each WHOLE record, then split its restoring force in time: the integrator's edges are
        # lost once per record, not at the split too (a 60 s record keeps a held-out part)
        self.band, self.settings = band, settings
        self.fit_recs, self.test_recs, self.fit_rfs, self.test_rfs = [], [], [], []
        for rec in records:
            rf = restoring_force(rec, band=band)
            k = int(round(settings.fit_fraction * rf.n))
            self.fit_rfs.append(rf.select(slice(0, k)))
            self.test_rfs.append(replace(rf.select(slice(k, rf.n)), start=rf.start + k))
            self.fit_recs.append(rec.slice(0, rf.start + k))
            self.test_recs.append(rec.slice(rf.start + k, rec.n))
        self.fit_parts = [_part(rf, i) for i, rf in enumerate(self.fit_rfs)]
        self.test_parts = [_part(rf, i) for i, rf in enumerate(self.test_rfs)]
        #: bump stops measured from the static position: term label → offset -m_i per record [m]
        self.static: dict[str, tuple[float, ...]] = {}
        self.regression: RegressionData | None = None   # characterize's rows of the fit parts (made on demand)
        spec = settings.spectral
        self.notes: list[str] = []
        shortest = min(r.n for r in self.test_recs)
        self.spec = spec if shortest >= 2 * spec.block else replace(
            spec, block=int(2 ** np.floor(np.log2(max(shortest // 8, 256)))))
        if self.spec.block != spec.block:
            self.notes.append(f"spectral block {spec.block} → {self.spec.block} samples for the per-band residual and "
                              f"the transmissibilities: the shortest held-out part is "
                              f"{shortest / records[0].fs_hz:.1f} s")
        self._measured = [cross_spectra(np.stack([r.spindle_accel, r.body_accel]), r.fs_hz, self.spec)
                          for r in self.test_recs]
        self._cache: dict = {}

    def joint(self, terms: Sequence[Term]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(θ = [k, c, θ_i...], fit rows y, X) of the equation-error fit on the fit part."""
        y, x = _design(self.fit_parts, terms, self.static)
        return np.linalg.lstsq(x, y, rcond=None)[0], y, x

    def errors(self, terms: Sequence[Term]) -> Errors:
        key = tuple(t.label for t in terms)
        if key in self._cache:
            return self._cache[key]
        terms = tuple(terms)
        theta, y, x = self.joint(terms)
        fit_nmse = _nmse_pct(y, y - x @ theta)
        yt, xt = _design(self.test_parts, terms, self.static)
        eq_nmse = _nmse_pct(yt, yt - xt @ theta)
        notes: list[str] = []
        pred_nmse, per_rec, trans, pairs = None, (), (), []
        residual_of, unavailable = "equation", None
        if self.settings.prediction == "none":
            unavailable = "prediction switched off (prediction='none')"
        else:
            try:
                pred_nmse, per_rec, trans, pairs = self._predict(terms)
                residual_of = "prediction"
            except (NifoError, np.linalg.LinAlgError) as err:
                unavailable = str(err)
                notes.append(f"no held-out prediction for this model ({err}); equation error only")
        eq_pairs = []  # per-band residual of the equation error (always: the gate compares like with like)
        for p in self.test_parts:
            e = p.y - np.column_stack([p.z, p.zdot, *[_g(p, t, self.static) for t in terms]]) @ theta
            if e.size >= self.spec.block:
                s = cross_spectra(np.stack([p.y, e]), p.rf.fs_hz, self.spec)
                eq_pairs.append((s.freq_hz, auto_spectrum(s, 0), auto_spectrum(s, 1)))
        eq_bands = _band_db(eq_pairs)
        out = Errors(terms=terms, theta_per_kg=tuple(float(v) for v in theta[2:]), k_per_kg=float(theta[0]),
                     c_per_kg=float(theta[1]), equation_nmse_pct=eq_nmse, equation_nmse_fit_pct=fit_nmse,
                     prediction_nmse_pct=pred_nmse, prediction_nmse_per_record_pct=tuple(per_rec),
                     band_residual_db=_band_db(pairs) if pairs else eq_bands, residual_of=residual_of,
                     equation_band_residual_db=eq_bands,
                     transmissibility_error_pct=tuple(trans), prediction_unavailable=unavailable,
                     notes=tuple(notes))
        self._cache[key] = out
        return out

    def model(self, terms: Sequence[Term]) -> IdentifiedModel:
        """The model that predicts, fitted on the fit parts (``settings.prediction``).

        ``'equation'``: the equation-error fit (k, c, θ_i) as a one-mass body; where that body is not
        physical (a multi-mode structure read as one mass, e.g. F-16) NIFO's static fit of the same terms
        with the linear part :func:`~nifo_core.linear_part.select_linear_part` chooses (a stable
        rational model), the reason in ``provenance``. ``'nifo'``: NIFO's static fit always.
        """
        s = self.settings
        terms = tuple(terms)
        theta = self.joint(terms)[0]
        physical = theta[0] > 0 and theta[1] > 0
        if s.prediction == "nifo" or not physical:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = identify_nifo(self.fit_recs, list(terms), settings=s.spectral, band=self.band,
                                    analysis_band_hz=s.analysis_band_hz, input_measured=False)
            model = IdentifiedModel.from_nifo(res, source="static")
            if s.prediction == "nifo":
                return model
            why = (f"the one-mass equation-error fit is not physical (k={theta[0]:.4g} 1/s², c={theta[1]:.4g} 1/s): "
                   f"NIFO's static fit of the same terms on the fit parts predicts instead, with a "
                   f"{model.linear.kind} linear part ({model.linear.reason})")
            return replace(model, provenance={**dict(model.provenance), "from": "nifo loop", "why": why})
        f = s.spectral.freq_hz(self.fit_recs[0].fs_hz)
        body = BodyModel(float(theta[0]), float(theta[1]))
        body = replace(body, fit_rms=self._misfit(body))
        t21 = body.t21(f)
        w2 = (2 * np.pi * f) ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            b = np.zeros((len(terms), f.size), complex)
            for i, th in enumerate(theta[2:]):
                b[i] = th * (1 - t21) / np.where(w2 > 0, w2, np.inf)
        return IdentifiedModel(freq_hz=f, t21=t21, b=b, terms=terms, c_over_m2=np.asarray(theta[2:], float),
                               body=body, analysis_band_hz=s.analysis_band_hz, fs_hz=self.fit_recs[0].fs_hz,
                               settings=s.spectral, band=self.band, source="static",
                               provenance={"from": "nifo loop equation-error fit"})

    def _misfit(self, body: BodyModel) -> float:
        """Relative RMS of T21_body/H1 - 1 over the analysis band, H1 measured on the fit parts (levels pooled).

        H1 at the test level holds the nonlinearity's equivalent linearisation: a strongly nonlinear
        strut shows here as misfit even when the nominal body is right.
        """
        if "h1_fit" not in self._cache:
            sp = [cross_spectra(np.stack([r.spindle_accel, r.body_accel]), r.fs_hz, self.spec) for r in self.fit_recs]
            f = sp[0].freq_hz
            self._cache["h1_fit"] = (f, np.mean([h1(x, 0, 1) for x in sp], axis=0))
        f, t = self._cache["h1_fit"]
        lo, hi = self.settings.analysis_band_hz
        m = (f >= lo) & (f <= hi) & (np.abs(t) > 0)
        return float(np.sqrt(np.mean(np.abs(body.t21(f[m]) / t[m] - 1) ** 2))) if m.any() else float("inf")

    def _predict(self, terms: tuple[Term, ...]):
        return self.predict_model(self.model(terms))

    def predict_model(self, model: IdentifiedModel):
        """Held-out prediction of ``model``: (pooled NMSE [%], per record [%], transmissibility errors, spectra).

        The one metric every model of the loop is scored on (the refined one too).
        """
        s = self.settings
        lo, hi = s.analysis_band_hz
        num = den = 0.0
        per, trans, pairs = [], [], []
        for rec, meas in zip(self.test_recs, self._measured):
            pt = predict_transmissibility(model, rec.spindle_accel, rec.fs_hz, settings=self.spec,
                                          method="parametric")
            v = pt.prediction.valid
            y = np.asarray(rec.body_accel)[v]
            e = y - pt.prediction.body_accel[v]
            num += float(np.sum(e ** 2))
            den += y.size * float(np.var(y))
            per.append(_nmse_pct(y, e))
            if y.size >= self.spec.block:
                sp = cross_spectra(np.stack([y, e]), rec.fs_hz, self.spec)
                pairs.append((sp.freq_hz, auto_spectrum(sp, 0), auto_spectrum(sp, 1)))
            sv = cross_spectra(np.stack([np.asarray(rec.spindle_accel)[v], y]), rec.fs_hz, self.spec)
            t_meas = h1(sv, 0, 1)
            m = (sv.freq_hz >= lo) & (sv.freq_hz <= hi)
            rel = np.abs(pt.t21[m] - t_meas[m]) / np.abs(t_meas[m])
            trans.append((rec.source, 100.0 * float(np.nanmedian(rel))))
        return 100.0 * num / den, per, trans, pairs


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
    """A bump-stop candidate re-measured from the static position (:mod:`nifo_core.characterize_static`).

    The ranking measures its gap from each record's mean position, which a one-sided stop pushes away
    from it, the more the harder the excitation. The gap from the static position and one offset
    -m_i per record come from the balance of the mean force; the candidate is re-scored with them and
    its offsets registered in ``ev.static`` (the loop's columns use them from then on).
    """
    if cand.kind not in STATIC_KINDS:
        return cand
    if ev.regression is None:
        ev.regression = RegressionData(ev.fit_rfs, n_groups=4, body_stiffness=False)
    data = ev.regression
    # the other terms keep their own (already static) frame; only the candidate is re-measured
    new, offs = static_bump_stops(data, [*terms, cand.term])
    term, off = new[-1], offs[-1]
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
        chans = np.vstack([p.y, p.z, p.zdot, *[_g(p, t, ev.static) for t in [*terms, cand]]])
        sp = cross_spectra(chans, p.rf.fs_hz, ev.spec)
        m = (sp.freq_hz >= s.analysis_band_hz[0]) & (sp.freq_hz <= s.analysis_band_hz[1])
        pc = partial_coherence(sp, 0, list(range(1, chans.shape[0])))[-1][m]
        pcs.append(pc)
        n_avg = max(n_avg, sp.n_avg)
    q = 2 + len(terms) + 1
    level = 1 - 0.05 ** (1 / max(n_avg - q - 1, 1)) if n_avg else float("nan")
    pc_all = np.concatenate(pcs) if pcs else np.array([np.nan])
    centres = 0.5 * (edges[1:] + edges[:-1])
    return Evidence(variable=cand.variable, bins=tuple(float(c) for c in centres), before=mean(e0), after=mean(e1),
                    effect=mean(effect), partial_coherence_mean=float(np.nanmean(pc_all)),
                    partial_coherence_level=float(level),
                    fraction_lines_above_level=float(np.nanmean(pc_all > level)) if pcs else float("nan"))


def _retune(ev: "_Evaluator", terms: Sequence[Term], s: LoopSettings) -> tuple[list[Term], list[str]]:
    """Each term's varying parameter re-tuned over its grid (then refined), the others held: best ERR."""
    z = np.concatenate([p.z for p in ev.fit_parts])
    v = np.concatenate([p.zdot for p in ev.fit_parts])
    rng = dict(z_range=float(np.quantile(np.abs(z), 0.995)), zdot_range=float(np.quantile(np.abs(v), 0.995)),
               z_neg=float(np.quantile(-z, 0.998)), z_pos=float(np.quantile(z, 0.998)))
    out, notes = list(terms), []
    for i, t in enumerate(terms):
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
        if key == t.spec.key_param:  # a declared gap/knee/deadband is the engineer's statement: within 2×
            v0 = float(t.params[key])
            vals = [x for x in vals if 0.5 * v0 <= x <= 2.0 * v0] or [v0]
        scores = [err(Term(t.kind, {**t.params, key: x})) for x in vals]
        j = int(np.argmax(scores))
        lo, hi = vals[max(j - 1, 0)], vals[min(j + 1, len(vals) - 1)]
        fine = [x for x in np.linspace(lo, hi, 9)[1:-1] if x > 0 or t.kind == "bump_stop"]
        cands = [(scores[j], vals[j])] + [(err(Term(t.kind, {**t.params, key: x})), x) for x in fine]
        cands.append((err(t), float(t.params[key])))
        best_score, best = max(cands)
        old = float(t.params[key])
        if best != old and best_score > 1.001 * cands[-1][0]:
            out[i] = Term(t.kind, {**t.params, key: best})
            notes.append(f"{t.label} re-tuned to {key}={best:.4g} on these data")
    return out, notes
