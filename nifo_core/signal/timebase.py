"""Turn raw per-sample time stamps into one uniform sample rate, or say why not."""

from __future__ import annotations

import numpy as np

from ..errors import RecordTooShortError, SampleRateError, TimestampError

__all__ = ["sample_rate_from_stamps", "check_common_rate"]


def sample_rate_from_stamps(stamp_ns: np.ndarray, *, source: str, channel: str,
                            gap_tolerance: float = 0.5) -> float:
    """Sample rate [Hz] of uniformly spaced stamps.

    Raises :class:`TimestampError` when stamps go backwards or repeat, or when
    any interval differs from the median by more than ``gap_tolerance`` of it
    (a gap: dropped samples; or jitter too large to treat as uniform).
    """
    t = np.asarray(stamp_ns, dtype=np.int64)
    if t.size < 2:
        raise RecordTooShortError(f"{t.size} sample(s): cannot tell the sample rate", source=source,
                                  channel=channel, hint="record at least a few seconds")
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise TimestampError(
            f"time stamps are not increasing at sample {i + 1} ({t[i]} ns then {t[i + 1]} ns)",
            source=source, channel=channel,
            hint="re-record with source stamps, or sort/deduplicate the messages first")
    med = float(np.median(dt))
    dev = np.abs(dt - med) > gap_tolerance * med
    if dev.any():
        i = int(np.argmax(dev))
        raise TimestampError(
            f"time stamps are not uniform: interval of {dt[i] / 1e6:.3f} ms at sample {i + 1} "
            f"(t={(t[i] - t[0]) / 1e9:.3f} s) vs typical {med / 1e6:.3f} ms; {int(dev.sum())} such intervals",
            source=source, channel=channel,
            hint="split the record at the gap (or fill dropped samples) and analyse the pieces")
    # least-squares rate over the whole span is more accurate than the median
    return float((t.size - 1) * 1e9 / (t[-1] - t[0]))


def check_common_rate(rates_hz: dict[str, float], *, source: str, rel_tol: float = 1e-3) -> float:
    """Return the common rate of several channels or raise :class:`SampleRateError`."""
    vals = np.array(list(rates_hz.values()))
    ref = float(np.median(vals))
    off = {k: v for k, v in rates_hz.items() if abs(v - ref) > rel_tol * ref}
    if off:
        desc = ", ".join(f"{k} {v:.3f} Hz" for k, v in rates_hz.items())
        raise SampleRateError(f"channels are sampled at different rates ({desc})", source=source,
                              channel=", ".join(off),
                              hint="resample all channels to one rate before analysis")
    return ref
