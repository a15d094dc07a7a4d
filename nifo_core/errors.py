"""The error hierarchy.

Every error nifo raises for a user's mistake derives from :class:`NifoError`
and carries a distinct process exit code, the file (``source``) and channel it
concerns, and a hint saying what to do. ``str(err)`` is one line::

    run1.mcap: /body/imu: 12 samples are NaN or infinite (first at t=3.215 s). Fix: ...

Built-in mixins keep ``except ValueError`` working for library users.
"""

from __future__ import annotations

__all__ = [
    "NifoError",
    "InputError",
    "DataFileError",
    "MissingChannelError",
    "NonFiniteError",
    "TimestampError",
    "SampleRateError",
    "RecordTooShortError",
    "ConfigError",
    "IllConditionedError",
    "OutputError",
    "OutputBusyError",
    "CorruptDataError",
    "ClippedSignalError",
    "EXIT_CODES",
    "USAGE_EXIT_CODE",
]


class NifoError(Exception):
    """Root of nifo's errors. ``exit_code`` is what the ``nifo`` command exits with."""

    exit_code = 1

    def __init__(self, message: str, *, source: str | None = None,
                 channel: str | None = None, hint: str | None = None) -> None:
        self.message = message
        self.source = source
        self.channel = channel
        self.hint = hint
        super().__init__(str(self))

    def __str__(self) -> str:
        parts = [p for p in (self.source, self.channel) if p]
        text = ": ".join([*parts, self.message])
        if self.hint:
            text += f". Fix: {self.hint}"
        return text.replace("\n", " ")

    def with_context(self, *, source: str | None = None, channel: str | None = None) -> "NifoError":
        """Return a copy naming ``source``/``channel`` where this one named none."""
        return type(self)(self.message, source=self.source or source,
                          channel=self.channel or channel, hint=self.hint)


class InputError(NifoError, ValueError):
    """Input data or arguments that cannot be used as given."""

    exit_code = 11  # 2 is argparse's: a command line that does not parse


class DataFileError(InputError):
    """A data file that cannot be read: missing, unreadable, truncated, empty or of unknown format."""

    exit_code = 3


class MissingChannelError(InputError, KeyError):
    """A required topic, column or key is absent."""

    exit_code = 4

    def __str__(self) -> str:  # KeyError would quote the message
        return NifoError.__str__(self)


class NonFiniteError(InputError):
    """NaN or infinite samples."""

    exit_code = 5


class TimestampError(InputError):
    """Non-monotonic, duplicated or gapped timestamps."""

    exit_code = 6


class SampleRateError(InputError):
    """Channels at different sample rates, or a rate that does not fit the request."""

    exit_code = 7


class RecordTooShortError(InputError):
    """Too few samples for the requested spectral block or analysis."""

    exit_code = 8


class ConfigError(InputError):
    """A model file, settings file or option value that is invalid."""

    exit_code = 9


class IllConditionedError(NifoError, ArithmeticError):
    """The estimation problem is too ill-conditioned to give a trustworthy answer."""

    exit_code = 10


class OutputError(NifoError):
    """An output path that cannot or must not be written: a regular file where a directory is to go,
    a directory holding the user's files, a read-only file system, a full disk, a path under a file."""

    exit_code = 13


class OutputBusyError(OutputError):
    """An output another nifo command is writing at this moment (its process is named): try again when it has ended."""

    exit_code = 15


class CorruptDataError(DataFileError):
    """A data file whose checksum or internal structure shows it was damaged (e.g. a bag chunk's CRC)."""

    exit_code = 14


class ClippedSignalError(InputError):
    """A channel that clipped: its samples sit flat at its extremes too often for any estimate to hold."""

    exit_code = 16


#: exit code of ``nifo`` for a command line argparse cannot parse (argparse's own)
USAGE_EXIT_CODE = 2

#: error class name -> (exit code, what it means), as ``nifo --help`` lists them; unique per class.
#: ``PredictionDivergedError`` (:mod:`nifo_core.predict.time_prediction`) and the fleet's errors (:mod:`nifo.fleet.cluster`) are
#: heavy to import and are listed here by name; tests/test_cli.py checks the numbers against the classes.
EXIT_CODES: dict[str, tuple[int, str]] = {
    **{cls.__name__: (cls.exit_code, (cls.__doc__ or "").strip().splitlines()[0].split(". ")[0].rstrip("."))
       for cls in (NifoError, InputError, DataFileError, MissingChannelError, NonFiniteError, TimestampError,
                   SampleRateError, RecordTooShortError, ConfigError, IllConditionedError, OutputError,
                   OutputBusyError, CorruptDataError, ClippedSignalError)},
    "PredictionDivergedError": (12, "The model's prediction diverged for this input"),
    # the fleet's errors live in nifo.fleet.cluster (Dask is not imported for other commands)
    "ClusterError": (20, "The Dask cluster could not be started or reached"),
    "FleetError": (21, "The fleet run could not go on"),
}
