"""What the data could not reveal: detection limits per kind, and confounded pairs (docs/method.md §5).

"Nothing significant is missing" is only half an answer; the other half is how
big an effect would have had to be to be seen in *these* data (their noise,
levels, length and the terms already in the model), and which effects the
data cannot tell apart at all.

Detection limit
    The loop accepts a candidate column g (band-limited after the map,
    orthogonalised against z, ż and the model's terms: g⊥) only if the F-test
    with N_eff effective samples passes at the Bonferroni level α/n_grid and it
    explains ≥ ``min_err`` of the residual (:mod:`nifo_core.characterize.automatic`). Adding
    θ·g to the truth lowers the residual sum of squares by θ²·Σg⊥² (in
    expectation), so the smallest θ the test could have passed is

        θ_min = sqrt( max(F_crit·RSS/dof, min_err·RSS, min_delta_r2·TSS) / Σg⊥² ),
        F_crit = F⁻¹(1 - α/n_grid; 1, dof),   dof = N_eff - q,

    with RSS the current model's residual and TSS the total sum of squares of -ẍ2 (a candidate must
    explain ``min_delta_r2`` of it: on records with little noise that binds, not the F-test). Reported as
    a coefficient (per kg, or in N, N/m... with M2) and as the peak force θ_min·M2·|g|₉₉.₅ of the effect
    on the measured motion [N or N/kg].

Confounding
    Two terms on different variables (z and ż: a play and a damper knee, say)
    whose orthogonalised columns correlate at |ρ| ≥ ``rho_max`` (0.8: the shared part
    is ≥ 64 % of each, the detection limit of either given the other grows
    ≥ 1/sqrt(1 - ρ²) ≈ 1.7×) explain mostly the same residual: the fit splits it
    between them almost arbitrarily. The motion is scaled (≈ linear
    response) by factors below and above the data's levels until |ρ| falls
    below ``rho_sep``: that level, relative to the lowest record, is where a
    record would separate them (the paper's two-step procedure, §3.3).

Undetermined terms
    Pairwise correlation beyond the linear columns misses the commonest case:
    a term the data hardly tell from the *linear* element and another term
    together. On the bundled sample's 1 and 2.5 mm records the play (0.43 mm)
    is 99.8 % a linear stiffness (play(z) ≈ z - b/2·sign ż once the motion is
    much larger than the play): what is left of it beyond z, ż is a small
    sign(ż) part, partly shared with the damper knee (ρ 0.4, below ``rho_max``),
    and its coefficient comes out ±47 % (95 %). A model term whose 95 % bound
    exceeds ``max_rel_bound`` of its value is reported with the columns that
    take its signature (each named by how much of the term's information beyond
    the others removing it would restore) and the level that would pin it: the
    lowest record's motion scaled by s (≈ linear response) is added as one more
    record of the same length; with I = Σ g⊥²/σ² the term's information beyond
    every other column per unit residual variance (σ per record; at the new
    level σ ∝ z_rms^p, p between 0, a fixed noise floor, and 1, noise and
    misfit in proportion to the level, read off the lowest and highest
    records), the bound falls to hw·sqrt(I_data / (I_data + I_new(s))). The s
    with the smallest bound is found; the term is reported when that record
    would shrink the bound ``level_gain`` (2) times more than one more record
    like the lowest: then the levels, not the length, limit it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..characterize.automatic import Candidate, Thresholds
from ..kinds.describing import Term
from ..characterize.restoring import RestoringForce, bandpass, bandpass_settle_samples
from ..characterize.score import smallest_visible

__all__ = ["DetectionLimit", "Confounding", "Undetermined", "detection_limits", "confounded_pairs",
           "undetermined_terms"]


@dataclass(frozen=True)
class DetectionLimit:
    """The smallest effect of one kind these data would have revealed.

    Attributes
    ----------
    term : Term
        The kind's best candidate (its parameters) on the current residual.
    theta_per_kg : float
        Smallest detectable coefficient c/M2 [unit of c per kg].
    coefficient : float or None
        The same times M2 [N, N/m, N·s/m...] when M2 is known.
    peak_force : float
        Peak (99.5 % quantile) force of that effect on the measured motion [N with M2, else N/kg].
    unit : str
        Unit of ``coefficient``.
    """

    term: Term
    theta_per_kg: float
    coefficient: float | None
    peak_force: float
    unit: str

    def text(self) -> str:
        f = (f"{self.peak_force:.3g} N" if self.coefficient is not None else f"{self.peak_force:.3g} N per kg of M2")
        c = (f"{self.coefficient:.3g} {self.unit}" if self.coefficient is not None
             else f"{self.theta_per_kg:.3g} {self.unit}/kg")
        return f"{self.term.kind} ({self.term.label}) with a peak force below ±{f} (coefficient {c})"

    def to_dict(self) -> dict:
        return {"kind": self.term.kind, "term": self.term.to_dict(), "theta_per_kg": self.theta_per_kg,
                "coefficient": self.coefficient, "coefficient_unit": self.unit, "peak_force": self.peak_force,
                "peak_force_unit": "N" if self.coefficient is not None else "N/kg"}


@dataclass(frozen=True)
class Confounding:
    """Two terms the data cannot tell apart, and the level that would (relative to the lowest record)."""

    a: Term
    b: Term
    rho: float
    separating_scale: float | None
    reference: str
    zdot_rms_at_scale: float | None

    def text(self) -> str:
        where = ("no level between 0.05× and 3× the data's separates them" if self.separating_scale is None else
                 f"add a record at ≈ {self.separating_scale:.2g}× the excitation of {self.reference or 'the lowest record'}"
                 f" (relative-velocity RMS ≈ {self.zdot_rms_at_scale:.2g} m/s)")
        return (f"{self.a.kind} ({self.a.label}) and {self.b.kind} ({self.b.label}) cannot be told apart at these "
                f"levels (correlation {self.rho:+.2f} beyond the linear terms; either hides up to "
                f"{1 / np.sqrt(max(1 - self.rho ** 2, 1e-12)):.1f}× its own detection limit in the other): {where}")

    def to_dict(self) -> dict:
        return {"a": self.a.to_dict(), "b": self.b.to_dict(), "rho": self.rho,
                "separating_scale": self.separating_scale, "reference": self.reference,
                "zdot_rms_at_scale": self.zdot_rms_at_scale, "text": self.text()}


@dataclass(frozen=True)
class Undetermined:
    """A model term the data's levels barely tell apart from other columns, and the level that would pin it.

    Attributes
    ----------
    term : Term
    rel_half_width : float
        Half-width of its coefficient's 95 % bound relative to the coefficient.
    partners : tuple of (str, float)
        Columns that take its signature: name, and the fraction of its information they take
        (1 - I_all / I_without_that_column).
    scale : float
        Excitation, relative to ``reference``, of the record that would pin it best.
    rel_half_width_at_scale : float
        The bound with that record added.
    rel_half_width_repeated : float
        The bound with one more record like ``reference`` instead (more of the same levels).
    reference : str
        The lowest record (by relative-velocity RMS).
    z_rms_at_scale_m, zdot_rms_at_scale_m_s : float
        Relative displacement [m] and velocity [m/s] RMS of the record that would pin it.
    """

    term: Term
    rel_half_width: float
    partners: tuple[tuple[str, float], ...]
    scale: float
    rel_half_width_at_scale: float
    rel_half_width_repeated: float
    reference: str
    z_rms_at_scale_m: float
    zdot_rms_at_scale_m_s: float

    def text(self) -> str:
        who = ", ".join(f"{n} ({100 * f:.3g} % of its signature)" for n, f in self.partners) or "the other columns"
        ref = self.reference or "the lowest record"
        return (f"{self.term.kind} ({self.term.label}) can hardly be told apart from {who} at these levels: its "
                f"coefficient is known only to ±{100 * self.rel_half_width:.0f} % (95 %), and another record like "
                f"{ref} would give ±{100 * self.rel_half_width_repeated:.0f} %; add a record at ≈ "
                f"{1e3 * self.z_rms_at_scale_m:.2g} mm relative-displacement RMS (≈ {self.scale:.2g}× the excitation "
                f"of {ref}, relative-velocity RMS ≈ {self.zdot_rms_at_scale_m_s:.2g} m/s): with it "
                f"±{100 * self.rel_half_width_at_scale:.0f} %")

    def to_dict(self) -> dict:
        return {"term": self.term.to_dict(), "rel_half_width": self.rel_half_width,
                "partners": [{"column": n, "information_share": f} for n, f in self.partners],
                "scale": self.scale, "rel_half_width_at_scale": self.rel_half_width_at_scale,
                "rel_half_width_repeated": self.rel_half_width_repeated, "reference": self.reference,
                "z_rms_at_scale_m": self.z_rms_at_scale_m, "zdot_rms_at_scale_m_s": self.zdot_rms_at_scale_m_s,
                "text": self.text()}


def _info(x: np.ndarray, j: int, others: Sequence[int]) -> float:
    """Σ g⊥² of column j beyond the columns ``others``."""
    g = _orth(x[:, j], x[:, list(others)]) if len(others) else x[:, j]
    return float(g @ g)


def undetermined_terms(rfs: Sequence[RestoringForce], terms: Sequence[Term], rel_half_widths: Sequence[float], *,
                       max_rel_bound: float = 0.25, level_gain: float = 2.0, min_share: float = 0.1
                       ) -> tuple[Undetermined, ...]:
    """Model terms whose coefficient the data's *levels* pin only to worse than ``max_rel_bound`` (module docstring).

    Parameters
    ----------
    rfs : sequence of RestoringForce
        The data the coefficients were fitted on.
    terms : sequence of Term
        The model's terms (besides the linear strut), in the order of ``rel_half_widths``.
    rel_half_widths : sequence of float
        95 % half-width of each term's coefficient relative to it (:mod:`nifo_core.signal.uncertainty`).
    max_rel_bound : float
        Consider a term whose relative half-width exceeds this.
    level_gain : float
        Report it when a record at another level would shrink its bound at least this many times more
        than one more record like the lowest (the levels, not the length, limit it).
    min_share : float
        Name a column as a partner when it takes at least this fraction of the term's information.
    """
    terms = list(terms)
    if not terms:
        return ()
    x = _columns(rfs, terms)
    y = np.concatenate([_settled(rf.force, rf) for rf in rfs])
    e = y - x @ np.linalg.lstsq(x, y, rcond=None)[0]
    # residual variance per record against its motion: σ ∝ z_rms^p, p from the lowest and highest record
    # (p = 0: a fixed noise floor, p = 1: noise and misfit in proportion to the level), clamped to [0, 1]
    edges = np.cumsum([0, *[rf.n - 2 * bandpass_settle_samples(rf.fs_hz, rf.band) for rf in rfs]])
    var = np.array([float(np.mean(e[a:b] ** 2)) for a, b in zip(edges[:-1], edges[1:])])
    zr = np.array([float(np.std(rf.z)) for rf in rfs])
    lo = min(range(len(rfs)), key=lambda r: float(np.std(rfs[r].zdot)))
    hi = int(np.argmax(zr))
    p = (0.5 * float(np.log(var[hi] / var[lo]) / np.log(zr[hi] / zr[lo]))
         if zr[hi] > 1.05 * zr[lo] and var[lo] > 0 and var[hi] > 0 else 1.0)
    p = min(max(p, 0.0), 1.0)
    names = ["the linear stiffness K2·z", "the linear damping C2·ż", *[f"{t.kind} ({t.label})" for t in terms]]
    lowest = rfs[lo]
    out = []
    for i, (t, hw) in enumerate(zip(terms, rel_half_widths)):
        if not (np.isfinite(hw) and hw > max_rel_bound and var[lo] > 0):
            continue
        j = 2 + i
        rest = [k for k in range(x.shape[1]) if k != j]
        # information per unit residual variance, summed over the records (each its own noise)
        w_data = sum(_info(x[a:b], j, rest) / v for a, b, v in zip(edges[:-1], edges[1:], var) if v > 0)
        if not w_data > 0:
            continue

        def bound(w_new: float) -> float:
            return float(hw) * float(np.sqrt(w_data / (w_data + w_new)))

        repeated = bound(_info(x[edges[lo]:edges[lo + 1]], j, rest) / var[lo])
        sc, h = min(((float(s), bound(_info(_columns([lowest], terms, float(s)), j, rest) / (var[lo] * s ** (2 * p))))
                     for s in [*np.geomspace(0.05, 0.95, 24), *np.geomspace(1.05, 3.0, 12)]), key=lambda sh: sh[1])
        if not h * level_gain <= repeated:
            continue   # more data at these levels would do about as well: the bound says it all
        i_all = _info(x, j, rest)
        partners = []
        for k in rest:
            i_wo = _info(x, j, [q for q in rest if q != k])
            if i_wo > 0 and 1.0 - i_all / i_wo >= min_share:
                partners.append((names[k], 1.0 - i_all / i_wo))
        out.append(Undetermined(term=t, rel_half_width=float(hw), partners=tuple(sorted(partners, key=lambda q: -q[1])),
                                scale=sc, rel_half_width_at_scale=h, rel_half_width_repeated=repeated,
                                reference=lowest.source, z_rms_at_scale_m=sc * float(np.std(lowest.z)),
                                zdot_rms_at_scale_m_s=sc * float(np.std(lowest.zdot))))
    return tuple(out)


def _columns(rfs: Sequence[RestoringForce], terms: Sequence[Term], scale: float = 1.0) -> np.ndarray:
    """[z, ż, g_1, ...] band-passed after the map, edges settled, records stacked (rows × columns)."""
    out = []
    for rf in rfs:
        s = bandpass_settle_samples(rf.fs_hz, rf.band)
        z, v = scale * rf.z, scale * rf.zdot
        cols = np.vstack([z, v, *[t.evaluate(z, v) for t in terms]])
        out.append(bandpass(cols, rf.fs_hz, rf.band)[:, s:rf.n - s].T)
    return np.vstack(out)


def _column(rfs: Sequence[RestoringForce], term: Term) -> np.ndarray:
    """The column of ``term`` alone, as :func:`_columns` makes it (each row of a band-pass is its own)."""
    return np.concatenate([_settled(term.evaluate(rf.z, rf.zdot), rf) for rf in rfs])


def _settled(x: np.ndarray, rf: RestoringForce) -> np.ndarray:
    """x band-passed like the columns, edges settled."""
    s = bandpass_settle_samples(rf.fs_hz, rf.band)
    return bandpass(x, rf.fs_hz, rf.band)[s:rf.n - s]


def _orth(a: np.ndarray, basis: np.ndarray) -> np.ndarray:
    return _beyond(a, np.linalg.qr(basis)[0])


def _beyond(a: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``a`` less its projection on the orthonormal columns ``q`` (a basis factored once for many columns)."""
    return a - q @ (q.T @ a)


def detection_limits(rfs: Sequence[RestoringForce], terms: Sequence[Term], candidates: Sequence[Candidate], *,
                     m2_kg: float | None = None, thresholds: Thresholds = Thresholds(),
                     n_grid: int = 24) -> tuple[DetectionLimit, ...]:
    """Smallest detectable effect of each candidate's kind (module docstring), one per kind.

    The model's columns are factored once and each candidate band-passes its own column alone (as
    :func:`confounded_pairs` does): the same numbers to the bit, and on ``benchmarks/bench_loop.py``'s records both
    took 0.38-0.46 s against 1.25-1.48 s when every candidate band-passed z and ż again and factored them anew.

    Parameters
    ----------
    rfs : sequence of RestoringForce
        The data the loop traced (its fit parts).
    terms : sequence of Term
        The model's terms (besides the linear strut).
    candidates : sequence of Candidate
        Each kind's best candidate on the current residual (``rank_beyond``); their ``n_eff`` is used.
    m2_kg : float, optional
    thresholds : Thresholds
        The loop's acceptance thresholds (α, min_err, min_delta_r2).
    n_grid : int
        Grid size of the Bonferroni correction.
    """
    x = _columns(rfs, terms)
    y = np.concatenate([bandpass(rf.force, rf.fs_hz, rf.band)[bandpass_settle_samples(rf.fs_hz, rf.band):
                                                                 rf.n - bandpass_settle_samples(rf.fs_hz, rf.band)]
                        for rf in rfs])
    coef = np.linalg.lstsq(x, y, rcond=None)[0]
    rss, tss = float(np.sum((y - x @ coef) ** 2)), float(y @ y)
    q, _ = np.linalg.qr(x)      # the model's columns, one basis for every candidate
    out = []
    for c in candidates:
        gp = _beyond(_column(rfs, c.term), q)
        info = float(gp @ gp)
        if not info > 0:
            continue
        dof = max(float(c.n_eff) - x.shape[1] - 1, 1.0)
        theta = smallest_visible(rss, info, dof, tss=tss, thresholds=thresholds, n_grid=n_grid)
        raw = np.concatenate([np.abs(c.term.evaluate(rf.z, rf.zdot)) for rf in rfs])
        peak = theta * float(np.quantile(raw, 0.995)) * (m2_kg or 1.0)
        out.append(DetectionLimit(term=c.term, theta_per_kg=theta,
                                  coefficient=None if m2_kg is None else theta * m2_kg, peak_force=peak,
                                  unit=c.term.spec.coef_unit))
    return tuple(out)


def confounded_pairs(rfs: Sequence[RestoringForce], terms: Sequence[Term], candidates: Sequence[Term], *,
                     rho_max: float = 0.8, rho_sep: float = 0.5) -> tuple[Confounding, ...]:
    """Model terms and candidates on different variables that the data cannot tell apart (module docstring)."""
    if not terms or not candidates:
        return ()
    out = []
    lowest = min(rfs, key=lambda rf: float(np.std(rf.zdot)))
    q = np.linalg.qr(_columns(rfs, []))[0]      # z, ż on every record: one basis for every term's column
    beyond: dict[str, np.ndarray] = {}

    def perp(t: Term) -> np.ndarray:
        """The column of ``t`` beyond z, ż on every record, made once."""
        if t.label not in beyond:
            beyond[t.label] = _beyond(_column(rfs, t), q)
        return beyond[t.label]

    for a in terms:
        for b in candidates:
            if b.variable == a.variable or b.kind == a.kind:
                continue
            rho = _cosine(perp(a), perp(b))
            if not abs(rho) >= rho_max:
                continue
            scale = None
            for s in [*np.geomspace(0.9, 0.05, 24), *np.geomspace(1.1, 3.0, 12)]:
                if abs(_rho([lowest], a, b, float(s))) < rho_sep:
                    scale = float(s)
                    break
            out.append(Confounding(a, b, rho, scale, lowest.source,
                                   None if scale is None else scale * float(np.std(lowest.zdot))))
    return tuple(out)


def _rho(rfs: Sequence[RestoringForce], a: Term, b: Term, scale: float) -> float:
    x = _columns(rfs, [a, b], scale)
    return _cosine(_orth(x[:, 2], x[:, :2]), _orth(x[:, 3], x[:, :2]))


def _cosine(ga: np.ndarray, gb: np.ndarray) -> float:
    d = float(np.linalg.norm(ga) * np.linalg.norm(gb))
    return float(ga @ gb / d) if d > 0 else 0.0
