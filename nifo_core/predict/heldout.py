"""Records split in time into a fit part and a held-out part, and the one metric every model is scored on.

Every choice the loop and ``nifo run`` make from the data (the linear part's
form, the feedback structure, a term, a width, keeping a refinement) is made
by how well the model *predicts data it was not fitted on*. Each record is
split in time: the fit part identifies (NIFO, the paths' least squares, the
refinement), the held-out part scores. The model is simulated from rest over
the whole record, from its first sample — as the test began — so no initial
state is guessed, and only the held-out part is scored.

The metric is the band NMSE of :mod:`nifo_core.predict.prediction_error` over the
analysis band (what ``nifo predict`` leads with and ``nifo identify --refine``
minimises): on the period average of the held-out periods for periodic data,
over the held-out samples otherwise. Records count by their *relative* error
(the mean over records), so a low level weighs as much as a high one.

Periodic data are split at a period boundary: the last third of the steady
periods (at least one) is held out. Random data: the last ``1 - fit_fraction``
of what follows the transient.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from ..errors import InputError, NifoError
from .model import IdentifiedModel, predict_records, record_inputs
from .output_signal import common_mode, measured_output, output_name
from .whole_signal import whole_signal_error
from ..signal.band import band_limit
from .prediction_error import band_nmse
from ..signal.parallel import batch_map
from ..signal.record import Record
from .refine import start_up_samples

__all__ = ["HeldOut", "split_records", "Scores"]


@dataclass(frozen=True)
class Scores:
    """Band NMSE [%] of a model on each record's held-out part (None: it could not be predicted, with why), and
    beside it the whole-signal NMSE [%] of the same predictions (:mod:`nifo_core.predict.whole_signal`: the raw
    output over all frequencies, offset included, the offset taken from the fit parts), with the prediction
    limited to the analysis band or not, whichever scores lower (``whole_policy``)."""

    per_record: tuple[float, ...]
    unavailable: str | None = None
    predictions: tuple = field(default=(), compare=False, repr=False)   # whole-record predictions scored
    whole: tuple[float, ...] = ()
    whole_policy: str = ""

    @property
    def mean(self) -> float:
        """The one metric: the mean over records of the held-out band NMSE [%] (inf when not available)."""
        return float(np.mean(self.per_record)) if self.per_record and self.unavailable is None else float("inf")

    @property
    def whole_mean(self) -> float | None:
        """The mean over records of the held-out whole-signal NMSE [%] (None when not computed)."""
        return float(np.mean(self.whole)) if self.whole and self.unavailable is None else None

    def to_dict(self) -> dict:
        return {"mean_percent": None if not np.isfinite(self.mean) else self.mean,
                "per_record_percent": list(self.per_record), "unavailable": self.unavailable,
                "whole_signal_mean_percent": self.whole_mean, "whole_signal_per_record_percent": list(self.whole),
                "whole_signal_prediction": self.whole_policy or None}


@dataclass(frozen=True)
class HeldOut:
    """Records split into fit and held-out parts (module docstring).

    Attributes
    ----------
    records : tuple of Record
        Whole records from their first sample (transient included): what is simulated from rest.
    skip : tuple of int
        Transient samples at the start of each record (not fitted, not scored).
    split : tuple of int
        First held-out sample of each record.
    period_samples : int or None
    band_hz : (float, float)
        The analysis band: where the metric is taken.
    """

    records: tuple[Record, ...]
    skip: tuple[int, ...]
    split: tuple[int, ...]
    period_samples: int | None
    band_hz: tuple[float, float]

    @property
    def fit(self) -> list[Record]:
        """The fit parts without the transient (for NIFO and the paths' least squares)."""
        return [r.slice(s, k) for r, s, k in zip(self.records, self.skip, self.split)]

    @property
    def fit_from_start(self) -> list[Record]:
        """Each record from its start to the end of its fit part (simulated from rest for in-sample scores)."""
        return [r.slice(0, k) for r, k in zip(self.records, self.split)]

    @property
    def whole(self) -> list[Record]:
        """Each record after its transient, fit and held-out parts together (the final identification)."""
        return [r.slice(s, r.n) for r, s in zip(self.records, self.skip)]

    @property
    def held_out(self) -> list[Record]:
        return [r.slice(k, r.n) for r, k in zip(self.records, self.split)]

    @property
    def sources(self) -> tuple[str, ...]:
        return tuple(r.source for r in self.records)

    def warmup(self, model: IdentifiedModel, i: int) -> int:
        """Samples simulated before record ``i``'s held-out part: one period (periodic data, at least the
        transient), else five time constants of the model's slowest pole (at least the transient)."""
        r = self.records[i]
        if self.period_samples:
            w = max(int(self.period_samples), self.skip[i])
        else:
            w = max(start_up_samples(model, r), self.skip[i])
        return min(w, self.split[i])

    def _simulated(self, model: IdentifiedModel, part: str) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per record (body acceleration, the output's predicted deviation in its measured unit), each an array of the
        record's length, NaN where not simulated (:meth:`predictions`). The records side by side: a batch on each
        thread, the parts of one length in a batch marched together (:func:`~nifo_core.predict.model.predict_records`:
        the same bits as one by one); the first record's divergence in record order is raised."""
        def span(i: int) -> tuple[int, int]:
            r = self.records[i]
            if part == "held-out":
                return self.split[i] - self.warmup(model, i), r.n
            return (0, self.split[i]) if part == "fit" else (0, r.n)

        def batch(idx: list[int]) -> list:
            drives = [record_inputs(self.records[i].slice(*span(i)), model) for i in idx]
            return predict_records(model, [a1 for a1, _ in drives], [self.records[i].fs_hz for i in idx],
                                   forces=[f for _, f in drives], labels=[self.records[i].source for i in idx])

        preds = batch_map(batch, range(len(self.records)))
        out = []
        for i, pred in enumerate(preds):
            if isinstance(pred, NifoError):
                raise pred
            r = self.records[i]
            lo, hi = span(i)
            y, dev = np.full(r.n, np.nan), np.full(r.n, np.nan)
            y[lo:hi] = pred.body_accel
            dev[lo:hi] = pred.z if output_name(r) == "body_disp" else pred.body_accel
            out.append((y, dev))
        return out

    def predictions(self, model: IdentifiedModel, *, part: str = "held-out") -> list[np.ndarray]:
        """The model's body acceleration of every record, simulated from rest (may raise NifoError), as arrays of the
        record's length (NaN where not simulated): ``part='held-out'`` from a warm-up before the held-out part
        (:meth:`warmup`) to the end, ``'fit'`` from the record's first sample to the end of its fit part,
        ``'whole'`` all of it."""
        return [y for y, _ in self._simulated(model, part)]

    def score(self, model: IdentifiedModel, *, part: str = "held-out") -> Scores:
        """Band NMSE of ``model`` on the held-out parts (``part='fit'``: on the fit parts, in-sample), and on the
        held-out parts their whole-signal NMSE (:class:`Scores`)."""
        try:
            sims = self._simulated(model, part)
        except (NifoError, np.linalg.LinAlgError) as err:
            return Scores((), str(err))
        scores = self.score_predictions([y for y, _ in sims], part=part)
        if part != "held-out" or scores.unavailable is not None:
            return scores
        whole, policy = self.whole_signal([d for _, d in sims])
        return replace(scores, whole=whole, whole_policy=policy)

    def whole_signal(self, deviations: Sequence[np.ndarray]) -> tuple[tuple[float, ...], str]:
        """Per record the held-out whole-signal NMSE [%] of the predicted output deviations (NaN where not
        simulated), unlimited or limited to the analysis band — whichever scores lower on the mean over records
        — and that choice ('whole' or 'band'). The output offset is pooled over the records: each fit part's
        measured mean beyond the common mode, less the mean the model predicts for the record (:class:`Scores`)."""
        best: tuple[tuple[float, ...], str] = ((), "")
        for policy in ("whole", "band"):
            devs = []
            for r, d, k in zip(self.records, deviations, self.split):
                ok = np.flatnonzero(np.isfinite(d))
                dd = d.copy()
                if policy == "band" and ok.size:
                    dd[ok[0]:] = band_limit(d[ok[0]:], r.fs_hz, self.band_hz)
                devs.append(dd)
            means, weights = [], []
            for r, dd, s, k in zip(self.records, devs, self.skip, self.split):
                cm = common_mode(r) if output_name(r) == "body_accel" else 0.0
                y = measured_output(r).values
                means.append(float(np.mean(y[s:k]) - cm - np.nanmean(dd[k:])))
                weights.append(k - s)
            y0 = float(np.average(means, weights=weights)) if sum(weights) > 0 else 0.0
            per = []
            for r, dd, k in zip(self.records, devs, self.split):
                cm = common_mode(r) if output_name(r) == "body_accel" else 0.0
                per.append(whole_signal_error(measured_output(r).values[k:], dd[k:] + cm + y0).nmse_percent)
            if not best[0] or np.mean(per) < np.mean(best[0]):
                best = (tuple(per), policy)
        return best

    def ridge_records(self, *, max_periods: int = 2, max_seconds: float = 60.0) -> tuple[list[Record], list[int]]:
        """Short in-sample records for choices made on the fit parts (a ridge weight): each record from its start,
        its transient and at most ``max_periods`` steady periods (periodic) or ``max_seconds`` of its fit part;
        and the samples each leaves out of the score."""
        recs, skips = [], []
        for r, s, k in zip(self.records, self.skip, self.split):
            if self.period_samples:
                p = int(self.period_samples)
                lead = max(s, p)
                n = min(k, lead + max_periods * p)
            else:
                lead = s
                n = min(k, s + int(round(max_seconds * r.fs_hz)))
            recs.append(r.slice(0, n))
            skips.append(min(lead, n - 1))
        return recs, skips

    def score_predictions(self, preds: Sequence[np.ndarray], *, part: str = "held-out") -> Scores:
        out = []
        for r, y, s, k in zip(self.records, preds, self.skip, self.split):
            lo, hi = (k, r.n) if part == "held-out" else (s, k)
            try:
                out.append(band_nmse(np.asarray(r.body_accel)[lo:hi], np.asarray(y)[lo:hi], r.fs_hz,
                                     band_hz=self.band_hz, period_samples=self.period_samples))
            except NifoError as err:
                return Scores(tuple(out), f"{r.source}: {err}")
        return Scores(tuple(out), predictions=tuple(preds))

    def noise_floor(self) -> tuple[float, ...]:
        """Per record, the band NMSE [%] a perfect model would still show on the held-out part: the noise left in
        its period average (periodic data: the spread of the held-out periods about their mean, divided by their
        number, on the analysis-band lines). 0 for random data (not measurable from one realisation)."""
        if not self.period_samples:
            return tuple(0.0 for _ in self.records)
        p = int(self.period_samples)
        out = []
        for r, k in zip(self.records, self.split):
            y = np.asarray(r.body_accel)[k:]
            n = y.size // p
            if n < 2:
                out.append(0.0)
                continue
            spec = np.fft.rfft(y[: n * p].reshape(n, p), axis=1)
            f = np.fft.rfftfreq(p, 1.0 / r.fs_hz)
            m = (f >= self.band_hz[0]) & (f <= self.band_hz[1])
            mean = spec[:, m].mean(axis=0)
            var = np.sum(np.abs(spec[:, m] - mean) ** 2) / (n - 1)
            out.append(float(100 * var / n / max(np.sum(np.abs(mean) ** 2), 1e-300)))
        return tuple(out)

    def zero_scores(self) -> Scores:
        """Predicting nothing: 100 % on every record (the floor every model must beat)."""
        return Scores(tuple(100.0 for _ in self.records))


def split_records(records: Sequence[Record], *, skip_samples: int = 0, period_samples: int | None = None,
                  fit_fraction: float = 2 / 3, band_hz: tuple[float, float], min_fit_samples: int = 0) -> HeldOut:
    """Split every record (whole, from its first sample) into fit and held-out parts (module docstring)."""
    recs = list(records)
    if not recs:
        raise InputError("no records to split")
    skips, splits = [], []
    for r in recs:
        skip = min(int(skip_samples), r.n)
        left = r.n - skip
        if period_samples:
            p = int(period_samples)
            k = left // p
            if k < 2:
                raise InputError(f"{k} whole period(s) of {p} samples after the transient: a fit part and a "
                                 f"held-out part need at least 2", source=r.source,
                                 hint="record more periods, or drop fewer (--skip-periods)")
            held = max(1, int(round(k * (1 - fit_fraction))))
            split = skip + (k - held) * p
        else:
            split = skip + int(round(fit_fraction * left))
        if split - skip < min_fit_samples:
            raise InputError(f"the fit part ({split - skip} samples) is shorter than {min_fit_samples} samples",
                             source=r.source, hint="record longer")
        skips.append(skip)
        splits.append(split)
    return HeldOut(tuple(recs), tuple(skips), tuple(splits), int(period_samples) if period_samples else None,
                   (float(band_hz[0]), float(band_hz[1])))
