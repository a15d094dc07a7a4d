"""The loop's held-out prediction (:mod:`nifo_core.loop.closing`, step 1): the model class ``nifo identify`` writes,
fitted on the fit parts for any term set and scored on the held-out parts (:class:`_Predictor`), and both residuals
of a term set, the equation error and that prediction, each labelled (:func:`_errors`).
"""

from __future__ import annotations

import copy
from dataclasses import replace
from typing import Sequence

import numpy as np

from ..kinds.describing import Term
from ..errors import NifoError
from ..predict.heldout import HeldOut
from .residual import _Evaluator
from ..predict.model_fit import RATIONAL_MARGIN, Fitted, LinearChoice, choose_linear_form, fit_model
from ..settings import AnalysisSettings
from .round_results import Errors
from .settings import LoopSettings


class _Predictor:
    """The model class ``nifo identify`` writes, fitted on the fit parts for any term set and scored held out.

    The linear part's form (one-mass body or rational) is chosen once, by which linear model predicts the
    held-out parts better (:func:`~nifo_core.predict.model_fit.choose_linear_form`). On a one-mass body every term set
    is the force-balance equation-error fit itself (k, c, the terms' coefficients and a measured force's 1/M2:
    the loop's own estimator of that structure; NIFO's where that body is not physical); on a rational part
    :func:`~nifo_core.predict.model_fit.fit_model` (feedback paths). Each term set is fitted once.
    """

    def __init__(self, held: HeldOut, data: AnalysisSettings, settings: LoopSettings, ev: _Evaluator) -> None:
        self.held, self.data, self.settings, self.ev = held, data, settings, ev
        self.off = settings.prediction == "none"
        self._cache: dict = {}
        # fit_model's fits on the chosen linear part, by the terms' labels: the same whatever form is in use, so kept
        # across a switch to the body and shared with the body twin (where its equation-error fit is not physical)
        self._models: dict = {}
        self.choice = None
        self._form: str | None = None      # the form in use when it changed after the linear choice
        self.switched = ""
        if not self.off:
            try:
                self.choice = choose_linear_form(held, data)
            except NifoError as err:   # NIFO cannot run on these fit parts: the equation error's own body, if any
                lin = self._equation([])
                if lin is None:
                    raise
                self.choice = LinearChoice("body", lin, {"nifo": {"error": err.message}},
                                           f"one-mass body from the force-balance equation error ({err.message})")
        if self.choice is not None and self.choice.form == "body":
            lin = self._equation([])
            if lin is not None:
                self.choice = replace(self.choice, linear=lin)

    @property
    def linear(self) -> Fitted | None:
        return None if self.choice is None else self.choice.linear

    def body_twin(self) -> "_Predictor":
        """The same predictor on the one-mass body (its own cache, the rational part's fits shared): to judge a term
        on the body while the rational form is in use."""
        twin = copy.copy(self)
        twin._form, twin._cache = "body", {}
        return twin

    def forget(self) -> None:
        """The fits kept dropped (kept by the terms' labels: a term's column changed with its frame)."""
        self._cache = {}
        self._models.clear()

    def switch_to_body(self, why: str) -> None:
        self._form, self._cache, self.switched = "body", {}, why

    @property
    def flexible(self) -> bool:
        """A rational linear part: a multi-mode structure, the terms' forces through their own paths."""
        return self.choice is not None and self.form == "rational"

    @property
    def form(self) -> str:
        return self._form or self.choice.form

    def _body_instead(self, terms: Sequence[Term]) -> tuple[Fitted, Fitted] | None:
        """(body, rational) fits of ``terms`` when the one-mass body would be taken back with them (the rule of
        :meth:`reconsider`), else None."""
        if self.off or not self.flexible or not terms:
            return None
        body, flex = self._equation(terms), self.fit(terms)
        if body is None or body.score is None or flex.score is None or flex.score <= RATIONAL_MARGIN * body.score:
            return None
        return body, flex

    def onward_score(self, terms: Sequence[Term]) -> tuple[float, str]:
        """The held-out prediction NMSE [%] of ``terms`` in the form the loop goes on with once they are in, and that
        form's name: the one-mass body's when :meth:`reconsider` would take it back with them, else this form's.

        Candidates of a round on the rational part are compared on it: the one the loop keeps is then predicted
        in that form. Measured (fleet case 64, a hidden friction 27.9 N, ż/√(ż² + v_s²), beside a declared cubic,
        the rational part chosen on the linear model): on the rational part a damper knee at 3.3 mm/s predicted
        the held-out parts at 0.98 % against 2.23 % for the friction and was added; on the one-mass body, taken
        back with either, the knee predicts them at 0.050 % and the friction at 0.013 %."""
        back = self._body_instead(terms)
        return (back[0].score, "one-mass body") if back is not None else (self.fit(terms).score, "rational part")

    def reconsider(self, terms: Sequence[Term]) -> bool:
        """Once terms are in, the one-mass body again (True when the form changes): a linear model of a strongly
        nonlinear quarter car predicts poorly in either form, and the black box's extra poles stand in for what the
        terms now model — the choice made on the linear model alone is biased towards it. The body is taken when
        its equation-error fit with the terms is physical and the rational model does not predict the held-out
        parts clearly better (:data:`~nifo_core.predict.model_fit.RATIONAL_MARGIN`), as for the linear choice."""
        back = self._body_instead(terms)
        if back is None:
            return False
        body, flex = back
        self._form, self._cache = "body", {}
        self.switched = (f"one-mass body from round {len(terms)} on: with {', '.join(t.label for t in terms)} its "
                         f"equation-error fit is physical and predicts the held-out parts at {body.score:.4g} % "
                         f"against {flex.score:.4g} % for the rational model (the rational form was chosen on the "
                         f"linear model alone)")
        return True

    def _equation(self, terms: Sequence[Term]) -> Fitted | None:
        model = self.ev.equation_model(terms, self.data.spectral, self.data.analysis_band_hz)
        if model is None:
            return None
        return Fitted(model, "constant" if terms else "linear", self.held.score(model),
                      "one-mass body and constant coefficients: the force-balance equation-error fit")

    def fit(self, terms: Sequence[Term]) -> Fitted:
        key = tuple(t.label for t in terms)
        if key not in self._cache:
            got = self._equation(terms) if self.form == "body" else None
            if got is None and key not in self._models:
                self._models[key] = fit_model(self.held, terms, self.data, linear=self.linear,
                                              structure=self.settings.structure)
            self._cache[key] = got or self._models[key]
        return self._cache[key]


def _errors(ev: _Evaluator, pred: _Predictor, terms: Sequence[Term]) -> Errors:
    """Both residuals of ``terms``: the equation error (:class:`_Evaluator`) and the held-out prediction of the
    model class ``nifo identify`` writes (:class:`_Predictor`), each labelled."""
    eq = ev.equation(terms)
    notes: list[str] = []
    pred_nmse, per, trans, bands, unavailable, fitted = None, (), (), None, None, None
    whole = (None, (), "")
    if pred.off:
        unavailable = "prediction switched off (prediction='none')"
    else:
        try:
            fitted = pred.fit(terms)
        except (NifoError, np.linalg.LinAlgError) as err:
            unavailable = str(err)
        else:
            if fitted.scores.unavailable is not None:
                unavailable = fitted.scores.unavailable
            else:
                pred_nmse, per = fitted.score, fitted.scores.per_record
                whole = (fitted.scores.whole_mean, fitted.scores.whole, fitted.scores.whole_policy)
                bands, trans = ev.band_numbers(fitted.scores.predictions)
        if unavailable is not None:
            notes.append(f"no held-out prediction for this model ({unavailable}); equation error only")
    return Errors(terms=tuple(terms), theta_per_kg=eq["theta_per_kg"], k_per_kg=eq["k_per_kg"],
                  c_per_kg=eq["c_per_kg"], equation_nmse_pct=eq["equation_nmse_pct"],
                  equation_nmse_fit_pct=eq["equation_nmse_fit_pct"], prediction_nmse_pct=pred_nmse,
                  prediction_nmse_per_record_pct=tuple(per),
                  band_residual_db=bands if bands else eq["equation_band_residual_db"],
                  residual_of="prediction" if bands else "equation",
                  equation_band_residual_db=eq["equation_band_residual_db"],
                  transmissibility_error_pct=tuple(trans), prediction_unavailable=unavailable, notes=tuple(notes),
                  structure="" if fitted is None else fitted.structure,
                  model_note="" if fitted is None else fitted.note, fitted=fitted, whole_nmse_pct=whole[0],
                  whole_nmse_per_record_pct=tuple(whole[1]), whole_policy=whole[2])
