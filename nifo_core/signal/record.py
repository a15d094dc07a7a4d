"""``Record``: the one in-memory form of measured data every command works on.

Whatever the source (rosbag2/MCAP, CSV, MAT, the simulator), loaders produce a
:class:`Record`: uniformly sampled spindle and body vertical accelerations
[m/s²] and, when measured, the tire-patch displacement [m] and a force on the
body [N] (a shaker rig's load cell, the Silverbox's input). A record whose
spindle is fixed (a single mass driven by a measured force:
m·ÿ + d·ẏ + k·y + Σ c_i·g_i(y, ẏ) = u) is built with ``spindle_accel=None``:
the spindle acceleration is then zero and ``spindle_fixed`` is True, and the
estimators drop it as an input instead of inverting a singular matrix.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Mapping

import numpy as np

from ..errors import InputError, NonFiniteError, RecordTooShortError

__all__ = ["Record", "CHANNELS", "acceleration_from_displacement", "acceleration_means", "concatenate"]

#: the channels whose constant part carries no dynamics (a constant acceleration would be an unbounded motion): a
#: sensor's bias or gravity, removed before any analysis (:meth:`Record.centred`)
ACCELERATIONS = ("spindle_accel", "body_accel")

#: channel names, in the order used throughout (CSV columns, bag topics' roles)
CHANNELS = ("spindle_accel", "body_accel", "tire_patch_disp", "force")


def _as_signal(x, name: str, source: str) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 1:
        arr = np.squeeze(arr)
    if arr.ndim != 1:
        raise InputError(f"expected a 1-D signal, got shape {np.shape(x)}", source=source, channel=name,
                         hint="pass one sample per time step")
    return arr


@dataclass(frozen=True)
class Record:
    """Uniformly sampled measurement of one quarter car.

    Parameters
    ----------
    fs_hz : float
        Sample rate [Hz].
    spindle_accel, body_accel : ndarray, shape (n,)
        Vertical accelerations of the unsprung (x1) and sprung (x2) mass [m/s²].
        ``spindle_accel=None``: the spindle is fixed (zero acceleration,
        ``spindle_fixed`` True); it needs a measured ``force``.
    tire_patch_disp : ndarray, shape (n,), optional
        Tire-patch (road/actuator) displacement xb [m], when measured.
    t0_ns : int
        Time stamp of the first sample [ns].
    source : str
        Where the data came from (file name, "simulator", ...), used in messages.
    meta : mapping
        Provenance (settings, truth file, topic names ...), JSON-serialisable.
    force : ndarray, shape (n,), optional
        Measured force acting on the body (sprung mass) [N], positive in the
        direction of x2, when measured.
    spindle_fixed : bool
        True when the spindle does not move (set by ``spindle_accel=None``).
    body_disp : ndarray, shape (n,), optional
        The body displacement as measured, when a displacement was recorded instead of the body
        acceleration (``body_accel`` is then its second derivative): the output in the unit the
        user measured, for predictions compared in that unit.

    Arrays are made read-only: a ``Record`` never changes once built.
    """

    fs_hz: float
    spindle_accel: np.ndarray
    body_accel: np.ndarray
    tire_patch_disp: np.ndarray | None = None
    t0_ns: int = 0
    source: str = ""
    meta: Mapping = field(default_factory=dict)
    force: np.ndarray | None = None
    spindle_fixed: bool = False
    body_disp: np.ndarray | None = None

    def __post_init__(self) -> None:
        src = self.source or "record"
        if not (np.isfinite(self.fs_hz) and self.fs_hz > 0):
            raise InputError(f"sample rate must be positive, got {self.fs_hz!r} Hz", source=src,
                             hint="give the sample rate in Hz")
        b = _as_signal(self.body_accel, "body_accel", src)
        if self.spindle_accel is None:
            object.__setattr__(self, "spindle_fixed", True)
            s = np.zeros_like(b)
        else:
            s = _as_signal(self.spindle_accel, "spindle_accel", src)
        object.__setattr__(self, "spindle_fixed", bool(self.spindle_fixed))
        if self.spindle_fixed and self.force is None:
            raise InputError("a record with a fixed spindle needs a measured force", source=src,
                             channel="force", hint="give the force channel (--columns force=NAME), or the spindle")
        sigs = {"spindle_accel": s, "body_accel": b}
        if self.tire_patch_disp is not None:
            sigs["tire_patch_disp"] = _as_signal(self.tire_patch_disp, "tire_patch_disp", src)
        if self.force is not None:
            sigs["force"] = _as_signal(self.force, "force", src)
        if self.body_disp is not None:
            sigs["body_disp"] = _as_signal(self.body_disp, "body_disp", src)
        n = {k: v.size for k, v in sigs.items()}
        if len(set(n.values())) != 1:
            raise InputError(f"channels have different lengths {n}", source=src,
                             hint="resample or trim the channels to one time base")
        if s.size == 0:
            raise RecordTooShortError("record holds no samples", source=src,
                                      hint="check the file and the time range selected")
        for name, v in sigs.items():
            bad = ~np.isfinite(v)
            if bad.any():
                i = int(np.argmax(bad))
                raise NonFiniteError(
                    f"{int(bad.sum())} samples are NaN or infinite (first at t={i / self.fs_hz:.3f} s)",
                    source=src, channel=name,
                    hint="cut the record before/after the bad stretch or repair the sensor data")
            v = v.copy() if v.flags.writeable and v.base is not None else v
            v.flags.writeable = False
            object.__setattr__(self, name, v)
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))

    # -- derived -------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.spindle_accel.size)

    @property
    def duration_s(self) -> float:
        return self.n / self.fs_hz

    @property
    def has_tire_patch(self) -> bool:
        return self.tire_patch_disp is not None

    @property
    def has_force(self) -> bool:
        return self.force is not None

    def time_s(self) -> np.ndarray:
        """Sample times relative to the first sample [s]."""
        return np.arange(self.n) / self.fs_hz

    def slice(self, start: int, stop: int) -> "Record":
        """Samples ``start:stop`` as a new record (stamps shifted accordingly)."""
        start, stop, _ = slice(start, stop).indices(self.n)
        tp = None if self.tire_patch_disp is None else self.tire_patch_disp[start:stop]
        fo = None if self.force is None else self.force[start:stop]
        bd = None if self.body_disp is None else self.body_disp[start:stop]
        return replace(self, spindle_accel=None if self.spindle_fixed else self.spindle_accel[start:stop],
                       body_accel=self.body_accel[start:stop], tire_patch_disp=tp, force=fo, body_disp=bd,
                       t0_ns=self.t0_ns + int(round(start * 1e9 / self.fs_hz)))

    def centred(self, means: Mapping[str, float] | None = None) -> "Record":
        """This record with the constant offsets of its accelerations removed: ``means`` (default its own,
        :func:`acceleration_means`). What every analysis step works on: a constant acceleration carries no
        dynamics, and removed in float64 before any spectrum, sum or square, an offset of any size (a sensor's bias,
        gravity, 1e6) gives the answer of the record without it. ``meta["offsets_m_s2"]`` adds up what was removed.
        Forces and displacements keep their means (a preload or a static deflection is physics)."""
        m = acceleration_means(self) if means is None else {k: float(means.get(k, 0.0)) for k in ACCELERATIONS}
        if not any(m.values()):
            return self
        before = dict(self.meta.get("offsets_m_s2") or {})
        meta = {**dict(self.meta), "offsets_m_s2": {k: before.get(k, 0.0) + v for k, v in m.items()}}
        return replace(self, spindle_accel=None if self.spindle_fixed else self.spindle_accel - m["spindle_accel"],
                       body_accel=self.body_accel - m["body_accel"], meta=meta)

    def require_samples(self, n_min: int, *, what: str) -> None:
        """Raise :class:`RecordTooShortError` unless the record holds ``n_min`` samples."""
        if self.n < n_min:
            raise RecordTooShortError(
                f"{self.n} samples ({self.duration_s:.1f} s) is too short for {what}, which needs {n_min}",
                source=self.source or "record",
                hint="record longer, or choose a smaller --block")


def acceleration_means(record: Record) -> dict[str, float]:
    """The mean of each acceleration channel [m/s²], in float64 (0 for a fixed spindle)."""
    return {k: 0.0 if k == "spindle_accel" and record.spindle_fixed else float(np.mean(getattr(record, k),
                                                                                       dtype=np.float64))
            for k in ACCELERATIONS}


def concatenate(parts) -> Record:
    """Consecutive chunks of one record (same rate and channels) joined into one; the first's stamp and meta."""
    parts = list(parts)
    if not parts:
        raise InputError("nothing to join")
    first = parts[0]

    def cat(name: str):
        vals = [getattr(p, name) for p in parts]
        return None if any(v is None for v in vals) else np.concatenate(vals)

    return replace(first, spindle_accel=None if first.spindle_fixed else cat("spindle_accel"),
                   body_accel=cat("body_accel"), tire_patch_disp=cat("tire_patch_disp"), force=cat("force"),
                   body_disp=cat("body_disp"))


def acceleration_from_displacement(x: np.ndarray, fs_hz: float, *, period_samples: int | None = None
                                   ) -> tuple[np.ndarray, str]:
    """Second time derivative of a displacement signal; returns (acceleration, method used).

    Parameters
    ----------
    x : ndarray, shape (n,)
        Displacement (or a displacement analogue, e.g. volts: the result is then in that unit per s²).
    fs_hz : float
        Sample rate [Hz].
    period_samples : int, optional
        Samples per period of periodic (multisine) data. When ``n`` is a
        whole number of periods the derivative is exact: multiply the DFT by
        -ω² on every line (the Nyquist line, which has no sign, is dropped).

    Notes
    -----
    Without whole periods the 5-point central difference is used
    (x[i-2] - 16x[i-1] + 30x[i] - ... )/12h² in the interior, relative error
    (ωh)⁴/90 (0.17 % at fs/10), the 3-point one at the two samples of each
    end; the method string says which.
    """
    x = np.asarray(x, dtype=np.float64)
    n = x.size
    if period_samples is not None and period_samples > 0 and n % int(period_samples) == 0 and n >= 2:
        spec = np.fft.rfft(x)
        w = 2 * np.pi * np.fft.rfftfreq(n, 1.0 / fs_hz)
        spec *= -(w ** 2)
        if n % 2 == 0:
            spec[-1] = 0.0
        return np.fft.irfft(spec, n), f"spectral, exact for periodic data ({n // int(period_samples)} whole periods)"
    if n < 5:
        raise RecordTooShortError(f"{n} samples are too few to differentiate a displacement",
                                  hint="give at least 5 samples")
    h2 = (1.0 / fs_hz) ** 2
    a = np.empty(n)
    a[2:-2] = (-x[:-4] + 16 * x[1:-3] - 30 * x[2:-2] + 16 * x[3:-1] - x[4:]) / (12 * h2)
    a[1] = (x[0] - 2 * x[1] + x[2]) / h2
    a[-2] = (x[-3] - 2 * x[-2] + x[-1]) / h2
    a[0] = (2 * x[0] - 5 * x[1] + 4 * x[2] - x[3]) / h2
    a[-1] = (2 * x[-1] - 5 * x[-2] + 4 * x[-3] - x[-4]) / h2
    return a, "5-point central differences (relative error (ωh)^4/90: 0.17 % at fs/10)"
