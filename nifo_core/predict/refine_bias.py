"""The output-error refinement's bias from noise on the spindle sensor, removed by simulating the fit (docs/method.md §9).

The refinement (:mod:`nifo_core.predict.refine`) simulates the body from the *measured* spindle acceleration.
Noise on that sensor is then part of the drive: it reaches the simulated x1 and z = x2 - x1, and the
θ that best predicts the body from a noisy drive is not the true one (errors in variables; measured,
2 % noise on both sensors: a cubic stiffness 2e8 N/m³ refined to 1.53e8-1.76e8, −12 to −24 %, the
prediction of another level missing the truth by 29-134× the variance its bounds state). Noise on the
body sensor alone is output noise and leaves the fit consistent.

The remedy is the loop's (:mod:`nifo_core.signal.bias_correction`): synthetic records whose truth is the
refined model — the measured spindle signal drives it, the estimated noise of each sensor
(:mod:`nifo_core.signal.noise`) is added to both channels, an antithetic pair — refitted by the same output
error from that truth; the bias (mean refit − truth) subtracted, twice. Each refit starts at the synthetic
truth and moves by the bias alone, so the Jacobian there (forward differences, as the refinement's) serves
all its steps: a simplified Gauss-Newton (chord) iteration, one simulation per step instead of 1 + len(θ);
its first step is the full one's, and it converges to the same point to first order in the bias; it stops once a
step hardly moves θ or the cost (:data:`REFIT_XTOL`, :data:`REFIT_FTOL`). On noise-free records of its own
model the output-error fit returns the model exactly, so the whole bias counts as the noise's
(``noise_only``): its uncertainty is 30 % of it (the noise level's error) plus the draws' scatter,
added to the refinement's covariance (inflated by the iteration's contraction). A correction that does
not contract, or moves a coefficient by more than half, is refused and the refinement kept as it was,
with a note that says why. One whose second step turns back past the first is taken at the secant through
its two iterates, where the fixed point lies (``bracket``; :func:`bracketed` says so, and the loop keeps it
only where it predicts the held-out data at least as well as the uncorrected refinement: measured, the physics
fleet's #198 bump stop −12.7 % → −7.2 % of the truth).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np
import scipy.optimize

from ..signal.bias_correction import MAX_RELATIVE_BIAS, Correction, simulated_correction
from ..errors import NifoError
from .model import predict_records, record_inputs
from ..signal.noise import NoiseEstimate
from .prediction_bounds import Z95
from ..signal.parallel import forward_jacobian
from ..signal.record import Record
from .refine import Refinement, march_jacobians, prediction_residuals, record_residuals
from .refine_space import moved_refinement, parameter_space

__all__ = ["REFIT_EVALUATIONS", "bracketed", "correct_refinement", "noted"]

#: function evaluations of each synthetic refit (started from the synthetic truth: a few Gauss-Newton steps)
REFIT_EVALUATIONS = 8
#: each synthetic refit stops when a step lowers its cost by less than this fraction of it (least squares' ``ftol``)
#: or moves θ by less than this fraction of its norm (``xtol``); scipy's defaults, 1e-8, ran every refit to
#: :data:`REFIT_EVALUATIONS`. Measured (issue 58): the chord steps shrink by 0.2-0.5 each, and past these tolerances
#: they move no coordinate of θ (relative coefficients, log factors) by more than 7e-4, against biases of 0.02-0.2 on
#: the loop benchmark's refits: ``benchmarks/bench_refine_bias.py`` 518 → 243 evaluations, every printed figure of
#: its 20 seeds the same but one half-width's third digit; the loop benchmark's 32 → 20
REFIT_FTOL = 1e-4
REFIT_XTOL = 1e-3
#: relative step of the refit's forward-difference Jacobian, as in the refinement
DIFF_STEP = 1e-3
#: relative error a diverged synthetic simulation counts as (per record), as in the refinement
_DIVERGED = 10.0


def correct_refinement(refinement: Refinement, records: Sequence[Record], noise: Sequence[NoiseEstimate], *,
                       oversample: int | None = None, seed: int = 0,
                       max_evaluations: int = REFIT_EVALUATIONS) -> Refinement:
    """``refinement`` (of ``records``) with its bias from the sensors' noise removed (module docstring).

    Parameters
    ----------
    refinement : Refinement
        From :func:`~nifo_core.predict.refine.refine_model` on ``records`` (it must carry its covariance).
    records : sequence of Record
        The records it was refined on, the same slices in the same order.
    noise : sequence of NoiseEstimate
        Each record's sensor noise (:func:`nifo_core.signal.noise.estimate_noise`).
    oversample, seed, max_evaluations
        The predictor's fine steps per sample; the noise draws' seed; evaluations per synthetic refit.

    Returns
    -------
    Refinement
        The corrected one (its model's ``provenance['refined']['bias_correction']`` says by how much),
        or ``refinement`` with a message saying why it is not corrected.
    """
    if len(noise) != len(records):
        raise ValueError(f"{len(noise)} noise estimates for {len(records)} records")
    space = parameter_space(refinement.model)
    why = None
    if space is None:
        why = "the refinement carries no covariance"
    elif not any(e.available for e in noise):
        why = "no noise estimate: " + "; ".join(e.text() for e in noise)
    if why is not None:
        return noted(refinement, f"not bias-corrected ({why})")
    to_model, x_star, cov = space.to_model, space.theta, space.cov
    info = refinement.model.provenance["refined"]
    band, period = tuple(info["band_hz"]), info.get("period_samples")
    skips = [int(v) for v in info["skip_samples"]]
    truth = {"x": x_star}

    def simulate_records(theta: np.ndarray, recs: Sequence[Record]) -> list[np.ndarray | None]:
        """Each record's body acceleration at θ, None where it cannot be simulated (predict_records)."""
        truth["x"] = np.asarray(theta, float)
        model = to_model(truth["x"])
        try:
            drives = [record_inputs(rec, model) for rec in recs]
            got = predict_records(model, [a1 for a1, _ in drives], [rec.fs_hz for rec in recs],
                                  forces=[f for _, f in drives], oversample=oversample)
        except (NifoError, FloatingPointError, np.linalg.LinAlgError):
            return [None] * len(recs)     # any None refuses the correction, whichever record it is
        return [None if isinstance(p, NifoError) else p.body_accel for p in got]

    def simulate(theta: np.ndarray, rec: Record) -> np.ndarray | None:
        return simulate_records(theta, [rec])[0]

    def fit(recs: Sequence[Record]) -> np.ndarray:
        def residuals(xs: list[np.ndarray]) -> list[np.ndarray]:   # pure: the refits run side by side
            """The residual vector at each θ of ``xs``; several θs (the Jacobian's columns) marched together."""
            models = [to_model(x) for x in xs]
            per_record = [prediction_residuals(models, rec, band_hz=band, period_samples=period, skip_samples=skip,
                                               oversample=oversample) for rec, skip in zip(recs, skips)]
            return [_vector([got[lane] for got in per_record]) for lane in range(len(xs))]

        def residual(x: np.ndarray) -> np.ndarray:     # the records of one length marched together
            return _vector(record_residuals(to_model(x), recs, band_hz=band, period_samples=period,
                                            skip_samples=skips, oversample=oversample))
        # the refit starts at the synthetic truth and moves by the bias alone (a fraction of a half-width): the
        # Jacobian there serves every step (simplified Gauss-Newton), one simulation per step instead of 1 + len(θ)
        x0 = np.asarray(truth["x"], float)
        f0 = residual(x0)
        m0 = to_model(x0)
        pars = space.march(m0)
        # from one march of each record (forward sensitivities); forward differences where the march cannot give
        # it, or a record diverges (its penalty is _vector's)
        parts = None if pars is None else march_jacobians(m0, pars, recs, band_hz=band, period_samples=period,
                                                          skips=skips, oversample=oversample)
        if parts is None or any(p is None for p in parts):
            jac0 = _forward_jacobian(residual, x0, f0, together=residuals)
        else:
            jc = np.concatenate(parts)
            jac0 = np.vstack([jc.real, jc.imag])
        key = x0.tobytes()

        def fun(x: np.ndarray) -> np.ndarray:      # θ0: least_squares' first evaluation is the Jacobian's base
            return f0.copy() if np.asarray(x, float).tobytes() == key else residual(x)
        sol = scipy.optimize.least_squares(fun, x0, jac=lambda x: jac0, method="trf", max_nfev=max_evaluations,
                                            ftol=REFIT_FTOL, xtol=REFIT_XTOL)
        return sol.x

    # a parameter the data do not determine (95 % half-width beyond half its value, or a log factor beyond ±0.5)
    # is held: its refits wander along the cost's flat valley and would swamp the correction of the others
    hold = Z95 * np.sqrt(np.maximum(np.diag(cov), 0.0)) > MAX_RELATIVE_BIAS
    if np.all(hold):
        return noted(refinement, "not bias-corrected (no parameter is determined to within half its value): the "
                                 "refined values may be biased by the spindle sensor's noise")
    cor = simulated_correction(fit, simulate, records, noise, x_star, seed=seed, scale=np.ones_like(x_star),
                               noise_only=True, hold=hold, side_by_side=True, bracket=True,
                               simulate_records=simulate_records)
    if cor is None:
        return noted(refinement, "not bias-corrected (the correction does not converge or would move a parameter "
                                 "by more than half): the refined values may be biased by the spindle sensor's noise")
    return _moved(refinement, cor, cov, noise, hold)


def _vector(parts: list) -> np.ndarray:
    """The refit's residual vector (real, imaginary) from each record's residual; a diverged one (None) counts as
    relative error _DIVERGED, spread over as many lines as the record before it."""
    out = []
    for p in parts:
        if p is None:
            n = out[-1].size if out else 1
            p = np.full(n, np.sqrt(_DIVERGED / n), complex)
        out.append(p)
    r = np.concatenate(out)
    return np.concatenate([r.real, r.imag])


def _forward_jacobian(fun, x0: np.ndarray, f0: np.ndarray, rel_step: float = DIFF_STEP, *,
                      together=None) -> np.ndarray:
    """Forward differences of ``fun`` at ``x0`` (``f0 = fun(x0)``), steps h_j = rel_step·sign(x_j)·max(1, |x_j|),
    the columns side by side on threads, or marched together by ``together`` (``fun`` of a list of points,
    :func:`nifo_core.signal.parallel.forward_jacobian`)."""
    h = rel_step * np.where(x0 >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x0))
    return forward_jacobian(fun, x0, f0, h, together=together)


def _moved(refinement: Refinement, cor: Correction, cov: np.ndarray, noise: Sequence[NoiseEstimate],
           hold: np.ndarray) -> Refinement:
    """The refinement at the corrected θ', its covariance the random part × gain² plus the correction's."""
    cov_c = cor.gain ** 2 * cov + np.diag(cor.extra_sd() ** 2)
    names = [p["name"] for p in refinement.parameters]
    # θ' coordinates: coefficients relative to the refined ones, key parameters and k, c as log factors
    moved_pct = [100 * (np.exp(d) - 1) if i >= sum(n.startswith("c/M2") for n in names) else 100 * d
                 for i, d in enumerate(cor.theta - cor.theta_fit)][:len(names)]
    note = {"method": "simulated (refit on synthetic records of the refined model with the estimated sensor noise, "
                      "antithetic pair; nifo_core.predict.refine_bias)",
            "moved_pct": {n: float(v) for n, v, h in zip(names, moved_pct, hold) if not h},
            "not_corrected": [n for n, h in zip(names, hold) if h], "gain": float(cor.gain),
            **({"bracketed": True} if cor.bracketed else {}),
            "noise": [e.to_dict() for e in noise]}
    model, params = moved_refinement(refinement.model, cor.theta, cov_c, note)
    what = ", ".join(f"{n} {v:+.1f} %" for n, v in note["moved_pct"].items())
    held = (f"; not corrected, the data do not determine them (may be biased by the spindle sensor's noise): "
            f"{', '.join(note['not_corrected'])}" if note["not_corrected"] else "")
    how = (" (its second step turned back past the first: the fixed point bracketed, the secant through the two "
           "taken)") if cor.bracketed else ""
    return noted(replace(refinement, model=model, parameters=params),
                 f"bias from the sensors' noise removed by simulating the refinement{how} ({what}){held}")


def bracketed(refinement: Refinement) -> bool:
    """Whether ``refinement``'s bias correction was taken from a step that turned back (``bracket``): the caller
    judges it against the uncorrected refinement on held-out data."""
    note = refinement.model.provenance.get("refined", {}).get("bias_correction") or {}
    return bool(note.get("bracketed")) if isinstance(note, dict) else False


def noted(refinement: Refinement, note: str) -> Refinement:
    return replace(refinement, message=f"{refinement.message}; {note}", bias_note=note)
