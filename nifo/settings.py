"""The settings of every command: the same flags everywhere, one merge, choices read off the data.

:func:`add_settings_arguments` gives every data command the same settings
flags (``--block``, ``--overlap``, ``--window``, ``--integration-band``, ``--analysis-band``,
``--cond-limit``; ``--period-samples``, ``--skip-periods``, ``--skip-seconds``
come with the input options of :func:`nifo.io.loader.add_input_arguments`).
:func:`resolve` merges them — command line > model file > chosen from the
data > default — through :func:`nifo_core.settings.resolve_settings`: the
data are probed once (the first :data:`PROBE_SAMPLES` samples of each file,
bounded memory whatever the recording's length) for a periodic excitation,
its transient and the excited band (:mod:`nifo_core.signal.excitation`). It returns
the :class:`~nifo_core.settings.AnalysisSettings`, once per command (``nifo run``: once
per job); :func:`loader_options` gives the loaders the period and transient it chose.
:func:`for_records` takes resolved settings on some of their records (a level, a file):
their checks and excitation, every value and its source unchanged.

Before any setting is chosen, each record is checked for what would make any
answer wrong (:func:`check_record`, on the same probed samples): a channel that
clipped (flat runs at its extremes, :mod:`nifo_core.signal.clipping`: refused
above :data:`~nifo_core.signal.clipping.REFUSE_FRACTION`, named below), a dead
channel, the spindle and the body read from the same channel; the constant
offsets of the accelerations are measured and reported (every step removes them
before it computes). When the settings are to be read off the data and no
excited band can be found, the command is refused (exit 10) rather than run on
fixed defaults; ``--analysis-band`` (and ``--integration-band``) or ``--no-settings-from-data``
say where to look instead.
"""

from __future__ import annotations

import argparse
import contextvars
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Sequence

import numpy as np

from nifo.io.loader import iter_record_chunks, seed_whole_bag
from nifo.io.memo import nbytes, remembered
from nifo_core.defaults import DEFAULT_ANALYSIS_BAND_HZ, DEFAULT_COND_LIMIT
from nifo_core.errors import ClippedSignalError, IllConditionedError, InputError, NifoError, RecordTooShortError
from nifo_core.signal.clipping import REFUSE_FRACTION, ClippingWarning, clipping
from nifo_core.signal.record import acceleration_means, concatenate
from nifo_core.signal.excitation import Excitation, analyse_excitation, combine_excitations
from nifo_core.characterize.restoring import suggest_band
from nifo_core.settings import (PAPER_BLOCK_S, AnalysisSettings, GivenSettings, merge_given, period_and_transient,
                                resolve_settings, shortest_after_transient)

__all__ = ["add_settings_arguments", "forget_step", "given_from_args", "given_from_file", "resolve", "for_records", "loader_options",
           "check_record", "in_context", "explain", "PROBE_SAMPLES"]

_DEFAULT_BAND = "{:g}-{:g}".format(*DEFAULT_ANALYSIS_BAND_HZ)

#: samples of each file read to choose settings from the data (58 min at 600 Hz: a whole sweep or road test; the
#: periods of a multisine), in chunks of PROBE_CHUNK (bags are decoded chunk by chunk)
PROBE_SAMPLES = 2 ** 21
PROBE_CHUNK = 2 ** 18


def add_settings_arguments(p: argparse.ArgumentParser, *, cond_limit: bool = True, band: bool = True,
                           analysis_band: bool = True, from_data: bool = True) -> None:
    """The spectral and band settings every data command takes (each chosen from the data when not given); a command
    leaves out the ones it has no use for (``band``: the integration band; ``analysis_band``; ``cond_limit``;
    ``from_data``: ``--no-settings-from-data``, for a command that never reads settings off the data). Each
    flag has the setting's one name (docs/CONTRACTS.md, "One name per setting"); the old flags stay as aliases."""
    g = p.add_argument_group("settings (each overrides the model file's; chosen from the data when neither gives it)")
    g.add_argument("--block", type=int, metavar="N",
                   help="samples per spectral block (periodic data: one period; random: the paper's 10.24 s)")
    g.add_argument("--overlap", type=float, metavar="F",
                   help="block overlap fraction (periodic: 0; random: 0.52)")
    g.add_argument("--window", metavar="W", help="window: flattop, hann, boxcar, ... (periodic: boxcar; random: "
                                                 "flattop)")
    if band:
        g.add_argument("--integration-band", "--band", type=float, nargs=2, metavar=("LO", "HI"),
                       dest="integration_band_hz",
                       help="integration band for z, ż [Hz] (from below the excited band to 3× its top)")
    if analysis_band:
        g.add_argument("--analysis-band", "--freq-range", type=float, nargs=2, metavar=("LO", "HI"),
                       dest="analysis_band_hz",
                       help="analysis band [Hz]: NIFO's pooled fit, the linear part, the prediction error (the "
                            "excited band)")
    if cond_limit:
        g.add_argument("--cond-limit", type=float, metavar="C",
                       help=f"scaled cond(G_UU) counted as ill-conditioned (default {DEFAULT_COND_LIMIT:g})")
    if not from_data:
        return
    g.add_argument("--no-settings-from-data", action="store_true", dest="no_settings_from_data",
                   help=f"settings not given take the defaults (paper Table 2, {_DEFAULT_BAND} Hz, 0.5-200 Hz), not "
                        "choices read off the data: what nifo fleet and the identifier node use")


def given_from_args(args: argparse.Namespace) -> GivenSettings:
    """What the command line gives (None where not given)."""
    get = lambda k: getattr(args, k, None)   # noqa: E731
    return GivenSettings(block=get("block"), overlap=get("overlap"), window=get("window"), integration_band_hz=get("integration_band_hz"),
                         analysis_band_hz=get("analysis_band_hz"), period_samples=get("period_samples"),
                         skip_periods=get("skip_periods"), skip_seconds=get("skip_seconds"),
                         cond_limit=get("cond_limit"))


def given_from_file(settings) -> GivenSettings:
    """A model file's ``settings:`` (validated by :mod:`nifo.io.modelfile`) as given settings."""
    s = dict(settings or {})
    return GivenSettings(block=s.get("block"), overlap=s.get("overlap"), window=s.get("window"),
                         integration_band_hz=s.get("integration_band_hz"),
                         analysis_band_hz=s.get("analysis_band_hz"))


#: bytes of probed records kept inside :func:`nifo.io.memo.reuse_reads` (an hour at 600 Hz probed is 2**21 samples
#: of 3-4 channels)
PROBE_MEMO_BYTES = 2 ** 27


def _load_options(opts: dict, given: GivenSettings) -> dict:
    load = {k: v for k, v in opts.items() if k not in ("skip_seconds", "skip_periods")}
    load["period_samples"] = given.period_samples
    return load


def _probe_read(path: Path, load: dict) -> tuple[object, int]:
    """(the first PROBE_SAMPLES samples of a file, whole from the start; the file's samples); inside
    :func:`nifo.io.memo.reuse_reads`, once per file."""
    return remembered(path, load, lambda: _read_first(path, load), kind="probe-read", max_bytes=PROBE_MEMO_BYTES,
                      size=lambda got: nbytes(got[0]))


def _read_first(path: Path, load: dict) -> tuple[object, int]:
    chunks = iter_record_chunks(path, chunk_samples=PROBE_CHUNK, **load)
    got = []
    try:
        for rec in chunks:
            got.append(rec)
            if sum(r.n for r in got) >= PROBE_SAMPLES:
                break
    finally:
        chunks.close()
    if not got:
        raise RecordTooShortError("the file holds no samples", source=str(path))
    total = int(got[0].meta.get("chunk", {}).get("total_samples", got[0].n))
    rec = got[0] if len(got) == 1 else concatenate(got)
    seed_whole_bag(path, rec, topics=load.get("topics"), axis=load.get("axis", "z"))   # read to its end: kept whole
    return rec, total


def _probe(path: Path, opts: dict, given: GivenSettings, read: tuple[object, int]
           ) -> tuple[Excitation | None, float, float, object]:
    """(excitation, fs, duration [s], first chunk) of one file from its first PROBE_SAMPLES samples (``read``:
    :func:`_probe_read`), whole from the start (the transient is part of what is probed); inside
    :func:`nifo.io.memo.reuse_reads`, once per file."""
    load = _load_options(opts, given)
    return remembered(path, load, lambda: _probe_file(path, load, *read), kind="probe", max_bytes=PROBE_MEMO_BYTES,
                      size=lambda got: nbytes(got[3]))


def _probe_file(path: Path, load: dict, rec, total: int) -> tuple[Excitation | None, float, float, object]:
    u = rec.force if rec.spindle_fixed else rec.spindle_accel
    name = "force" if rec.spindle_fixed else "spindle acceleration"
    means = acceleration_means(rec)      # removed in float64 before any spectrum: offsets of any size alike
    if not rec.spindle_fixed:
        u = u - means["spindle_accel"]
    try:
        ex = analyse_excitation(u, rec.body_accel - means["body_accel"], rec.fs_hz,
                                period_samples=load["period_samples"], input_name=name, source=str(path))
    except NifoError as err:      # nothing to read off these data: the caller says so, or takes what is given
        ex = None
        rec = replace(rec, meta={**dict(rec.meta), "settings_not_from_data": err.message})
    return ex, rec.fs_hz, total / rec.fs_hz, rec


#: a channel's constant offset is named when it is at least this fraction of the channel's RMS about its mean
OFFSET_NOTED = 0.1


def check_record(path: Path, rec) -> tuple[dict, list[str]]:
    """What is found in record ``rec`` of file ``path`` (its probed samples) before any setting is chosen (module
    docstring): ({"offsets_m_s2": ..., "clipping": ...}, notes to print). Raises for a clipped, dead or doubled
    channel; warns of a little clipping."""
    channels = {} if rec.spindle_fixed else {"spindle_accel": rec.spindle_accel}
    if rec.body_disp is not None:
        channels["body_disp"] = rec.body_disp
    else:
        channels["body_accel"] = rec.body_accel
    if rec.force is not None:
        channels["force"] = rec.force
    for name, x in channels.items():
        if x.size > 1 and not np.ptp(x) > 0:
            raise InputError(f"the channel is constant ({float(x[0]):g} in all {x.size} samples): a dead sensor or "
                             "an unplugged channel", source=str(path), channel=name,
                             hint="check the sensor and the channel mapping (--columns/--topics)")
    if not rec.spindle_fixed and np.array_equal(rec.spindle_accel, rec.body_accel):
        raise InputError("the spindle and the body hold the same samples: there is no relative motion to identify",
                         source=str(path), channel="body_accel",
                         hint="check the channel mapping (--columns/--topics): one channel read twice?")
    notes: list[str] = []
    clipped = {name: clipping(x) for name, x in channels.items()}
    for name, c in clipped.items():
        if c.fraction > REFUSE_FRACTION:
            raise ClippedSignalError(
                f"{100 * c.fraction:.3g} % of the samples sit flat at the channel's extremes ({c.low:.6g} and "
                f"{c.high:.6g}): the sensor or its amplifier clipped, which biases every estimate (nifo refuses "
                f"above {100 * REFUSE_FRACTION:g} %)", source=str(path), channel=name,
                hint="record again with more range (a less sensitive setting), or cut the record to a stretch "
                     "without clipping")
        if c.fraction > 0:   # printed once per command, on stderr even with --quiet (nifo.cli)
            warnings.warn(f"{path}: {name}: {100 * c.fraction:.2g} % of the samples sit flat at the channel's "
                          f"extremes (clipped?); nifo refuses above {100 * REFUSE_FRACTION:g} %: check the sensor's "
                          "range", ClippingWarning, stacklevel=1)
    means = acceleration_means(rec)
    big = {k: m for k, m in means.items()
           if abs(m) > OFFSET_NOTED * float(np.std(getattr(rec, k) - m)) and not (k == "spindle_accel" and
                                                                                 rec.spindle_fixed)}
    if big:
        notes.append(f"{path}: constant offset removed before every step: "
                     + ", ".join(f"{k} {m:.6g} m/s²" for k, m in big.items())
                     + " (a constant acceleration carries no dynamics)")
    return {"offsets_m_s2": means, "clipping": {k: c.to_dict() for k, c in clipped.items()}}, notes


def resolve(paths: Sequence[Path], args: argparse.Namespace | None = None, *, file_settings=None,
            opts: dict | None = None, given: GivenSettings | None = None,
            from_data: bool = True) -> AnalysisSettings:
    """The settings for ``paths``: command line (``args`` or ``given``) > model file > data > default — once per
    command (``nifo run``: once per job; its steps take the result through :func:`for_records`).

    Every record is checked first (:func:`check_record`). ``from_data=False`` (or ``--no-settings-from-data``): no
    probing for settings (the merge of what is given with the defaults).
    """
    cli = given if given is not None else (given_from_args(args) if args is not None else GivenSettings())
    merged, origin = merge_given(cli, given_from_file(file_settings))
    origins = {k: ("command line", "model file")[i] for k, i in origin.items()}
    opts = dict(opts or {})
    paths = [Path(p) for p in paths]
    inputs, notes, reads = _checked(paths, _load_options(opts, merged))
    excitation, snr, fs, durations = None, None, None, []
    if args is not None and getattr(args, "no_settings_from_data", False):
        from_data = False
    if from_data and paths:
        parts, probes = [], []
        for p, read in zip(paths, reads):
            ex, fs_p, dur, rec = _probe(p, opts, merged, read)
            if ex is None and merged.analysis_band_hz is None:
                _too_short_to_tell(p, rec)
                why = rec.meta.get("settings_not_from_data", "")
                raise IllConditionedError(
                    f"no excited band found in the data ({why}): the analysis band cannot be chosen from them",
                    source=str(p), hint="check the channels (--columns/--topics) and that the excitation was on; "
                    "or give the band yourself: --analysis-band LO HI (and --integration-band LO HI)")
            parts.append(ex)
            durations.append(dur)
            fs = fs_p if fs is None else fs
            probes.append(rec)
        first = probes[0]
        excitation = combine_excitations(parts) if all(e is not None for e in parts) else None
        if excitation is not None and not excitation.periodic and not first.spindle_fixed:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    snr = suggest_band([r.centred() for r in probes]).band.f_lo_hz
                except NifoError:
                    snr = None
    # without the data's choices the integration band stays open (None): each step takes its default for the
    # records it reads (default_band of the shortest, or characterize's noise edge), as before settings existed
    try:
        st = resolve_settings(merged, fs_hz=fs, durations_s=durations, excitation=excitation, snr_lo_hz=snr,
                              origins=origins)
    except NifoError as err:     # a setting the data cannot take (e.g. a band edge too low): name the data
        raise in_context(err, _Origins(origins), source=_shortest(paths, durations)) from None
    st = replace(st, inputs=inputs, notes=tuple(notes))
    _step.set((st, [str(p) for p in paths]))
    return st


def for_records(settings: AnalysisSettings, paths: Sequence[Path], *, opts: dict | None = None,
                from_data: bool = True) -> AnalysisSettings:
    """The settings resolved once (:func:`resolve`) on some of their records: a level ``nifo run`` characterizes
    alone, each file ``nifo predict`` predicts. Not a second resolution: every value stays the resolved one and keeps
    its source; what belongs to these records is theirs — their checks and notes (:func:`check_record`), their
    excitation (``from_data``), and the period and transient where the resolved settings left them to the data and
    found none (a periodic file among random ones: :func:`nifo_core.settings.period_and_transient`). The integration
    band is checked against the shortest of them (refused, naming it, when it cannot resolve the band's edge)."""
    opts = dict(opts or {})
    paths = [Path(p) for p in paths]
    fixed = GivenSettings(period_samples=settings.period_samples)
    inputs, notes, reads = _checked(paths, _load_options(opts, fixed))
    out: dict = {"inputs": inputs, "notes": tuple(notes), "excitation": None}
    probes = [_probe(p, opts, fixed, read) for p, read in zip(paths, reads)] if from_data else []
    if probes and all(ex is not None for ex, *_ in probes):
        out["excitation"] = combine_excitations([ex for ex, *_ in probes])
    try:
        if settings.period_samples is None and out["excitation"] is not None:
            choices = dict(settings.choices)
            left = GivenSettings(skip_seconds=settings.skip_seconds)
            timing = period_and_transient(left, out["excitation"], choices, lambda value, name: settings.choices[name])
            out.update(period_samples=timing.period_samples, skip_periods=timing.skip_periods, choices=choices)
        durations = [dur for _, _, dur, _ in probes]
        if settings.band is not None and probes:
            now = replace(settings, **out)
            fs = probes[0][1]
            shortest = shortest_after_transient(durations, fs, now.period_samples, now.skip_periods, now.skip_seconds)
            settings.band.validate(fs, n_samples=int(shortest * fs))
    except NifoError as err:
        raise in_context(err, settings, source=_shortest(paths, durations)) from None
    st = replace(settings, **out)
    _step.set((st, [str(p) for p in paths]))
    return st


def _checked(paths: list[Path], load: dict) -> tuple[dict, list[str], list]:
    """({path: what :func:`check_record` found}, its notes, the probed reads) of ``paths``."""
    inputs, notes, reads = {}, [], []
    for p in paths:
        reads.append(_probe_read(p, load))
        found, said = check_record(p, reads[-1][0])
        inputs[str(p)] = found
        notes += said
    return inputs, notes, reads


def _shortest(paths: list[Path], durations: list[float]) -> str | None:
    """The shortest record of ``paths`` (the one a band edge is about), else the first."""
    if durations:
        return str(paths[int(min(range(len(durations)), key=lambda i: durations[i]))])
    return str(paths[0]) if paths else None


#: fewer samples than this many of the paper's blocks (10.24 s) say nothing about a band: the record is too short
_FEWEST_BLOCKS = 2


def _too_short_to_tell(path: Path, rec) -> None:
    """A record too short for any band to be found in it is refused as too short, not as unexcited."""
    need = int(_FEWEST_BLOCKS * PAPER_BLOCK_S * rec.fs_hz)
    if rec.n < need:
        raise RecordTooShortError(f"{rec.n} samples ({rec.duration_s:.3g} s) are too few to tell the excited band "
                                  f"(at least {need}, {need / rec.fs_hz:.3g} s)", source=str(path),
                                  hint="record longer, or give the band yourself: --analysis-band LO HI")


class _Origins:
    """Where each setting came from, before the settings are whole (for :func:`in_context`)."""

    def __init__(self, origins: dict[str, str]) -> None:
        self.origins = origins

    def source_of(self, name: str) -> str:
        src = self.origins.get({"band": "integration_band_hz"}.get(name, name))
        return "chosen from the data" if src in (None, "data") else src


#: the settings an error may be about: (its flag, its name in the settings' choices, the words for it)
_SETTINGS_NAMED = (("--analysis-band", "analysis_band_hz", "analysis band"),
                   ("--integration-band", "band", "integration band"))

#: the settings of the step running in this context and the files it reads (:func:`explain`)
_step: contextvars.ContextVar[tuple[object, list[str]] | None] = contextvars.ContextVar("nifo_step", default=None)


def in_context(err: NifoError, settings, *, source: str | None = None) -> NifoError:
    """``err`` naming ``source`` (the data it is about) when it names none, and a setting by where it really came
    from: ``--analysis-band`` only when the user gave that flag, else "analysis band (chosen from the data)" or "(model
    file)", with a fix that fits (issue 56: a band nifo chose was reported as the user's flag, and no file named)."""
    msg, channel, hint = err.message, err.channel, err.hint
    for flag, name, words in _SETTINGS_NAMED:
        if not (channel in (flag, name, words) or msg.startswith((flag, words))):
            continue
        where = settings.source_of(name)
        if where != "command line":
            if channel in (flag, name, words) and not msg.startswith((flag, words)):
                channel = f"{words} ({where})"
            else:        # the message names the setting: it says where it came from
                channel = None if channel in (flag, name, words) else channel
                said = "given in the model file" if where == "model file" else f"{where}, not given"
                msg = msg.replace(flag, words, 1) + f" (the {words} was {said})"
            if where == "model file":
                hint = (f"{hint}, in the model file's settings (or give {flag} LO HI)" if hint else
                        f"correct it in the model file's settings, or give {flag} LO HI")
            else:
                hint = f"give {flag} LO HI where the data are excited" + (f"; or {hint}" if hint else "")
        break
    if (msg, channel, hint) == (err.message, err.channel, err.hint) and (err.source or not source):
        return err
    return type(err)(msg, source=err.source or source, channel=channel, hint=hint)


def forget_step() -> None:
    """Forget the settings a step chose in this context (a new command starts: :func:`explain` names its own)."""
    _step.set(None)


def explain(err: NifoError) -> NifoError:
    """``err`` in the context of the step that raised it (:func:`in_context` with the settings :func:`resolve`
    chose last in this context and the files they were chosen for)."""
    step = _step.get()
    if step is None:
        return err
    settings, paths = step
    return in_context(err, settings, source=", ".join(paths[:3]) + (", ..." if len(paths) > 3 else "") or None)


def loader_options(opts: dict, settings: AnalysisSettings) -> dict:
    """Input options for the loaders with the resolved period and transient."""
    out = dict(opts)
    out["period_samples"] = settings.period_samples
    out["skip_periods"] = settings.skip_periods if settings.period_samples else None
    out["skip_seconds"] = settings.skip_seconds
    return out
