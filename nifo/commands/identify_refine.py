"""The fits of ``nifo identify`` after NIFO: ``--refine``/``--refine-linear`` (output error) and
``--feedback-paths`` (each term through its own linear path), on the identification records from their start."""

from __future__ import annotations

from nifo.progress import Progress
from nifo_core.errors import ConfigError


def from_start(opts: dict, paths: list) -> list[tuple]:
    """Every identification record read once, whole from its start, with the samples the identification skipped
    (--skip-periods/--skip-seconds)."""
    from nifo.io.loader import load_record

    period = opts.get("period_samples")
    load_opts = {k: v for k, v in opts.items() if k not in ("skip_periods", "skip_seconds")}
    out = []
    for path in paths:
        rec = load_record(path, **load_opts)
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
    from nifo_core.refine import start_up_samples

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


def refine(args, model, linear, opts: dict, paths: list):
    """Output-error refinement of ``model`` on the identification records (``--refine``): (refinement, None).

    ``--refine-linear`` with a rational linear part: the joint procedure
    (:func:`nifo_core.refine.refine_jointly`): the linear model's residues refined alone, then the terms with
    them from two starts; (refinement, the linear model's refinement).
    """
    from nifo_core.refine import refine_jointly, refine_model

    period = opts.get("period_samples")
    records, skips = score_records(args, model, opts, from_start(opts, paths))
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


def fit_feedback_paths(args, linear, terms, opts: dict, paths: list):
    """``--feedback-paths``: the terms through their own paths on the linear model's poles
    (:func:`nifo_core.feedback_paths.path_model`), the ridge chosen on the identification records."""
    from nifo_core.feedback_paths import path_model

    if linear.linear.kind != "rational":
        raise ConfigError(f"feedback paths need a rational linear part; this one is a {linear.linear.kind} "
                          f"({linear.linear.reason})",
                          hint="a physical one-mass body already feeds the strut force back through its mass: use "
                               "--refine")
    period = opts.get("period_samples")
    loaded = from_start(opts, paths)
    fit_records = [rec.slice(skip, rec.n) for rec, skip in loaded]      # what the identification used
    records, skips = score_records(args, linear, opts, loaded)
    with Progress(None, "feedback paths (ridge grid)", enabled=True) as bar:
        def progress(ridge: float, total: float):
            bar.desc = f"feedback paths: ridge {ridge:g} predicts the records at {total:.4g} %"
            bar.advance(1)
        return path_model(linear, terms, fit_records, records, period_samples=period, skip_samples=skips,
                          progress=progress)
