"""Removing the bias of a fit by simulating it: what the fit does to data whose truth is known (docs/method.md §9).

The loop's equation-error fit (and characterize's) is biased in two ways that a random-error bound
does not hold: noise on both accelerometers reaches the regressors (z, ż integrated from ẍ2 - ẍ1 and
every g(z, ż) of them: errors in variables, paper §2.2 — a stiffness attenuated, a friction's sign(ż)
blurred), and the processing itself (z, ż integrated in a band lack their motion outside it, and a
sign(ż) or a stop's contact computed from them differs from the true one: measured −3.8 % on Coulomb
100 N with no noise at all). Both are properties of the estimator on *these* records, so they can be
measured on synthetic records that share everything but a known truth (parametric-bootstrap bias
correction, indirect inference; Gouriéroux & Monfort; Carroll et al., *Measurement Error in Nonlinear
Models*, ch. 5 for the measurement-error case):

1. θ₀ = the fit on the data.
2. Synthetic records: the measured spindle acceleration drives the model with θ (the one-mass body
   and the terms, :func:`nifo_core.predict.model.predict_body`); the estimated noise of each sensor
   (:mod:`nifo_core.signal.noise`) is added to both channels, one draw and its negative (antithetic).
3. θ_syn = the same fit on them; the bias b = θ_syn - θ; the corrected θ ← θ₀ - b.
   Repeated :data:`ITERATIONS` times (θ from the previous step: the fixed point is the θ whose
   synthetic fit reproduces θ₀), then the rest of the way to the fixed point extrapolated from the
   last two steps (geometric tail, Aitken: step × q/(1 - q), q their ratio per coefficient). Measured on
   a bump stop (2e5 N/m, 4 mm gap, 2.5 mm road, 2 % noise on both sensors), whose steps shrink only
   by q ≈ 0.4-0.5: θ₀ 1.28e5, two steps 1.78e5, with the tail 1.91e5, five steps and their tail 1.95e5.
   Where the steps do not contract (:data:`MAX_CONTRACTION`) or the first steps' correction exceeds
   half a coefficient (:data:`MAX_RELATIVE_BIAS`: terms that share their shape —
   a friction beside a damper knee — make the bias map ill-conditioned: measured, a knee's
   coefficient moved by -130 %) there is no correction (None): the caller says the fit may be biased.
   Asked (``bracket``: the output-error refinement's correction), a step that turns back past the one
   before (the synthetic refit moves more than its truth) is not refused: the fixed point lies between
   the two iterates, and the secant through them (the same tail, its ratio unclipped) lands there, inside
   the first step's correction; the caller keeps such a correction only where it predicts the held-out
   data at least as well as the uncorrected fit (:mod:`nifo_core.loop.refine`). Measured on the physics fleet's
   #198 (a bump stop 3.96e5 N/m beyond 6.8 mm beside a declared knee, 2.2 % spindle noise), the
   output-error refinement's refits -11.8 % at θ₀ and -1.5 % at the first corrected θ (the second step
   -0.87 × the first): refused before, the stop stayed at 3.46e5 (-12.7 %, its bound ± 0.35 %); taken,
   3.68e5 ± 0.48e5 (-7.2 %) and the held-out prediction 4.37 % → 1.62 %. On noise-free records the same
   refinement gives 3.84e5: what is left is the noise.

Why a bump stop's corrected coefficient stayed 4-5 % low (measured on the stop above, seeds 500-519; the
loop now runs five steps with four antithetic pairs, :mod:`nifo_core.loop.residual`):

- not converged: two steps and the tail stopped 1-2 % short of the fixed point (q rises from 0.41-0.46
  to 0.49-0.55 in later steps); after five steps the tail is within 0.2 %.
- the fixed point itself, -2.5 % on average (seeds 500-509), is not the simulated noise model's shape
  nor the static position (at the true θ a synthetic fit with the data's own noise realisation on the
  model's response reproduces θ₀ to 0.001, and a noise-free synthetic fit the data's noise-free fit): it is
  (a) the estimated noise level — the floor of ẍ2 - ẍ1 read 0.76-1.03 × the truth, 0.89 on average (the
  lowest octave's mean over 11 lines and 3 averages, taken as the minimum of the octaves) — and (b) the
  drive: the synthetic records are driven by the measured spindle signal, its noise inside, which moves a
  stop's contacts: the synthetic fit at the true θ moves by -0.014 to +0.048 of the coefficient between the
  clean and the measured drive, +0.010 on average over 12 seeds, while one more dose of drive noise moves it
  by -0.004 on average: a scatter per record more than a bias to extrapolate away (:func:`_drive_sd`).
- the bound was too narrow for the correction's own uncertainty: an error in the estimated bias moves the
  fixed point by 1/(1 - r) of it (r ≈ 0.5 here) and was counted once; the synthetic fits scatter over
  noise draws by 0.5-2.9 × (1.6 × in the median) the residual's random error of θ₀ (errors in variables
  scatter too); and standard deviations read from one or a few pairs of draws had the normal quantile.

Uncertainty (:meth:`Correction.half_width`, :meth:`Correction.extra_sd`): the draws' scatter (the
correction's Monte-Carlo error), the drive noise's effect (:attr:`Correction.drive_sd`, when measured)
and the noise level's own error (:data:`NOISE_LEVEL_RTOL`, measured: estimates 0.7-1.3 × the truth on
simulated records) times the part of the bias the noise makes (b minus the bias of a noise-free
synthetic fit), all times 1/(1 - r) with r the iteration's contraction (the bias's sensitivity to θ),
and :data:`TAIL_RTOL` of the extrapolated tail. The random error of θ₀ carries over, times 1/(1 - r),
from the residual or, where larger, from the synthetic fits' scatter over the draws
(:attr:`Correction.fit_sd`); the quantile is Student's t with Welch-Satterthwaite's degrees of freedom.
What it cannot remove is bias from a model outside the family (an effect the model lacks).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
from scipy import stats

from .noise import NoiseEstimate, noise_draw
from .parallel import batch_map, thread_map
from .record import Record

__all__ = ["ITERATIONS", "NOISE_LEVEL_RTOL", "Correction", "LinearFit", "simulated_correction"]

#: bias-correction iterations (1: θ₀ - b(θ₀); 2: once more from the corrected θ)
ITERATIONS = 2
#: a correction whose last step exceeds MAX_CONTRACTION × the one before (plus CONVERGED_RTOL·|θ₀|) in the same
#: direction is refused (turned back, it brackets the fixed point: module docstring);
#: measured: 0.05 on a friction or a cubic alone, 0.43 on a bump stop (its contact depends on the amplitude)
MAX_CONTRACTION = 0.6
#: a correction larger than this fraction of a coefficient is refused: the fit cannot tell the term apart
#: (measured: a friction beside a damper knee, the knee's coefficient moved by -130 %, the friction's +53 %)
MAX_RELATIVE_BIAS = 0.5
CONVERGED_RTOL = 0.01
#: relative error of an estimated noise variance (measured on simulated records: 0.7-1.3 × the truth)
NOISE_LEVEL_RTOL = 0.3
#: pairs of drive-noise draws behind :attr:`Correction.drive_sd` (one pair's half difference is a one-draw estimate
#: of a standard deviation: on a bump stop it read 0.003 of the coefficient where ten draws scatter by 0.03)
DRIVE_PAIRS = 4
#: the last steps run on every pair of draws; the ones before on the first pair alone. An early step's Monte-Carlo
#: error reaches the result only through the later steps, shrunk by their contraction (≈ 0.5 per step on a bump
#: stop); the last two set the result, the tail's ratio and the scatter the bound holds. Measured on the loop's
#: five steps with four pairs: 18 of the 53 equation-error fits saved
FULL_STEPS = 2
#: relative error of the extrapolated tail (measured on a bump stop: it fell 20-30 % short of the tail that
#: three more iterations give)
TAIL_RTOL = 0.5


@dataclass(frozen=True)
class Correction:
    """Coefficients with the fit's bias removed, and what the correction adds to their uncertainty.

    Attributes
    ----------
    theta : ndarray
        Corrected coefficients.
    theta_fit : ndarray
        The plain fit θ₀ on the data.
    noise_bias : ndarray
        The part of the bias the sensor noise makes (the rest is the processing's).
    draw_sd : ndarray
        Standard deviation of the correction from its noise draws.
    gain : float
        Factor on θ₀'s random error carried into θ: 1/(1 - r), r the iteration's contraction.
    tail : ndarray or None
        The extrapolated rest of the way to the fixed point (included in ``theta``).
    drive_sd : ndarray or None
        Standard deviation of the synthetic fit from the noise in the drive (the measured spindle signal
        drives the synthetic records, its noise with it), when measured (``drive_noise``).
    fit_sd : ndarray or None
        Standard deviation of one synthetic fit over the noise draws (``pairs`` > 1): a parametric bootstrap
        of θ₀'s random error, the errors in variables' own scatter included (which a bound from the residual
        alone does not hold: measured on a bump stop, 2 % noise, seeds 500-519, 0.5-2.9 × the residual's,
        1.6 × in the median).
    pairs : int
        Antithetic pairs of noise draws per step.
    """

    theta: np.ndarray
    theta_fit: np.ndarray
    noise_bias: np.ndarray
    draw_sd: np.ndarray
    gain: float = 1.0
    tail: np.ndarray | None = None
    drive_sd: np.ndarray | None = None
    fit_sd: np.ndarray | None = None
    pairs: int = 1
    #: a coordinate's last step turned back past MAX_CONTRACTION × the one before and the secant was taken
    #: (``bracket``): the bias map is far from linear over the step
    bracketed: bool = False

    @property
    def bias(self) -> np.ndarray:
        """θ₀ - θ: the plain fit's estimated bias."""
        return self.theta_fit - self.theta

    def _extra_parts(self) -> list[tuple[np.ndarray, float]]:
        """The standard deviations the correction adds beyond θ₀'s random error, each with the degrees of freedom
        it was read with (inf: taken as known)."""
        zero = np.zeros_like(self.draw_sd)
        # an error δb in the estimated bias moves the fixed point θ + b(θ) = θ₀ by δb/(1 - r): the gain, as θ₀'s own
        # random error (measured on a bump stop, r ≈ 0.5, five steps: without it 7 of 10 seeds' bounds held the truth)
        return [(self.gain * self.draw_sd, float(self.pairs - 1) if self.pairs > 1 else np.inf),
                (self.gain * (zero if self.drive_sd is None else self.drive_sd), float(DRIVE_PAIRS)),
                (self.gain * NOISE_LEVEL_RTOL * self.noise_bias, np.inf),
                (TAIL_RTOL * (zero if self.tail is None else self.tail), np.inf)]

    def extra_sd(self) -> np.ndarray:
        """Standard deviation the correction adds beyond θ₀'s random error."""
        return np.sqrt(sum(np.square(sd) for sd, _ in self._extra_parts()))

    def half_width(self, random_half_width: np.ndarray, random_dof: float, *, level: float = 0.95) -> np.ndarray:
        """Half-width of the bound on :attr:`theta` at ``level``.

        θ₀'s random error (``random_half_width`` at ``level`` with ``random_dof`` degrees of freedom, or
        :attr:`fit_sd` where larger) times :attr:`gain`, and the parts of :meth:`extra_sd`, added in
        variance; the quantile is Student's t with the Welch-Satterthwaite degrees of freedom, since
        :attr:`fit_sd`, :attr:`draw_sd` and :attr:`drive_sd` are read from a few pairs of draws
        (with a single pair :attr:`draw_sd` counts as known: one half difference overstates the
        antithetic mean's error).
        """
        two = 0.5 + level / 2
        dof_r = max(float(random_dof), 1.0)
        rand = np.asarray(random_half_width, float) / stats.t.ppf(two, dof_r)
        rand_dof = np.full(rand.shape, dof_r)
        if self.fit_sd is not None:
            rand_dof = np.where(self.fit_sd > rand, float(self.pairs), rand_dof)
            rand = np.maximum(rand, self.fit_sd)
        parts = [(self.gain * rand, rand_dof), *self._extra_parts()]
        var = sum(np.square(sd) for sd, _ in parts)
        den = sum(np.square(np.square(sd)) / dof for sd, dof in parts)
        with np.errstate(divide="ignore", invalid="ignore"):
            dof = np.where(den > 0, np.square(var) / den, np.inf)
        quantile = np.where(np.isfinite(dof), stats.t.ppf(two, np.maximum(dof, 1.0)), stats.norm.ppf(two))
        return quantile * np.sqrt(var)


@dataclass(frozen=True)
class LinearFit:
    """A fit whose data are made from the records by a map linear in their channels (band-limited integration,
    band-passes: the loop's equation-error fit), then solved: ``solve(prepare(records))``.

    The synthetic records are a simulated body plus ± a noise draw, so their prepared data are the clean records'
    plus ± the draw's own (a record of the noise alone, the force channel zero): :func:`simulated_correction`
    prepares each step's clean records once and each draw once, instead of every noisy record of every step (the
    same to rounding). Measured on the loop benchmark's correction (four 300 s records, five steps, four pairs,
    the drive's four pairs), the whole `nifo loop` run: 35 → 20 preparations, 18.1 → 9.6 s of their time on
    threads (measured beside other work)."""

    prepare: Callable[[Sequence[Record]], object]
    combine: Callable[[object, object, float], object]   # (a, b, sign) → a + sign·b
    solve: Callable[[object], np.ndarray]

    def __call__(self, records: Sequence[Record]) -> np.ndarray:
        return self.solve(self.prepare(records))


def _noise_alone(rec: Record, est: NoiseEstimate, draw: np.ndarray) -> Record:
    """A record of ``draw`` × the estimated noise alone (zero where there is no estimate, a measured force zero):
    what :func:`_noisy` adds to a clean record."""
    n = rec.n
    if est.available:
        s1, s2 = est.stds
        a1, a2 = s1 * draw[0, :n], s2 * draw[1, :n]
    else:
        a1 = a2 = np.zeros(n)
    return replace(rec, spindle_accel=a1, body_accel=a2, force=None if rec.force is None else np.zeros(n))


class _Fits:
    """The synthetic fits of :func:`simulated_correction`: each noisy record set fitted whole, or (``fit`` a
    :class:`LinearFit`) from the clean set's prepared data plus ± the draw's, each draw prepared once."""

    def __init__(self, fit, records: Sequence[Record], noise: Sequence[NoiseEstimate], draws) -> None:
        self.fit, self.records, self.noise, self.draws = fit, list(records), list(noise), draws
        self.linear = isinstance(fit, LinearFit)
        self._drawn: dict[int, object] = {}

    def ready(self, pairs: Sequence[int], each) -> None:
        """The draws ``pairs`` prepared (side by side where ``each`` runs so), before fits on threads read them."""
        todo = [k for k in dict.fromkeys(pairs) if k not in self._drawn] if self.linear else []
        for k, got in zip(todo, each(lambda k: self.fit.prepare([_noise_alone(r, e, d) for r, e, d in
                                                                  zip(self.records, self.noise, self.draws[k])]),
                                     todo)):
            self._drawn[k] = got

    def clean(self, drives: Sequence[Record], bodies: Sequence[np.ndarray]):
        """What the fits of one step share: the clean synthetic records, prepared when the fit is linear."""
        recs = [_noisy(r, b, e, None) for r, b, e in zip(drives, bodies, self.noise)]
        return self.fit.prepare(recs) if self.linear else recs

    def fitted(self, clean, job: tuple[int, float] | None) -> np.ndarray:
        """The fit of the clean records plus ``job`` = (draw, sign) × the noise (None: none)."""
        if self.linear:
            data = clean if job is None else self.fit.combine(clean, self._drawn[job[0]], job[1])
            return np.asarray(self.fit.solve(data), float)
        if job is None:
            return np.asarray(self.fit(clean), float)
        k, sign = job
        return np.asarray(self.fit([_noisy(r, r.body_accel, e, sign * d)
                                    for r, e, d in zip(clean, self.noise, self.draws[k])]), float)


def _noisy(rec: Record, body: np.ndarray, est: NoiseEstimate, draw: np.ndarray | None) -> Record:
    """A synthetic record: the measured spindle signal and ``body``, plus ``draw`` × the estimated noise."""
    a1, a2 = np.asarray(rec.spindle_accel, float), np.asarray(body, float)
    if draw is not None and est.available:
        s1, s2 = est.stds
        a1, a2 = a1 + s1 * draw[0, :rec.n], a2 + s2 * draw[1, :rec.n]
    return replace(rec, spindle_accel=a1, body_accel=a2)


def simulated_correction(fit: Callable[[Sequence[Record]], np.ndarray],
                         simulate: Callable[[np.ndarray, Record], np.ndarray | None],
                         records: Sequence[Record], noise: Sequence[NoiseEstimate], theta0: np.ndarray, *,
                         seed: int = 0, iterations: int = ITERATIONS, scale: np.ndarray | None = None,
                         noise_only: bool = False, hold: np.ndarray | None = None,
                         side_by_side: bool = False, drive_noise: bool = False,
                         pairs: int = 1, reads: Sequence[int] | None = None,
                         bracket: bool = False,
                         simulate_records: Callable[[np.ndarray, Sequence[Record]], list] | None = None
                         ) -> Correction | None:
    """``theta0`` (the fit ``fit`` on ``records``) with the fit's bias removed (module docstring).

    ``simulate(θ, record)`` is the body acceleration the model with θ gives for the record's spindle
    signal (None: it cannot: no correction). ``noise`` holds one estimate per record.
    ``scale``: the size each coordinate of θ is judged against (refusal, convergence; default |θ₀|:
    give it where a coordinate is a log factor that is 0 at θ₀). ``noise_only``: the fit is consistent
    on noise-free records of its own model (an output-error fit: no noise-free synthetic fit is run,
    the whole bias counts as the noise's). ``hold``: coordinates kept at θ₀, neither corrected nor judged
    (those the data do not determine: their synthetic refits scatter along a flat valley of the cost).
    ``side_by_side``: ``fit`` and ``simulate`` are safe on several threads at once; the records'
    simulations and the antithetic pair's two refits then run on threads (:mod:`nifo_core.signal.parallel`),
    the result the same to the last digit. ``drive_noise``: measure :attr:`Correction.drive_sd` (2·:data:`DRIVE_PAIRS`
    more simulations and fits, at the last θ, the drive given ± one more draw of the spindle's estimated noise).
    ``pairs``: antithetic pairs of noise draws per step of the last :data:`FULL_STEPS` (more: a smaller Monte-Carlo
    error, and :attr:`Correction.fit_sd` measured); the steps before them run on the first pair.
    ``reads``: the first ``reads[i]`` samples of record i are all that ``fit`` reads of it, and all its simulation
    needs to give them (the simulation's look-ahead included): every synthetic record is cut there, so the
    simulations and the fits do only that work. The noise draws are still taken for the whole records, so the same
    seed gives the same draws; the result is the same to rounding (the filters' FFT lengths differ).
    ``bracket``: a last step that turned back past :data:`MAX_CONTRACTION` × the one before is not refused: the
    fixed point lies between the two iterates and the secant through them is taken (:attr:`Correction.bracketed`;
    module docstring). ``simulate_records(θ, records)``: ``[simulate(θ, r) for r in records]``, the same values, cheaper
    together (:func:`~nifo_core.predict.model.predict_records`: records of one length marched side by side); each
    step's records and the drive noise's versions of each record are then simulated so."""
    each = thread_map if side_by_side else (lambda fn, items: [fn(x) for x in items])

    def bodies_of(theta: np.ndarray, recs: Sequence[Record]) -> list:
        """Each record's simulation at ``theta``: side by side on threads, in batches where given together."""
        if simulate_records is None:
            return each(lambda r: simulate(theta, r), recs)
        return batch_map(lambda b: simulate_records(theta, b), recs) if side_by_side else simulate_records(theta, recs)

    rng = np.random.default_rng(seed)
    whole = [r.n for r in records]
    draws = [[noise_draw(n, rng) for n in whole] for _ in range(max(int(pairs), 1))]
    if reads is not None:
        records = [r.slice(0, max(1, min(r.n, int(k)))) for r, k in zip(records, reads, strict=True)]
    jobs = [(k, sign) for k in range(len(draws)) for sign in (1.0, -1.0)]
    t0 = np.asarray(theta0, float)
    size = np.abs(t0) if scale is None else np.broadcast_to(np.abs(np.asarray(scale, float)), t0.shape)
    free = np.ones(t0.shape, bool) if hold is None else ~np.asarray(hold, bool)
    theta = t0.copy()
    noise_bias, draw_sd, fit_sd = np.zeros_like(t0), np.zeros_like(t0), None
    steps = []
    n_steps = max(int(iterations), 1)
    fits = _Fits(fit, records, noise, draws)
    for step in range(n_steps):
        bodies = bodies_of(theta, records)
        if any(b is None or not np.all(np.isfinite(b)) for b in bodies):
            return None
        # steps before the last two on the first pair alone (:data:`FULL_STEPS`)
        now = jobs if step >= n_steps - FULL_STEPS else jobs[:2]
        fits.ready([k for k, _ in now], each)
        clean_records = fits.clean(records, bodies)
        # the noisy fits and the noise-free one side by side, the noise-free one last; it is only needed for the
        # noise's part of the bias at the last step (noise_only: the whole bias)
        clean_too = not noise_only and step == n_steps - 1
        got = each(lambda job: fits.fitted(clean_records, job), [*now, None] if clean_too else now)
        clean = got.pop() if clean_too else theta
        half = np.array([0.5 * (got[i] - got[i + 1]) for i in range(0, len(got), 2)])
        means = np.array([0.5 * (got[i] + got[i + 1]) for i in range(0, len(got), 2)])
        syn = means.mean(axis=0)
        if clean_too or noise_only:
            noise_bias = free * (syn - clean)
        if len(half) == 1:
            draw_sd = free * np.abs(half[0])
        else:   # the pairs' means scatter by the Monte-Carlo error; each half difference is one draw's own effect
            draw_sd = free * means.std(axis=0, ddof=1) / np.sqrt(len(half))
            fit_sd = free * np.sqrt(np.mean(half ** 2, axis=0))
        steps.append(free * (t0 - syn))
        theta = theta + steps[-1]
        if len(steps) == min(int(iterations), ITERATIONS) and np.any(np.abs(theta - t0) > MAX_RELATIVE_BIAS * size):
            return None     # judged on the first steps: a converged correction may exceed it (a bump stop's: +52 %)
    beyond = np.zeros(t0.shape, bool)   # coordinates whose last step turned back by more than MAX_CONTRACTION
    if len(steps) > 1:
        big = np.abs(steps[-1]) > MAX_CONTRACTION * np.abs(steps[-2]) + CONVERGED_RTOL * size
        beyond = big & (steps[-1] * steps[-2] < 0) & bool(bracket)
        if np.any(big & ~beyond):
            return None     # the fixed point contracts slowly: the bias map is ill-conditioned (confounded terms)
    # the drive noise's simulations only for a correction that is kept (they do not change the refusal above)
    drive_sd = _drive_sd(fits, bodies_of, theta, rng, each, free, whole) if drive_noise else None
    if drive_sd is not None and not np.all(np.isfinite(drive_sd)):
        return None
    gain, tail = 1.0, None
    if len(steps) > 1:
        gain, tail = _tail(steps, free, size, beyond)
        theta = theta + tail
    return Correction(theta, t0, noise_bias, draw_sd, gain, tail, drive_sd, fit_sd, len(draws), bool(np.any(beyond)))


def _tail(steps: list[np.ndarray], free: np.ndarray, size: np.ndarray, beyond: np.ndarray) -> tuple[float, np.ndarray]:
    """The iteration's gain 1/(1 - r), r its contraction, and the geometric rest of the way to the fixed point from
    the last two of ``steps`` (module docstring); ``beyond``: the coordinates whose last step turned back past
    :data:`MAX_CONTRACTION` × the one before (their secant)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(np.abs(steps[-2]) > 0, steps[-1] / steps[-2], 0.0)
    # a step that turned back past the last one brackets the fixed point between the two iterates: the secant
    # through them (the same geometric tail, unclipped) lands inside the first step's correction, never beyond
    q_back = q
    q = np.clip(q, -MAX_CONTRACTION, MAX_CONTRACTION)
    # the contraction read where the steps are above the convergence tolerance: the ratio of two steps already
    # within it is noise (measured: k's and c's after five steps on a bump stop, clipped at MAX_CONTRACTION)
    moving = free & (np.abs(steps[-2]) > CONVERGED_RTOL * size)
    rate = float(np.max(np.abs(q[moving]))) if np.any(moving) else float(np.max(np.abs(q)))
    q_tail = np.where(beyond, q_back, q)
    return float(1.0 / (1.0 - rate)), free * steps[-1] * q_tail / (1.0 - q_tail)


def _drive_sd(fits: _Fits, bodies_of, theta, rng, each, free, whole) -> np.ndarray:
    """The synthetic fit's standard deviation from the noise in its drive: the root mean square of the half
    differences of the fits whose drive carries ± one more draw of the spindle's estimated noise
    (:data:`DRIVE_PAIRS` pairs, at ``theta``).

    The synthetic records are driven by the measured spindle signal, its sensor noise inside: their truth
    differs from the data's by that noise. On a stop in partial contact the fit follows the contacts, which
    that noise moves: measured on a bump stop (2e5 N/m, 4 mm gap, 2.5 mm road, 2 % noise, seeds 500-509,
    512, 518, at the true θ) the synthetic fit with the clean drive against the measured one differs by
    -0.014 to +0.048 of the coefficient, +0.010 on average, and one more dose of drive noise moves it by
    -0.015 to +0.005 (-0.004 on average): no consistent bias to extrapolate away (the measured drive's own
    noise cannot be taken out of it), a scatter per record as large as the measurement draws', carried in
    the bound.
    """
    extra = [[noise_draw(n, rng)[0] for n in whole] for _ in range(DRIVE_PAIRS)]   # whole records: the same draws
    fits.ready([0], each)
    jobs = [(k, sign) for k in range(DRIVE_PAIRS) for sign in (1.0, -1.0)]
    # drove[j][i]: record i driven with job j's draw; a record's versions simulated together (one length)
    drove = [[replace(r, spindle_accel=np.asarray(r.spindle_accel, float) + sign * e.stds[0] * x[:r.n])
              if e.available else r for r, e, x in zip(fits.records, fits.noise, extra[k])] for k, sign in jobs]
    by_record = [bodies_of(theta, [d[i] for d in drove]) for i in range(len(fits.records))]

    def one(j: int) -> np.ndarray:
        bodies = [got_i[j] for got_i in by_record]
        if any(b is None or not np.all(np.isfinite(b)) for b in bodies):
            return np.full(theta.shape, np.nan)
        return fits.fitted(fits.clean(drove[j], bodies), (0, 1.0))   # the first pair's first draw, as the steps'

    got = each(one, range(len(jobs)))
    half = [0.5 * (got[2 * k] - got[2 * k + 1]) for k in range(DRIVE_PAIRS)]
    return free * np.sqrt(np.mean(np.square(half), axis=0))
