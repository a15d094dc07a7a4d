"""The nonlinear quarter-car simulator (paper Eq. 1-2, docs/method.md §1 and §6).

Equations of motion (signs as in :mod:`nifo_core.simulate.vehicle`), z = x2 - x1::

    M2·ẍ2 = -K2·z - C2·ż - K3·x2 - N1                         (paper Eq. 2)
    M1·ẍ1 =  K2·z + C2·ż + N1 + Ftire
    Ftire = K1·(xb - x1) + C1·(ẋb - ẋ1)     (dynamic part; with lift-off ≥ -(M1+M2)·g)
    N1    = Σ c_i · g_i(z, ż)                (g_i from :mod:`nifo_core.kinds.describing`)

x1, x2 are measured from static equilibrium, so gravity drops out except in
the lift-off limit: the total tire force (static load plus dynamic part) can
pull no wheel down, i.e. the dynamic part is clamped at -static load.

How it runs: the road (:mod:`nifo_core.simulate.road`) is generated at twice the
integration rate ``fs·oversample`` (RK4 needs it at half steps); a compiled
fixed-step RK4 integrates the motion with the strut forces evaluated by kind
code (the backlash play state is committed once per step, at the step's start,
exactly as :func:`describing.play_operator` does per sample); accelerations
and road are anti-aliased and decimated to ``fs`` with one zero-phase FIR
(:func:`decimate`); a warm-up is discarded; sensor noise is
added. Same seed, same bits.

The truth states (x1, x2, z, ż, N1, Ftire) are the integrator's exact states
at the recorded instants (not filtered), so ``Σ c_i·Term.evaluate(z, ż)`` on
them reproduces ``strut_force_n`` (exactly with ``oversample=1``; with
oversampling a backlash term may differ by the extremum missed between
samples).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from types import MappingProxyType
from typing import Callable, Mapping

import numba
import numpy as np
from scipy import fft as sfft
from scipy import signal

from .. import __version__
from ..kinds.describing import LIBRARY as K, Kind, Term, make_term
from ..errors import ConfigError
from ..signal.record import Record
from .road import ChirpRoad, RandomRoad, Road, road_from_dict, road_signal
from ..kinds.strut_forces import slopes_within, strut_arrays
from ..kinds.strut_forces import strut_force as _strut_force
from .vehicle import QuarterCar

__all__ = ["StrutForce", "RandomRoad", "ChirpRoad", "SensorNoise", "SimConfig", "Simulation", "Truth",
           "simulate", "preset", "PRESETS", "decimate", "antialias_taps"]

#: seconds simulated before the record starts (the input fades in over the first FADE_S)
WARMUP_S = 8.0
FADE_S = 3.0
#: seconds simulated after the record ends, so the decimation filter sees no edge
TAIL_S = 0.5
#: the anti-aliasing filter passes up to this fraction of the record's Nyquist frequency
PASSBAND_FRACTION = 0.8
STOPBAND_DB = 100.0
#: largest number of integration steps one call may take (peak memory ≈ 120 B per step)
MAX_STEPS = 12_000_000
#: default record length for a random road [s]
DEFAULT_DURATION_S = 300.0


# --------------------------------------------------------------------------------------------
# configuration
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StrutForce:
    """A strut nonlinearity: force ``coefficient · term.evaluate(z, ż)`` [N] added to the linear strut.

    Parameters
    ----------
    term : describing.Term
        The basis function g (kind and parameters).
    coefficient : float
        c, in N per unit of g (N/m for stiffness kinds, N·s/m for damping kinds,
        N for ``coulomb``; see ``Term.spec.coef_unit``).
    """

    term: Term
    coefficient: float

    def __post_init__(self) -> None:
        if not isinstance(self.term, Term):
            object.__setattr__(self, "term", make_term(self.term))
        c = float(self.coefficient)
        if not np.isfinite(c):
            raise ConfigError(f"strut force {self.term.label}: coefficient {self.coefficient!r} must be finite")
        object.__setattr__(self, "coefficient", c)

    def evaluate(self, z: np.ndarray, zdot: np.ndarray) -> np.ndarray:
        """The force c·g(z, ż) [N] along a motion (library evaluation)."""
        return self.coefficient * self.term.evaluate(z, zdot)

    @property
    def label(self) -> str:
        return f"{self.coefficient:g}·{self.term.label}"

    def to_dict(self) -> dict:
        return {**self.term.to_dict(), "coefficient": self.coefficient}

    @classmethod
    def from_dict(cls, d: Mapping) -> "StrutForce":
        if "coefficient" not in d:
            raise ConfigError(f"strut force {dict(d)!r} has no coefficient", hint="add coefficient: C [N per unit of g]")
        return cls(make_term({k: v for k, v in d.items() if k != "coefficient"}), d["coefficient"])


@dataclass(frozen=True)
class SensorNoise:
    """White sensor noise added to each recorded channel after decimation.

    Parameters
    ----------
    relative : float
        Noise standard deviation as a fraction of the channel's RMS (all three channels).
    absolute_m_s2 : float
        Further noise standard deviation [m/s²] on the two accelerations.
    """

    relative: float = 0.0
    absolute_m_s2: float = 0.0

    def __post_init__(self) -> None:
        for name in ("relative", "absolute_m_s2"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise ConfigError(f"sensor noise {name}={getattr(self, name)!r} must be finite and non-negative",
                                  hint="e.g. relative=0.02 for 2 % noise")
            object.__setattr__(self, name, v)

    @property
    def off(self) -> bool:
        return self.relative == 0 and self.absolute_m_s2 == 0

    def to_dict(self) -> dict:
        return {"relative": self.relative, "absolute_m_s2": self.absolute_m_s2}


@dataclass(frozen=True)
class SimConfig:
    """Everything that defines a simulation (frozen and validated).

    Parameters
    ----------
    vehicle : QuarterCar
        Linear parameters (the truth a nonlinear identification is scored against).
    strut : tuple of StrutForce
        Nonlinear strut forces N1 = Σ c_i·g_i (empty: linear). See :func:`preset`.
    tire_lift_off : bool
        Clamp the dynamic tire force at -static load (the wheel leaves the road).
    road : RandomRoad or ChirpRoad
        Tire-patch input.
    duration_s : float or None
        Recorded length [s]; None: 300 s for a random road, the sweep time for a chirp.
    fs_hz : float
        Record sample rate [Hz].
    oversample : int
        Integration rate = ``fs_hz · oversample``.
    noise : SensorNoise
        Sensor noise on the recorded channels.
    """

    vehicle: QuarterCar = field(default_factory=QuarterCar)
    strut: tuple[StrutForce, ...] = ()
    tire_lift_off: bool = False
    road: Road = field(default_factory=lambda: RandomRoad(0.0025))
    duration_s: float | None = None
    fs_hz: float = 600.0
    oversample: int = 10
    noise: SensorNoise = field(default_factory=SensorNoise)

    def __post_init__(self) -> None:
        _check_types(self)
        object.__setattr__(self, "strut", tuple(self.strut))
        object.__setattr__(self, "tire_lift_off", bool(self.tire_lift_off))
        _check_rates(self)
        _check_step(self)

    @property
    def duration(self) -> float:
        """Recorded length [s] (``duration_s`` resolved)."""
        if self.duration_s is not None:
            return float(self.duration_s)
        return self.road.sweep_s if isinstance(self.road, ChirpRoad) else DEFAULT_DURATION_S

    @property
    def n_samples(self) -> int:
        """Recorded samples."""
        return int(round(self.duration * self.fs_hz))

    @property
    def integration_hz(self) -> float:
        return self.fs_hz * self.oversample

    def to_dict(self) -> dict:
        return {"vehicle": self.vehicle.to_dict(), "strut": [s.to_dict() for s in self.strut],
                "tire_lift_off": self.tire_lift_off, "road": self.road.to_dict(),
                "duration_s": self.duration, "fs_hz": float(self.fs_hz), "oversample": self.oversample,
                "noise": self.noise.to_dict()}

    @classmethod
    def from_dict(cls, d: Mapping) -> "SimConfig":
        """Inverse of :meth:`to_dict` (also reads the ``config`` of a truth file)."""
        d = dict(d)
        try:
            return cls(vehicle=QuarterCar(**d.pop("vehicle", {})),
                       strut=tuple(StrutForce.from_dict(s) for s in d.pop("strut", ())),
                       road=road_from_dict(d.pop("road")) if "road" in d else RandomRoad(0.0025),
                       noise=SensorNoise(**d.pop("noise", {})), **d)
        except TypeError as err:
            raise ConfigError(f"cannot read simulation config: {err}") from None


def _check_types(cfg: SimConfig) -> None:
    if not isinstance(cfg.vehicle, QuarterCar):
        raise ConfigError(f"vehicle must be a QuarterCar, got {type(cfg.vehicle).__name__}")
    if not isinstance(cfg.road, (RandomRoad, ChirpRoad)):
        raise ConfigError(f"road must be a RandomRoad or ChirpRoad, got {type(cfg.road).__name__}")
    if not isinstance(cfg.noise, SensorNoise):
        raise ConfigError(f"noise must be a SensorNoise, got {type(cfg.noise).__name__}")
    bad = [s for s in cfg.strut if not isinstance(s, StrutForce)]
    if bad:
        raise ConfigError(f"strut must hold StrutForce items, got {bad[0]!r}",
                          hint="use StrutForce(Term(kind, params), coefficient) or preset(name)")


def _check_rates(cfg: SimConfig) -> None:
    fs = float(cfg.fs_hz)
    if not np.isfinite(fs) or fs <= 0:
        raise ConfigError(f"fs_hz={cfg.fs_hz!r} must be a positive sample rate [Hz]")
    q = cfg.oversample
    if isinstance(q, bool) or not isinstance(q, (int, np.integer)) or q < 1:
        raise ConfigError(f"oversample={q!r} must be a whole number ≥ 1", hint="e.g. 10")
    if cfg.duration_s is not None:
        d = float(cfg.duration_s)
        if not np.isfinite(d) or d <= 0:
            raise ConfigError(f"duration_s={cfg.duration_s!r} must be positive [s]")
    if cfg.n_samples < 1:
        raise ConfigError(f"duration {cfg.duration:g} s at {fs:g} Hz records no sample")
    top = cfg.road.top_hz
    usable = PASSBAND_FRACTION * fs / 2
    if top > usable:
        raise ConfigError(f"fs_hz={fs:g} is too low for a road with energy up to {top:g} Hz "
                          f"(the anti-aliasing filter passes up to {usable:g} Hz)",
                          hint=f"use fs_hz >= {top / PASSBAND_FRACTION * 2:g} or lower the road's upper frequency")
    steps = (cfg.duration + WARMUP_S + TAIL_S) * fs * q
    if steps > MAX_STEPS:
        raise ConfigError(f"{cfg.duration:g} s at {fs:g} Hz × {q} needs {steps:.3g} integration steps "
                          f"(limit {MAX_STEPS:.0e})", hint="simulate shorter records and concatenate, or lower oversample")


def _stiffest_rates(cfg: SimConfig) -> tuple[float, float]:
    """Upper bounds of the strut's stiffness [N/m] and damping [N·s/m] slopes, nonlinear terms included."""
    k, c = cfg.vehicle.k2, cfg.vehicle.c2
    for s in cfg.strut:
        # slopes up to |z| = 50 mm and |ż| = 2 m/s where g has no global bound (cubic, quadratic)
        lz, lzd = slopes_within(s.term, 0.05, 2.0)
        k += abs(s.coefficient) * lz
        c += abs(s.coefficient) * lzd
    return k, c


def _check_step(cfg: SimConfig) -> None:
    """RK4 is accurate for ω·h ≲ 0.3; refuse steps that are too coarse for the stiffest motion."""
    v = cfg.vehicle
    k, c = _stiffest_rates(cfg)
    w_hop = np.sqrt((v.k1 + k) / v.m1)
    rate = (v.c1 + c) * (1 / v.m1 + 1 / v.m2)
    h = 1.0 / cfg.integration_hz
    worst = max(w_hop * h, rate * h)
    if worst > 0.3:
        need = int(np.ceil(cfg.oversample * worst / 0.3))
        raise ConfigError(f"integration step 1/{cfg.integration_hz:g} s is too coarse for this vehicle/strut "
                          f"(ω·h = {worst:.2f} > 0.3)", hint=f"use oversample >= {need}, or smooth the strut forces")


# --------------------------------------------------------------------------------------------
# presets
# --------------------------------------------------------------------------------------------
def _sf(kind: Kind, coef: float, **params) -> StrutForce:
    return StrutForce(Term(kind.name, params), coef)


#: name -> (strut forces, description)
PRESETS: Mapping[str, tuple[tuple[StrutForce, ...], str]] = MappingProxyType({
    "linear": ((), "no strut nonlinearity: the linear QuarterCar"),
    "paper_deadzone": ((_sf(K.velocity_deadzone, -700.0, knee=0.03),),
                       "paper's velocity deadzone: damping drops from C2=1400 to 700 N·s/m above |ż| = 0.03 m/s"),
    "paper_backlash": ((_sf(K.backlash, 8e3, deadband=0.00043),),
                       "paper's backlash: 8 kN/m through a 0.43 mm play (hysteretic stiffness)"),
    "paper": ((_sf(K.backlash, 8e3, deadband=0.00043), _sf(K.velocity_deadzone, -700.0, knee=0.03)),
              "paper_backlash + paper_deadzone (the paper's strut)"),
    "digressive_damper": ((_sf(K.asymmetric_damping, 1400.0, side="rebound"),
                           _sf(K.velocity_deadzone, -840.0, knee=0.1),
                           _sf(K.coulomb, 50.0, eps=0.005)),
                          "realistic damper: rebound 2× compression below 0.1 m/s, 840 N·s/m less above "
                          "(blow-off), 50 N seal friction"),
    "friction": ((_sf(K.coulomb, 100.0, eps=0.005),), "100 N strut friction (tanh, eps 5 mm/s)"),
    K.bump_stop.name: ((_sf(K.bump_stop, 50e3, gap=0.008, side="compression"),),
                       "50 kN/m bump stop contacting 8 mm into compression"),
    "all": ((_sf(K.cubic_stiffness, 2e7),
             _sf(K.clearance, 5e3, gap=0.005),
             _sf(K.saturation, 4e3, limit=0.002),
             _sf(K.bump_stop, 50e3, gap=0.008, side="compression"),
             _sf(K.backlash, 8e3, deadband=0.00043),
             _sf(K.velocity_deadzone, -700.0, knee=0.1),
             _sf(K.velocity_saturation, 300.0, limit=0.05),
             _sf(K.coulomb, 80.0, eps=0.005),
             _sf(K.quadratic_damping, 500.0),
             _sf(K.asymmetric_damping, 1400.0, side="rebound")),
            "every kind on: cubic 2e7 N/m³, +5 kN/m beyond ±5 mm, 4 kN/m saturating at ±2 mm, "
            "50 kN/m bump stop at -8 mm, 8 kN/m backlash (0.43 mm), -700 N·s/m above 0.1 m/s, "
            "300 N·s/m saturating at 0.05 m/s, 80 N friction, 500 N·s²/m² quadratic, "
            "+1400 N·s/m in rebound"),
})


def preset(name: str) -> tuple[StrutForce, ...]:
    """Strut forces of a named preset (``PRESETS[name][1]`` describes each).

    ``linear``, ``paper_deadzone``, ``paper_backlash``, ``paper``,
    ``digressive_damper``, ``friction``, ``bump_stop``, ``all``.
    """
    try:
        return PRESETS[name][0]
    except KeyError:
        raise ConfigError(f"unknown preset {name!r}", hint=f"use one of {', '.join(PRESETS)}") from None


# --------------------------------------------------------------------------------------------
# the compiled integrator
# --------------------------------------------------------------------------------------------
# strut forces by kind code: one compiled definition, shared with the prediction engine


@numba.njit(cache=True)
def _forces(x1, x2, v1, v2, xb, xbd, par, codes, coef, p0, p1, play, commit):  # pragma: no cover
    """Accelerations ẍ1, ẍ2 [m/s²], N1 and the dynamic tire force [N], and whether the wheel lifts."""
    m1, m2, k1, c1, k2, c2, k3, w_static, lift = par[0], par[1], par[2], par[3], par[4], par[5], par[6], par[7], par[8]
    z = x2 - x1
    zd = v2 - v1
    n1 = _strut_force(z, zd, codes, coef, p0, p1, play, commit)
    strut = k2 * z + c2 * zd + n1
    ft = k1 * (xb - x1) + c1 * (xbd - v1)
    lifted = lift > 0 and ft < -w_static
    if lifted:
        ft = -w_static
    a1 = (strut + ft) / m1             # spindle, paper Eq. 1
    a2 = (-strut - k3 * x2) / m2       # body, paper Eq. 2
    return a1, a2, n1, ft, lifted


@numba.njit(cache=True)
def _run(state, play, par, codes, coef, p0, p1, xb, xbd, h, q, start, stop, rec_start, rec_stop,
         acc1, acc2, truth):  # pragma: no cover - compiled
    """Integrate samples ``start..stop-1`` with RK4 (road at half steps in xb[2i+1]).

    Records ẍ1, ẍ2 at every sample and, at every q-th, the truth row
    (x1, x2, ẋ1, ẋ2, N1, Ftire). Returns the number of samples in
    [rec_start, rec_stop) with the wheel lifted off. ``state``/``play`` carry over.
    """
    x1, x2, v1, v2 = state[0], state[1], state[2], state[3]
    n_lift = 0
    hh = 0.5 * h
    for i in range(start, stop):
        a1, a2, n1, ft, lifted = _forces(x1, x2, v1, v2, xb[2 * i], xbd[2 * i], par, codes, coef, p0, p1, play, True)
        acc1[i] = a1
        acc2[i] = a2
        if i % q == 0:
            j = i // q
            truth[j, 0], truth[j, 1], truth[j, 2], truth[j, 3], truth[j, 4], truth[j, 5] = x1, x2, v1, v2, n1, ft
        if lifted and rec_start <= i < rec_stop:
            n_lift += 1
        # RK4 stages (the play state stays committed at its value for x(t_i))
        b1, b2, _, _, _ = _forces(x1 + hh * v1, x2 + hh * v2, v1 + hh * a1, v2 + hh * a2,
                                  xb[2 * i + 1], xbd[2 * i + 1], par, codes, coef, p0, p1, play, False)
        u1, u2, w1, w2 = v1 + hh * a1, v2 + hh * a2, v1 + hh * b1, v2 + hh * b2
        c1_, c2_, _, _, _ = _forces(x1 + hh * u1, x2 + hh * u2, w1, w2,
                                    xb[2 * i + 1], xbd[2 * i + 1], par, codes, coef, p0, p1, play, False)
        s1, s2, r1, r2 = v1 + hh * b1, v2 + hh * b2, v1 + h * c1_, v2 + h * c2_
        d1, d2, _, _, _ = _forces(x1 + h * s1, x2 + h * s2, r1, r2,
                                  xb[2 * i + 2], xbd[2 * i + 2], par, codes, coef, p0, p1, play, False)
        x1 += h / 6 * (v1 + 2 * u1 + 2 * s1 + r1)
        x2 += h / 6 * (v2 + 2 * u2 + 2 * s2 + r2)
        v1 += h / 6 * (a1 + 2 * b1 + 2 * c1_ + d1)
        v2 += h / 6 * (a2 + 2 * b2 + 2 * c2_ + d2)
    state[0], state[1], state[2], state[3] = x1, x2, v1, v2
    return n_lift


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class Truth:
    """What the simulation really was: parameters, and noise-free states at the record's instants.

    Attributes
    ----------
    vehicle, strut, tire_lift_off, road, noise :
        The configuration simulated.
    fs_hz : float
        Sample rate of the state arrays [Hz] (that of the record).
    seed : int or None
        Seed of the random generator, when known.
    x1, x2 : ndarray
        Spindle and body displacement from static equilibrium [m].
    z, zdot : ndarray
        Relative displacement x2 - x1 [m] and velocity [m/s].
    xb : ndarray
        Tire-patch displacement [m] (noise-free).
    strut_force_n : ndarray
        Total nonlinear strut force N1 = Σ c_i·g_i [N].
    tire_force_n : ndarray
        Dynamic tire force [N] (≥ -static load with lift-off).
    lift_off_fraction : float
        Fraction of the recorded time with the wheel off the road.
    """

    vehicle: QuarterCar
    strut: tuple[StrutForce, ...]
    tire_lift_off: bool
    road: Road
    noise: SensorNoise
    fs_hz: float
    seed: int | None
    x1: np.ndarray
    x2: np.ndarray
    z: np.ndarray
    zdot: np.ndarray
    xb: np.ndarray
    strut_force_n: np.ndarray
    tire_force_n: np.ndarray
    lift_off_fraction: float

    def t21(self, freq_hz) -> np.ndarray:
        """True linear spindle→body transmissibility (:meth:`QuarterCar.t21`)."""
        return self.vehicle.t21(freq_hz)

    def h11(self, freq_hz) -> np.ndarray:
        """True linear spindle receptance [m/N] (:meth:`QuarterCar.h11`)."""
        return self.vehicle.h11(freq_hz)

    def t1b(self, freq_hz) -> np.ndarray:
        """True linear tire-patch→spindle transmissibility (:meth:`QuarterCar.t1b`)."""
        return self.vehicle.t1b(freq_hz)

    @property
    def terms(self) -> list[Term]:
        """The describing functions of the strut forces."""
        return [s.term for s in self.strut]

    def to_dict(self) -> dict:
        """JSON-able parameters (no arrays)."""
        return {"vehicle": self.vehicle.to_dict(), "strut": [s.to_dict() for s in self.strut],
                "tire_lift_off": self.tire_lift_off, "road": self.road.to_dict(), "noise": self.noise.to_dict(),
                "fs_hz": float(self.fs_hz), "seed": self.seed, "lift_off_fraction": float(self.lift_off_fraction),
                "natural_frequencies_hz": list(self.vehicle.natural_frequencies_hz()),
                "static_tire_load_n": self.vehicle.static_tire_load_n}


@dataclass(frozen=True, eq=False)
class Simulation:
    """A simulated record and the truth behind it."""

    record: Record
    truth: Truth
    config: SimConfig


# --------------------------------------------------------------------------------------------
# simulate
# --------------------------------------------------------------------------------------------
def _generator(rng) -> tuple[np.random.Generator, int | None]:
    if isinstance(rng, np.random.Generator):
        return rng, None
    if rng is None:
        seed = int(np.random.SeedSequence().entropy)  # fresh, but recorded: the run can be repeated
        return np.random.default_rng(seed), seed
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and rng >= 0:
        return np.random.default_rng(int(rng)), int(rng)
    raise ConfigError(f"rng={rng!r} must be a numpy Generator, a non-negative int seed or None")


def _strut_arrays(strut: tuple[StrutForce, ...]):
    return strut_arrays([s.term for s in strut], [s.coefficient for s in strut])


def _integrate(cfg: SimConfig, xb, xbd, n_steps: int, rec: tuple[int, int],
               progress: Callable[[float], None] | None):
    """Run the compiled RK4 in chunks (for progress); returns accelerations, truth rows, lift-off count."""
    v = cfg.vehicle
    par = np.array([v.m1, v.m2, v.k1, v.c1, v.k2, v.c2, v.k3, v.static_tire_load_n,
                    1.0 if cfg.tire_lift_off else 0.0])
    codes, coef, p0, p1 = _strut_arrays(cfg.strut)
    q = cfg.oversample
    acc1, acc2 = np.empty(n_steps), np.empty(n_steps)
    truth = np.empty(((n_steps - 1) // q + 1, 6))
    state, play = np.zeros(4), np.zeros(codes.size)
    chunk = max(q, int(30 * cfg.integration_hz))  # 30 s of simulated time per call
    n_lift = 0
    for a in range(0, n_steps, chunk):
        b = min(a + chunk, n_steps)
        n_lift += _run(state, play, par, codes, coef, p0, p1, xb, xbd, 1.0 / cfg.integration_hz, q, a, b,
                       rec[0], rec[1], acc1, acc2, truth)
        if progress is not None:
            progress(b / n_steps)
    return acc1, acc2, truth, n_lift


@lru_cache(maxsize=8)
def antialias_taps(q: int) -> np.ndarray:
    """Odd-length Kaiser FIR: flat (±1e-5) to PASSBAND_FRACTION of the new Nyquist, -100 dB from it."""
    width = (1 - PASSBAND_FRACTION) / q  # transition band, relative to the integration Nyquist
    n, beta = signal.kaiserord(STOPBAND_DB, width)
    taps = signal.firwin(n | 1, (1 + PASSBAND_FRACTION) / 2 / q, window=("kaiser", beta))
    taps.flags.writeable = False
    return taps


#: FFT length of :func:`decimate`'s and :func:`interpolate`'s blocks (measured on 0.96 M samples, q = 8: 12.5 ms at
#: 4096, 12.7-13.7 ms at 1024-16384)
PHASE_FFT = 4096


@lru_cache(maxsize=16)
def _phase_spectra(q: int, up: bool) -> tuple[np.ndarray, int, int]:
    """The anti-alias filter h (:func:`antialias_taps`, centre tap c) split into its q phases at the coarse rate, as
    spectra of :data:`PHASE_FFT` (q, 1, PHASE_FFT/2 + 1), with how many coarse samples the phases reach back and
    their length. Decimating, phase p holds h[n·q + c - p]: what input sample n·q + p gives the output; interpolating,
    q·h[n·q + c + p]: what input sample -n gives fine output p (resample_poly's gain q, for the zeros stuffed)."""
    h = antialias_taps(q)
    c = (h.size - 1) // 2
    sign, reach = (1, (c + q - 1) // q) if up else (-1, c // q)
    k = (h.size - 1 - c + (0 if up else q - 1)) // q + reach + 1
    g = np.zeros((q, k))
    for p in range(q):
        j = np.arange(-reach, k - reach) * q + c + sign * p
        ok = (j >= 0) & (j < h.size)
        g[p, ok] = (q if up else 1) * h[j[ok]]
    spec = sfft.rfft(g, PHASE_FFT, axis=-1)[:, None, :]
    spec.flags.writeable = False
    return spec, reach, k


def _overlap_add(y: np.ndarray, k: int, seg: int) -> np.ndarray:
    """Blocks (..., nb, PHASE_FFT) of a convolution with a k-tap filter, each from ``seg`` inputs, added into one
    signal (..., (nb + 1)·seg): each block's tail onto the next block's start."""
    lead, nb = y.shape[:-2], y.shape[-2]
    out = np.zeros(lead + ((nb + 1) * seg,))
    out[..., :nb * seg] = y[..., :seg].reshape(lead + (nb * seg,))
    tails = np.zeros(lead + (nb, seg))
    tails[..., :k - 1] = y[..., seg:]
    out[..., seg:] += tails.reshape(lead + (nb * seg,))
    return out


def decimate(x: np.ndarray, q: int) -> np.ndarray:
    """Anti-alias (zero-phase FIR, :func:`antialias_taps`) and keep every q-th sample: output k is at input k·q.

    The same numbers as ``scipy.signal.resample_poly(x, 1, q, window=taps)`` (zeros beyond the ends) to rounding,
    computed only at the kept samples: the signal's q phases (every q-th sample from p on) each convolved with the
    filter's matching phase at the coarse rate, their spectra summed before one inverse FFT, in overlap-added blocks
    of :data:`PHASE_FFT` (measured against the overlap-add convolution at the fine rate it replaces, q = 8, 515
    taps: 0.96 M samples 12.2 ms against 20.5 ms, five rows of them 67 ms against 120 ms, equal to 7e-16 of the
    peak; that one was 2.3× faster than the polyphase filter). The simulator and every model simulation
    (:mod:`nifo_core.predict.timesim`: the loop's and the refinement's hundreds, the sensitivity march's columns as
    rows) decimate through it. ``x``: one signal, or one per row (the last axis is time).
    """
    x = np.asarray(x, float)
    if q == 1:
        return np.array(x, float)
    n, rows = x.shape[-1], x.shape[:-1]
    m = -(-n // q)                                  # the kept samples
    spec, lead, k = _phase_spectra(q, False)
    seg = PHASE_FFT - k + 1                         # coarse samples per block
    nb = -(-(m + lead) // seg)
    fine = np.zeros(rows + (nb * seg * q,))
    fine[..., :n] = x
    phases = np.swapaxes(fine.reshape(rows + (nb * seg, q)), -1, -2).reshape(rows + (q, nb, seg))
    y = sfft.irfft((sfft.rfft(phases, PHASE_FFT, axis=-1) * spec).sum(axis=-3), PHASE_FFT, axis=-1)
    return np.ascontiguousarray(_overlap_add(y, k, seg)[..., lead:lead + m])


def interpolate(x: np.ndarray, q: int) -> np.ndarray:
    """``x`` (one signal) at q times its rate, band-limited by the same zero-phase FIR as :func:`decimate`: fine sample
    k·q is at input k.

    The same numbers as ``scipy.signal.resample_poly(x, q, 1, window=taps)`` to rounding (1e-15 of the peak),
    without the stuffed zeros' products: one FFT of each block of ``x``, times each of the filter's q phases, q inverse
    FFTs, interleaved (measured, 120 000 samples to q = 8: 8.1 ms against 24.4 ms). Every model simulation
    interpolates its input through it (:mod:`nifo_core.predict.timesim`).
    """
    x = np.asarray(x, float)
    if q == 1:
        return np.array(x, float)
    n = x.shape[-1]
    spec, lead, k = _phase_spectra(q, True)
    seg = PHASE_FFT - k + 1
    nb = -(-(n + lead) // seg)
    coarse = np.zeros(nb * seg)
    coarse[:n] = x
    y = sfft.irfft(sfft.rfft(coarse.reshape(nb, seg), PHASE_FFT, axis=-1)[None] * spec, PHASE_FFT, axis=-1)
    return np.ascontiguousarray(_overlap_add(y, k, seg)[:, lead:lead + n].T).reshape(n * q)


def _add_noise(x: np.ndarray, noise: SensorNoise, rng: np.random.Generator, *, absolute: float) -> np.ndarray:
    std = noise.relative * np.sqrt(np.mean(x**2)) + absolute
    return x + std * rng.standard_normal(x.size) if std > 0 else x


def _truth(cfg: SimConfig, seed: int | None, rows: np.ndarray, xb: np.ndarray, lift: float) -> Truth:
    """Truth from the integrator's rows (x1, x2, ẋ1, ẋ2, N1, Ftire) at the recorded instants."""
    return Truth(vehicle=cfg.vehicle, strut=cfg.strut, tire_lift_off=cfg.tire_lift_off, road=cfg.road,
                 noise=cfg.noise, fs_hz=float(cfg.fs_hz), seed=seed, x1=_frozen(rows[:, 0]), x2=_frozen(rows[:, 1]),
                 z=_frozen(rows[:, 1] - rows[:, 0]), zdot=_frozen(rows[:, 3] - rows[:, 2]), xb=_frozen(xb),
                 strut_force_n=_frozen(rows[:, 4]), tire_force_n=_frozen(rows[:, 5]), lift_off_fraction=lift)


def simulate(config: SimConfig, *, rng: np.random.Generator | int | None = None,
             progress: Callable[[float], None] | None = None) -> Simulation:
    """Simulate the quarter car on a road and return the record with its truth.

    Parameters
    ----------
    config : SimConfig
        Vehicle, strut forces, road, lengths and rates, noise.
    rng : numpy.random.Generator, int or None
        Randomness (road and noise). An int is a seed (recorded in the record's
        meta and the truth); None draws a fresh seed and records it too.
    progress : callable, optional
        Called with the fraction done (0-1] during the integration.

    Returns
    -------
    Simulation
        ``record`` (spindle/body accelerations [m/s²], tire-patch displacement
        [m] at ``fs_hz``, source "simulator") and ``truth``.
    """
    if not isinstance(config, SimConfig):
        raise ConfigError(f"simulate needs a SimConfig, got {type(config).__name__}")
    gen, seed = _generator(rng)
    q, fs = config.oversample, float(config.fs_hz)
    n_warm, n_rec, n_tail = int(round(WARMUP_S * fs)), config.n_samples, int(round(TAIL_S * fs))
    n_steps = (n_warm + n_rec + n_tail) * q
    rec = (n_warm * q, (n_warm + n_rec) * q)
    xb, xbd = road_signal(config.road, fs_hz=2 * config.integration_hz, n=2 * n_steps + 1,
                          warmup_s=WARMUP_S, fade_s=FADE_S, rng=gen)
    acc1, acc2, truth_rows, n_lift = _integrate(config, xb, xbd, n_steps, rec, progress)
    keep = slice(n_warm, n_warm + n_rec)
    chans = [decimate(x, q)[keep] for x in (acc1, acc2, xb[: 2 * n_steps: 2])]
    noisy = [_add_noise(chans[0], config.noise, gen, absolute=config.noise.absolute_m_s2),
             _add_noise(chans[1], config.noise, gen, absolute=config.noise.absolute_m_s2),
             _add_noise(chans[2], config.noise, gen, absolute=0.0)]
    truth = _truth(config, seed, truth_rows[keep], xb[: 2 * n_steps: 2 * q][keep], n_lift / (n_rec * q))
    meta = {"simulator": {"config": config.to_dict(), "seed": seed, "nifo_version": __version__,
                          "warmup_s": WARMUP_S, "truth": truth.to_dict()}}
    record = Record(fs, noisy[0], noisy[1], noisy[2], source="simulator", meta=meta)
    return Simulation(record=record, truth=truth, config=config)
