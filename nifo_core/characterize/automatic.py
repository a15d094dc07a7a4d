"""Automatic characterization: which describing function explains the restoring force (docs/method.md §5).

Equation error of the body equation (paper Eq. 2) per unit sprung mass::

    y = -ẍ2 = a·z + b·ż [+ k3·x2] + Σ θ_i·g_i(z, ż) + e,    a = K2/M2, b = C2/M2, θ_i = c_i/M2

For every kind of the describing-function library (:mod:`nifo_core.kinds.describing`,
the one place the forms live) over a grid of its parameters scaled to the
observed motion, the candidate g is evaluated on the measured z, ż and then
band-passed with the integrator's band (docs/method.md §5 step 3). Candidates are
scored by the error reduction ratio (Billings) — the fraction of the variance
the linear fit leaves that the candidate explains:

    ERR = (g⊥ᵀ r)² / (g⊥ᵀ g⊥ · rᵀ r),   g⊥ = g orthogonalised against [z, ż],  r = linear residual

vectorised over the grid (one QR of the linear regressors, then one dot
product per grid point on a row subsample), refined around each kind's best
grid point and refitted at full length. A forward orthogonal selection (FROLS)
builds the suggested model one term at a time, then each chosen term is chosen
again given all the others (iterative OFR, :func:`_reselect`: the greedy first
step may take a term that stands in for two); kinds that explain the same
thing as a chosen term are listed as its alternatives, not suggested beside it.

One filter for every column. ``y``, ``z``, ``ż`` (and ``x2``) are band-passed
once more with the same filter that band-limits each g, so every column of the
regression carries the same final band shape. This matters for the negative
control: with 2 % accelerometer noise, z holds integrated noise that peaks in
the integrator's low transition band; if g saw the filter one more time than
y and z, a static g(z) weighted that noise differently from z and "explained"
10-20 % of a linear strut's residual (small-gap clearance, tiny backlash).
With the same final filter, a static g of jointly Gaussian data is
uncorrelated with the linear residual (Bussgang), as it should be.

A candidate counts as *present* only if all of (:class:`Thresholds`):

- ERR ≥ 2 % of what the linear fit leaves (for later terms: of what the terms
  chosen before leave),
- cross-validated ERR ≥ 1 % (fitted on alternate blocks, scored on the others),
- F-test p < 0.001 with effective degrees of freedom for coloured residuals
  (N_eff = N·mean(S)²/mean(S²) from the residual spectrum S), Bonferroni-corrected
  for the grid points searched,
- coefficient stable across data groups (records, or quarters of one record):
  information-weighted relative spread ≤ 0.5,
- explains at least 0.001 % of the total variance of -ẍ2 (ΔR² ≥ 1e-5: on
  noise-free data the linear residual is rounding, and any ERR means nothing),
- ``coulomb`` only with c > 0 (friction that feeds energy in is an artefact).

What was not found is not called absent: for every kind not suggested, a note gives
its detection limit given the suggested model (:func:`~.score.detection_limit`, the
loop's formula): the smallest coefficient these data, their noise, levels and length
would have shown, at the kind's best parameter and at both ends of its grid.

``backlash`` with c < 0 is physical: a·z + c·play(z) with c = -a is a spring in
series with dry friction (Jenkins element, stick-slip; its force saturates at
|c|·deadband/2, paper §3.3 after Ferri), the loops with flat tops of paper Fig. 7b.

Exact equivalences once z and ż are in the fit: ``saturation(limit=x) =
z - clearance(gap=x)`` and ``velocity_saturation(limit=x) = ż -
velocity_deadzone(knee=x)`` explain the data identically; the
clearance/deadzone form is reported (its linear part is then the small-motion
behaviour, docs/method.md §3) and the other is named as its equivalent.
``asymmetric_damping`` rebound and compression differ by a linear term: the
side with the positive (added-damping) coefficient is reported.
"""


from dataclasses import replace
from typing import Callable, Sequence

import numpy as np
from scipy import stats

from .data import GridSearch, RegressionData, candidate_grid
from .result import (DEFAULT_KINDS, Candidate, Characterization, Equivalence, FittedModel,
                     RecordSummary, Thresholds)
from .score import BaseFit, base_fit, detection_limit, lstsq, score_candidate
from .static import shifted_offsets, static_bump_stops, static_frame
from .subsets import better_set, forward_order
from ..kinds.describing import Term, kind as lookup_kind
from ..errors import ConfigError, InputError
from ..signal.integrate import IntegrationBand
from ..signal.parallel import thread_map
from ..signal.record import Record
from .restoring import RestoringForce, instantaneous_frequency, restoring_force, suggest_band

__all__ = ["Thresholds", "Candidate", "FittedModel", "Characterization", "RecordSummary", "characterize",
           "characterize_restoring", "rank_beyond", "grid_search", "DEFAULT_KINDS",
           "candidate_grid"]

#: kinds re-scored at full length per selection step (the best ones on the subsample)
_FULL_PER_STEP = 3


# Long (over 100 lines): the ranking, the greedy model search and the suggested model share one set of
# band-limited columns and grids. Left whole here while the noise branch (issue 28) edits its body; to split after
# the merge.
def _kind_names(kinds: Sequence[str]) -> tuple[str, ...]:
    """Each kind by its library name (aliases resolved), once, in the order given."""
    return tuple(dict.fromkeys(lookup_kind(k).name for k in kinds))


def characterize_restoring(rfs: Sequence[RestoringForce], *, m2_kg: float | None = None,
                           kinds: Sequence[str] = DEFAULT_KINDS, thresholds: Thresholds = Thresholds(),
                           grid_points: int = 24, max_terms: int = 3, n_groups: int = 4,
                           body_stiffness: bool = False, masks: Sequence[np.ndarray | None] | None = None,
                           progress: Callable[[float], None] | None = None) -> Characterization:
    """Characterize restoring-force data (the work behind :func:`characterize`; same parameters).

    ``rfs`` must share one integration band. ``masks`` (one per ``rf``, or
    None) select the samples to fit, e.g. a frequency window of a sweep; the
    candidates are still evaluated and band-passed over the whole record.
    ``n_groups``: parts of a single record (consecutive) for the
    coefficient-stability check; several records are one group each.
    """
    if not rfs:
        raise InputError("no restoring-force data to characterize")
    bands = {(rf.band.f_lo_hz, rf.band.f_hi_hz) for rf in rfs}
    if len(bands) > 1:
        raise ConfigError(f"records were integrated in different bands {sorted(bands)}",
                          hint="characterize records integrated with one band")
    if m2_kg is not None and not (np.isfinite(m2_kg) and m2_kg > 0):
        raise ConfigError(f"m2_kg={m2_kg!r} must be a positive mass [kg]")
    if max_terms < 1:
        raise ConfigError(f"max_terms={max_terms} must be at least 1")
    if masks is not None and len(masks) != len(rfs):
        raise InputError(f"{len(masks)} masks for {len(rfs)} records")
    kinds = _kind_names(kinds)

    means = RegressionData(rfs, n_groups=n_groups, body_stiffness=body_stiffness, masks=masks)

    def once(data: RegressionData, progress, prior: GridSearch | None) -> tuple[Characterization, GridSearch]:
        return _characterize(data, rfs, m2_kg=m2_kg, kinds=kinds, thresholds=thresholds, grid_points=grid_points,
                             max_terms=max_terms, body_stiffness=body_stiffness, progress=progress, prior=prior)

    data = means
    out, search = once(data, progress, None)
    frame = None
    for _ in range(_FRAME_PASSES):
        new = _frame_of(out, data)
        if new is None or (frame is not None and _moved(frame, new) < _FRAME_SETTLED):
            break
        frame = new
        data = means.in_frame(frame)
        out, search = once(data, None, search)      # the forms of ż searched once: the same in every frame
    if frame is None:
        return out
    where = ", ".join(f"{1e3 * -o:+.2f} mm ({rf.source or f'record {i}'})" for i, (o, rf) in enumerate(zip(frame, rfs)))
    return replace(out, notes=(f"every form of z measured from the static position: the suggested terms' mean "
                               f"force moves the mean position, which sat {where} from it (rebound positive)",
                               *out.notes), mean_position_m=tuple(-o for o in frame))


#: characterization passes with the forms of z measured from the static position the last pass implies
_FRAME_PASSES = 3
#: a mean position this far from the static one, relative to the record's z RMS, moves the frame
_FRAME_MATERIAL = 0.05
#: the frame has settled when no record's offset moves by more than this fraction of the largest one
_FRAME_SETTLED = 0.1


def _frame_of(ch: Characterization, data: RegressionData) -> tuple[float, ...] | None:
    """Where the static position lies in each record given the suggestion made on ``data``
    (:func:`.static.static_frame`), or None when no record's mean sits more than :data:`_FRAME_MATERIAL` of its
    z RMS from it."""
    if not ch.suggested:
        return None
    frame = static_frame(data, [c.term for c in ch.suggested], [c.offsets or None for c in ch.suggested])
    if all(abs(o) <= _FRAME_MATERIAL * float(np.std(rf.z)) for o, rf in zip(frame, data.rfs)):
        return None
    return frame


def _moved(a: Sequence[float], b: Sequence[float]) -> float:
    return max(abs(x - y) for x, y in zip(a, b)) / max(max(abs(x) for x in b), 1e-12)


def _characterize(data: RegressionData, rfs: Sequence[RestoringForce], *, m2_kg: float | None,
                  kinds: tuple[str, ...], thresholds: Thresholds, grid_points: int, max_terms: int,
                  body_stiffness: bool, progress: Callable[[float], None] | None,
                  prior: GridSearch | None = None) -> tuple[Characterization, GridSearch]:
    """One characterization of ``data`` in its frame (:func:`characterize_restoring`), and its grid search
    (``prior``: the search of the same rows in the frame before, :class:`GridSearch`)."""
    search = GridSearch(data, kinds, grid_points, progress, prior)
    n_grid = {k: len(search.grids[k]) for k in kinds}

    def score(j: int, base: list[np.ndarray], names: tuple[str, ...], fit: BaseFit | None = None) -> Candidate:
        t = search.terms[j]
        return score_candidate(data, base, t, thresholds=thresholds, n_grid=n_grid[t.kind], m2=m2_kg, names=names,
                               fit=fit)

    # --- each kind's best on its own, refitted at full length: the ranked table ------------
    none = np.empty((data.rows.size, 0))
    e1, s1 = search.err(none, search.r0)
    best1 = {}
    for k in kinds:  # a kind with only unphysical signs keeps its best, to show why it fails
        j = search.best_of(k, e1, s1)
        best1[k] = j if j is not None else search.best_of(k, e1, np.ones_like(s1))
    alone = base_fit(data, [])
    table = dict(zip(kinds, thread_map(lambda k: score(best1[k], [], (), alone), kinds)))
    # --- stepwise selection: forward, each term chosen again given the others, backward ------------------------
    chosen_j, replaced = _stepwise(search, data, kinds, score, max_terms, table, best1)
    chosen_terms = [search.terms[i] for i in chosen_j]
    shifts = shifted_offsets(data, chosen_terms)
    base = [data.regressor(t, offsets=o) for t, o in zip(chosen_terms, shifts)]
    # each suggested term scored given ALL the others: its partial contribution, above its detection limit
    chosen = [replace(score(j, base[:i] + base[i + 1:],
                            tuple(t.label for n, t in enumerate(chosen_terms) if n != i)), status="suggested")
              for i, j in enumerate(chosen_j)]
    extra, r = search.basis(base)
    # --- bump stops: the gap from the static position, which sits elsewhere in every record ----
    static_terms, static_off = static_bump_stops(data, [c.term for c in chosen])
    base = [data.regressor(t, offsets=o) for t, o in zip(static_terms, static_off)]
    for i, (t, o) in enumerate(zip(static_terms, static_off)):
        if o is not None:
            new = score_candidate(data, base[:i] + base[i + 1:], t, thresholds=thresholds, n_grid=n_grid[t.kind],
                                  m2=m2_kg, names=tuple(c.term.label for n, c in enumerate(chosen) if n != i),
                                  offsets=o)
            chosen[i] = replace(new, status="suggested")
    # --- kinds these data cannot tell from a suggested one: named together, not suggested beside it -------------
    ambiguities = _equivalences(search, data, chosen, base, kinds, score, thresholds)
    # --- what the suggestion explains of the other kinds ----------------------------------------
    out = []
    chosen_kinds = [c.kind for c in chosen]
    names = tuple(c.term.label for c in chosen)
    against = base_fit(data, base)      # the suggestion's fit: what every other kind is scored and limited against
    for k in sorted(kinds, key=lambda k: -table[k].err):
        c = table[k]
        mine = [ch for ch in chosen if ch.kind == k]
        if mine:  # its statistics given the terms chosen before it
            out.append(mine[0])
            continue
        if not c.present:
            out.append(replace(c, status="weak"))
            continue
        by = None
        ex, rr = none, search.r0
        for cj, jj in zip(chosen, chosen_j):  # the first suggested term after which it adds < min_err
            v = search.unit(jj, ex)
            ex = np.column_stack([ex, v])
            rr = rr - v * (v @ rr)
            e, sg = search.err(ex, rr)
            j = search.best_of(k, e, sg)
            if j is None or e[j] < thresholds.min_err:
                by = cj
                break
        if by is not None:
            status = "alternative" if c.err >= 0.5 * table[by.kind].err else "redundant"
            out.append(replace(c, status=status, alternative_to=by.term.label))
        else:  # still adds something given the suggestion: say why it was not taken
            e, sg = search.err(extra, r)
            cond = score(search.best_of(k, e, sg) if search.best_of(k, e, sg) is not None else best1[k], base, names,
                         against)
            why = cond.failed or (f"the suggestion holds max_terms={max_terms} terms",)
            out.append(replace(c, status="unselected", failed=tuple(f"given the suggestion: {w}" for w in why)))
    out = sorted(out, key=lambda c: (c.status != "suggested",
                                     chosen_kinds.index(c.kind) if c.status == "suggested" else 0))
    model = _joint(data, [c.term for c in chosen], [c.offsets or None for c in chosen])
    lin = _linear(data, m2_kg, body_stiffness)
    notes = []
    for before, after in replaced:
        notes.append(f"one change at a time stopped at {_labels(search, before)}; the set "
                     f"{_labels(search, after)} leaves less and each of its terms passes given the others: "
                     f"the selection went on from it")
    if not chosen:
        notes.append("no nonlinear candidate met the thresholds: no form of the library explains what the "
                     "linear fit leaves")
    for c in chosen:
        if c.offsets:
            where = ", ".join(f"{1e3 * -o:+.2f} mm ({rf.source or f'record {i}'})"
                              for i, (o, rf) in enumerate(zip(c.offsets, rfs)))
            what = ("gap from the static position" if c.term.spec.static_frame == "threshold"
                    else "z measured from the static position")
            notes.append(f"{c.term.label}: {what}; the mean position sat {where} from it (rebound positive), "
                         f"found from the balance of the mean force")
    unseen = []
    e, sg = search.err(extra, r)
    for k in [c.kind for c in out if c.status in ("weak", "alternative", "redundant")]:
        # what was not seen, and how big it would have had to be: the kind's best given the suggestion
        j = search.best_of(k, e, sg)
        t = search.terms[j if j is not None else best1[k]]
        th, peak = detection_limit(data, base, t, thresholds=thresholds, n_grid=n_grid[k], fit=against)
        if not np.isfinite(th):
            continue
        unit = t.spec.coef_unit if m2_kg else f"{t.spec.coef_unit}/kg"
        scale = m2_kg or 1.0
        force = f"±{th * peak * scale:.3g} N" + ("" if m2_kg else " per kg of M2")
        text = f"{t.label} with |coefficient| below {th * scale:.3g} {unit} (peak force below {force}"
        kp = t.spec.key_param
        if kp is not None and len(search.grids[k]) > 2:  # the limit depends on the parameter: at the grid's ends
            ends = []
            for g in (search.grids[k][0], search.grids[k][-1]):
                th_g, _ = detection_limit(data, base, g, thresholds=thresholds, n_grid=n_grid[k], fit=against)
                ends.append(f"{th_g * scale:.3g} {unit} at {kp}={float(g.params[kp]):.3g}")
            text += f"; {', '.join(ends)}"
        unseen.append(text + ")")
    if unseen:
        notes.append("could not have been seen in these data (detection limits given the suggested terms, "
                     "their noise, levels and length): " + "; ".join(unseen))
    if lin["r2"] < 0.9:
        notes.append(f"the linear fit explains only {100 * lin['r2']:.0f} % of the force: the rest is noise or "
                     f"dynamics outside the one-mass equation of the output side (another mode, a second load "
                     f"path), which no nonlinearity of the element models")
    if rfs[0].band.f_lo_hz > 1.0:
        notes.append(f"the integration band starts at {rfs[0].band.f_lo_hz:g} Hz: motion below it is only partly "
                     f"in z, ż: the lowest mode of interest must lie above it")
    return Characterization(candidates=tuple(out), suggested=tuple(chosen), band=rfs[0].band,
                            thresholds=thresholds, records=tuple(_summary(rf, data, i) for i, rf in enumerate(rfs)),
                            linear=lin, model=model, m2_kg=m2_kg,
                            z_range_m=data.zmax, zdot_range_m_s=data.vmax, notes=tuple(notes),
                            ambiguities=ambiguities), search


def grid_search(rfs: Sequence[RestoringForce], *, kinds: Sequence[str] = DEFAULT_KINDS, grid_points: int = 24,
                n_groups: int = 4, progress: Callable[[float], None] | None = None,
                data: RegressionData | None = None) -> GridSearch:
    """The candidate grids of ``kinds`` on ``rfs``, band-limited and orthogonalised against the linear columns: what
    :func:`rank_beyond` scores. It depends on the data alone, not on the terms a model holds, so the loop builds it
    once and ranks every round's residual on it (``rank_beyond(..., search=)``): building it is most of a ranking's
    time (the grid's regressors, one band-pass per column and record). Kept, it holds the grid's projected columns on
    the row subsample, not their full-length copies (:meth:`RegressionData.forget`: measured on four 300 s records,
    +168 MB of peak memory for the loop when they were kept). ``data``: the regression rows of ``rfs`` already made
    (``RegressionData(rfs, n_groups=n_groups, body_stiffness=False)``, or a view of them: :meth:`RegressionData.in_frame`)."""
    if not rfs:
        raise InputError("no restoring-force data to rank candidates on")
    kinds = _kind_names(kinds)
    data = RegressionData(rfs, n_groups=n_groups, body_stiffness=False) if data is None else data
    search = GridSearch(data, kinds, grid_points, progress)
    search.data.forget()
    return search


def rank_beyond(rfs: Sequence[RestoringForce], declared: Sequence[Term], *, m2_kg: float | None = None,
                kinds: Sequence[str] = DEFAULT_KINDS, thresholds: Thresholds = Thresholds(),
                grid_points: int = 24, n_groups: int = 4,
                progress: Callable[[float], None] | None = None,
                offsets: Sequence[Sequence[float] | None] | None = None,
                search: GridSearch | None = None) -> tuple[Candidate, ...]:
    """Each kind's best candidate on top of a linear strut AND the ``declared`` terms, ranked by ERR.

    What a model holding ``declared`` still lacks (the tracing step of the
    loop, docs/method.md §5): the same grids, band-limiting and QR-orthogonalised
    scoring as :func:`characterize_restoring`, with the declared terms' regressors
    (coefficients refitted) in the base. ERR is then the fraction of what the
    linear + declared fit leaves that the candidate explains; every statistic of
    :class:`Candidate` is given the declared terms (``conditional_on``).
    A candidate identical to a declared term is not listed. ``offsets``: per declared term, None or
    one ``offset`` [m] per record (a bump stop from the static position, :mod:`.characterize_static`).
    ``search``: the :func:`grid_search` of these ``rfs``, ``kinds``, ``grid_points`` and ``n_groups``, built before
    (the same ranking, without building it again).
    """
    if search is None:
        search = grid_search(rfs, kinds=kinds, grid_points=grid_points, n_groups=n_groups, progress=progress)
    elif ([id(r) for r in search.data.rfs], tuple(search.grids), search.grid_points, search.data.n_groups) != (
            [id(r) for r in rfs], _kind_names(kinds), grid_points, n_groups):
        raise ConfigError("the grid search given was built on other data, kinds, grid points or groups than these")
    kinds = tuple(search.grids)
    declared = tuple(declared)
    data = search.data
    base = [data.regressor(t, offsets=o) for t, o in zip(declared, offsets or [None] * len(declared))]
    extra, r = search.basis(base)
    e, sg = search.err(extra, r)
    n_grid = {k: len(search.grids[k]) for k in kinds}
    names = tuple(t.label for t in declared)
    best = []
    ok = np.array([t not in declared for t in search.terms])
    for k in kinds:
        j = search.best_of(k, np.where(ok, e, -1.0), sg)
        if j is None:  # only the unphysical sign: keep its best, to show why it fails
            j = search.best_of(k, np.where(ok, e, -1.0), np.ones_like(sg))
        if j is not None and ok[j]:
            best.append((k, j))
    fit = base_fit(data, base)
    out = thread_map(lambda kj: score_candidate(data, base, search.terms[kj[1]], thresholds=thresholds,
                                                n_grid=n_grid[kj[0]], m2=m2_kg, names=names, fit=fit), best)
    data.forget()
    return tuple(sorted(out, key=lambda c: -c.err))


def _base_of(search: GridSearch, data: RegressionData, js: Sequence[int]) -> tuple[list[np.ndarray], tuple[str, ...]]:
    """The regressors of grid terms ``js`` (an even stiffness evaluated from the static position) and their labels."""
    terms = [search.terms[j] for j in js]
    return [data.regressor(t, offsets=o) for t, o in zip(terms, shifted_offsets(data, terms))], \
        tuple(t.label for t in terms)


def _labels(search: GridSearch, js: Sequence[int]) -> str:
    return "{" + ", ".join(search.terms[j].label for j in js) + "}"


def _stepwise(search: GridSearch, data: RegressionData, kinds: Sequence[str],
              score: Callable[..., Candidate], max_terms: int,
              table: dict, best1: dict) -> tuple[list[int], list[tuple[list[int], list[int]]]]:
    """The suggested terms (grid indices) by stepwise selection: every kind whose partial contribution, given all
    the other terms chosen, passes the thresholds (is above its detection limit), and none that does not.

    Each pass: every chosen term is chosen again given the others (:func:`_reselect`, iterative OFR); then the
    term whose partial contribution given all the others fails the thresholds worst (smallest ERR) is dropped
    (backward elimination); else the best present candidate of a kind not chosen, given all the chosen terms, is
    added (forward selection, ≤ ``max_terms``). It ends when a pass changes nothing or would return to a set
    seen before. Then the best set of as many kinds (:func:`~.subsets.best_subsets`, on the subsample), else of one
    kind more, replaces it when it leaves :data:`_SUBSET_GAIN` less and each of its terms passes given the others,
    and the passes go on from there (:func:`~.subsets.better_set`): one change at a time can stop short of the best
    set.
    Returns the terms and the replacements made (what the passes stopped at, what replaced it) for the notes.

    Forward selection alone keeps what an early step took: measured on quadratic damping beside the paper's damper
    knee (the independent simulator, 4 levels), step 1 took a rising knee at 0.18 m/s standing in for the quadratic
    damping (ERR 0.86 against 0.74), step 2 a friction, step 3 the quadratic damping; once
    the quadratic damping is in, neither the re-placed knee nor the friction passes given the others
    (coefficient spread across the levels 1.5 and 1.0), and the true pair is found.
    """
    chosen = _steps(search, data, kinds, score, max_terms, table, best1, [])
    replaced = []       # (the set the passes stopped at, the set that replaced it)

    def passes(js: Sequence[int]) -> bool:     # each term passes the thresholds given the others
        return all(score(j, *_base_of(search, data, [i for i in js if i != j])).present for j in js)

    for _ in range(_SUBSET_ROUNDS):
        better = better_set(search, kinds, chosen, max_terms=max_terms, passes=passes, gain=_SUBSET_GAIN)
        if better is None:
            break
        replaced.append((chosen, better))
        chosen = _steps(search, data, kinds, score, max_terms, table, best1, better)
    return (forward_order(search, chosen) if replaced else chosen), replaced


#: tries of :func:`~.subsets.better_set` after the stepwise passes
_SUBSET_ROUNDS = 2


#: a set of kinds found by :func:`~.subsets.best_subsets` replaces the stepwise one when its residual on the subsample
#: is this much smaller (relative)
_SUBSET_GAIN = 0.01


def _steps(search: GridSearch, data: RegressionData, kinds: Sequence[str],
           score: Callable[..., Candidate], max_terms: int,
           table: dict, best1: dict, chosen: list[int]) -> list[int]:
    """The passes of :func:`_stepwise` from the terms ``chosen``."""
    seen: set[frozenset] = set()
    for _ in range(6 * max_terms + 2):
        changed = False
        if len(chosen) > 1:
            new = _reselect(search, data, chosen, kinds, score, passes=1)
            changed = new != chosen
            chosen = new
        dropped = False
        if len(chosen) > 1:
            worst = None
            for i in range(len(chosen)):
                others = chosen[:i] + chosen[i + 1:]
                c = score(chosen[i], *_base_of(search, data, others))
                if not c.present and (worst is None or c.err < worst[1]):
                    worst = (i, c.err)
            if worst is not None:
                chosen = chosen[:worst[0]] + chosen[worst[0] + 1:]
                dropped = changed = True
        if not dropped and len(chosen) < max_terms:
            taken = {search.terms[j].kind for j in chosen}
            if not chosen:     # the ranked table itself: each kind's best on its own, at full length
                scored = [(table[k], best1[k]) for k in kinds]
            else:
                base, names = _base_of(search, data, chosen)
                extra, r = search.basis(base)
                e, sg = search.err(extra, r)
                js = {k: search.best_of(k, e, sg) for k in kinds if k not in taken}
                js = {k: j for k, j in js.items() if j is not None and e[j] > 0}
                top = sorted(js, key=lambda k: -e[js[k]])[:_FULL_PER_STEP]
                fit = base_fit(data, base)
                scored = list(zip(thread_map(lambda k: score(js[k], base, names, fit), top), [js[k] for k in top]))
            scored = [(c, j) for c, j in scored if c.present and c.kind not in taken]
            if scored:
                chosen = chosen + [max(scored, key=lambda cj: cj[0].err)[1]]
                changed = True
        key = frozenset(search.terms[j].label for j in chosen)
        if not changed or key in seen:
            break
        seen.add(key)
    return chosen


def _equivalences(search: GridSearch, data: RegressionData, chosen: Sequence[Candidate], base: Sequence[np.ndarray],
                  kinds: Sequence[str], score: Callable[..., Candidate],
                  thresholds: Thresholds) -> tuple[Equivalence, ...]:
    """Per suggested term, the other kinds that explain as much in its place (:class:`Equivalence`).

    Given the other suggested terms, each kind not suggested is scored at its best parameter (the two best on
    the subsample, at full length). It is equivalent when it passes the thresholds and the difference of the two
    fits' residuals is not significant: F = (ERR_T - ERR_K)·dof/(1 - ERR_T), dof = N_eff - q (the F-test of
    :func:`~.score.score_candidate`), p ≥ alpha.
    """
    out = []
    taken = {c.kind for c in chosen}
    for i, c in enumerate(chosen):
        others = list(base[:i]) + list(base[i + 1:])
        names = tuple(x.term.label for n, x in enumerate(chosen) if n != i)
        extra, r = search.basis(others)
        e, sg = search.err(extra, r)
        js = {k: search.best_of(k, e, sg) for k in kinds if k not in taken}
        js = {k: j for k, j in js.items() if j is not None and e[j] > 0}
        top = sorted(js, key=lambda k: -e[js[k]])[:2]
        dof = max(c.n_eff - (len(data.lin) + len(base)), 1.0)
        alts, ps = [], []
        fit = base_fit(data, others)
        for a in thread_map(lambda k: score(js[k], others, names, fit), top):
            if not a.present:
                continue
            p = float(stats.f.sf(max(c.err - a.err, 0.0) / max(1.0 - c.err, 1e-12) * dof, 1, dof))
            if p >= thresholds.alpha:
                alts.append(a)
                ps.append(p)
        if alts:
            out.append(Equivalence(c, tuple(alts), tuple(ps)))
    return tuple(out)


def _reselect(search: GridSearch, data: RegressionData, chosen_j: Sequence[int], kinds: Sequence[str],
              score: Callable[..., Candidate], *, passes: int = 2) -> list[int]:
    """The forward selection's terms, each chosen again given all the others (iterative orthogonal forward
    regression: Guo, Guo, Billings & Wei, Int. J. Systems Science 46 (2015) 776-789).

    Forward selection takes at every step the term that explains most of what the terms before it leave, so
    the first term may be one that stands in for two: measured, with a 6e4 N/m backlash beside the paper's
    damper knee (``benchmarks/bench_characterize_sets.py``), step 1 took a friction with a 13 mm/s ramp (the
    knee's saturating part plus the play's friction-like reversals; ERR 0.0802 against the knee's 0.0799) and
    step 2 the backlash. Given the backlash, the knee explains more than that friction, and replaces it. A term
    is replaced when another kind's best (or its own kind at another parameter), scored at full length given
    the other terms, explains more of what they leave and passes every threshold.
    """
    chosen_j = list(chosen_j)
    for _ in range(passes):
        changed = False
        for i in range(len(chosen_j)):
            others = [search.terms[j] for n, j in enumerate(chosen_j) if n != i]
            shifts = shifted_offsets(data, others)
            base = [data.regressor(t, offsets=o) for t, o in zip(others, shifts)]
            names = tuple(t.label for t in others)
            extra, r = search.basis(base)
            e, sg = search.err(extra, r)
            taken = {t.kind for t in others}
            js = {k: search.best_of(k, e, sg) for k in kinds if k not in taken}
            js = {k: j for k, j in js.items() if j is not None and e[j] > 0}
            fit = base_fit(data, base)
            now = score(chosen_j[i], base, names, fit)
            best_j, best_err = chosen_j[i], now.err
            for k in sorted(js, key=lambda k: -e[js[k]])[:_FULL_PER_STEP]:
                if js[k] == chosen_j[i]:
                    continue
                c = score(js[k], base, names, fit)
                if c.present and c.err > best_err:
                    best_j, best_err = js[k], c.err
            if best_j != chosen_j[i]:
                chosen_j[i], changed = best_j, True
        if not changed:
            break
    return chosen_j


def _joint(data: RegressionData, terms: list[Term], offsets: list) -> "FittedModel":
    lin = data.x[:, data.lin]
    a = np.column_stack([lin, *[data.regressor(t, offsets=o) for t, o in zip(terms, offsets)]]) if terms else lin
    c = lstsq(a, data.y)
    res = data.y - a @ c
    tss = float(data.y @ data.y)
    return FittedModel(k_per_kg=float(c[0]), c_per_kg=float(c[1]),
                       terms=tuple((t, float(th)) for t, th in zip(terms, c[len(data.lin):])),
                       r2=1.0 - float(res @ res) / tss if tss > 0 else 0.0)


def _linear(data: RegressionData, m2: float | None, body_stiffness: bool) -> dict:
    c = lstsq(data.x, data.y)
    r = data.y - data.x @ c
    tss = float(data.y @ data.y)
    out = {"k_per_kg": float(c[0]), "c_per_kg": float(c[1]), "r2": 1.0 - float(r @ r) / tss if tss > 0 else 0.0}
    if body_stiffness:
        out["k3_per_kg"] = float(c[2])
    if data.forced and c[-1] < 0:                 # -ẍ2 = ... - F/M2
        out["m2_from_force_kg"] = -1.0 / float(c[-1])
    if m2 is not None:
        out.update(k2_n_per_m=float(c[0]) * m2, c2_n_s_per_m=float(c[1]) * m2)
        if body_stiffness:
            out["k3_n_per_m"] = float(c[2]) * m2
    return out


def _summary(rf: RestoringForce, data: RegressionData, i: int) -> RecordSummary:
    m = data.rec == i
    x, y = data.x[m][:, data.lin], data.y[m]
    coef = lstsq(x, y)
    res = y - x @ coef
    return RecordSummary(source=rf.source, fs_hz=rf.fs_hz, duration_s=(rf.n + 2 * rf.start) / rf.fs_hz,
                         seconds_used=float(m.sum()) / rf.fs_hz,
                         z_rms_m=float(np.std(x[:, 0])), z_peak_m=float(np.max(np.abs(x[:, 0]))),
                         zdot_rms_m_s=float(np.std(x[:, 1])), zdot_peak_m_s=float(np.max(np.abs(x[:, 1]))),
                         k_per_kg=float(coef[0]), c_per_kg=float(coef[1]),
                         linear_r2=1.0 - float(res @ res) / float(y @ y))


def characterize(records: Record | Sequence[Record], *, band: IntegrationBand | None = None,
                 m2_kg: float | None = None, kinds: Sequence[str] = DEFAULT_KINDS,
                 thresholds: Thresholds = Thresholds(), grid_points: int = 24, max_terms: int = 3,
                 freq_window_hz: tuple[float, float] | None = None, body_stiffness: bool = False,
                 progress: Callable[[float], None] | None = None) -> Characterization:
    """Rank describing functions by how much of the restoring force they explain beyond linear.

    Parameters
    ----------
    records : Record or sequence of Record
        One record, or several at different excitation levels (same vehicle).
    band : IntegrationBand, optional
        Integration band for z, ż and the band-pass of every column; default
        :func:`~nifo_core.characterize.restoring.suggest_band` of the records together.
    m2_kg : float, optional
        Sprung mass [kg]: coefficients are then also given in N/m, N·s/m, N, ...
    kinds : sequence of str
        Kinds of :mod:`nifo_core.kinds.describing` to try (default :data:`DEFAULT_KINDS`).
    thresholds : Thresholds
        When a candidate counts as present.
    grid_points : int
        Grid points per parameter (then refined around each kind's best).
    max_terms : int
        Most terms in the suggested model.
    freq_window_hz : (float, float), optional
        Fit only the samples whose instantaneous frequency (tracked on the
        spindle signal, :func:`~nifo_core.characterize.restoring.track_frequency`) lies in
        this window: sweeps of multi-mode structures, where one linear k, c
        holds only near one mode.
    body_stiffness : bool
        Also fit K3·x2 (a rig restraint from body to ground), x2 integrated from
        ẍ2 alone. Off by default: x2 is a low-passed copy of the very signal
        being explained (y = -ẍ2), so the fit can lean on it; use it only when
        K3 ≠ 0 is known.
    progress : callable, optional
        Called with the fraction of the grid evaluated.

    Returns
    -------
    Characterization
    """
    recs = [records] if isinstance(records, Record) else list(records)
    if not recs:
        raise InputError("no records to characterize")
    if band is None:
        band = suggest_band(recs).band
    rfs = [restoring_force(r, band=band, body_displacement=body_stiffness) for r in recs]
    masks = None
    if freq_window_hz is not None:
        lo, hi = (float(v) for v in freq_window_hz)
        if not 0 < lo < hi:
            raise ConfigError(f"frequency window {lo:g}-{hi:g} Hz must satisfy 0 < lo < hi")
        masks = [(f >= lo) & (f <= hi) for f in (instantaneous_frequency(rf.spindle_accel, rf.fs_hz) for rf in rfs)]
    return characterize_restoring(rfs, m2_kg=m2_kg, kinds=kinds, thresholds=thresholds,
                                  grid_points=grid_points, max_terms=max_terms, body_stiffness=body_stiffness,
                                  masks=masks, progress=progress)
