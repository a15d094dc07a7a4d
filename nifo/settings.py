"""The settings of every command: the same flags everywhere, one merge, choices read off the data.

:func:`add_settings_arguments` gives every data command the same settings
flags (``--block``, ``--overlap``, ``--window``, ``--band``, ``--freq-range``,
``--cond-limit``; ``--period-samples``, ``--skip-periods``, ``--skip-seconds``
come with the input options of :func:`nifo.io.loader.add_input_arguments`).
:func:`resolve` merges them — command line > model file > chosen from the
data > default — through :func:`nifo_core.settings.resolve_settings`: the
data are probed once (the first :data:`PROBE_SAMPLES` samples of each file,
bounded memory whatever the recording's length) for a periodic excitation,
its transient and the excited band (:mod:`nifo_core.signal.excitation`). It returns
the :class:`~nifo_core.settings.AnalysisSettings` and the input options with
the period and transient filled in, for the loaders.
"""

from __future__ import annotations

import argparse
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Sequence

from nifo.io.loader import iter_record_chunks
from nifo.io.memo import nbytes, remembered
from nifo_core.errors import NifoError, RecordTooShortError
from nifo_core.signal.record import concatenate
from nifo_core.signal.excitation import Excitation, analyse_excitation, combine_excitations
from nifo_core.characterize.restoring import suggest_band
from nifo_core.settings import AnalysisSettings, GivenSettings, merge_given, resolve_settings

__all__ = ["add_settings_arguments", "given_from_args", "given_from_file", "resolve", "loader_options",
           "PROBE_SAMPLES"]

#: samples of each file read to choose settings from the data (58 min at 600 Hz: a whole sweep or road test; the
#: periods of a multisine), in chunks of PROBE_CHUNK (bags are decoded chunk by chunk)
PROBE_SAMPLES = 2 ** 21
PROBE_CHUNK = 2 ** 18


def add_settings_arguments(p: argparse.ArgumentParser, *, cond_limit: bool = True, band: bool = True,
                           freq_range: bool = True) -> None:
    """The spectral and band settings every data command takes (each chosen from the data when not given); a command
    leaves out the ones it has no use for (``band``: the integration band; ``freq_range``; ``cond_limit``)."""
    g = p.add_argument_group("settings (each overrides the model file's; chosen from the data when neither gives it)")
    g.add_argument("--block", type=int, metavar="N",
                   help="samples per spectral block (periodic data: one period; random: the paper's 10.24 s)")
    g.add_argument("--overlap", type=float, metavar="F",
                   help="block overlap fraction (periodic: 0; random: 0.52)")
    g.add_argument("--window", metavar="W", help="window: flattop, hann, boxcar, ... (periodic: boxcar; random: "
                                                 "flattop)")
    if band:
        g.add_argument("--band", type=float, nargs=2, metavar=("LO", "HI"),
                       help="integration band for z, ż [Hz] (from below the excited band to 3× its top)")
    if freq_range:
        g.add_argument("--freq-range", type=float, nargs=2, metavar=("LO", "HI"),
                       help="analysis band [Hz]: NIFO's pooled fit, the linear part, the prediction error (the "
                            "excited band)")
    if cond_limit:
        g.add_argument("--cond-limit", type=float, metavar="C",
                       help="scaled cond(G_UU) counted as ill-conditioned (default 1e4)")
    g.add_argument("--no-settings-from-data", action="store_true", dest="no_settings_from_data",
                   help="settings not given take the defaults (paper Table 2, 2-30 Hz, 0.5-200 Hz), not choices read "
                        "off the data: what nifo fleet and the identifier node use")


def given_from_args(args: argparse.Namespace) -> GivenSettings:
    """What the command line gives (None where not given)."""
    get = lambda k: getattr(args, k, None)   # noqa: E731
    return GivenSettings(block=get("block"), overlap=get("overlap"), window=get("window"), band_hz=get("band"),
                         analysis_band_hz=get("freq_range"), period_samples=get("period_samples"),
                         skip_periods=get("skip_periods"), skip_seconds=get("skip_seconds"),
                         cond_limit=get("cond_limit"))


def given_from_file(settings) -> GivenSettings:
    """A model file's ``settings:`` (validated by :mod:`nifo.io.modelfile`) as given settings."""
    s = dict(settings or {})
    return GivenSettings(block=s.get("block"), overlap=s.get("overlap"), window=s.get("window"),
                         band_hz=s.get("band_hz"), analysis_band_hz=s.get("freq_range_hz"))


#: bytes of probed records kept inside :func:`nifo.io.memo.reuse_reads` (an hour at 600 Hz probed is 2**21 samples
#: of 3-4 channels)
PROBE_MEMO_BYTES = 2 ** 27


def _probe(path: Path, opts: dict, given: GivenSettings) -> tuple[Excitation, float, float, object]:
    """(excitation, fs, duration [s], first chunk) of one file from its first PROBE_SAMPLES samples, whole from the
    start (the transient is part of what is probed); inside :func:`nifo.io.memo.reuse_reads`, once per file."""
    load = {k: v for k, v in opts.items() if k not in ("skip_seconds", "skip_periods")}
    load["period_samples"] = given.period_samples
    return remembered(path, load, lambda: _probe_file(path, load), kind="probe", max_bytes=PROBE_MEMO_BYTES,
                      size=lambda got: nbytes(got[3]))


def _probe_file(path: Path, load: dict) -> tuple[Excitation, float, float, object]:
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
    u = rec.force if rec.spindle_fixed else rec.spindle_accel
    name = "force" if rec.spindle_fixed else "spindle acceleration"
    try:
        ex = analyse_excitation(u, rec.body_accel, rec.fs_hz, period_samples=load["period_samples"],
                                input_name=name, source=str(path))
    except NifoError as err:      # nothing to read off these data: the defaults, and why (the steps say what fails)
        ex = None
        rec = replace(rec, meta={**dict(rec.meta), "settings_not_from_data": err.message})
    return ex, rec.fs_hz, total / rec.fs_hz, rec


def resolve(paths: Sequence[Path], args: argparse.Namespace | None = None, *, file_settings=None,
            opts: dict | None = None, given: GivenSettings | None = None,
            from_data: bool = True) -> AnalysisSettings:
    """The settings for ``paths``: command line (``args`` or ``given``) > model file > data > default.

    ``from_data=False``: no probing (the merge of what is given with the defaults).
    """
    cli = given if given is not None else (given_from_args(args) if args is not None else GivenSettings())
    merged, origin = merge_given(cli, given_from_file(file_settings))
    origins = {k: ("command line", "model file")[i] for k, i in origin.items()}
    opts = dict(opts or {})
    excitation, snr, fs, durations = None, None, None, []
    if args is not None and getattr(args, "no_settings_from_data", False):
        from_data = False
    if from_data and paths:
        parts, probes = [], []
        for p in paths:
            ex, fs_p, dur, rec = _probe(Path(p), opts, merged)
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
                    snr = suggest_band(probes).band.f_lo_hz
                except NifoError:
                    snr = None
    # without the data's choices the integration band stays open (None): each step takes its default for the
    # records it reads (default_band of the shortest, or characterize's noise edge), as before settings existed
    try:
        return resolve_settings(merged, fs_hz=fs, durations_s=durations, excitation=excitation, snr_lo_hz=snr,
                                origins=origins)
    except NifoError as err:     # a setting the data cannot take (e.g. a band edge too low): name the data
        shortest = paths[int(min(range(len(durations)), key=lambda i: durations[i]))] if durations else \
            (paths[0] if paths else None)
        raise err.with_context(source=None if shortest is None else str(shortest)) from None


def loader_options(opts: dict, settings: AnalysisSettings) -> dict:
    """Input options for the loaders with the resolved period and transient."""
    out = dict(opts)
    out["period_samples"] = settings.period_samples
    out["skip_periods"] = settings.skip_periods if settings.period_samples else None
    out["skip_seconds"] = settings.skip_seconds
    return out
