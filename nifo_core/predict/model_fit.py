"""The model class ``nifo identify`` writes, fitted on the fit parts of records: one service for identify, loop, run.

A model is fitted as ``nifo identify`` fits it (:mod:`nifo_core.nifo.identify`, then
:meth:`~nifo_core.predict.model.IdentifiedModel.from_nifo`):

- NIFO on the fit parts (with the measured force as one more input when the
  records have one: then M2 and the one-mass body of the force path);
- the linear part in the form chosen for these data (:func:`choose_linear_form`:
  the one-mass body or a stable rational model, whichever linear model
  predicts the held-out parts better); a rational part at the linear model's
  order, the structure's modes chosen once by how well the linear model
  predicts the fit parts (``nifo identify`` chooses the order of its model
  among 2-40 poles by the model's own T21 misfit);
- the feedback structure: constant coefficients (the static NIFO fit: the
  structure of one rigid body mass), or — on a rational linear part, a
  structure with its own modes, for terms whose force is bounded — each term
  through its own feedback path on the linear model's poles
  (:mod:`nifo_core.predict.feedback_paths`, the ridge chosen on the fit parts).
  ``structure='auto'`` takes the paths where they are possible, constant
  coefficients elsewhere.

Every model is scored on one metric (:mod:`nifo_core.predict.heldout`), so the model
the loop keeps is exactly the model ``nifo predict`` runs from its model.json.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Literal, Sequence

import numpy as np

from ..kinds.describing import Term
from ..errors import ConfigError, NifoError
from .feedback_paths import (PATH_KINDS, JointFit, PathResult, equivalent_gammas, fit_joint,
                             regimes_stable)
from .heldout import HeldOut, Scores, split_records
from .linear_part import pole_residue_response
from .vector_fit import RecordLines
from .model import IdentifiedModel
from ..signal.record import Record
from ..signal.spectral import cross_spectra
from ..nifo.identify import identify_nifo
from ..settings import AnalysisSettings

__all__ = ["Fitted", "JointPathResult", "LinearChoice", "choose_linear_form", "fit_linear", "fit_model",
           "joint_paths", "path_eligible"]

Structure = Literal["auto", "constant", "paths"]

#: ridge weights of the joint least squares of the linear part and the feedback paths (relative to the largest path
#: column), each scored on the held-out parts
JOINT_RIDGES = (0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0)


@dataclass(frozen=True)
class Fitted:
    """A fitted model, how it was made and its held-out scores.

    Attributes
    ----------
    model : IdentifiedModel
    structure : {'linear', 'constant', 'paths'}
    scores : Scores
        Held-out band NMSE of ``model``.
    note : str
        How it was made (the structure chosen and why).
    paths : PathResult or None
    """

    model: IdentifiedModel
    structure: str
    scores: Scores
    note: str = ""
    paths: PathResult | None = None

    @property
    def score(self) -> float:
        return self.scores.mean


@dataclass(frozen=True)
class LinearChoice:
    """The linear part's form chosen for these data, the linear model of that form and why."""

    form: Literal["body", "rational"]
    linear: Fitted
    candidates: dict
    reason: str


def _nifo(held: HeldOut, terms: Sequence[Term], settings: AnalysisSettings):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # ill-conditioning of single lines: the pooled fit is what is used
        return identify_nifo(held.fit, list(terms), settings=settings.spectral, band=settings.band,
                             analysis_band_hz=settings.analysis_band_hz, on_ill_conditioned="ignore",
                             cond_limit=settings.cond_limit, input_measured=False)


def record_lines(records: Sequence[Record], settings: AnalysisSettings) -> list[RecordLines] | None:
    """Each record's transmissibility and prediction weights on the analysis band (one spectral engine), or None for
    records driven by a measured force (their linear part is the force path's one-mass body)."""
    if any(r.spindle_fixed or r.has_force for r in records):
        return None
    out = []
    for r in records:
        sp = cross_spectra(np.stack([r.spindle_accel, r.body_accel]), r.fs_hz, settings.spectral)
        out.append(RecordLines.from_spectra(sp.freq_hz, sp.G[:, 0, 0], sp.G[:, 0, 1], sp.G[:, 1, 1],
                                            settings.analysis_band_hz))
    return out


def fit_linear(held: HeldOut, settings: AnalysisSettings, *, form: str = "auto", order: int | None = None) -> Fitted:
    """The linear model of the fit parts (NIFO's plain H1, the force path when measured) in ``form``; a rational
    part's residues predict every fit part best (:class:`~nifo_core.predict.vector_fit.RecordLines`)."""
    res = _nifo(held, [], settings)
    model = IdentifiedModel.from_nifo(res, source="h1", linear_form=form, order=order,
                                      records=record_lines(held.fit, settings))
    return Fitted(model, "linear", held.score(model), f"linear: {model.linear.reason}")


#: a physical one-mass body is the structure of a quarter car: the rational (black-box) linear part replaces it only
#: when its linear model predicts the held-out parts this much better (relative error ratio)
RATIONAL_MARGIN = 0.5


def choose_linear_form(held: HeldOut, settings: AnalysisSettings) -> LinearChoice:
    """The one-mass body or the rational linear part, whichever linear model predicts the held-out parts better.

    A one-mass body that is not physical is not a candidate; a physical one is kept unless the rational model
    predicts clearly better (:data:`RATIONAL_MARGIN`); when only one form can be fitted it is taken.
    A single mass driven by a measured force (a fixed spindle) whose force path gives a physical one-mass body
    keeps it: that is its structure (M2·ÿ + C2·ẏ + K2·y = F), and a linear model of a strongly nonlinear
    record predicts too poorly for its held-out error to choose between forms.
    """
    if all(r.spindle_fixed for r in held.records):
        try:
            body = fit_linear(held, settings, form="body")
        except (NifoError, ValueError):
            body = None
        if body is not None and body.model.linear.kind == "body" and body.model.linear.physical:
            return LinearChoice("body", body, {"body": {"held_out_nmse_percent": body.scores.to_dict()["mean_percent"],
                                                        "reason": body.model.linear.reason}},
                                "one-mass body: a single mass driven by the measured force, its force path physical "
                                f"({body.model.linear.reason})")
    cands: dict[str, Fitted] = {}
    why: dict[str, str] = {}
    for form in ("body", "rational"):
        try:
            fit = fit_linear(held, settings, form=form)
        except (NifoError, ValueError) as err:
            why[form] = str(err.message if isinstance(err, NifoError) else err)
            continue
        cands[form] = fit
    if not cands:
        raise ConfigError("no linear part can be fitted to these data: " + "; ".join(f"{k}: {v}" for k, v in
                                                                                      why.items()),
                          hint="check the analysis band (--analysis-band) and the channels")
    best = min(cands, key=lambda k: cands[k].score)
    body = cands.get("body")
    if best == "rational" and body is not None and body.model.linear.kind == "body" and body.model.linear.physical \
            and not cands["rational"].score <= RATIONAL_MARGIN * body.score:
        best = "body"       # the physical structure, unless the black box predicts clearly better
    table = {k: {"held_out_nmse_percent": v.scores.to_dict()["mean_percent"], "reason": v.model.linear.reason}
             for k, v in cands.items()}
    table.update({k: {"error": v} for k, v in why.items()})
    if len(cands) == 1:
        other = next(iter(why.items()), None)
        reason = (f"{best} linear part: the only form that could be fitted"
                  + (f" ({other[0]}: {other[1]})" if other else ""))
    else:
        a, b = cands[best].score, cands["rational" if best == "body" else "body"].score
        reason = (f"{'one-mass body' if best == 'body' else 'rational'} linear part: its linear model predicts the "
                  f"held-out parts at {a:.4g} % against {b:.4g} % for the "
                  f"{'rational model' if best == 'body' else 'one-mass body'}"
                  + (f" (a physical one-mass body is kept unless the rational model predicts at least "
                     f"{100 * (1 - RATIONAL_MARGIN):.0f} % better)" if best == "body" else ""))
    return LinearChoice(best, cands[best], table, reason)


def _joint_model(linear: IdentifiedModel, terms: Sequence[Term], fit: JointFit) -> IdentifiedModel:
    """The model of one joint fit: the linear part's poles with the fit's residues, the terms through its paths."""
    lin = linear.linear
    new = replace(lin, residues=fit.residues, paths=fit.paths,
                  reason=lin.reason + "; its residues identified jointly with the terms' feedback paths on its poles")
    f = linear.freq_hz
    return replace(linear, terms=tuple(terms), t21=new.t21(f), b=pole_residue_response(lin.poles, fit.paths, f),
                   c_over_m2=equivalent_gammas(new, fit.paths, linear.analysis_band_hz), linear=new, source="paths",
                   provenance={**dict(linear.provenance), "from": "feedback paths, identified jointly with the "
                                                                   "linear part's residues"})


def _fit_joint_paths(held: HeldOut, terms: Sequence[Term], linear: Fitted) -> Fitted:
    """Every ridge weight of :data:`JOINT_RIDGES` fitted (:func:`~nifo_core.predict.feedback_paths.fit_joint`), the models
    whose every regime is stable scored on the held-out parts, the best kept."""
    lm = linear.model
    fits = fit_joint(held.fit, terms, lm.linear, settings=lm.settings, band=lm.band,
                     analysis_band_hz=lm.analysis_band_hz, period_samples=held.period_samples, ridges=JOINT_RIDGES)
    grid, best = [], None
    for jf in fits:
        model = _joint_model(lm, terms, jf)
        if not regimes_stable(model.linear, terms):
            grid.append({"ridge": jf.ridge, "regimes_stable": False})
            continue
        sc = held.score(model)
        grid.append({"ridge": jf.ridge, "regimes_stable": True, "held_out_nmse_percent": sc.to_dict()["mean_percent"]})
        if best is None or sc.mean < best[1].mean:
            best = (model, sc, jf.ridge)
    if best is None:
        raise ConfigError("no ridge weight gives feedback paths whose every regime (each term stuck or active) is "
                          "stable: these data do not determine the paths of " + ", ".join(t.label for t in terms))
    model, sc, ridge = best
    note = (f"each term through its own feedback path on the rational linear part's poles, the linear part's "
            f"residues identified jointly (ridge {ridge:g} of {len(fits)}, chosen on the held-out parts): the body "
            f"is not one rigid mass")
    return Fitted(replace(model, provenance={**dict(model.provenance), "ridge_grid": grid}), "paths", sc, note)


@dataclass(frozen=True)
class JointPathResult:
    """A model whose terms act through feedback paths identified jointly with its linear part (:func:`joint_paths`):
    the ridge weight chosen on held-out parts, the model fitted with it on every record."""

    model: IdentifiedModel
    ridge: float
    grid: tuple
    held_out: Scores
    linear_held_out: Scores

    @property
    def message(self) -> str:
        return (f"feedback paths identified jointly with the linear part: ridge {self.ridge:g} chosen on the held-out "
                f"parts (the last third of each record) — {self.held_out.mean:.4g} % against the linear model's "
                f"{self.linear_held_out.mean:.4g} % — then fitted on every record")

    def to_dict(self) -> dict:
        return {"ridge": self.ridge, "nmse_percent": list(self.held_out.per_record),
                "linear_nmse_percent": list(self.linear_held_out.per_record), "message": self.message,
                "how": "ridge chosen on held-out parts; linear part's residues and the paths in one least squares",
                "grid": [{"ridge": g["ridge"], "regimes_stable": g["regimes_stable"],
                          "nmse_sum_percent": g.get("held_out_nmse_percent"), "nmse_percent": []} for g in self.grid]}


def joint_paths(records: Sequence[Record], terms: Sequence[Term], linear: IdentifiedModel, settings: AnalysisSettings,
                *, skip_samples: int = 0) -> JointPathResult:
    """``terms`` through feedback paths on ``linear``'s rational part, identified jointly with its residues
    (:func:`~nifo_core.predict.feedback_paths.fit_joint`): the ridge weight chosen on held-out parts of ``records`` (whole,
    from their start), then the model fitted with it on every record after ``skip_samples``.

    ``linear`` is the linear model of all the records (its poles are kept).
    """
    if not path_eligible(terms, linear):
        raise ConfigError("feedback paths need a rational linear part and backlash, clearance or saturation terms "
                          f"(linear part: {linear.linear.kind}; terms: {', '.join(t.label for t in terms)})",
                          hint="a one-mass body feeds the strut force back through its mass: use --refine")
    held = split_records(records, skip_samples=skip_samples, period_samples=settings.period_samples,
                         band_hz=linear.analysis_band_hz)
    lin_fit = fit_linear(held, settings, form="rational")
    chosen = _fit_joint_paths(held, terms, lin_fit)
    ridge = float(next(g["ridge"] for g in chosen.model.provenance["ridge_grid"]
                       if g.get("held_out_nmse_percent") == chosen.scores.to_dict()["mean_percent"]))
    whole = held.whole
    jf = fit_joint(whole, terms, linear.linear, settings=linear.settings, band=linear.band,
                   analysis_band_hz=linear.analysis_band_hz, period_samples=settings.period_samples,
                   ridges=(ridge,))[0]
    model = _joint_model(linear, terms, jf)
    if not regimes_stable(model.linear, terms):
        raise ConfigError(f"the feedback paths fitted on every record with ridge {ridge:g} have an unstable regime",
                          hint="identify on levels that include the small-amplitude regime, or use --refine")
    return JointPathResult(model, ridge, tuple(chosen.model.provenance["ridge_grid"]), chosen.scores, lin_fit.scores)


def path_eligible(terms: Sequence[Term], linear: IdentifiedModel) -> bool:
    """Terms can act through feedback paths: a rational linear part and every term of a bounded-remainder kind."""
    return bool(terms) and linear.linear.kind == "rational" and all(t.kind in PATH_KINDS for t in terms)


def fit_model(held: HeldOut, terms: Sequence[Term], settings: AnalysisSettings, *, linear: Fitted,
              structure: Structure = "auto") -> Fitted:
    """The model with ``terms`` on the linear part of ``linear`` (module docstring), scored on the held-out parts.

    Parameters
    ----------
    held : HeldOut
    terms : sequence of Term
        Empty: ``linear`` itself.
    settings : AnalysisSettings
    linear : Fitted
        The linear model of the same fit parts (:func:`choose_linear_form`); its form is kept, and a rational
        part's order (measured on physics-fleet case 64, ``nifo loop`` of four 273 s records: the orders each term
        set chose by its T21 misfit jumped between 20 and 32 from one candidate to the next, and their 440 vector
        fits took 26 of the loop's 54 CPU-s).
    structure : {'auto', 'constant', 'paths'}
    """
    terms = tuple(terms)
    if not terms:
        return linear
    form = linear.model.linear.kind
    out: dict[str, Fitted] = {}
    errors: dict[str, str] = {}
    can_paths = path_eligible(terms, linear.model)
    if structure == "constant" or not can_paths:
        try:
            res = _nifo(held, terms, settings)
            # a rational part at the linear model's order (module docstring)
            model = IdentifiedModel.from_nifo(res, source="static", linear_form=form,
                                              order=linear.model.linear.fitted_poles if form == "rational" else None)
            out["constant"] = Fitted(model, "constant", held.score(model), "constant coefficients (NIFO's static fit)")
        except NifoError as err:
            errors["constant"] = err.message
    if can_paths and structure in ("auto", "paths"):
        try:
            out["paths"] = _fit_joint_paths(held, terms, linear)
        except NifoError as err:
            errors["paths"] = err.message
    if not out:
        raise ConfigError("the model cannot be fitted with " + ", ".join(t.label for t in terms) + ": "
                          + "; ".join(f"{k}: {v}" for k, v in errors.items()))
    best = min(out, key=lambda k: out[k].score)
    chosen = out[best]
    if len(out) > 1:
        other = out["constant" if best == "paths" else "paths"]
        chosen = replace(chosen, note=chosen.note + f"; chosen over {other.structure} "
                                                    f"({chosen.score:.4g} % against {other.score:.4g} % held out)")
    return chosen
