"""The linear quarter car (paper Eq. 1 with N1 = N2 = 0) and its transfer functions.

Sign conventions, used everywhere in nifo (docs/method.md §1):

    z = x2 - x1                                    (relative displacement, rebound positive)
    M2·ẍ2 = -K2·z - C2·ż - K3·x2 - N1              (body, paper Eq. 2)
    M1·ẍ1 =  K2·z + C2·ż + N1 + K1·(xb-x1) + C1·(ẋb-ẋ1) - N2

The truth a simulation is scored against is this linear system: every
nonlinear force is an *addition* N1 to the linear strut, zero at zero motion
(describing functions are kept whole, docs/method.md §3).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import ConfigError

__all__ = ["QuarterCar"]

G_ACCEL = 9.80665  # m/s²


@dataclass(frozen=True)
class QuarterCar:
    """Linear quarter-car parameters (SI). Defaults: a mid-size car corner (docs/method.md §6)."""

    m1: float = 40.0        # unsprung mass [kg]
    m2: float = 300.0       # sprung mass per corner [kg]
    k1: float = 250e3       # tire stiffness [N/m]
    c1: float = 200.0       # tire damping [N·s/m]
    k2: float = 22e3        # strut spring [N/m]
    c2: float = 1400.0      # strut damping (near-zero-amplitude, compression) [N·s/m]
    k3: float = 0.0         # body-to-ground stiffness (rig restraint) [N/m]

    def __post_init__(self) -> None:
        for name, val in asdict(self).items():
            if not np.isfinite(val) or val < 0 or (name in ("m1", "m2", "k1", "k2") and val == 0):
                raise ConfigError(f"vehicle parameter {name}={val!r} must be finite and positive",
                                  hint="give masses [kg], stiffnesses [N/m] and damping [N·s/m] in SI")

    # -- modal facts ----------------------------------------------------------
    def natural_frequencies_hz(self) -> tuple[float, float]:
        """Undamped body-bounce and wheel-hop frequencies [Hz]."""
        m = np.diag([self.m1, self.m2])
        k = np.array([[self.k1 + self.k2, -self.k2], [-self.k2, self.k2 + self.k3]])
        w2 = np.sort(np.linalg.eigvals(np.linalg.solve(m, k)).real)
        f = np.sqrt(w2) / (2 * np.pi)
        return float(f[0]), float(f[1])

    @property
    def static_tire_load_n(self) -> float:
        """Static tire load (both masses on the tire) [N]."""
        return (self.m1 + self.m2) * G_ACCEL

    # -- transfer functions ------------------------------------------------------
    def _omega(self, freq_hz) -> np.ndarray:
        return 2 * np.pi * np.asarray(freq_hz, dtype=float)

    def strut_impedance(self, freq_hz) -> np.ndarray:
        """Z(ω) = K2 + jωC2 [N/m]."""
        return self.k2 + 1j * self._omega(freq_hz) * self.c2

    def t21(self, freq_hz) -> np.ndarray:
        """Spindle→body transmissibility X2/X1 of the linear system (paper Eq. 7 with damping)."""
        w = self._omega(freq_hz)
        z = self.strut_impedance(freq_hz)
        return z / (-w**2 * self.m2 + z + self.k3)

    def receptance(self, freq_hz) -> np.ndarray:
        """2×2 receptance matrix H(ω) = B_L(ω)⁻¹ [m/N], shape (nf, 2, 2); index 0 = spindle, 1 = body."""
        w = np.atleast_1d(self._omega(freq_hz))
        zs = self.k2 + 1j * w * self.c2
        zt = self.k1 + 1j * w * self.c1
        b = np.empty((w.size, 2, 2), complex)
        b[:, 0, 0] = -w**2 * self.m1 + zt + zs
        b[:, 0, 1] = b[:, 1, 0] = -zs
        b[:, 1, 1] = -w**2 * self.m2 + zs + self.k3
        return np.linalg.inv(b)

    def h11(self, freq_hz) -> np.ndarray:
        """H11(ω): spindle receptance [m/N] (the H11 of paper Eq. 10)."""
        return self.receptance(freq_hz)[:, 0, 0]

    def h12(self, freq_hz) -> np.ndarray:
        """H12(ω) = H21(ω): spindle/body cross receptance [m/N]."""
        return self.receptance(freq_hz)[:, 0, 1]

    def t1b(self, freq_hz) -> np.ndarray:
        """Tire-patch→spindle transmissibility X1/Xb = H11·(K1 + jωC1) (paper Eq. 10, first row)."""
        return self.h11(freq_hz) * (self.k1 + 1j * self._omega(freq_hz) * self.c1)

    def t2b(self, freq_hz) -> np.ndarray:
        """Tire-patch→body transmissibility X2/Xb = H21·(K1 + jωC1)."""
        return self.h12(freq_hz) * (self.k1 + 1j * self._omega(freq_hz) * self.c1)

    def to_dict(self) -> dict:
        return asdict(self)
