"""A second quarter-car simulator, written apart from :mod:`nifo_core.simulate.quarter_car` (issue 54).

Nothing of the first simulator is used: not its strut forces (of :mod:`nifo_core.kinds` only the kinds' names), not
its road (:mod:`nifo_core.simulate.road`), not its integrator or its anti-aliasing. What the estimators are checked on
then rests on two discretisations, two force codes and two road generators:

==================  ==============================================  ==============================================
                    :mod:`~nifo_core.simulate.quarter_car`           this module
==================  ==============================================  ==============================================
integrator          fixed-step RK4 at ``fs·oversample``              adaptive Dormand–Prince 5(4) with error control,
                                                                     steps landing on a grid of 4·fs
strut forces        the describing functions' numba code             written here, in physical words
play (backlash)     committed once per step                          a slider moved to the window's edge at each
                                                                     accepted (adaptive) step's end
friction            tanh(ż/eps)                                      ż/√(ż² + v_s²)
road                FFT-shaped Gaussian noise, flat or ∝ f⁻²         harmonic superposition, PSD ∝ f^-w
                                                                     (w: waviness) between two edges
anti-aliasing       Kaiser FIR, overlap-add                          Hamming FIR, polyphase (scipy ``decimate``)
sensors             white noise                                      white noise and a constant bias per channel
==================  ==============================================  ==============================================

Equations (paper Eq. 1-2; x1, x2 from static equilibrium, z = x2 - x1)::

    M2·ẍ2 = -K2·z - C2·ż - N(z, ż, s)
    M1·ẍ1 =  K2·z + C2·ż + N(z, ż, s) + F_t,    F_t = K1·(xb - x1) + C1·(ẋb - ẋ1)  (≥ -(M1+M2)·g with lift-off)

with N the sum of the strut's :class:`Element` forces. The elements' vocabulary is the library's kind names, so
that a fleet's truth can be compared with what nifo names, with the coefficient and parameter meaning the same
physical quantity (a knee's damping change beyond the knee velocity, a friction's force, a stop's stiffness beyond
its gap from static equilibrium, a play's stiffness and total width...).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Mapping

import numba
import numpy as np
from scipy import signal

from ..errors import ConfigError
from ..kinds.describing import LIBRARY as K
from ..signal.record import Record

__all__ = ["Corner", "Element", "HarmonicRoad", "Sensors", "IndependentConfig", "IndependentRun",
           "SimulationStoppedError", "simulate_independent", "ELEMENT_KINDS"]

G = 9.80665
#: the output grid of the integrator, a multiple of the record's rate; the record is decimated from it
GRID_FACTOR = 4
#: simulated before the record (the road fades in over the first FADE_S) and after it (the decimation's edge) [s]
WARMUP_S, FADE_S, TAIL_S = 12.0, 4.0, 1.0
#: a relative displacement no strut travels [m]: beyond it the quarter car has diverged (e.g. an even stiffness
#: whose total spring K2 + 2·k_q·z turns negative past z = -K2/(2·k_q): the strut collapses in finite time)
Z_MAX_M = 0.5
#: the integrator's budget of steps (accepted and rejected) per output instant (4·fs); a converging record takes
#: about one, a stop or a play's kink a few more
MAX_STEPS_PER_OUTPUT = 50
#: why the integrator stopped (its status 1, 2, 3)
STOPS = {1: f"the strut's travel |z| passed {Z_MAX_M:g} m: the quarter car diverged",
         2: "the step size fell below 1e-9 of the output interval: the equations are too stiff (or singular) here",
         3: f"the integrator used its budget of {MAX_STEPS_PER_OUTPUT} steps per output instant"}


class SimulationStoppedError(ArithmeticError):
    """The integrator could not carry the record to its end (:data:`STOPS`): the quarter car diverged or its
    equations are too stiff for the step control. Nothing of the record is returned."""

#: element kind → (code, what its value is, its parameter's meaning)
ELEMENT_KINDS: Mapping[str, tuple[int, str, str]] = {
    K.velocity_deadzone.name: (0, "change of damping beyond the knee [N·s/m]", "knee velocity [m/s]"),
    K.quadratic_damping.name: (1, "orifice coefficient [N·s²/m²]", "—"),
    K.coulomb.name: (2, "friction force [N]", "regularising velocity v_s [m/s]"),
    K.asymmetric_damping.name: (3, "extra damping on one side [N·s/m]", "side: +1 rebound, -1 compression"),
    K.cubic_stiffness.name: (4, "cubic stiffness [N/m³]", "—"),
    K.quadratic_stiffness.name: (5, "even (quadratic) stiffness [N/m²]", "—"),
    K.clearance.name: (6, "stiffness beyond ±gap [N/m]", "gap [m]"),
    K.bump_stop.name: (7, "contact stiffness [N/m]",
                       "gap from static equilibrium [m]; side -1 compression, +1 rebound"),
    K.backlash.name: (8, "stiffness through the play [N/m]", "total width of the play [m]"),
}


@dataclass(frozen=True)
class Corner:
    """One corner's linear parameters [SI]."""

    m1: float = 40.0
    m2: float = 300.0
    k1: float = 250e3
    c1: float = 200.0
    k2: float = 22e3
    c2: float = 1400.0

    def __post_init__(self) -> None:
        for k, v in asdict(self).items():
            if not (np.isfinite(v) and v >= 0) or (k in ("m1", "m2", "k1", "k2") and v == 0):
                raise ConfigError(f"corner parameter {k}={v!r} must be finite and positive")

    def frequencies_hz(self) -> tuple[float, float]:
        """Undamped body bounce and wheel hop [Hz]."""
        m = np.diag([self.m1, self.m2])
        k = np.array([[self.k1 + self.k2, -self.k2], [-self.k2, self.k2]])
        w = np.sort(np.sqrt(np.linalg.eigvals(np.linalg.solve(m, k)).real))
        return float(w[0] / 2 / np.pi), float(w[1] / 2 / np.pi)


@dataclass(frozen=True)
class Element:
    """One strut element: ``kind`` (a key of :data:`ELEMENT_KINDS`), its ``value`` and its parameter(s)."""

    kind: str
    value: float
    param: float = 0.0
    side: int = 0

    def __post_init__(self) -> None:
        if self.kind not in ELEMENT_KINDS:
            raise ConfigError(f"unknown strut element {self.kind!r}", hint=f"use one of {', '.join(ELEMENT_KINDS)}")
        if not np.isfinite(self.value) or not np.isfinite(self.param):
            raise ConfigError(f"strut element {self.kind}: value and parameter must be finite")
        if self.kind in (K.velocity_deadzone.name, K.clearance.name, K.bump_stop.name, K.backlash.name,
                         K.coulomb.name) and not self.param > 0:
            raise ConfigError(f"strut element {self.kind} needs a positive parameter "
                              f"({ELEMENT_KINDS[self.kind][2]})")
        if self.kind in (K.asymmetric_damping.name, K.bump_stop.name) and self.side not in (-1, 1):
            raise ConfigError(f"strut element {self.kind} needs side=+1 (rebound) or -1 (compression)")

    def force(self, z: np.ndarray, zd: np.ndarray, slider: np.ndarray | None = None) -> np.ndarray:
        """The element's force on the motion [N] (numpy; the integrator has its own compiled copy)."""
        z, zd = np.asarray(z, float), np.asarray(zd, float)
        k, c, p = self.kind, self.value, self.param
        if k == K.velocity_deadzone.name:
            return c * np.where(np.abs(zd) > p, zd - p * np.sign(zd), 0.0)
        if k == K.quadratic_damping.name:
            return c * zd * np.abs(zd)
        if k == K.coulomb.name:
            return c * zd / np.sqrt(zd * zd + p * p)
        if k == K.asymmetric_damping.name:
            return c * (np.maximum(zd, 0.0) if self.side > 0 else np.minimum(zd, 0.0))
        if k == K.cubic_stiffness.name:
            return c * z ** 3
        if k == K.quadratic_stiffness.name:
            return c * z * z
        if k == K.clearance.name:
            return c * np.where(np.abs(z) > p, z - p * np.sign(z), 0.0)
        if k == K.bump_stop.name:
            return c * (np.maximum(z - p, 0.0) if self.side > 0 else np.minimum(z + p, 0.0))
        if slider is None:
            raise ConfigError("a play's force needs its slider state")
        return c * np.asarray(slider, float)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "value": self.value, "param": self.param, "side": self.side}


@dataclass(frozen=True)
class HarmonicRoad:
    """A random road as a sum of ``n`` cosines at random frequencies (harmonic superposition).

    Displacement PSD ∝ f^-``waviness`` between ``f_lo_hz`` and ``f_hi_hz`` (ISO 8608 at constant speed for
    waviness 2), with half-cosine tapers over an octave below and a quarter octave above; scaled to ``rms_m``.
    """

    rms_m: float
    f_lo_hz: float = 0.5
    f_hi_hz: float = 40.0
    waviness: float = 2.0
    n: int = 600

    def __post_init__(self) -> None:
        if not (0 < self.rms_m < 0.1):
            raise ConfigError(f"road RMS {self.rms_m!r} m must be in (0, 0.1)")
        if not (0 < self.f_lo_hz < self.f_hi_hz):
            raise ConfigError(f"road band {self.f_lo_hz!r}-{self.f_hi_hz!r} Hz must satisfy 0 < lo < hi")
        if not (0 <= self.waviness <= 4) or self.n < 16:
            raise ConfigError("road waviness must be in [0, 4] and n at least 16")

    def harmonics(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(frequencies [Hz], amplitudes [m], phases [rad]): log-spaced bins, one jittered line per bin."""
        lo, hi = 0.5 * self.f_lo_hz, 1.19 * self.f_hi_hz
        edges = np.geomspace(lo, hi, self.n + 1)
        f = edges[:-1] + rng.random(self.n) * np.diff(edges)
        psd = f ** -self.waviness
        taper = np.ones_like(f)
        low = f < self.f_lo_hz
        taper[low] = 0.5 - 0.5 * np.cos(np.pi * np.log(f[low] / lo) / np.log(self.f_lo_hz / lo))
        high = f > self.f_hi_hz
        taper[high] = 0.5 + 0.5 * np.cos(np.pi * np.log(f[high] / self.f_hi_hz) / np.log(hi / self.f_hi_hz))
        amp = np.sqrt(2 * psd * taper ** 2 * np.diff(edges))
        amp *= self.rms_m / np.sqrt(0.5 * np.sum(amp ** 2))
        return f, amp, 2 * np.pi * rng.random(self.n)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Sensors:
    """Accelerometer errors: white noise (fraction of each channel's RMS) and a constant bias [m/s²] per channel."""

    noise_spindle: float = 0.0
    noise_body: float = 0.0
    bias_spindle_m_s2: float = 0.0
    bias_body_m_s2: float = 0.0

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class IndependentConfig:
    """Everything one record of :func:`simulate_independent` depends on (with the seed)."""

    corner: Corner = field(default_factory=Corner)
    elements: tuple[Element, ...] = ()
    road: HarmonicRoad = field(default_factory=lambda: HarmonicRoad(0.0025))
    duration_s: float = 300.0
    fs_hz: float = 600.0
    sensors: Sensors = field(default_factory=Sensors)
    lift_off: bool = False
    rtol: float = 1e-7

    def __post_init__(self) -> None:
        object.__setattr__(self, "elements", tuple(self.elements))
        if not (self.duration_s > 0 and self.fs_hz > 0):
            raise ConfigError("duration_s and fs_hz must be positive")
        if self.road.f_hi_hz * 1.19 > 0.4 * self.fs_hz:
            raise ConfigError(f"fs_hz={self.fs_hz:g} is too low for a road up to {self.road.f_hi_hz:g} Hz")

    def to_dict(self) -> dict:
        return {"corner": asdict(self.corner), "elements": [e.to_dict() for e in self.elements],
                "road": self.road.to_dict(), "duration_s": self.duration_s, "fs_hz": self.fs_hz,
                "sensors": self.sensors.to_dict(), "lift_off": self.lift_off, "rtol": self.rtol,
                "simulator": "nifo_core.simulate.independent (Dormand-Prince 5(4), adaptive)"}


# --------------------------------------------------------------------------------------------
# the compiled integrator
# --------------------------------------------------------------------------------------------
@numba.njit(cache=True)
def _road_at(t, t0, h, xg, vg):  # pragma: no cover - compiled
    """Cubic Hermite interpolation of the road (xb, ẋb known on a grid of step h from t0)."""
    u = (t - t0) / h
    i = int(np.floor(u))
    if i < 0:
        return xg[0], vg[0]
    if i >= xg.size - 1:
        return xg[-1], vg[-1]
    s = u - i
    x0, x1, d0, d1 = xg[i], xg[i + 1], vg[i] * h, vg[i + 1] * h
    s2, s3 = s * s, s * s * s
    x = (2 * s3 - 3 * s2 + 1) * x0 + (s3 - 2 * s2 + s) * d0 + (-2 * s3 + 3 * s2) * x1 + (s3 - s2) * d1
    dx = ((6 * s2 - 6 * s) * x0 + (3 * s2 - 4 * s + 1) * d0 + (-6 * s2 + 6 * s) * x1 + (3 * s2 - 2 * s) * d1) / h
    return x, dx


@numba.njit(cache=True)
def _strut(z, zd, y, codes, vals, pars, sides):  # pragma: no cover - compiled
    """Σ element forces [N]; play sliders are y[4 + j] for the j-th play element (in order)."""
    n = 0.0
    j = 0
    for i in range(codes.size):
        c, v, p = codes[i], vals[i], pars[i]
        if c == 0:
            a = abs(zd)
            if a > p:
                n += v * (zd - p * (1.0 if zd > 0 else -1.0))
        elif c == 1:
            n += v * zd * abs(zd)
        elif c == 2:
            n += v * zd / np.sqrt(zd * zd + p * p)
        elif c == 3:
            if sides[i] > 0:
                if zd > 0:
                    n += v * zd
            elif zd < 0:
                n += v * zd
        elif c == 4:
            n += v * z * z * z
        elif c == 5:
            n += v * z * z
        elif c == 6:
            if z > p:
                n += v * (z - p)
            elif z < -p:
                n += v * (z + p)
        elif c == 7:
            if sides[i] > 0:
                if z > p:
                    n += v * (z - p)
            elif z < -p:
                n += v * (z + p)
        else:   # a play: the slider held at y[4 + j] until the window's edge reaches it
            half = 0.5 * p
            sl = y[4 + j]
            if sl < z - half:
                sl = z - half
            elif sl > z + half:
                sl = z + half
            n += v * sl
            j += 1
    return n


@numba.njit(cache=True)
def _rhs(t, y, dy, par, codes, vals, pars, sides, t0, h, xg, vg):  # pragma: no cover - compiled
    """dy/dt for y = [x1, x2, v1, v2, sliders...] (a slider's rate is 0: it is moved between steps); returns
    (a1, a2)."""
    m1, m2, k1, c1, k2, c2, wst, lift = par[0], par[1], par[2], par[3], par[4], par[5], par[6], par[7]
    x1, x2, v1, v2 = y[0], y[1], y[2], y[3]
    z, zd = x2 - x1, v2 - v1
    n = _strut(z, zd, y, codes, vals, pars, sides)
    xb, vb = _road_at(t, t0, h, xg, vg)
    ft = k1 * (xb - x1) + c1 * (vb - v1)
    if lift > 0 and ft < -wst:
        ft = -wst
    fs = k2 * z + c2 * zd + n
    a1 = (fs + ft) / m1
    a2 = -fs / m2
    dy[0], dy[1], dy[2], dy[3] = v1, v2, a1, a2
    for q in range(4, y.size):
        dy[q] = 0.0          # a slider moves only at an accepted step's end (``_dopri``)
    return a1, a2


@numba.njit(cache=True)
def _dopri(y, par, codes, vals, pars, sides, t0, h, xg, vg, t_start, dt_out, n_out, rtol, atol, z_max,
           max_steps, out):  # pragma: no cover - compiled
    """Dormand–Prince 5(4) with step control (Hairer, Nørsett & Wanner, *Solving ODEs I*, II.4-5), never
    stepping over an output instant. ``out[k] = (x1, x2, v1, v2, a1, a2, N)`` at t_start + k·dt_out.
    Returns (accepted steps, rejected steps, status, t): status 0 done; otherwise it stopped at t because
    :data:`STOPS` [status] (the rows of ``out`` from there on are not written)."""
    a21 = 1 / 5
    a31, a32 = 3 / 40, 9 / 40
    a41, a42, a43 = 44 / 45, -56 / 15, 32 / 9
    a51, a52, a53, a54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
    a61, a62, a63, a64, a65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
    b1, b3, b4, b5, b6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
    e1, e3, e4, e5, e6, e7 = 71 / 57600, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40
    c2_, c3_, c4_, c5_ = 1 / 5, 3 / 10, 4 / 5, 8 / 9
    m = y.size
    k1 = np.empty(m)
    k2 = np.empty(m)
    k3 = np.empty(m)
    k4 = np.empty(m)
    k5 = np.empty(m)
    k6 = np.empty(m)
    k7 = np.empty(m)
    yt = np.empty(m)
    yn = np.empty(m)
    t = t_start
    a1, a2 = _rhs(t, y, k1, par, codes, vals, pars, sides, t0, h, xg, vg)
    out[0, 0], out[0, 1], out[0, 2], out[0, 3], out[0, 4], out[0, 5] = y[0], y[1], y[2], y[3], a1, a2
    out[0, 6] = _strut(y[1] - y[0], y[3] - y[2], y, codes, vals, pars, sides)
    step = 0.25 * dt_out
    n_acc = 0
    n_rej = 0
    for k in range(1, n_out):
        t_end = t_start + k * dt_out
        while t < t_end - 1e-12 * dt_out:
            if n_acc + n_rej >= max_steps:
                return n_acc, n_rej, 3, t
            if not step > 1e-9 * dt_out:       # False for NaN too
                return n_acc, n_rej, 2, t
            hs = min(step, t_end - t)
            for q in range(m):
                yt[q] = y[q] + hs * a21 * k1[q]
            _rhs(t + c2_ * hs, yt, k2, par, codes, vals, pars, sides, t0, h, xg, vg)
            for q in range(m):
                yt[q] = y[q] + hs * (a31 * k1[q] + a32 * k2[q])
            _rhs(t + c3_ * hs, yt, k3, par, codes, vals, pars, sides, t0, h, xg, vg)
            for q in range(m):
                yt[q] = y[q] + hs * (a41 * k1[q] + a42 * k2[q] + a43 * k3[q])
            _rhs(t + c4_ * hs, yt, k4, par, codes, vals, pars, sides, t0, h, xg, vg)
            for q in range(m):
                yt[q] = y[q] + hs * (a51 * k1[q] + a52 * k2[q] + a53 * k3[q] + a54 * k4[q])
            _rhs(t + c5_ * hs, yt, k5, par, codes, vals, pars, sides, t0, h, xg, vg)
            for q in range(m):
                yt[q] = y[q] + hs * (a61 * k1[q] + a62 * k2[q] + a63 * k3[q] + a64 * k4[q] + a65 * k5[q])
            _rhs(t + hs, yt, k6, par, codes, vals, pars, sides, t0, h, xg, vg)
            for q in range(m):
                yn[q] = y[q] + hs * (b1 * k1[q] + b3 * k3[q] + b4 * k4[q] + b5 * k5[q] + b6 * k6[q])
            _rhs(t + hs, yn, k7, par, codes, vals, pars, sides, t0, h, xg, vg)
            err = 0.0
            for q in range(m):
                sc = atol[q] + rtol * max(abs(y[q]), abs(yn[q]))
                d = hs * (e1 * k1[q] + e3 * k3[q] + e4 * k4[q] + e5 * k5[q] + e6 * k6[q] + e7 * k7[q]) / sc
                err += d * d
            err = np.sqrt(err / m)
            if not np.isfinite(err):
                err = 1e10                      # a stage left the finite numbers: a much smaller step
            if err <= 1.0:
                if abs(yn[1] - yn[0]) > z_max:
                    return n_acc, n_rej, 1, t + hs
                t += hs
                for q in range(m):
                    y[q] = yn[q]
                    k1[q] = k7[q]           # first same as last
                # a play's slider follows the window's edge to the step's end (within a step the force reads
                # it clamped to the window at every stage: the play operator on the stage's z)
                j = 0
                for i in range(codes.size):
                    if codes[i] == 8:
                        half = 0.5 * pars[i]
                        zz = y[1] - y[0]
                        if y[4 + j] < zz - half:
                            y[4 + j] = zz - half
                        elif y[4 + j] > zz + half:
                            y[4 + j] = zz + half
                        j += 1
                n_acc += 1
                fac = 0.9 * (1.0 / max(err, 1e-10)) ** 0.2
                step = hs * min(5.0, max(0.2, fac))
            else:
                n_rej += 1
                step = hs * max(0.1, 0.9 * (1.0 / err) ** 0.2)
        a1, a2 = _rhs(t, y, k1, par, codes, vals, pars, sides, t0, h, xg, vg)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4], out[k, 5] = y[0], y[1], y[2], y[3], a1, a2
        out[k, 6] = _strut(y[1] - y[0], y[3] - y[2], y, codes, vals, pars, sides)
    return n_acc, n_rej, 0, t


@numba.njit(cache=True)
def _superpose(t0, dt, n, f, amp, ph, x, v):  # pragma: no cover - compiled
    """x(t) = Σ a·cos(2πft + φ) and v = ẋ on t0 + i·dt: each harmonic's phasor turned by e^{jωdt} per
    sample, set afresh from cos/sin every 1024 samples (rounding does not accumulate)."""
    for i in range(n):
        x[i] = 0.0
        v[i] = 0.0
    for k in range(f.size):
        w = 2 * np.pi * f[k]
        cr, ci = np.cos(w * dt), np.sin(w * dt)
        a = amp[k]
        for i0 in range(0, n, 1024):
            arg = w * (t0 + i0 * dt) + ph[k]
            pr, pi = np.cos(arg), np.sin(arg)
            for i in range(i0, min(i0 + 1024, n)):
                x[i] += a * pr
                v[i] -= a * w * pi
                pr, pi = pr * cr - pi * ci, pr * ci + pi * cr


def _road(road: HarmonicRoad, t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The road on the uniform instants ``t`` (from -WARMUP_S), faded in over FADE_S by a half-Hann (exact
    derivative)."""
    f, amp, ph = road.harmonics(rng)
    x, v = np.empty_like(t), np.empty_like(t)
    _superpose(float(t[0]), float(t[1] - t[0]), t.size, f, amp, ph, x, v)
    u = np.clip((t - t[0]) / FADE_S, 0.0, 1.0)
    w = 0.5 - 0.5 * np.cos(np.pi * u)
    dw = np.where((u > 0) & (u < 1), 0.5 * np.pi / FADE_S * np.sin(np.pi * u), 0.0)
    return w * x, w * v + dw * x


@dataclass(frozen=True, eq=False)
class IndependentRun:
    """A record of :func:`simulate_independent` and its noise-free truth at the record's instants."""

    record: Record
    z: np.ndarray               # relative displacement [m]
    zdot: np.ndarray            # relative velocity [m/s]
    strut_force_n: np.ndarray   # the elements' force N [N]
    steps: tuple[int, int]      # the integrator's accepted and rejected steps


def simulate_independent(config: IndependentConfig, *, seed: int,
                         source: str = "independent simulator") -> IndependentRun:
    """One record of the quarter car of ``config`` (module docstring); its truth in ``record.meta["truth"]``.

    The road, then the sensors' noise, are drawn from ``numpy.random.default_rng(seed)``. The record's meta holds
    the configuration, the seed and the integrator's step counts; the run, the noise-free states.
    """
    if not isinstance(config, IndependentConfig):
        raise ConfigError(f"simulate_independent needs an IndependentConfig, got {type(config).__name__}")
    rng = np.random.default_rng(seed)
    fs, q = float(config.fs_hz), GRID_FACTOR
    fo = fs * q
    n_rec = int(round(config.duration_s * fs))
    n_warm, n_tail = int(round(WARMUP_S * fs)), int(round(TAIL_S * fs))
    n_out = (n_warm + n_rec + n_tail) * q
    t = -WARMUP_S + np.arange(n_out) / fo
    # the road on a grid twice as fine as the output grid (Hermite between its points)
    tr = -WARMUP_S + np.arange(2 * n_out + 2) / (2 * fo)
    xg, vg = _road(config.road, tr, rng)
    c = config.corner
    par = np.array([c.m1, c.m2, c.k1, c.c1, c.k2, c.c2, (c.m1 + c.m2) * G, 1.0 if config.lift_off else 0.0])
    els = config.elements
    codes = np.array([ELEMENT_KINDS[e.kind][0] for e in els], dtype=np.int64)
    vals = np.array([e.value for e in els], dtype=np.float64)
    pars = np.array([e.param for e in els], dtype=np.float64)
    sides = np.array([e.side for e in els], dtype=np.int64)
    n_play = int(np.sum(codes == 8))
    y = np.zeros(4 + n_play)
    atol = np.array([1e-10, 1e-10, 1e-8, 1e-8] + [1e-10] * n_play)
    out = np.empty((n_out, 7))
    n_acc, n_rej, status, t_stop = _dopri(y, par, codes, vals, pars, sides, float(tr[0]), 1.0 / (2 * fo), xg, vg,
                                          float(t[0]), 1.0 / fo, n_out, float(config.rtol), atol, Z_MAX_M,
                                          MAX_STEPS_PER_OUTPUT * n_out, out)
    if status:
        raise SimulationStoppedError(
            f"{source}: stopped at t = {t_stop:.4g} s of {config.duration_s:g} s (warm-up from -{WARMUP_S:g} s) "
            f"after {n_acc} accepted and {n_rej} rejected steps: {STOPS[status]} (strut: "
            f"{', '.join(f'{e.kind} {e.value:.3g}' for e in els) or 'linear'}; road RMS {1e3 * config.road.rms_m:.3g} mm)")
    keep = slice(n_warm, n_warm + n_rec)
    acc = [signal.decimate(out[:, i], q, ftype="fir", zero_phase=True)[keep] for i in (4, 5)]
    states = out[::q][keep]
    s = config.sensors
    a1 = acc[0] + s.bias_spindle_m_s2
    a2 = acc[1] + s.bias_body_m_s2
    a1 = a1 + s.noise_spindle * float(np.std(acc[0])) * rng.standard_normal(n_rec)
    a2 = a2 + s.noise_body * float(np.std(acc[1])) * rng.standard_normal(n_rec)
    xb = np.interp(t[::q][keep], tr, xg)
    truth = {"config": config.to_dict(), "seed": int(seed), "steps_accepted": int(n_acc),
             "steps_rejected": int(n_rej), "natural_frequencies_hz": list(c.frequencies_hz())}
    rec = Record(fs, a1, a2, xb, source=source, meta={"independent_simulator": truth})
    return IndependentRun(record=rec, z=states[:, 1] - states[:, 0], zdot=states[:, 3] - states[:, 2],
                          strut_force_n=states[:, 6], steps=(int(n_acc), int(n_rej)))
