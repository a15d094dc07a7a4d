"""The Rerun viewer node: the pipeline's topics in, the live Rerun view out (same layout as ``nifo view``).

Subscribes (relative names, remappable; see :mod:`nifo_nodes.common`)

* ``accel/block`` — aligned spindle/body accelerations → ``accel/live``;
* ``motion/block`` — integrated relative motion; with the body acceleration
  at the same stamps → restoring-force points ``restoring/{velocity,displacement}/live``;
* ``identifier/status`` (``nifo_msgs/LoopStatus``) — on every new estimate the
  result document it names (``result_file``: ``NifoResult`` JSON with
  ``stamp_ns`` and ``stream``) → transmissibility, coherence, coefficient
  functions, convergence; and the stream's health (samples used / lost, gaps,
  state) → ``stream/*`` scalars and the ``summary`` text;

and logs them with :mod:`nifo.viz.rerun_log` at the data's stamps (never the
wall clock), so the live view and a replayed bag look the same.

Where the recording goes is Rerun's own script options, after ``--``::

    python -m nifo_nodes.rerun_viewer --ros-args -r __ns:=/nifo -- --connect
    python -m nifo_nodes.rerun_viewer --ros-args -r __ns:=/nifo -- --save live.rrd

(no option: spawn a viewer).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from collections import deque

import numpy as np

from nifo_core.errors import NifoError

from .common import TOPICS, block_qos, result_qos, run_node
from .messages import Block, block_from_msg

__all__ = ["RerunViewerNode", "main", "body_accel_at"]

RECORD = "live"
#: accel blocks kept to match the (delayed) motion blocks' stamps
_KEEP_BLOCKS = 64

try:
    from rclpy.node import Node
except ImportError:  # pragma: no cover - documented: the nodes need rclpy
    Node = object


def body_accel_at(blocks, stamp_ns: np.ndarray) -> np.ndarray:
    """Body acceleration at ``stamp_ns`` from recent accel blocks (NaN where no sample has that stamp)."""
    if not blocks:
        return np.full(stamp_ns.shape, np.nan)
    st = np.concatenate([b.stamp_ns + np.round(np.arange(b.n) * 1e9 / b.fs_hz).astype(np.int64) for b in blocks])
    val = np.concatenate([b.column("body_accel") for b in blocks])
    order = np.argsort(st, kind="stable")
    st, val = st[order], val[order]
    i = np.clip(np.searchsorted(st, stamp_ns), 0, st.size - 1)
    return np.where(np.abs(st[i] - stamp_ns) <= 1e9 / (2 * blocks[-1].fs_hz), val[i], np.nan)


def _stamps(b: Block) -> np.ndarray:
    return b.stamp_ns + np.round(np.arange(b.n) * 1e9 / b.fs_hz).astype(np.int64)


class RerunViewerNode(Node):
    def __init__(self, recording, **kwargs) -> None:
        from std_msgs.msg import Float64MultiArray

        from .results import msg_types

        LoopStatus = msg_types()[2]

        from nifo.viz import rerun_log as rl

        super().__init__("rerun_viewer", **kwargs)
        self._rl, self._rec = rl, recording
        self._accel: deque = deque(maxlen=_KEEP_BLOCKS)
        self._scale: tuple[float, float, float] | None = None
        rl.log_styling(recording=recording)
        rl.log_record_styling(RECORD, recording=recording)
        rl.log_restoring_styling(RECORD, recording=recording)
        self.create_subscription(Float64MultiArray, TOPICS["accel"], self._on_accel, block_qos())
        self.create_subscription(Float64MultiArray, TOPICS["motion"], self._on_motion, block_qos())
        self._shown = (None, -1)
        self.create_subscription(LoopStatus, TOPICS["status"], self._on_status, result_qos())
        # wakes the executor so SIGINT/SIGTERM are handled even when no message arrives (run_node's handlers
        # are Python's); only for that: every stamp logged comes from the data
        self.create_timer(0.5, lambda: None)

    def _block(self, msg, topic: str) -> Block | None:
        try:
            return block_from_msg(msg)
        except NifoError as err:
            self.get_logger().warning(f"{topic}: malformed block skipped ({err})", throttle_duration_sec=5.0)
            return None

    def _on_accel(self, msg) -> None:
        b = self._block(msg, TOPICS["accel"])
        if b is None:
            return
        self._accel.append(b)
        self._rl.log_accelerations(RECORD, _stamps(b), b.column("spindle_accel"), b.column("body_accel"),
                                   recording=self._rec)

    def _on_motion(self, msg) -> None:
        b = self._block(msg, TOPICS["motion"])
        if b is None:
            return
        st, z, zd = _stamps(b), b.column("rel_disp"), b.column("rel_vel")
        a2 = body_accel_at(list(self._accel), st)
        ok = np.isfinite(a2) & np.isfinite(z) & np.isfinite(zd) & (z != 0)   # zero: integrator start-up
        if not ok.any():
            return
        if self._scale is None:      # fixed once, from the first motion seen, so the view does not breathe
            self._scale = (np.std(z[ok]), np.std(zd[ok]), np.std(a2[ok]))
        self._rl.log_restoring(RECORD, st[ok], z[ok], zd[ok], a2[ok], scale=self._scale, recording=self._rec)

    def _on_status(self, msg) -> None:
        import rerun as rr

        stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        rr.set_time(self._rl.TIMELINE, timestamp=np.datetime64(stamp, "ns"), recording=self._rec)
        for k in ("samples_used", "samples_lost", "gaps"):
            rr.log(f"stream/{k}", rr.Scalars(float(getattr(msg, k))), recording=self._rec)
        self._rl.log_summary(f"**live identification: {msg.state}**\n\n{msg.message}\n\n"
                             f"| spectral averages | samples used | samples lost | stream gaps |\n|---|---|---|---|\n"
                             f"| {msg.n_avg} | {msg.samples_used} | {msg.samples_lost} | {msg.gaps} |\n\n"
                             "No spectral block spans a gap: lost samples are never averaged.", recording=self._rec)
        key = (msg.result_file, msg.n_avg)
        if not msg.result_file or key == self._shown:
            return
        from nifo_core.nifo.identify import NifoResult

        try:
            doc = json.loads(Path(msg.result_file).read_text())
            res = NifoResult.from_dict(doc)
        except (OSError, ValueError, KeyError, NifoError) as err:
            self.get_logger().warning(f"{msg.result_file}: unreadable result skipped ({err})",
                                      throttle_duration_sec=5.0)
            return
        self._shown = key
        self._rl.log_nifo_result(int(doc.get("stamp_ns", stamp)), res, recording=self._rec)


def main(args: list[str] | None = None) -> int:
    import rerun as rr
    from rclpy.utilities import remove_ros_args

    from nifo.viz import rerun_log as rl

    argv = list(sys.argv if args is None else args)
    parser = argparse.ArgumentParser(prog="rerun_viewer", description=__doc__.split("\n", 1)[0])
    rr.script_add_args(parser)
    ours = [a for a in remove_ros_args(argv)[1:] if a != "--"]
    opts = parser.parse_args(ours)
    rec = rr.script_setup(opts, rl.APP_ID, default_blueprint=rl.blueprint())
    rl.use_data_stamps(rec)
    try:
        return run_node(lambda: RerunViewerNode(rec), argv)
    finally:
        rec.flush()
        rr.script_teardown(opts)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
