"""The describing-function library: static and hysteretic strut nonlinearities.

Each *kind* is a basis function g(z, ż; params) of the relative displacement
z = x2 - x1 [m] and velocity ż [m/s] (docs/method.md §2, paper Fig. 1). A strut
nonlinearity is ``c · g`` with a coefficient c added to the linear strut force
(body equation ``M2·ẍ2 = -K2·z - C2·ż - K3·x2 - Σ c_i·g_i``). The forms are kept
*whole* (their linear part is not removed, docs/method.md §3), and every one is
zero at zero motion, so the nominal linear system is what remains when all
coefficients vanish.

==========================  ========  ===============================  =======================================
kind                        variable  parameters                       g
==========================  ========  ===============================  =======================================
``cubic_stiffness``         z         —                                z³
``quadratic_stiffness``     z         —                                z² (even: stiffer on one side)
``clearance``               z         ``gap`` [m]                      sign(z)·max(|z| - gap, 0)
``saturation``              z         ``limit`` [m]                    clip(z, -limit, limit)
``bump_stop``               z         ``gap`` [m], ``side``, ``offset``  compression: min(z - offset + gap, 0)
                                                                        rebound: max(z - offset - gap, 0)
``backlash``                z         ``deadband`` [m]                 play operator of total width deadband
``velocity_deadzone``       ż         ``knee`` [m/s]                   sign(ż)·max(|ż| - knee, 0)
``velocity_saturation``     ż         ``limit`` [m/s]                  clip(ż, -limit, limit)
``coulomb``                 ż         ``eps`` [m/s]                    tanh(ż/eps)
``quadratic_damping``       ż         —                                ż·|ż|
``asymmetric_damping``      ż         ``side``                         rebound: max(ż, 0); compression: min(ż, 0)
==========================  ========  ===============================  =======================================

Aliases: ``deadzone``/``piecewise_linear_stiffness`` → ``clearance``,
``piecewise_linear_damping``/``knee`` → ``velocity_deadzone``, ``friction`` →
``coulomb``, ``play`` → ``backlash``, ``cubic`` → ``cubic_stiffness``.

Physical meaning of the coefficient c (units N per unit of g), e.g. a
digressive damper blowing off above 0.03 m/s from C2 = 1400 to 700 N·s/m is
``velocity_deadzone(knee=0.03)`` with c = -700 N·s/m; 100 N of strut friction
is ``coulomb`` with c = 100 N; a bump stop of 50 kN/m is ``bump_stop`` with
c = 50e3 N/m.

The kind registry: :data:`KINDS` holds every fact the rest of nifo needs about a kind (PySINDy's feature libraries
that name and fit themselves) — its variable, parameters and g, and:

- what it accepts: :meth:`Kind.check` (``zero_ok``, ``signed``; one rule for the core, the command line and the
  model file, which validates through it);
- how characterize searches it: :meth:`Kind.grid` (``grid_spec``, ``fixed``), ``searched`` (in
  :data:`DEFAULT_KINDS`), ``positive`` (the sign of a physical coefficient), ``equivalent`` and ``mirror`` (what a fit
  reports, :meth:`Kind.canonical`), ``static_frame`` (a threshold or a z counted from the static position);
- how a fit reads: :meth:`Kind.describe` (``phrase``), ``noun``, ``joiner``, ``beyond``, ``sentence``,
  ``coef_unit``, and the reach of its key parameter (:meth:`Kind.reach`);
- how the model treats it: ``hysteretic`` and ``play_state`` (a state from sample to sample: the play);
  ``shape_param`` (what an output-error fit may move: the key parameter, or a friction's smoothing); ``absorb``
  (the slopes (α, β) of the linear part α·z + β·ż its g leaves to the model's linear part, its remainder being
  bounded); ``bounded`` (a force bounded whatever the motion); ``path_slopes`` and ``path_width`` (for a kind a
  feedback path may carry: its slope of z at large and at small amplitude, its width per unit of its key
  parameter); ``compiled`` (its numba code and parameters for :mod:`nifo_core.kinds.strut_forces`);
  ``lipschitz`` and ``slopes_within`` (bounds of its slopes, for the fixed point's contraction and the
  simulator's step).

Code outside this package asks the kind (``term.spec.positive``), never its name; where it names a kind as data (a
simulator preset) it takes it from :data:`LIBRARY` (``tests/test_kinds_own_facts.py`` counts kind names written as
strings elsewhere: none). Adding a kind is one :class:`Kind` in :func:`_kinds` below plus its tests; a g that is not
one of the compiled forms of :data:`CODES` also takes one branch in ``g_one`` of :mod:`nifo_core.kinds.strut_forces`
(docs/CONTRACTS.md, "A new kind").
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from types import MappingProxyType, SimpleNamespace
from typing import Callable, Literal, Mapping

import numba
import numpy as np

from ..errors import ConfigError

__all__ = ["Kind", "GridSpec", "Term", "KINDS", "LIBRARY", "DEFAULT_KINDS", "ALIASES", "kind", "make_term",
           "evaluate_terms", "play_operator", "path_slopes", "linear_twin", "CODES"]

Variable = Literal["z", "zdot"]


@numba.njit(cache=True)
def _play(z, deadband, y0):  # pragma: no cover - compiled
    y = np.empty_like(z)
    h = 0.5 * deadband
    prev = y0
    for i in range(z.size):
        zi = z[i]
        if prev < zi - h:
            prev = zi - h
        elif prev > zi + h:
            prev = zi + h
        y[i] = prev
    return y


def play_operator(z: np.ndarray, deadband: float, *, y0: float | None = None) -> np.ndarray:
    """Backlash (play) operator of total width ``deadband`` (paper Fig. 7b, 9a).

    The output stays put while z moves inside a window of width ``deadband``
    around it and follows z at the window's edge otherwise. It starts at
    ``y0`` (default: z[0]) and is centred so that it is zero-mean for a
    symmetric motion: y - z ∈ [-deadband/2, deadband/2].
    """
    z = np.ascontiguousarray(z, dtype=np.float64)
    if z.size == 0:
        return z.copy()
    return _play(z, float(deadband), float(z[0] if y0 is None else y0))


def _sym_deadzone(x, w):
    return np.sign(x) * np.maximum(np.abs(x) - w, 0.0)


def _bump_pieces(p):
    """g of a bump stop (:func:`_bump`) as pieces of a polynomial of z (``Kind.pieces``)."""
    gap, off = float(p["gap"]), float(p["offset"])
    if p["side"] == "compression":
        return ((-np.inf, off - gap, (gap - off, 1.0)),)
    return ((off + gap, np.inf, (-off - gap, 1.0)),)


def _bump(z, gap, side, offset):
    s = str(side)
    if s == "compression":
        return np.minimum(z - offset + gap, 0.0)
    if s == "rebound":
        return np.maximum(z - offset - gap, 0.0)
    raise ConfigError(f"bump_stop side={side!r} must be 'compression' or 'rebound'")


def _asym(zd, side):
    s = str(side)
    if s == "rebound":
        return np.maximum(zd, 0.0)
    if s == "compression":
        return np.minimum(zd, 0.0)
    raise ConfigError(f"asymmetric_damping side={side!r} must be 'rebound' or 'compression'")


@dataclass(frozen=True)
class Kind:
    """One form of the library: its variable, named parameters (with units and defaults) and g."""

    name: str
    variable: Variable
    params: Mapping[str, tuple[object, str]]  # name -> (default, unit/choices)
    func: Callable[..., np.ndarray]
    description: str
    key_param: str | None = None
    hysteretic: bool = False
    coef_unit: str = ""
    #: (α, β): g = α·z + β·ż + a bounded remainder, the linear part the model's linear part absorbs
    absorb: tuple[float, float] = (0.0, 0.0)
    #: (slope at large amplitude, slope at small amplitude) of z for a kind a feedback path may carry; None: not
    path_slopes: tuple[float, float] | None = None
    #: params -> (numba code, p0, p1) for :func:`nifo_core.kinds.strut_forces.g_one`
    compiled: Callable[[Mapping[str, object]], tuple[int, float, float]] | None = None
    #: params -> global Lipschitz constants (L_z, L_ż) of g (inf: none); None: 1 in its variable
    lipschitz: Callable[[Mapping[str, object]], tuple[float, float]] | None = None
    #: the parameter that shapes g, which an output-error fit may move, when it is not the key parameter (a
    #: friction's smoothing eps: not physics a user states, but what its prediction at small motion hangs on)
    shape: str | None = None

    @property
    def shape_param(self) -> str | None:
        """The parameter an output-error refinement moves: ``shape``, else the key parameter (gap, knee...)."""
        return self.shape or self.key_param

    #: what a test engineer calls it ("damper knee", "play"): the report's and the export's words
    noun: str = ""
    #: numbers that may be 0, numbers of either sign (:meth:`check`; every other number is positive)
    zero_ok: tuple[str, ...] = ()
    signed: tuple[str, ...] = ()
    #: the candidate values characterize scores (:meth:`grid`), and the parameters its candidates hold fixed
    grid_spec: GridSpec | None = None
    fixed: Mapping[str, object] = field(default_factory=dict)
    #: tried by characterize and the loop when no kinds are named (:data:`DEFAULT_KINDS`)
    searched: bool = True
    #: its coefficient must be positive to be physical (a friction force)
    positive: bool = False
    #: the kind whose column is this one's with the opposite coefficient plus a linear term (named, not searched)
    equivalent: str | None = None
    #: one-sided with a ``side``: a negative coefficient is the other side's positive one (:meth:`canonical`)
    mirror: bool = False
    #: how the static position enters: "threshold" (one-sided, it moves the mean: its gap counts from the static
    #: position, its ``offset`` places it), "position" (even, no threshold: z counts from the static position)
    static_frame: Literal["", "threshold", "position"] = ""
    #: its force is bounded whatever the motion (a feedback through it needs no absorbed slope)
    bounded: bool = False
    #: a feedback path's width per unit of its key parameter: 1 for a play's total width, 0.5 for a half-width
    path_width: float = 1.0
    #: (θ, params, measured from the static position) -> what the fitted term means (:meth:`describe`)
    phrase: Callable[[float, Mapping[str, object], bool], str] | None = None
    #: the report's words: its force acts beyond its threshold; the word between its noun and its parameter
    beyond: bool = False
    joiner: str = " at "
    #: a finding's sentence names it by this instead of its meaning and label ("Coulomb friction of 80 N")
    sentence: str = ""
    #: (params, |z| reach, |ż| reach) -> the slopes (dg/dz, dg/dż) up to that motion, for a g without a global
    #: Lipschitz constant (the simulator's step check); None: :attr:`lipschitz`
    slopes_within: Callable[[Mapping[str, object], float, float], tuple[float, float]] | None = None
    #: a hysteretic kind whose state is a play operator's (streaming NIFO carries it)
    play_state: bool = False
    #: params -> g of a memoryless kind of z as pieces of a polynomial: ((from, to, (a0, a1, ...)), ...), g =
    #: Σ a_j·z^j on from ≤ z < to and 0 elsewhere; its mean over a record at any shift of z then comes from the
    #: record's sorted z in log time (:class:`nifo_core.characterize.static.RecordMeans`). None: g is evaluated
    #: sample by sample
    pieces: Callable[[Mapping[str, object]], tuple[tuple[float, float, tuple[float, ...]], ...]] | None = None

    def check(self, params: Mapping[str, object]) -> dict:
        """The parameters with their defaults filled in, numbers as floats; :class:`ConfigError` naming the value.

        One rule for every caller (the model file, the command line, the API): a choice (``side``) is one of its
        words; a number is a real number, not text or true/false, and finite; it is positive, except the ones in
        ``zero_ok`` (≥ 0: a bump stop touching at the static position) and ``signed`` (a bump stop's offset). A
        threshold of 0 would make the term the linear one (a clearance or a damper knee at 0 is z or ż itself,
        the linear part's own column), a width or a smoothing of 0 makes g zero or undefined.
        """
        unknown = set(params) - set(self.params)
        if unknown:
            raise ConfigError(f"{self.name} has no parameter(s) {sorted(unknown)}; it takes {list(self.params) or 'none'}")
        out = {k: params.get(k, d) for k, (d, _) in self.params.items()}
        for k, v in out.items():
            if v is None:
                raise ConfigError(f"{self.name} needs parameter {k!r} [{self.params[k][1]}]",
                                  hint=f"e.g. {self.name}: {{{k}: ...}}")
            out[k] = self.check_value(k, v)
        return out

    def check_value(self, param: str, value: object) -> object:
        """One parameter's value by :meth:`check`'s rule: a choice as given, a number as a float."""
        if param not in self.params:
            raise ConfigError(f"{self.name} has no parameter {param!r}; it takes {list(self.params) or 'none'}")
        unit = self.params[param][1]
        where = f"{self.name}.{param}={_short(value)}"
        if "|" in unit:   # a choice
            if not isinstance(value, str) or value not in unit.split("|"):
                raise ConfigError(f"{where} must be one of {unit.replace('|', ', ')}")
            return value
        if not isinstance(value, numbers.Real) or isinstance(value, (bool, np.bool_)):
            raise ConfigError(f"{where} must be a number [{unit}]"
                              + (" (true/false is not a number)" if isinstance(value, (bool, np.bool_)) else ""))
        fv = float(value)
        if not np.isfinite(fv) or abs(fv) > 1e300:
            raise ConfigError(f"{where} must be finite [{unit}]")
        if not self.may_be(param, fv):
            raise ConfigError(f"{where} must be positive [{unit}]" + (" (0 makes the term the linear one)"
                                                                     if fv == 0 else ""))
        return fv

    def grid(self, *, z_range: float, zdot_range: float, points: int, z_neg: float | None = None,
             z_pos: float | None = None) -> list["Term"]:
        """The candidate terms characterize scores for this kind (``grid_spec``; one term without one)."""
        g = self.grid_spec
        if g is None:
            return [Term(self.name, dict(self.fixed))]
        span = np.linspace if g.linear else np.geomspace
        scale = zdot_range if self.variable == "zdot" else z_range
        if not g.per_side:
            return [Term(self.name, {**self.fixed, g.param: x}) for x in span(g.lo, g.hi, points) * scale]
        out = []
        for side, peak in (("compression", z_neg or scale), ("rebound", z_pos or scale)):
            out += [Term(self.name, {**self.fixed, g.param: x, "side": side}) for x in span(g.lo, g.hi, points) * peak]
        return out

    def may_be(self, param: str, value: float) -> bool:
        """Whether ``value`` passes :meth:`check`'s sign rule for the number ``param``."""
        return param in self.signed or value > 0 or (value == 0 and param in self.zero_ok)

    def reach(self, term: "Term", *, z_max: float, zdot_max: float, z_neg: float = 0.0,
              z_pos: float = 0.0) -> float | None:
        """The motion peak a term's key parameter is measured against: |ż| for a velocity kind, the side's peak
        for a one-sided kind (``grid_spec.per_side``), |z| otherwise; None where that side never moved."""
        if self.variable == "zdot":
            return zdot_max
        if self.grid_spec is not None and self.grid_spec.per_side:
            peak = z_neg if term.params["side"] == "compression" else z_pos
            return peak if peak > 0 else None
        return z_max

    def canonical(self, term: "Term", theta: float) -> tuple["Term", float, str | None]:
        """(reported term, sign to apply to θ, the equivalent form in words or None) of a fitted term.

        A one-sided kind with ``mirror`` reports a negative coefficient as the other side's positive one
        (c·max(ż,0) = c·ż - c·min(ż,0): the rest is linear); a kind with an ``equivalent`` names it.
        """
        if self.mirror and theta < 0:
            other = "compression" if term.params["side"] == "rebound" else "rebound"
            return Term(self.name, {**term.params, "side": other}), -1.0, None
        if self.equivalent is not None:
            other = KINDS[self.equivalent]
            return term, 1.0, (f"{other.name}({other.key_param}={float(term.params[self.key_param]):.4g}) "
                               "with the opposite coefficient")
        return term, 1.0, None

    def describe(self, term: "Term", theta: float, *, from_static: bool = False) -> str:
        """What a fitted term means in a test engineer's words (``phrase``; ``description`` without one)."""
        if self.phrase is None:  # pragma: no cover - every kind of the registry has one
            return self.description
        return self.phrase(theta, term.params, from_static)


@dataclass(frozen=True)
class GridSpec:
    """The candidate values of a kind's parameter ``param``: ``lo`` to ``hi`` times the motion's peak (of the
    kind's variable; of each side's peak with ``per_side``), geometric unless ``linear``."""

    param: str
    lo: float
    hi: float
    linear: bool = False
    per_side: bool = False


def _short(v: object) -> str:
    r = repr(v)
    return r if len(r) <= 40 else r[:37] + "..."


#: numba codes of the compiled forms (:mod:`nifo_core.kinds.strut_forces`), one per kind and side
CODES: Mapping[str, int] = MappingProxyType({name: i for i, name in enumerate(
    ("cubic", "clearance", "saturation", "bump_compression", "bump_rebound", "play", "velocity_deadzone",
     "velocity_saturation", "coulomb", "quadratic_damping", "asymmetric_rebound", "asymmetric_compression",
     "quadratic_stiffness"))})


def _code(name: str, p0: str | None = None, scale: float = 1.0):
    return lambda p: (CODES[name], scale * float(p[p0]) if p0 else 0.0, 0.0)


def _cube(z, zd):
    """z³ as (z·z)·z: numpy's ``z**3`` calls pow per element, 140× slower on a strut's z (18 ms against 0.13 ms
    for 300 000 samples of millimetres: the loop's static-position balance evaluates it thousands of times);
    the compiled force (:mod:`.strut_forces`) multiplies the same way. Within 1 ulp of pow."""
    return z * z * z


def _mm(x: float) -> str:
    return f"{1e3 * x:.3g} mm"


def _cubic_words(th, p, static):
    return f"{'hardening' if th > 0 else 'softening'} cubic stiffness"


def _quadratic_words(th, p, static):
    return f"asymmetric stiffness: stiffer in {'rebound (z > 0)' if th > 0 else 'compression (z < 0)'}"


def _clearance_words(th, p, static):
    how = "stiffens (clearance/contact)" if th > 0 else "softens (saturation)"
    return f"stiffness {how} beyond ±{_mm(p['gap'])}"


def _bump_words(th, p, static):
    return (f"one-sided {'stiffening' if th > 0 else 'softening'} beyond {_mm(p['gap'])} "
            f"of {p['side']} from the {'static' if static else 'mean'} position")


def _play_words(th, p, static):
    if th < 0:
        return (f"spring in series with dry friction (stick-slip, Jenkins element): slips after "
                f"{_mm(p['deadband'])} of reversal")
    return f"hysteretic stiffness through a play of {_mm(p['deadband'])}"


def _knee_words(th, p, static):
    how = "rises (progressive)" if th > 0 else "drops (digressive, blow-off)"
    return f"damping {how} beyond ±{p['knee']:.3g} m/s"


def _quadratic_damping_words(th, p, static):
    return f"velocity-squared damping ({'adds' if th > 0 else 'removes'} damping at speed)"


def _kinds() -> dict[str, Kind]:
    inf = float("inf")
    ks = [
        Kind("cubic_stiffness", "z", {}, _cube,
             "hardening (c>0) or softening (c<0) cubic spring", None, coef_unit="N/m³",
             compiled=_code("cubic"), lipschitz=lambda p: (inf, 0.0), noun="cubic spring", phrase=_cubic_words,
             slopes_within=lambda p, z, zd: (3 * z**2, 0.0), pieces=lambda p: ((-inf, inf, (0.0, 0.0, 0.0, 1.0)),)),
        Kind("quadratic_stiffness", "z", {}, lambda z, zd: z**2,
             "asymmetric (even) quadratic spring: stiffer on one side than the other, e.g. a cubic centred off the "
             "static position", None, coef_unit="N/m²", compiled=_code("quadratic_stiffness"),
             lipschitz=lambda p: (inf, 0.0), noun="even (quadratic) spring", static_frame="position",
             phrase=_quadratic_words, slopes_within=lambda p, z, zd: (2 * z, 0.0),
             pieces=lambda p: ((-inf, inf, (0.0, 0.0, 1.0)),)),
        Kind("clearance", "z", {"gap": (None, "m")}, lambda z, zd, gap: _sym_deadzone(z, gap),
             "stiffness change beyond ±gap (clearance, piecewise-linear stiffness)", "gap", coef_unit="N/m",
             absorb=(1.0, 0.0), path_slopes=(1.0, 0.0), compiled=_code("clearance", "gap"), noun="clearance",
             grid_spec=GridSpec("gap", 0.03, 0.9), equivalent="saturation", path_width=0.5,
             phrase=_clearance_words, beyond=True, joiner=" ",
             pieces=lambda p: ((-inf, -p["gap"], (p["gap"], 1.0)), (p["gap"], inf, (-p["gap"], 1.0)))),
        Kind("saturation", "z", {"limit": (None, "m")}, lambda z, zd, limit: np.clip(z, -limit, limit),
             "stiffness that saturates beyond ±limit", "limit", coef_unit="N/m",
             path_slopes=(0.0, 1.0), compiled=_code("saturation", "limit"), noun="saturating spring",
             grid_spec=GridSpec("limit", 0.03, 0.9), searched=False, bounded=True, path_width=0.5,
             phrase=lambda th, p, static: f"stiffness saturates beyond ±{_mm(p['limit'])}", joiner=" at ±",
             pieces=lambda p: ((-inf, -p["limit"], (-p["limit"],)), (-p["limit"], p["limit"], (0.0, 1.0)),
                               (p["limit"], inf, (p["limit"],)))),
        Kind("bump_stop", "z", {"gap": (None, "m"), "side": ("compression", "compression|rebound"), "offset": (0.0, "m")},
             lambda z, zd, gap, side, offset: _bump(z, gap, side, offset),
             "one-sided contact stiffness beyond gap (compression: z < offset-gap)", "gap", coef_unit="N/m",
             compiled=lambda p: (CODES["bump_compression" if p["side"] == "compression" else "bump_rebound"],
                                 p["gap"], p["offset"]), noun="bump stop", zero_ok=("gap",), signed=("offset",),
             grid_spec=GridSpec("gap", 0.0, 0.92, linear=True, per_side=True), static_frame="threshold",
             phrase=_bump_words, beyond=True, pieces=_bump_pieces),
        Kind("backlash", "z", {"deadband": (None, "m")}, lambda z, zd, deadband: play_operator(z, deadband),
             "hysteretic stiffness through a play of total width deadband (paper Fig. 9a)", "deadband",
             hysteretic=True, coef_unit="N/m", absorb=(1.0, 0.0), path_slopes=(1.0, 0.0),
             compiled=lambda p: (CODES["play"], 0.5 * float(p.get("deadband", 0.0)), 0.0), noun="play",
             grid_spec=GridSpec("deadband", 0.01, 0.7), phrase=_play_words, joiner=" ", play_state=True),
        Kind("velocity_deadzone", "zdot", {"knee": (None, "m/s")}, lambda z, zd, knee: _sym_deadzone(zd, knee),
             "damping change beyond ±knee (digressive/progressive damper, paper Fig. 12a)", "knee", coef_unit="N·s/m",
             absorb=(0.0, 1.0), compiled=_code("velocity_deadzone", "knee"), noun="damper knee",
             grid_spec=GridSpec("knee", 0.02, 0.9), equivalent="velocity_saturation", phrase=_knee_words,
             beyond=True),
        Kind("velocity_saturation", "zdot", {"limit": (None, "m/s")}, lambda z, zd, limit: np.clip(zd, -limit, limit),
             "damping force that saturates beyond ±limit", "limit", coef_unit="N·s/m",
             compiled=_code("velocity_saturation", "limit"), noun="damper force limit",
             grid_spec=GridSpec("limit", 0.02, 0.9), searched=False, bounded=True,
             phrase=lambda th, p, static: f"damping force saturates beyond ±{p['limit']:.3g} m/s", beyond=True),
        Kind("coulomb", "zdot", {"eps": (0.005, "m/s")}, lambda z, zd, eps: np.tanh(zd / eps),
             "dry friction, smoothed over ±eps", None, coef_unit="N", compiled=_code("coulomb", "eps"),
             lipschitz=lambda p: (0.0, 1.0 / float(p.get("eps", 0.005))), shape="eps", noun="friction",
             grid_spec=GridSpec("eps", 0.001, 0.3), positive=True, bounded=True,
             phrase=lambda th, p, static: "dry friction", sentence="Coulomb friction"),
        Kind("quadratic_damping", "zdot", {}, lambda z, zd: zd * np.abs(zd),
             "velocity-squared (orifice) damping", None, coef_unit="N·s²/m²", compiled=_code("quadratic_damping"),
             lipschitz=lambda p: (0.0, inf), noun="quadratic damping", phrase=_quadratic_damping_words,
             slopes_within=lambda p, z, zd: (0.0, 2 * zd)),
        Kind("asymmetric_damping", "zdot", {"side": ("rebound", "rebound|compression")},
             lambda z, zd, side: _asym(zd, side), "extra damping on one side (rebound ≠ compression)", None,
             coef_unit="N·s/m",
             compiled=lambda p: (CODES["asymmetric_rebound" if p["side"] == "rebound" else "asymmetric_compression"],
                                 0.0, 0.0), noun="asymmetric damping", fixed={"side": "rebound"}, mirror=True,
             phrase=lambda th, p, static: f"extra damping in {p['side']}"),
    ]
    return {k.name: k for k in ks}


KINDS: Mapping[str, Kind] = MappingProxyType(_kinds())
#: every kind by attribute (``LIBRARY.bump_stop``): how code outside this package names a particular kind as data (a
#: simulator's preset, a fleet's truth) without a string a renamed kind would leave behind
LIBRARY = SimpleNamespace(**KINDS)
#: the kinds characterize and the loop try when none are named (``Kind.searched``; saturation and
#: velocity_saturation are exact equivalents of clearance and velocity_deadzone, named as such)
DEFAULT_KINDS: tuple[str, ...] = tuple(name for name, k in KINDS.items() if k.searched)
ALIASES: Mapping[str, str] = MappingProxyType({
    "deadzone": "clearance", "piecewise_linear_stiffness": "clearance", "piecewise_linear": "clearance",
    "piecewise_linear_damping": "velocity_deadzone", "knee": "velocity_deadzone", "deadzone_velocity": "velocity_deadzone",
    "friction": "coulomb", "play": "backlash", "cubic": "cubic_stiffness", "hysteresis": "backlash",
})


def kind(name: str) -> Kind:
    """Look a kind up by name or alias; raise :class:`ConfigError` listing the kinds otherwise."""
    key = ALIASES.get(name, name)
    try:
        return KINDS[key]
    except KeyError:
        raise ConfigError(f"unknown nonlinearity kind {name!r}",
                          hint=f"use one of {', '.join(KINDS)}") from None


def linear_twin(reach_m: float) -> Term:
    """A term whose remainder is z itself over the motion (a saturation 100 times beyond the peak |z| ``reach_m``):
    through a feedback path it adds only linear flexibility — what a path candidate must beat."""
    return Term("saturation", {"limit": 100.0 * reach_m})


def path_slopes(terms) -> np.ndarray:
    """The large-amplitude slopes α_i of terms a feedback path may carry (``Kind.path_slopes``);
    :class:`ConfigError` for a kind without a bounded remainder, or no terms."""
    paths = {n: KINDS[n].path_slopes[0] for n in sorted(KINDS) if KINDS[n].path_slopes is not None}
    bad = [t.kind for t in terms if t.kind not in paths]
    if bad or not terms:
        raise ConfigError(f"feedback paths need terms with a bounded remainder ({', '.join(paths)}); "
                          f"got {', '.join(bad) or 'no terms'}", hint="declare backlash, clearance or saturation terms")
    return np.array([paths[t.kind] for t in terms])


@dataclass(frozen=True)
class Term:
    """A describing function: a kind with its parameters fixed. ``g = term.evaluate(z, zdot)``."""

    kind: str
    params: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        k = kind(self.kind)
        object.__setattr__(self, "kind", k.name)
        object.__setattr__(self, "params", MappingProxyType(k.check(dict(self.params))))

    @property
    def spec(self) -> Kind:
        return KINDS[self.kind]

    @property
    def variable(self) -> Variable:
        return self.spec.variable

    @property
    def label(self) -> str:
        p = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in self.params.items())
        return f"{self.kind}({p})" if p else self.kind

    def evaluate(self, z: np.ndarray, zdot: np.ndarray) -> np.ndarray:
        """g(z, ż) sample by sample (hysteretic kinds run through the samples in order)."""
        z = np.asarray(z, dtype=float)
        zdot = np.asarray(zdot, dtype=float)
        return np.asarray(self.spec.func(z, zdot, **self.params), dtype=float)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "params": dict(self.params)}


def make_term(spec: Mapping | str) -> Term:
    """A :class:`Term` from ``"coulomb"`` or ``{"kind": "clearance", "params": {"gap": 4e-4}}``
    or the short form ``{"clearance": {"gap": 4e-4}}``."""
    if isinstance(spec, str):
        return Term(spec)
    if isinstance(spec, Term):
        return spec
    if not isinstance(spec, Mapping):
        raise ConfigError(f"a nonlinearity must be a name or a mapping, got {spec!r}")
    if "kind" in spec:
        extra = set(spec) - {"kind", "params", "coefficient", "name", "note"}
        if extra:
            raise ConfigError(f"nonlinearity {spec.get('kind')!r} has unknown field(s) {sorted(extra)}",
                              hint="use kind: and params:")
        return Term(str(spec["kind"]), dict(spec.get("params") or {}))
    if len(spec) == 1:
        (name, params), = spec.items()
        return Term(str(name), dict(params or {}))
    raise ConfigError(f"cannot read nonlinearity {dict(spec)!r}", hint="write {kind: NAME, params: {...}}")


def evaluate_terms(terms: list[Term], z: np.ndarray, zdot: np.ndarray) -> np.ndarray:
    """All describing functions at once: array of shape (len(terms), n)."""
    out = np.empty((len(terms), np.size(z)))
    for i, t in enumerate(terms):
        out[i] = t.evaluate(z, zdot)
    return out
