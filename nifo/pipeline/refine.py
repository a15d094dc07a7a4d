"""The fits of ``nifo identify`` after NIFO: ``--refine``/``--refine-linear`` (output error) and
``--feedback-paths`` (each term through its own linear path), on the identification records from their start."""

from __future__ import annotations

from dataclasses import dataclass

from nifo.io.loader import load_record
from nifo.progress import Progress
from nifo_core.predict.heldout import Scores, split_records
from nifo_core.predict.model_fit import joint_paths
from nifo_core.predict.refine import refine_jointly, refine_model, start_up_samples
from nifo_core.predict.scope_fit import fit_scope


def from_start(opts: dict, paths: list, *, centred: bool = True) -> list[tuple]:
    """Every identification record read once, whole from its start, with the samples the identification skipped
    (--skip-periods/--skip-seconds); ``centred``: the accelerations' constant offsets removed (what the fits read:
    offsets of any size alike), else as measured (what the model's static part is fitted on)."""
    period = opts.get("period_samples")
    load_opts = {k: v for k, v in opts.items() if k not in ("skip_periods", "skip_seconds")}
    out = []
    for path in paths:
        rec = load_record(path, **load_opts, centred=centred)
        out.append((rec, int(opts.get("skip_periods") or 0) * int(period or 0)
                    or int(round(float(opts.get("skip_seconds") or 0.0) * rec.fs_hz))))
    return out


def score_records(args, model, opts: dict, loaded: list[tuple]) -> tuple[list, list[int]]:
    """The records of :func:`from_start` cut to at most ``--refine-seconds`` after the skipped part, and the
    samples each leaves out of the score.

    Every record is simulated from its start, where the measurement began (a test rig starts from rest); the part
    the identification skipped (--skip-periods/--skip-seconds) is left out of the score, and --refine-seconds
    counts after it.
    """
    period = opts.get("period_samples")
    records, skips = [], []
    for rec, skip in loaded:
        n = int(round(args.refine_seconds * rec.fs_hz))
        if period:
            n = max(int(period) * 2, n // int(period) * int(period))
        if skip + n < rec.n:
            rec = rec.slice(0, skip + n)
        records.append(rec)
        skips.append(max(skip, start_up_samples(model, rec, period)))
    return records, skips


@dataclass(frozen=True)
class HeldOutCheck:
    """Whether the refined model is kept: both models scored on the held-out parts of the identification records."""

    kept: bool
    before: Scores
    after: Scores
    fit_seconds: tuple

    def to_dict(self) -> dict:
        return {"kept": self.kept, "held_out_nmse_before": self.before.to_dict(),
                "held_out_nmse_after": self.after.to_dict(), "fit_seconds": list(self.fit_seconds),
                "rule": "the refined model is kept only when it predicts the held-out parts (the last third of each "
                        "record, whole periods for periodic data) no worse than NIFO's model"}

    @property
    def message(self) -> str:
        b, a = self.before.mean, self.after.mean
        which = "the refined model" if self.kept else "NIFO's model (the refined one predicts held-out data worse)"
        return (f"held-out check (refined on the first two thirds of each record, scored on the last third): "
                f"{b:.4g} % (NIFO) → {a:.4g} % (refined): model.json holds {which}")


def refine(args, model, linear, opts: dict, paths: list):
    """Output-error refinement of ``model`` (``--refine``), on the fit parts of the identification records, kept when
    it predicts their held-out parts no worse: (refinement, None, check).

    ``--refine-linear`` with a rational linear part: the joint procedure
    (:func:`nifo_core.predict.refine.refine_jointly`): the linear model's residues refined alone, then the terms with
    them from two starts; (refinement, the linear model's refinement, check).
    """
    period = opts.get("period_samples")
    loaded = from_start(opts, paths)
    held = split_records([rec for rec, _ in loaded], skip_samples=max(skip for _, skip in loaded),
                         period_samples=period, band_hz=model.analysis_band_hz)
    fit_loaded = [(rec.slice(0, k), skip) for (rec, skip), k in zip(loaded, held.split)]
    records, skips = score_records(args, model, opts, fit_loaded)
    out = _refine(args, model, linear, records, skips, period, refine_jointly, refine_model)
    before, after = held.score(model), held.score(out[0].model)
    check = HeldOutCheck(after.mean <= before.mean, before, after, tuple(float(r.duration_s) for r in records))
    return (*out, check)


def with_scope(model, linear, opts: dict, paths: list):
    """``model`` and ``linear`` with their offsets, prediction band, periodic response and validity from the
    identification records (:func:`nifo_core.predict.scope_fit.fit_scope`: held-out parts as the refinement's check
    splits them)."""
    loaded = from_start(opts, paths, centred=False)      # the static part: the records as measured
    held = split_records([rec for rec, _ in loaded], skip_samples=max(skip for _, skip in loaded),
                         period_samples=opts.get("period_samples"), band_hz=model.analysis_band_hz)
    with Progress(None, "the static part and the band the prediction covers", enabled=True):
        linear = None if linear is None else fit_scope(linear, held)
        return fit_scope(model, held, linear=linear), linear


def _refine(args, model, linear, records, skips, period, refine_jointly, refine_model):
    jointly = bool(getattr(args, "refine_linear", False)) and linear.linear.kind == "rational"
    with Progress(None, "refine (simulations)", enabled=True) as bar:
        def progress(what: str, starts: bool = True):
            return lambda start, k, cost: setattr(bar, "desc", f"refine {what}"
                                                  + (f" from the {start} start" if starts else "")
                                                  + f": cost {cost:.4g}") or bar.advance(1)
        if jointly:
            lin = refine_model(linear, records, period_samples=period, skip_samples=skips, linear_residues=True,
                               max_iterations=40, progress=progress("the linear model's residues", starts=False))
            return refine_jointly(model, lin, records, period_samples=period, skip_samples=skips,
                                  progress=progress("jointly")), lin
        return refine_model(model, records, linear=linear, period_samples=period, skip_samples=skips,
                            linear_residues=bool(getattr(args, "refine_linear", False)),
                            progress=progress("the model")), None


def fit_feedback_paths(args, linear, terms, opts: dict, paths: list, settings):
    """``--feedback-paths``: the terms through their own paths on the linear model's poles, identified jointly with
    its residues (:func:`nifo_core.predict.model_fit.joint_paths`), the ridge chosen on held-out parts of the records."""
    loaded = from_start(opts, paths)
    with Progress(None, "feedback paths (ridge grid on held-out parts)", enabled=True):
        return joint_paths([rec for rec, _ in loaded], terms, linear, settings,
                           skip_samples=max(skip for _, skip in loaded))
