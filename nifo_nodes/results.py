"""The identifier's results as ``nifo_msgs`` messages, and the result document written to a file.

Typed, moderate-size messages a ROS user can plot (Foxglove: ``t21_nominal_abs``
against ``freq_hz``; PlotJuggler; ``ros2 topic echo``), each with a
``std_msgs/Header`` whose stamp is the source stamp of the newest sample in the
estimate (never the wall clock) and whose frame id is the body sensor's:

* ``nifo_msgs/Transmissibility`` — nominal T21 (pooled static fit, what ``nifo
  identify`` recommends), per-line T21 (paper Eq. 9), plain H1, coherences,
  cond(G_UU), plus the stream accounting (samples used / lost, gaps);
* ``nifo_msgs/Coefficients`` — pooled c_i/M2 per term and the per-line c_i/M2,
  B_i (paper Eq. 8), term i at entries ``[i·F, (i+1)·F)``;
* ``nifo_msgs/LoopStatus`` — state, one-line message, counters, conditioning and
  the path of the full result document.

The full document (``NifoResult.to_dict()``, ≈2 MB: every line of every
quantity, the bounds' random errors, settings) never goes onto a topic: it is
written atomically to a file (:func:`write_result_file`) and its path published.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["msg_types", "StreamStats", "transmissibility_msg", "coefficients_msg", "status_msg", "write_result_file",
           "STATES", "state_of"]

#: ``LoopStatus.state`` values
STATES = ("waiting", "estimating", "ill_conditioned")


@dataclass
class StreamStats:
    """What happened to the stream the estimate was made from."""

    samples_received: int = 0  #: samples pushed into the estimator
    samples_lost: int = 0      #: samples missing between blocks (by their stamps), never averaged
    gaps: int = 0              #: discontinuities: each closed the record (no spectral block spans one)
    samples_skipped: int = 0   #: samples received again (duplicates, a replay started over): used once
    blocks_missing: int = 0    #: sample blocks that never arrived (gaps in the integrator's block counter)

    def as_dict(self) -> dict:
        return {"samples_received": self.samples_received, "samples_lost": self.samples_lost, "gaps": self.gaps,
                "samples_skipped": self.samples_skipped, "blocks_missing": self.blocks_missing}


def msg_types():
    """``(Transmissibility, Coefficients, LoopStatus)`` from ``nifo_msgs``, or one :class:`ConfigError`
    saying how to build them (a node started without them stops with one line, not a traceback)."""
    try:
        from nifo_msgs.msg import Coefficients, LoopStatus, Transmissibility
    except ImportError as err:
        from nifo_core.errors import ConfigError
        raise ConfigError(f"the nifo_msgs result messages are not installed ({err})", source="nifo_msgs",
                          hint="build them into the venv: ros2_ws/build_msgs.sh .venv (./test.sh and ./nifo.sh "
                               "do it); with ROS 2: colcon build ros2_ws") from None
    return Transmissibility, Coefficients, LoopStatus


def _header(msg, stamp_ns: int, frame_id: str):
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(sec), int(nsec)
    msg.header.frame_id = frame_id
    return msg


def _f(a) -> list:
    return np.ascontiguousarray(a, np.float64).tolist()


def state_of(r, cond_limit: float) -> tuple[str, str]:
    """``(state, one-line message)`` for a result (``None``: nothing averaged yet)."""
    if r is None:
        return "waiting", "no spectral block averaged yet"
    cond = r.conditioning(cond_limit)     # the summary nifo identify reports (NifoResult.conditioning)
    med, ill = cond.median, cond.ill_fraction
    if ill > 0.5:
        return "ill_conditioned", (f"cond(G_UU) above {cond_limit:g} on {100 * ill:.0f} % of the analysis band: "
                                   "the terms cannot be separated at this level (more amplitude or fewer terms)")
    return "estimating", f"{r.n_avg} blocks averaged; cond(G_UU) median {med:.3g}"


def transmissibility_msg(r, *, stamp_ns: int, frame_id: str, stream: StreamStats):
    from nifo_msgs.msg import Transmissibility

    nominal = r.static.t21 if r.static is not None else r.t21
    m = _header(Transmissibility(), stamp_ns, frame_id)
    m.n_avg, m.samples_used = int(r.n_avg), int(r.n_samples)
    m.samples_lost, m.gaps = int(stream.samples_lost), int(stream.gaps)
    m.fs_hz = float(r.fs_hz)
    m.analysis_band_hz = [float(x) for x in r.analysis_band_hz]
    m.freq_hz = _f(r.freq_hz)
    m.t21_nominal_abs, m.t21_nominal_phase_deg = _f(np.abs(nominal)), _f(np.degrees(np.angle(nominal)))
    m.t21_nominal_re, m.t21_nominal_im = _f(nominal.real), _f(nominal.imag)
    m.t21_re, m.t21_im = _f(r.t21.real), _f(r.t21.imag)
    m.t21_h1_re, m.t21_h1_im = _f(r.t21_h1.real), _f(r.t21_h1.imag)
    m.coherence_h1, m.multiple_coherence, m.cond = _f(r.coherence_h1), _f(r.multiple_coherence), _f(r.cond)
    return m


def coefficients_msg(r, *, stamp_ns: int, frame_id: str):
    from nifo_msgs.msg import Coefficients

    m = _header(Coefficients(), stamp_ns, frame_id)
    m.n_avg = int(r.n_avg)
    m.terms = [t.label for t in r.terms]
    nt = len(r.terms)
    m.c_pooled = _f(r.static.c_over_m2 if r.static is not None else np.full(nt, np.nan))
    m.freq_hz = _f(r.freq_hz)
    c = np.asarray(r.c_over_m2).reshape(nt, -1)
    b = np.asarray(r.b).reshape(nt, -1)
    m.c_re, m.c_im = _f(c.real.ravel()), _f(c.imag.ravel())
    m.b_re, m.b_im = _f(b.real.ravel()), _f(b.imag.ravel())
    return m


def status_msg(r, *, stamp_ns: int, frame_id: str, stream: StreamStats, cond_limit: float, result_file: str):
    from nifo_msgs.msg import LoopStatus

    m = _header(LoopStatus(), stamp_ns, frame_id)
    m.state, m.message = state_of(r, cond_limit)
    if stream.gaps:
        m.message += f"; {stream.gaps} stream gap(s), {stream.samples_lost} samples lost (not averaged)"
    m.samples_lost, m.gaps = int(stream.samples_lost), int(stream.gaps)
    m.samples_used = 0
    if r is not None:
        m.n_avg, m.samples_used = int(r.n_avg), int(r.n_samples)
        cond = r.conditioning(cond_limit)
        m.cond_median, m.cond_max, m.ill_conditioned_fraction = cond.median, cond.max, cond.ill_fraction
    else:
        m.cond_median = m.cond_max = float("nan")
        m.ill_conditioned_fraction = 0.0
    m.result_file = result_file
    return m


def write_result_file(path: str | Path, r, *, stamp_ns: int, stream: StreamStats) -> None:
    """``NifoResult.to_dict()`` plus ``stamp_ns`` and ``stream`` (samples used/lost, gaps) as JSON, atomically."""
    from nifo.io.atomic import staged_file

    from nifo_core import __version__

    doc = r.to_dict()
    doc["nifo_version"] = __version__   # nifo's mark: the next write may replace it (nifo.io.ownership)
    doc["stamp_ns"] = int(stamp_ns)
    doc["stream"] = {"samples_used": int(r.n_samples), **stream.as_dict()}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with staged_file(path) as tmp:
        Path(tmp).write_text(json.dumps(doc))
