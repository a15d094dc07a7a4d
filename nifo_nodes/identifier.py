"""The identifier node: aligned acceleration blocks in, the live NIFO estimate out.

Subscribes ``accel/block`` (from the integrator node) and feeds the samples to
:class:`nifo_core.nifo.identify.StreamingNifo` — the code path ``identify_nifo`` (``nifo
identify``) runs, so the live estimate is the batch one. Every
``publish_period_s`` (when new spectral blocks were averaged) it publishes,
reliable + transient local (a late subscriber gets the latest), typed
``nifo_msgs`` messages with a ``std_msgs/Header`` (stamp = source stamp of the
newest sample used, frame id ``frame_id``; fields in :mod:`nifo_nodes.results`):

* ``identifier/transmissibility`` — ``nifo_msgs/Transmissibility``: nominal T21
  (pooled static fit, what ``nifo identify`` recommends), per-line T21 = X2/X1
  (paper Eq. 9), plain H1, coherences, cond(G_UU), samples used / lost, gaps;
* ``identifier/coefficients`` — ``nifo_msgs/Coefficients``: pooled and per-line
  c_i/M2, B_i (paper Eq. 8);
* ``identifier/status`` — ``nifo_msgs/LoopStatus``: state, counters,
  conditioning, and ``result_file``: the full ``NifoResult`` JSON (with a
  ``stream`` section), written atomically to ``result_file`` (large documents
  go to a file, not onto a topic).

and once a second ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``: WARN
with stream gaps or an ill-conditioned estimate).

Stream bookkeeping: samples are identified by their stamps and each stamp is
used once. A block continuing the previous one is pushed; one that starts
later (a gap, a new segment) first closes the current record
(``StreamingNifo.end_record``: no block spans the gap); samples at or before
the newest already used are skipped (a duplicate, a replay started again:
that is how a restarted identifier resumes exactly). To accumulate the same
data again, reset first.

Parameters: ``model_file`` (YAML model file, ``nifo_model: 1``; its
``settings`` give the defaults of the next four), ``block``, ``overlap``,
``window``, ``integration_band_hz`` (an edge 0: its default; also read as ``f_lo_hz``/``f_hi_hz``),
``analysis_band_hz``, ``cond_limit``, ``publish_period_s``, ``checkpoint_file``
(``""``: none), ``checkpoint_period_s``, ``result_file`` (``""``: beside the
checkpoint, else ``$ROS_HOME/nifo/identifier_result.json``), ``frame_id``,
``reset`` (set true to drop everything accumulated; reads back false). The
settings parameters and the model file's ``settings`` are resolved once at
start-up, by the precedence function of every command (:func:`node_settings`:
parameter > model file > default), into the one
:class:`~nifo_core.settings.AnalysisSettings` the accumulator is built from
when the stream's rate is known (:func:`identify_setup`), as ``nifo fleet``
builds its workers' set-ups from it. Every
parameter has a descriptor (description, range; ``ros2 param describe``). With ``std_srvs`` installed there is also the service
``~/reset`` (``std_srvs/srv/Trigger``).

Checkpoint: an ``.npz`` of ``StreamingNifo.state_dict()`` plus the newest stamp
used, written atomically (:func:`nifo.io.atomic.staged_file`) every
``checkpoint_period_s`` and at shutdown. At start-up an existing checkpoint
with the same terms and settings is resumed; one that does not match is left
in place and the node refuses to start (delete it or point elsewhere).
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from nifo_core.defaults import DEFAULT_ANALYSIS_BAND_HZ, DEFAULT_COND_LIMIT
from nifo_core.errors import ConfigError, NifoError

from .common import (IDENTIFIER_BLOCK_DEPTH, INTEGRATION_BAND_PARAMS, TOPICS, Diagnostics, Param, block_qos,
                     declare_parameters, integration_edges, result_qos, run_node)
from .integrator import ACCEL_CHANNELS
from .messages import block_from_msg
from .results import (StreamStats, coefficients_msg, msg_types, state_of, status_msg, transmissibility_msg,
                      write_result_file)

__all__ = ["IdentifierNode", "main", "load_checkpoint", "save_checkpoint", "node_settings", "identify_setup",
           "given_fields"]

try:
    from rclpy.node import Node
except ImportError:  # pragma: no cover
    Node = object

_CKPT_VERSION = 1


_STREAM_KEYS = ("samples_received", "samples_lost", "gaps", "samples_skipped", "blocks_missing")


def save_checkpoint(path: str | Path, nifo, *, next_ns: int, stream: StreamStats | None = None) -> None:
    """Write ``nifo``'s state, the stream position and its accounting atomically (``.npz``)."""
    from nifo.io.atomic import staged_file

    state = nifo.state_dict()
    state["node.version"] = np.array(_CKPT_VERSION)
    state["node.next_ns"] = np.array(int(next_ns), np.int64)
    for k, v in (stream or StreamStats()).as_dict().items():
        state[f"node.stream.{k}"] = np.array(int(v), np.int64)
    with staged_file(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **state)


def load_checkpoint(path: str | Path):
    """``(StreamingNifo, next_ns, stream)`` from :func:`save_checkpoint`'s file (``stream``: the
    :class:`StreamStats` fields as a dict).

    Anything else — a truncated or corrupt file, another program's ``.npz``, an
    older layout — raises one :class:`ConfigError` naming the file and the fix.
    """
    from nifo_core.nifo.identify import StreamingNifo

    def bad(why: str) -> ConfigError:
        return ConfigError(f"not a usable nifo identifier checkpoint ({why})", source=str(path),
                           hint="delete it (or set another checkpoint_file) to start afresh")

    try:
        with np.load(path, allow_pickle=False) as z:
            state = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as err:
        raise bad(f"cannot read it: {type(err).__name__}: {err}") from None
    try:
        version = int(state.pop("node.version", -1))
    except (TypeError, ValueError):
        version = -1
    if version != _CKPT_VERSION or "node.next_ns" not in state:
        raise bad(f"layout version {version}, expected {_CKPT_VERSION}")
    try:
        next_ns = int(state.pop("node.next_ns"))
        stream = {k: int(state.pop(f"node.stream.{k}", 0)) for k in _STREAM_KEYS}
        return StreamingNifo.from_state(state), next_ns, stream
    except NifoError as err:
        raise bad(str(err)) from None
    except (KeyError, ValueError, TypeError, IndexError) as err:
        raise bad(f"incomplete state: {type(err).__name__}: {err}") from None


def default_result_file(checkpoint: str) -> Path:
    if checkpoint:
        c = Path(checkpoint)
        return c.with_name(c.stem + ".result.json")
    home = Path(os.environ.get("ROS_HOME") or Path.home() / ".ros")
    return home / "nifo" / "identifier_result.json"


def given_fields(p: dict) -> dict:
    """The node's parameters as settings given (0 / -1 / empty: not given — the model file's or the
    default)."""
    out: dict = {}
    if int(p.get("block", 0)):
        out["block"] = int(p["block"])
    if float(p.get("overlap", -1.0)) >= 0:
        out["overlap"] = float(p["overlap"])
    if str(p.get("window", "")):
        out["window"] = str(p["window"])
    lo, hi = integration_edges(p)
    if lo > 0 and hi > 0:
        out["integration_band_hz"] = (lo, hi)
    band = tuple(float(x) for x in p.get("analysis_band_hz", (0.0, 0.0)))
    if any(band):                      # [0, 0]: not given
        out["analysis_band_hz"] = band
    if float(p.get("cond_limit", 0.0)) > 0:
        out["cond_limit"] = float(p["cond_limit"])
    return out


def node_settings(p: dict, *, log=None):
    """The identifier's terms and its :class:`~nifo_core.settings.AnalysisSettings`, resolved once at start-up by the
    precedence function every command uses (:func:`nifo.settings.resolve`: node parameters > model file > defaults;
    no data yet, so an integration band not given stays open until the stream's rate is known: :func:`identify_setup`).
    ``p``: the node's parameters (:data:`PARAMS`)."""
    from nifo.io.modelfile import load_model_spec
    from nifo.settings import resolve
    from nifo_core.settings import GivenSettings

    terms, ms = (), {}
    if p["model_file"]:
        spec = load_model_spec(p["model_file"])
        if spec.two_step:
            raise ConfigError("the identifier node runs single-step models only", source=p["model_file"],
                              hint="identify step 1 offline (nifo identify) and list step 2's terms")
        terms, ms = spec.terms, dict(spec.settings)
    if not terms and log is not None:
        log.warning("no nonlinearities given (model_file): estimating the linear T21 only")
    settings = resolve([], given=GivenSettings(**given_fields(p)), file_settings=ms, from_data=False)
    return tuple(terms), settings


def identify_setup(settings, terms, fs_hz: float, *, edges: tuple[float, float] = (0.0, 0.0)):
    """The core's set-up (:class:`~nifo_core.nifo.engine.IdentifySetup`: the conditioning limit included) of a stream
    at ``fs_hz`` with the resolved ``settings``; the integration band not given is the default of this rate, and one
    edge given alone (``edges``: the node's integration-band parameters, 0 an edge not given) replaces that edge of
    it. The live stream carries the two accelerations only (:data:`ACCEL_CHANNELS`)."""
    from nifo_core.nifo.engine import IdentifySetup
    from nifo_core.signal.integrate import IntegrationBand, default_band

    band = (settings.band or default_band(fs_hz)).validate(fs_hz)
    lo, hi = edges
    if (lo or hi) and not (lo and hi):
        band = IntegrationBand(lo or band.f_lo_hz, hi or band.f_hi_hz)
    return IdentifySetup(fs_hz=fs_hz, terms=tuple(terms), spectral=settings.spectral, band=band,
                         analysis_band_hz=settings.analysis_band_hz, cond_limit=settings.cond_limit)


#: the identifier's parameters (descriptors: ``ros2 param describe /nifo/identifier <name>``)
PARAMS = {
    "model_file": Param("", "YAML model file (nifo_model: 1): nonlinear terms; its settings give the defaults of "
                        "block, overlap, window, band", read_only=True),
    "block": Param(0, "spectral block [samples]; 0: model file, else 6144 (paper Table 2)", 0, 1 << 22,
                   read_only=True),
    "overlap": Param(-1.0, "block overlap fraction; -1: model file, else 0.52", -1.0, 0.99, read_only=True),
    "window": Param("", "spectral window; '': model file, else flattop", read_only=True),
    **INTEGRATION_BAND_PARAMS,
    "analysis_band_hz": Param([0.0, 0.0], "[lo, hi] band of the pooled fit, conditioning and summary [Hz]; "
                              f"[0, 0]: model file, else {list(DEFAULT_ANALYSIS_BAND_HZ)}", read_only=True),
    "cond_limit": Param(0.0, f"scaled cond(G_UU) counted as ill-conditioned [-]; 0: model file, else "
                        f"{DEFAULT_COND_LIMIT:g}", 0.0, 1e300, read_only=True),
    "publish_period_s": Param(2.0, "how often the estimate is published when it changed [s]", 0.01, 3600.0),
    "checkpoint_file": Param("", "checkpoint (.npz) resumed at start-up and written periodically; '': none",
                             read_only=True),
    "checkpoint_period_s": Param(10.0, "how often the checkpoint is written [s]", 0.01, 86400.0),
    "result_file": Param("", "full result document (JSON); '': beside the checkpoint, else "
                         "$ROS_HOME/nifo/identifier_result.json", read_only=True),
    "frame_id": Param("body", "header.frame_id of the result messages (the body sensor's frame)", read_only=True),
    "reset": Param(False, "set true to drop the accumulated estimate (reads back false)"),
}


class IdentifierNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("identifier", **kwargs)
        from rcl_interfaces.msg import SetParametersResult
        from std_msgs.msg import Float64MultiArray
        Transmissibility, Coefficients, LoopStatus = msg_types()
        self._SetParametersResult = SetParametersResult
        p = declare_parameters(self, PARAMS, self._problems)
        self._terms, self._settings = node_settings(p, log=self.get_logger())
        self._band_edges = integration_edges(p)
        self._cond_limit = self._settings.cond_limit
        self._frame_id = str(p["frame_id"])
        self._ckpt = Path(p["checkpoint_file"]) if p["checkpoint_file"] else None
        self._result_file = Path(p["result_file"] or default_result_file(p["checkpoint_file"]))
        self._nifo = None
        self._next_ns: int | None = None
        self._last_ns = 0
        self._published_navg = None
        self._result = None
        self._dirty = False
        self._stream = StreamStats()
        self._blocks = 0
        self._seq: int | None = None
        if self._ckpt is not None and self._ckpt.exists():
            self._resume()
        self.add_on_set_parameters_callback(self._on_params)
        self._pub_t = self.create_publisher(Transmissibility, TOPICS["transmissibility"], result_qos())
        self._pub_c = self.create_publisher(Coefficients, TOPICS["coefficients"], result_qos())
        self._pub_s = self.create_publisher(LoopStatus, TOPICS["status"], result_qos())
        # deep: a block the identifier has not taken yet is not overwritten (lossless path; common.block_qos)
        self._sub = self.create_subscription(Float64MultiArray, TOPICS["accel"], self._on_block,
                                             block_qos(depth=IDENTIFIER_BLOCK_DEPTH))
        self._timer = self.create_timer(float(p["publish_period_s"]), self._publish)
        if self._ckpt is not None:
            self._ckpt_timer = self.create_timer(float(p["checkpoint_period_s"]), self._checkpoint)
        self._reset_pending = False
        self._reset_timer = self.create_timer(0.1, self._reset_param_back)
        self._diag = Diagnostics(self, 1.0, self._diagnostics)
        self._service = None
        try:
            from std_srvs.srv import Trigger
        except ImportError:
            self.get_logger().info("std_srvs not installed: reset with 'ros2 param set <node> reset true'")
        else:
            self._service = self.create_service(Trigger, "~/reset", self._on_reset_service)

    # ------------------------------------------------------------------ set-up
    @staticmethod
    def _problems(p: dict) -> str:
        """What is wrong with (some of) the node's parameters: its own (periods) here, the analysis settings by
        the one settings object (:class:`~nifo_core.settings.GivenSettings`, as for the command line and a
        model file)."""
        from nifo_core.settings import GivenSettings

        bad = [f"{k}={p[k]} must be > 0" for k in ("publish_period_s", "checkpoint_period_s") if k in p
               and not p[k] > 0]
        if "overlap" in p and p["overlap"] < 0 and p["overlap"] != -1.0:
            bad.append(f"overlap={p['overlap']} must be -1 (default) or in [0, 1)")
        elif "block" in p and p["block"] < 0:
            bad.append(f"block={p['block']} must be 0 (model file / default) or >= 8")
        else:
            try:
                GivenSettings(**given_fields(p))
                integration_edges(p)
            except ConfigError as err:
                bad.append(err.message)
        return "; ".join(bad)

    def _new_nifo(self, fs_hz: float):
        """The accumulator of a stream at ``fs_hz``, from the settings resolved once at start-up
        (:func:`identify_setup`: no second resolution when the rate is known)."""
        return identify_setup(self._settings, self._terms, fs_hz, edges=self._band_edges).accumulator(
            on_ill_conditioned="ignore")

    def _resume(self) -> None:
        nifo, next_ns, stream = load_checkpoint(self._ckpt)
        fresh = self._new_nifo(nifo.fs_hz)
        if not fresh.same_setup(nifo):
            raise ConfigError("the checkpoint was made with other terms, spectral settings or band",
                              source=str(self._ckpt), hint="delete it (or set another checkpoint_file) to start afresh")
        self._nifo, self._next_ns = nifo, next_ns
        self._last_ns = next_ns
        self._stream = StreamStats(**stream)
        self.get_logger().info(f"resumed from {self._ckpt}: {nifo.n_avg} blocks, stream at stamp {next_ns} ns")

    # ------------------------------------------------------------------ input
    def _on_block(self, msg) -> None:
        try:
            b = block_from_msg(msg)
            if b.channels[:2] != ACCEL_CHANNELS:
                raise ConfigError(f"block channels {b.channels} are not {ACCEL_CHANNELS}")
        except NifoError as err:
            self.get_logger().warning(f"{TOPICS['accel']}: malformed block skipped ({err})", throttle_duration_sec=5.0)
            return
        if self._nifo is None:
            self._nifo = self._new_nifo(b.fs_hz)
        if b.fs_hz != self._nifo.fs_hz:
            self.get_logger().error(f"block at {b.fs_hz:g} Hz, the estimate is at {self._nifo.fs_hz:g} Hz: skipped "
                                    "(reset to start over at the new rate)", throttle_duration_sec=5.0)
            return
        if self._seq is None and b.seq > 0 and self._next_ns is None:
            self.get_logger().info(f"{TOPICS['accel']}: the first block taken is the integrator's block {b.seq}; "
                                   f"the {b.seq} before it were published before this node listened (not in the "
                                   "estimate)")
        if self._seq is not None and b.seq != self._seq + 1 and b.seq != 0:  # 0: the integrator restarted
            self._stream.blocks_missing += max(0, b.seq - self._seq - 1)
            self.get_logger().warning(f"{TOPICS['accel']}: blocks {self._seq + 1}..{b.seq - 1} never arrived "
                                      f"({self._stream.blocks_missing} so far); a later block's stamp shows the gap")
        self._seq = b.seq
        rows = b.data
        period = 1e9 / b.fs_hz
        if self._next_ns is not None:
            off = int(round((b.stamp_ns - self._next_ns) / period))
            if off < 0:  # samples already used: keep only the new ones
                rows = rows[-off:]
                self._stream.samples_skipped += min(-off, b.n)
                if rows.shape[0] == 0:
                    return
            elif off > 0:
                self._stream.gaps += 1
                self._stream.samples_lost += off
                self.get_logger().warning(f"stream gap of {off} samples before stamp {b.stamp_ns} ns: "
                                          "closing the record (no spectral block spans a gap); "
                                          f"{self._stream.gaps} gap(s), {self._stream.samples_lost} samples lost")
                self._nifo.end_record()
            start_ns = b.stamp_ns + int(round(max(0, -off) * period))
        else:
            start_ns = b.stamp_ns
        try:
            self._nifo.push(rows[:, 0], rows[:, 1])
        except NifoError as err:  # non-finite samples: StreamingNifo checks before changing state
            self.get_logger().warning(f"block at stamp {b.stamp_ns} ns skipped ({err}); closing the record")
            self._nifo.end_record()
            return
        self._stream.samples_received += rows.shape[0]
        self._blocks += 1
        self._next_ns = start_ns + int(round(rows.shape[0] * period))
        self._last_ns = self._next_ns - int(round(period))
        self._dirty = True

    # ------------------------------------------------------------------ output
    def _publish(self) -> None:
        # republish when anything changed (samples, gaps), not only n_avg: the tail of a stream adds samples
        # (and the stream's accounting) without completing a block
        mark = (self._nifo.n_avg if self._nifo is not None else 0, self._stream.samples_received, self._stream.gaps)
        if self._nifo is None or mark == self._published_navg:
            return
        r = None
        if self._nifo.n_avg:
            try:
                r = self._nifo.result()
            except NifoError as err:
                self.get_logger().warning(f"no estimate yet: {err}", throttle_duration_sec=30.0)
        if r is None:  # samples but no estimate yet: the status still says how the stream is doing
            self._published_navg = mark
            self._pub_s.publish(status_msg(None, stamp_ns=self._last_ns, frame_id=self._frame_id,
                                           stream=self._stream, cond_limit=self._cond_limit, result_file=""))
            return
        self._published_navg = mark
        self._result = r
        stamp, frame = self._last_ns, self._frame_id
        try:
            write_result_file(self._result_file, r, stamp_ns=stamp, stream=self._stream)
            path = str(self._result_file)
        except OSError as err:
            self.get_logger().error(f"cannot write the result file {self._result_file}: {err}",
                                    throttle_duration_sec=30.0)
            path = ""
        self._pub_t.publish(transmissibility_msg(r, stamp_ns=stamp, frame_id=frame, stream=self._stream))
        self._pub_c.publish(coefficients_msg(r, stamp_ns=stamp, frame_id=frame))
        self._pub_s.publish(status_msg(r, stamp_ns=stamp, frame_id=frame, stream=self._stream,
                                       cond_limit=self._cond_limit, result_file=path))

    def _diagnostics(self) -> tuple[int, str, dict]:
        r, st = self._result, self._stream
        state, message = state_of(r, self._cond_limit)
        values = {"state": state, "blocks_received": self._blocks, **st.as_dict(),
                  "n_avg": r.n_avg if r is not None else 0, "samples_used": r.n_samples if r is not None else 0}
        if r is not None:
            cond = r.conditioning(self._cond_limit)
            values.update(cond_median=cond.median, cond_max=cond.max, ill_conditioned_fraction=cond.ill_fraction)
        level = Diagnostics.OK
        if st.gaps:
            level = Diagnostics.WARN
            message += f"; {st.gaps} stream gap(s), {st.samples_lost} samples lost (not averaged)"
        if st.blocks_missing:
            level = Diagnostics.WARN
            message += f"; {st.blocks_missing} sample block(s) never arrived"
        if state == "ill_conditioned":
            level = Diagnostics.WARN
        return level, message, values

    def _checkpoint(self) -> None:
        if self._ckpt is None or self._nifo is None or not self._dirty or self._next_ns is None:
            return
        try:
            save_checkpoint(self._ckpt, self._nifo, next_ns=self._next_ns, stream=self._stream)
            self._dirty = False
        except OSError as err:
            self.get_logger().error(f"cannot write checkpoint {self._ckpt}: {err}", throttle_duration_sec=30.0)

    # ------------------------------------------------------------------ reset
    def reset(self) -> None:
        """Drop everything accumulated (and the checkpoint's content on its next write)."""
        self._nifo = None
        self._next_ns = None
        self._published_navg = None
        self._result = None
        self._stream = StreamStats()
        if self._ckpt is not None and self._ckpt.exists():
            self._ckpt.unlink()
        self.get_logger().info("reset: the estimate starts afresh")

    def _on_params(self, params):
        fixed = [q.name for q in params if PARAMS.get(q.name) is None or PARAMS[q.name].read_only]
        if fixed:
            return self._SetParametersResult(successful=False,
                                             reason=f"{fixed} are read at start-up; restart the node to change them")
        bad = self._problems({q.name: q.value for q in params})
        if bad:
            return self._SetParametersResult(successful=False, reason=bad)
        for q in params:
            if q.name == "reset" and q.value:
                self._reset_pending = True
        return self._SetParametersResult(successful=True)

    def _reset_param_back(self) -> None:
        if self._reset_pending:
            self._reset_pending = False
            self.reset()
            from rclpy.parameter import Parameter
            self.set_parameters([Parameter("reset", Parameter.Type.BOOL, False)])

    def _on_reset_service(self, request, response):
        self.reset()
        response.success = True
        response.message = "estimate reset"
        return response

    def _take_pending(self) -> None:
        """Blocks already delivered but not yet handed to :meth:`_on_block` (the executor stopped)."""
        from rclpy.exceptions import InvalidHandle

        try:
            with self._sub.handle:
                while (got := self._sub.handle.take_message(self._sub.msg_type, False)) is not None:
                    self._on_block(got[0])
        except InvalidHandle:
            pass

    def close(self) -> None:
        """On the way out: publish (and write the result file of) the last estimate, then the checkpoint."""
        from rclpy.duration import Duration

        try:
            self._take_pending()
            self._publish()
            for pub in (self._pub_t, self._pub_c, self._pub_s):  # delivered before the process goes (bounded)
                pub.wait_for_all_acked(Duration(seconds=2.0))
        except Exception as err:  # shutting down: report, do not lose the checkpoint
            self.get_logger().warning(f"could not publish the last estimate on shutdown: {err}")
        self._checkpoint()


def main(args: list[str] | None = None) -> int:
    return run_node(IdentifierNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
