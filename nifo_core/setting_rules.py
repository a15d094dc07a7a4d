"""The rule of each timing setting's value — the period and the transient — once, for every source.

:class:`nifo_core.settings.GivenSettings` (the command line, a model file, the identifier node) and the loader
(:mod:`nifo.io.loader`, which must stay light: ``nifo info`` loads no signal processing) both check through
:func:`check_timing`; on a99f355 the loader took a period of 1 sample where the settings asked for 8.

It sits low in the core's layers (``.importlinter``): it imports only :mod:`nifo_core.errors`.
"""

from __future__ import annotations

import math

from .errors import ConfigError

__all__ = ["MIN_PERIOD_SAMPLES", "check_timing"]

#: the shortest period a periodic excitation may be given with [samples] (the spectral engine's shortest block)
MIN_PERIOD_SAMPLES = 8


def check_timing(*, period_samples=None, skip_periods=None, skip_seconds=None) -> None:
    """:class:`ConfigError` for a period, transient periods or transient seconds no record can be read with."""
    if period_samples is not None and (isinstance(period_samples, bool) or int(period_samples) != period_samples
                                       or period_samples < MIN_PERIOD_SAMPLES):
        raise ConfigError(f"period_samples={period_samples!r} must be a whole number of samples ≥ "
                          f"{MIN_PERIOD_SAMPLES}", channel="--period-samples", hint="e.g. --period-samples 8192")
    if skip_periods is not None and (int(skip_periods) != skip_periods or skip_periods < 0):
        raise ConfigError(f"skip_periods={skip_periods!r} must be a whole number ≥ 0", channel="--skip-periods")
    if skip_seconds is not None and not (math.isfinite(skip_seconds) and skip_seconds >= 0):
        raise ConfigError(f"skip_seconds={skip_seconds!r} must be a number of seconds ≥ 0", channel="--skip-seconds")
