"""Per-channel time stamps and values in, one uniformly sampled :class:`~nifo_core.signal.record.Record` out.

Shared by every reader (bag, CSV, MAT): :func:`assemble_record` checks the
stamps (increasing, no gaps), the common rate, the common sample instants and
finiteness, and names file, channel and fix in every error.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nifo_core.errors import (ConfigError, DataFileError, NifoError, NonFiniteError, RecordTooShortError,
                              SampleRateError, TimestampError)
from nifo_core.signal.record import Record, acceleration_from_displacement
from nifo_core.signal.timebase import check_common_rate, sample_rate_from_stamps

__all__ = ["assemble_record", "Assembly", "Skip", "READ_ROLES", "FIXED", "nominal_rate", "check_declared_rate",
           "check_rate_range", "check_values",
           "seconds_to_ns"]


#: channel roles a CSV/MAT reader looks for (``body_disp`` becomes ``body_accel``)
READ_ROLES = ("spindle_accel", "body_accel", "body_disp", "tire_patch_disp", "force")
#: ``spindle_accel=fixed``: the spindle does not move
FIXED = "fixed"


@dataclass(frozen=True)
class Skip:
    """Samples to drop from the start of a record (a transient): seconds, or whole periods."""

    seconds: float | None = None
    periods: int | None = None
    period_samples: int | None = None

    def samples(self, fs_hz: float, n: int, *, source: str) -> int:
        """Samples to drop from a record of ``n`` samples at ``fs_hz``; a clear error if nothing would be left."""
        k = 0
        if self.seconds is not None:
            k += int(round(self.seconds * fs_hz))
        if self.periods is not None:
            k += int(self.periods) * int(self.period_samples)
        if k >= n:
            raise RecordTooShortError(f"skipping {k} samples ({k / fs_hz:.3g} s) leaves nothing of {n}",
                                      source=source, channel="--skip-seconds/--skip-periods",
                                      hint="skip less than the record's length")
        return k

    @property
    def active(self) -> bool:
        return bool(self.seconds) or bool(self.periods)


@dataclass(frozen=True)
class Assembly:
    """What :func:`assemble_record` does besides stamps → Record (set by :func:`load_record`).

    extra : {role: (values, label, rate in Hz or None)}
        Channels read from other files (``NAME@FILE``), appended as they are.
    spindle_fixed : bool
        ``spindle_accel=fixed``: build the record with a fixed spindle.
    skip : Skip
        Transient start to drop.
    required : frozenset
        Roles the reader must find in the file.
    collect : bool
        Return ``{role: values}`` and the rate instead of a Record (reading one channel of another file).
    """

    extra: Mapping[str, tuple[np.ndarray, str, float | None]] = field(default_factory=dict)
    spindle_fixed: bool = False
    skip: Skip = Skip()
    required: frozenset = frozenset({"spindle_accel", "body_accel"})
    collect: bool = False


def _check_declared_rate(rate: float, fs_hz: float, *, source: str) -> None:
    if isinstance(fs_hz, bool) or not (np.isfinite(fs_hz) and fs_hz > 0):
        raise ConfigError(f"sample rate must be positive, got {fs_hz!r} Hz", source=source, channel="--fs",
                          hint="give the sample rate in Hz")
    if abs(rate - fs_hz) > 1e-3 * fs_hz:
        raise SampleRateError(f"the time stamps give {rate:.6g} Hz but the sample rate was given as "
                              f"{fs_hz:.6g} Hz", source=source, channel="--fs",
                              hint="drop --fs (the stamps set the rate) or correct it")


def nominal_rate(stamp_ns: np.ndarray, rate: float, tol_ns: float) -> float:
    """``rate`` rounded to the fewest decimals (0..9) that still reproduces every stamp within ``tol_ns``.

    Stamps written as ``t0 + round(i·1e9/fs)`` give back ``fs`` exactly; jittery
    real stamps keep the least-squares rate.
    """
    rel = (stamp_ns - stamp_ns[0]).astype(np.float64)
    i = np.arange(stamp_ns.size, dtype=np.float64)
    for digits in range(10):
        r = round(rate, digits)
        if r > 0 and abs(r - rate) <= 1e-6 * rate and np.max(np.abs(rel - np.rint(i * (1e9 / r)))) <= tol_ns:
            return r
    return rate


def _align(stamps: dict[str, np.ndarray], fs: float, *, labels: Mapping[str, str],
           source: str) -> dict[str, slice]:
    """The slice of each channel that covers the samples common to all (stamps equal within fs/4)."""
    tol = 0.25e9 / fs
    start = max(int(s[0]) for s in stamps.values())
    stop = min(int(s[-1]) for s in stamps.values())
    ref_name = next(iter(stamps))
    if stop < start - tol:
        spans = ", ".join(f"{labels[k]} {s[0] / 1e9:.3f}–{s[-1] / 1e9:.3f} s" for k, s in stamps.items())
        raise TimestampError(f"channels do not overlap in time ({spans})", source=source,
                             channel=", ".join(labels[k] for k in stamps),
                             hint="give channels recorded at the same time")
    cuts = {k: slice(int(np.searchsorted(s, start - tol, "left")), int(np.searchsorted(s, stop + tol, "right")))
            for k, s in stamps.items()}
    ref = stamps[ref_name][cuts[ref_name]]
    for k, s in stamps.items():
        part = s[cuts[k]]
        m = min(part.size, ref.size)
        if m == 0:
            raise TimestampError("the channels share no sample instants", source=source,
                                 channel=f"{labels[ref_name]}, {labels[k]}",
                                 hint="give channels recorded at the same time on one clock")
        dev = np.abs(part[:m] - ref[:m]) > tol
        if part.size != ref.size or dev.any():
            i = int(np.argmax(dev)) if dev.any() else 0
            period = 1e9 / fs
            lag = (float(part[i] - ref[i]) + period / 2) % period - period / 2  # nearest-sample offset
            raise TimestampError(
                f"the channels are not sampled at the same instants: at t={(ref[i] - ref[0]) / 1e9:.3f} s "
                f"{labels[k]} is {lag / 1e6:+.3f} ms off {labels[ref_name]} (sample period {period / 1e6:.3f} ms)",
                source=source, channel=f"{labels[ref_name]}, {labels[k]}",
                hint="resample the channels onto one clock so that each sample has one stamp for all")
    return cuts


def assemble_record(channels: Mapping[str, tuple[np.ndarray | None, np.ndarray]], *,
                    labels: Mapping[str, str], path: str | os.PathLike, meta: Mapping,
                    fs_hz: float | None = None, t0_ns: int = 0, stamp_tol_ns: float = 1.0,
                    assembly: Assembly | None = None) -> Record:
    """Build a :class:`Record` from ``{channel: (stamp_ns or None, values)}``.

    With stamps: each channel's rate comes from its stamps
    (:func:`~nifo_core.signal.timebase.sample_rate_from_stamps`: increasing, no gaps),
    the rates must agree (:func:`~nifo_core.signal.timebase.check_common_rate`), and
    the channels are trimmed to their common samples (stamps equal within a
    quarter period, else :class:`TimestampError`); ``meta["trimmed"]`` says how
    many samples were cut. The rate is snapped to its short decimal form when
    that reproduces every stamp within ``stamp_tol_ns``. Without stamps
    ``fs_hz`` is required. ``labels`` name channels in messages (topic, column or key).
    ``assembly`` (from :func:`load_record`) adds channels of other files, a
    fixed spindle, a skipped start and a displacement's derivative, in that order.
    """
    src = str(path)
    meta = dict(meta)
    asm = assembly or Assembly()
    # a fixed spindle: a spindle column the file may still hold (zeros) is not a channel of this record
    names = [c for c in READ_ROLES if c in channels and not (asm.spindle_fixed and c == "spindle_accel")]
    values = {c: np.asarray(channels[c][1], dtype=np.float64).ravel() for c in names}
    stamps = {c: channels[c][0] for c in names}
    if all(s is None for s in stamps.values()):
        if fs_hz is None and asm.collect:
            return values[names[0]], None
        if fs_hz is None:
            raise ConfigError("the file has no time stamps and no sample rate was given", source=src,
                              channel="fs", hint="pass --fs HZ (fs_hz=...) or add a time column/key")
        _check_declared_rate(fs_hz, fs_hz, source=src)
        fs = float(fs_hz)
        lengths = {labels[c]: v.size for c, v in values.items()}
        if len(set(lengths.values())) != 1:
            raise TimestampError(f"channels have different lengths {lengths} and no time stamps to align them",
                                 source=src, channel=", ".join(lengths),
                                 hint="trim the channels to the same samples")
        t0 = int(t0_ns)
    else:
        st = {c: np.asarray(s, dtype=np.int64).ravel() for c, s in stamps.items()}
        for c in names:   # one stamp per sample: never drop (or invent) samples silently
            if st[c].size != values[c].size:
                raise TimestampError(f"{st[c].size} time stamps for {values[c].size} samples", source=src,
                                     channel=labels[c],
                                     hint="give one time value per sample (or drop the time vector and give fs)")
        rates = {labels[c]: sample_rate_from_stamps(s, source=src, channel=labels[c]) for c, s in st.items()}
        fs = check_common_rate(rates, source=src)
        cuts = _align(st, fs, labels=labels, source=src)
        trimmed = {labels[c]: [cuts[c].start, st[c].size - cuts[c].stop] for c in names
                   if cuts[c].start or cuts[c].stop != st[c].size}
        if trimmed:
            meta["trimmed"] = trimmed  # samples cut at [start, end] to cover the same instants
        values = {c: v[cuts[c]] for c, v in values.items()}
        common = st[names[0]][cuts[names[0]]]
        if common.size < 2:
            fs = float(np.mean(list(rates.values())))
        else:
            fs = nominal_rate(common, float((common.size - 1) * 1e9 / (common[-1] - common[0])), stamp_tol_ns)
        if fs_hz is not None:
            _check_declared_rate(fs, fs_hz, source=src)
        t0 = int(common[0]) if common.size else 0
    check_rate_range(fs, source=src)
    for c, v in values.items():
        bad = ~np.isfinite(v)
        if bad.any():
            i = int(np.argmax(bad))
            raise NonFiniteError(f"{int(bad.sum())} of {v.size} samples are NaN or infinite "
                                 f"(first at t={i / fs:.3f} s, sample {i})", source=src, channel=labels[c],
                                 hint="cut the record before/after the bad stretch or repair the sensor data")
    check_values(values, labels=labels, fs=fs, source=src)
    if asm.collect:
        return values[names[0]], fs
    labels = dict(labels)
    for role, (v, label, f_other) in asm.extra.items():            # NAME@FILE channels
        n_here = next(iter(values.values())).size if values else v.size
        if v.size != n_here:
            raise TimestampError(f"{label} has {v.size} samples but the record has {n_here}", source=src,
                                 channel=role, hint="combine channels recorded together (same length and rate)")
        if f_other is not None and abs(f_other - fs) > 1e-6 * fs:
            raise SampleRateError(f"{label} is sampled at {f_other:.10g} Hz, the record at {fs:.10g} Hz",
                                  source=src, channel=role, hint="combine channels sampled at one rate")
        values[role], labels[role] = np.asarray(v, np.float64), label
        meta.setdefault("columns", {})[role] = label
    if asm.skip.active:                                             # transient start
        k = asm.skip.samples(fs, next(iter(values.values())).size, source=src)
        values = {c: v[k:] for c, v in values.items()}
        t0 += int(round(k * 1e9 / fs))
        meta["skipped_samples"] = k
    if "body_disp" in values:                                       # displacement -> acceleration
        values["body_accel"], how = acceleration_from_displacement(values["body_disp"], fs,
                                                                   period_samples=asm.skip.period_samples)
        meta["body_from_displacement"] = how
    if asm.spindle_fixed:
        meta["spindle"] = "fixed"
    try:
        return Record(fs, None if asm.spindle_fixed else values["spindle_accel"], values["body_accel"],
                      values.get("tire_patch_disp"), t0_ns=t0, source=Path(path).name, meta=meta,
                      force=values.get("force"), body_disp=values.get("body_disp"))
    except NifoError as err:
        raise err.with_context(source=src) from None


#: the sample rates accepted [Hz]: beyond these a "rate" is a unit or stamp error, not a measurement
FS_RANGE_HZ = (1e-3, 1e8)
#: the largest magnitude accepted in a channel: beyond it a value is a scale/unit error and would overflow spectra
MAX_ABS_VALUE = 1e15


def check_rate_range(fs: float, *, source: str, channel: str | None = None) -> None:
    """Raise :class:`SampleRateError` unless ``FS_RANGE_HZ[0] <= fs <= FS_RANGE_HZ[1]``."""
    lo, hi = FS_RANGE_HZ
    if not (np.isfinite(fs) and lo <= fs <= hi):
        raise SampleRateError(f"sample rate {fs:.3g} Hz is outside {lo:g}..{hi:g} Hz", source=source,
                              channel=channel, hint="check the time unit (seconds) or the fs value/--fs")


def check_values(values: Mapping[str, np.ndarray], *, labels: Mapping[str, str], fs: float, source: str,
                 constant: bool = True) -> None:
    """Refuse implausibly large values and (``constant=True``) an acceleration channel that never changes."""
    for c, v in values.items():
        big = np.abs(v) > MAX_ABS_VALUE
        if big.any():
            i = int(np.argmax(big))
            raise DataFileError(f"{int(big.sum())} samples exceed {MAX_ABS_VALUE:.0e} in magnitude (first "
                                f"{v[i]:.3g} at t={i / fs:.3f} s): not a measurement", source=source,
                                channel=labels[c], hint="check the channel's unit/scale or repair the data")
        if constant and c != "tire_patch_disp" and v.size > 1 and v[0] == v[-1] and not (v != v[0]).any():
            raise DataFileError(f"all {v.size} samples are {v[0]:g}: the sensor recorded nothing", source=source,
                                channel=labels[c], hint="check the channel mapping (--topics/--columns/--axis) and the sensor")


#: the largest |time| [s] that int64 nanosecond stamps hold (year 2262)
MAX_TIME_S = 9.2e9


def seconds_to_ns(t: np.ndarray, *, source: str, channel: str) -> np.ndarray:
    """Time values [s] to int64 stamps [ns]; raises rather than overflow or accept NaN."""
    t = np.asarray(t, dtype=np.float64)
    if not np.isfinite(t).all():
        i = int(np.argmax(~np.isfinite(t)))
        raise DataFileError(f"time value {i} (of {t.size}) is not finite", source=source, channel=channel,
                            hint="repair or delete that row/sample, or drop the time vector and give fs")
    if t.size and np.abs(t).max() > MAX_TIME_S:
        raise DataFileError(f"time values reach {np.abs(t).max():.3g} s, beyond what nanosecond stamps hold "
                            f"(±{MAX_TIME_S:.1e} s)", source=source, channel=channel,
                            hint="give time in seconds (not ns or µs), or drop the time vector and give fs")
    return np.rint(t * 1e9).astype(np.int64)


_nominal_rate = nominal_rate
check_declared_rate = _check_declared_rate
