"""What nifo shows in Rerun: one ``log_*`` function per entity subtree, and the blueprint.

Shared by ``nifo view`` (offline, from result directories) and the live viewer
node (:mod:`nifo_nodes.rerun_viewer`), so live and replay look the same. All
time-indexed data sit on one timeline, :data:`TIMELINE` (``stamp``), holding
the data's own stamps (source stamps of the samples; for an estimate, the stamp
of the newest sample in it), never the wall clock.

Entity tree
-----------
==================================  =====================================================================
``accel/<record>``                  spindle and body acceleration [m/s²] (two series), ``send_columns``
``restoring/velocity/<record>``     points (ż, ẍ2) per sample: the screen's y points down, so
                                    up is −ẍ2, the restoring force per unit mass; RMS-normalised axes
``restoring/displacement/<record>`` points (z, ẍ2), the same
``transmissibility/magnitude_db/*`` |T21| in dB vs frequency [Hz] (bar charts: Rerun's plots with an x
                                    axis other than time): ``nifo`` (pooled NIFO T21), ``per_line``
                                    (Eq. 9), ``h1`` (plain H1 at the identification level)
``transmissibility/phase_deg/*``    phase [°], the same curves
``transmissibility/coherence/*``    ``h1`` ordinary coherence, ``multiple`` multiple coherence
``coefficients/<term>/re``, ``/im`` μᵢ(ω)/K2 real and imaginary parts vs frequency
``convergence/n_avg``               spectral averages in the estimate (scalar vs stamp)
``convergence/cond_median``         median scaled cond(G_UU) over the analysis band (scalar vs stamp)
``loop/nmse``, ``loop/rounds``      held-out NMSE per loop round (bar chart), the rounds as a table
``summary``                         markdown: what was identified, settings and data provenance
==================================  =====================================================================

Frequency-domain curves are logged at the stamp of their estimate, so
scrubbing the timeline back shows the estimate converging.
"""

from __future__ import annotations

import re
from typing import Mapping, Sequence

import numpy as np

import rerun as rr
import rerun.blueprint as rrb

__all__ = ["TIMELINE", "APP_ID", "use_data_stamps", "blueprint", "entity_name", "log_styling", "log_accelerations", "log_restoring",
           "log_transmissibility", "log_coefficients", "log_convergence", "log_loop", "log_summary",
           "log_nifo_result", "FREQ_VIEW_HZ"]

APP_ID = "nifo"
TIMELINE = "stamp"
#: frequencies shown in the frequency-domain views [Hz]
FREQ_VIEW_HZ = (0.5, 40.0)

_SPINDLE, _BODY = (31, 119, 180), (214, 39, 40)
_COLOURS = {"nifo": (192, 57, 43), "per_line": (31, 119, 180), "h1": (60, 60, 60), "multiple": (46, 139, 87),
            "re": (31, 78, 121), "im": (230, 126, 34)}


def entity_name(name: str) -> str:
    """A record or term name as one entity-path part (letters, digits, ``_``, ``-``, ``.``)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name)).strip("_") or "record"


def _stamp(stamp_ns) -> rr.TimeColumn | None:
    return rr.TimeColumn(TIMELINE, timestamp=np.asarray(stamp_ns, dtype="datetime64[ns]"))


def _set_stamp(stamp_ns: int, recording) -> None:
    rr.set_time(TIMELINE, timestamp=np.datetime64(int(stamp_ns), "ns"), recording=recording)


def use_data_stamps(recording) -> None:
    """Only the data's stamps index this recording: no wall-clock ``log_time``, no ``log_tick``."""
    recording.set_log_time_enabled(False)
    recording.set_log_tick_enabled(False)


# ----------------------------------------------------------------------------------- blueprint
def blueprint() -> rrb.Blueprint:
    """The layout: time data on the left, frequency-domain estimate on the right, summary tab."""
    rolling = rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.cursor_relative(seconds=-10.0),
                                   end=rrb.TimeRangeBoundary.cursor_relative())
    left = rrb.Vertical(
        rrb.TimeSeriesView(origin="accel", name="accelerations [m/s²]",
                           time_ranges=[rrb.VisibleTimeRange(
                               TIMELINE, start=rrb.TimeRangeBoundary.cursor_relative(seconds=-5.0),
                               end=rrb.TimeRangeBoundary.cursor_relative())]),
        rrb.Horizontal(
            rrb.Spatial2DView(origin="restoring/velocity", name="restoring force −ẍ2 (up) vs ż, last 10 s",
                              time_ranges=[rolling]),
            rrb.Spatial2DView(origin="restoring/displacement", name="restoring force −ẍ2 (up) vs z, last 10 s",
                              time_ranges=[rolling])),
        rrb.Horizontal(
            rrb.TimeSeriesView(origin="convergence/n_avg", name="spectral averages"),
            rrb.TimeSeriesView(origin="convergence/cond_median", name="median scaled cond(G_UU)")),
        row_shares=[1.0, 1.4, 0.7], name="time domain")
    right = rrb.Vertical(
        rrb.BarChartView(origin="transmissibility/magnitude_db", name="|T21| [dB] vs frequency [Hz]"),
        rrb.BarChartView(origin="transmissibility/phase_deg", name="phase T21 [°] vs frequency [Hz]"),
        rrb.BarChartView(origin="transmissibility/coherence", name="coherence vs frequency [Hz]"),
        rrb.BarChartView(origin="coefficients", name="coefficient functions μᵢ/K2: Re, Im vs frequency [Hz]"),
        row_shares=[1.4, 0.9, 0.8, 1.1], name="frequency domain")
    main = rrb.Horizontal(left, right, column_shares=[1.0, 1.1], name="nifo")
    extra = rrb.Vertical(rrb.BarChartView(origin="loop/nmse", name="loop: held-out NMSE [%] per round"),
                         rrb.TextDocumentView(origin="loop/rounds", name="loop rounds"), name="loop")
    summary = rrb.TextDocumentView(origin="summary", name="summary")
    return rrb.Blueprint(rrb.Tabs(main, extra, summary, name="nifo"),
                         rrb.TimePanel(state="collapsed", timeline=TIMELINE),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"))


# ----------------------------------------------------------------------------------- static styling
def log_styling(*, recording=None) -> None:
    """Static styling logged once: series names and colours."""
    rr.log("convergence/n_avg", rr.SeriesLines(colors=[(46, 139, 87)], names=["n_avg"]), static=True,
           recording=recording)
    rr.log("convergence/cond_median", rr.SeriesLines(colors=[(161, 92, 0)], names=["median cond"]), static=True,
           recording=recording)


def log_record_styling(record: str, *, recording=None) -> None:
    """Static styling of one record's acceleration series."""
    rr.log(f"accel/{entity_name(record)}",
           rr.SeriesLines(colors=[_SPINDLE, _BODY], names=[f"{record} spindle ẍ1", f"{record} body ẍ2"],
                          widths=[1.0, 1.0]), static=True, recording=recording)


# ----------------------------------------------------------------------------------- time domain
def log_accelerations(record: str, stamp_ns: np.ndarray, spindle_accel: np.ndarray, body_accel: np.ndarray, *,
                      recording=None) -> None:
    """Spindle and body acceleration [m/s²] of ``record`` at the samples' stamps [ns] (one bulk send)."""
    rr.send_columns(f"accel/{entity_name(record)}", indexes=[_stamp(stamp_ns)],
                    columns=rr.Scalars.columns(scalars=np.column_stack([spindle_accel, body_accel])),
                    recording=recording)


def log_restoring(record: str, stamp_ns: np.ndarray, z: np.ndarray, zdot: np.ndarray, body_accel: np.ndarray, *,
                  scale: tuple[float, float, float], recording=None) -> None:
    """Restoring-force points, one per sample at its stamp: (ż/s_ż, ẍ2/s_a) and (z/s_z, ẍ2/s_a).

    ``scale`` = (s_z [m], s_ż [m/s], s_a [m/s²]) makes the clouds about square in Rerun's equal-aspect 2D
    views (use the RMS of each). The screen's y axis points down, so the restoring force −ẍ2 points up.
    """
    sz, sv, sa = (float(s) if s and np.isfinite(s) else 1.0 for s in scale)
    idx = [_stamp(stamp_ns)]
    y = np.asarray(body_accel) / sa
    name = entity_name(record)
    for sub, x in (("velocity", np.asarray(zdot) / sv), ("displacement", np.asarray(z) / sz)):
        rr.send_columns(f"restoring/{sub}/{name}", indexes=idx,
                        columns=rr.Points2D.columns(positions=np.column_stack([x, y])).partition(
                            np.ones(len(x), dtype=np.int32)), recording=recording)


def log_restoring_styling(record: str, *, colour=(31, 78, 121), recording=None) -> None:
    name = entity_name(record)
    for sub in ("velocity", "displacement"):
        rr.log(f"restoring/{sub}/{name}", rr.Points2D.from_fields(colors=[colour], radii=[-1.5]), static=True,
               recording=recording)


# ----------------------------------------------------------------------------------- frequency domain
def _bars(path: str, freq_hz: np.ndarray, values: np.ndarray, colour, *, recording) -> None:
    f = np.asarray(freq_hz, float)
    v = np.asarray(values, float)
    m = (f >= FREQ_VIEW_HZ[0]) & (f <= FREQ_VIEW_HZ[1]) & np.isfinite(v)
    df = float(np.median(np.diff(f))) if f.size > 1 else 1.0
    rr.log(path, rr.BarChart(v[m], abscissa=f[m], widths=np.full(int(m.sum()), df, np.float32), color=colour),
           recording=recording)


def log_transmissibility(stamp_ns: int, freq_hz: np.ndarray, curves: Mapping[str, np.ndarray], *,
                         coherence: Mapping[str, np.ndarray] | None = None, recording=None) -> None:
    """Complex transmissibilities (name → T21(f)) as magnitude [dB] and phase [°], and coherences, at ``stamp_ns``."""
    _set_stamp(stamp_ns, recording)
    for name, h in curves.items():
        h = np.asarray(h, complex)
        with np.errstate(divide="ignore"):
            db = 20 * np.log10(np.abs(h))
        col = _COLOURS.get(name, (120, 120, 120))
        _bars(f"transmissibility/magnitude_db/{entity_name(name)}", freq_hz, db, col, recording=recording)
        _bars(f"transmissibility/phase_deg/{entity_name(name)}", freq_hz, np.degrees(np.angle(h)), col,
              recording=recording)
    for name, c in (coherence or {}).items():
        _bars(f"transmissibility/coherence/{entity_name(name)}", freq_hz, c, _COLOURS.get(name, (120, 120, 120)),
              recording=recording)


def log_coefficients(stamp_ns: int, freq_hz: np.ndarray, labels: Sequence[str], mu_over_k2: np.ndarray, *,
                     recording=None) -> None:
    """Coefficient functions μᵢ(ω)/K2 (shape (n_terms, nf)), real and imaginary parts, at ``stamp_ns``."""
    _set_stamp(stamp_ns, recording)
    for label, mu in zip(labels, np.asarray(mu_over_k2, complex)):
        name = entity_name(label)
        _bars(f"coefficients/{name}/re", freq_hz, mu.real, _COLOURS["re"], recording=recording)
        _bars(f"coefficients/{name}/im", freq_hz, mu.imag, _COLOURS["im"], recording=recording)


def log_convergence(stamp_ns: int, *, n_avg: int, cond_median: float, recording=None) -> None:
    """Spectral averages and the median condition number of the estimate at ``stamp_ns``."""
    _set_stamp(stamp_ns, recording)
    rr.log("convergence/n_avg", rr.Scalars(float(n_avg)), recording=recording)
    if np.isfinite(cond_median):
        rr.log("convergence/cond_median", rr.Scalars(float(cond_median)), recording=recording)


def log_nifo_result(stamp_ns: int, result, *, recording=None) -> None:
    """A :class:`nifo_core.nifo.identify.NifoResult` (final or intermediate): transmissibility, coherence,
    coefficients and convergence at ``stamp_ns`` — what the identifier node publishes."""
    curves = {"h1": result.t21_h1}
    if len(result.terms):
        curves["per_line"] = result.t21
        curves["nifo"] = result.static.t21 if result.static is not None else result.t21
    log_transmissibility(stamp_ns, result.freq_hz, curves,
                         coherence={"h1": result.coherence_h1, "multiple": result.multiple_coherence},
                         recording=recording)
    if len(result.terms):
        log_coefficients(stamp_ns, result.freq_hz, [t.label for t in result.terms], result.mu_over_k2,
                         recording=recording)
    c = np.asarray(result.cond)[result.in_band]
    log_convergence(stamp_ns, n_avg=int(result.n_avg),
                    cond_median=float(np.nanmedian(c)) if np.any(np.isfinite(c)) else float("nan"),
                    recording=recording)


# ----------------------------------------------------------------------------------- loop and summary
def log_loop(rounds: Sequence[Mapping], *, nmse: Sequence[float] | None = None, text: str = "",
             recording=None) -> None:
    """The loop's rounds (static): held-out NMSE per round as bars (round 0 = declared model) and a table."""
    if nmse is not None and len(nmse):
        v = np.asarray([np.nan if x is None else x for x in nmse], float)
        rr.log("loop/nmse", rr.BarChart(np.nan_to_num(v), abscissa=np.arange(v.size, dtype=float),
                                        color=(31, 78, 121)), static=True, recording=recording)
    lines = [text, "", "| round | added | NMSE after [%] |", "|---|---|---|"] if rounds else [text]
    for i, r in enumerate(rounds, 1):
        after = nmse[i] if nmse is not None and i < len(nmse) else None
        lines.append(f"| {r.get('round', i)} | {r.get('_label', '')} | {'' if after is None else f'{after:.3g}'} |")
    rr.log("loop/rounds", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True,
           recording=recording)


def log_summary(markdown: str, *, recording=None) -> None:
    """What was identified, the settings and the data provenance, as a static markdown document."""
    rr.log("summary", rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True, recording=recording)
