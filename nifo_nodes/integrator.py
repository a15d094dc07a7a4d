"""The integrator node: per-sample Imu in, aligned acceleration blocks and integrated motion out.

Subscribes (raw serialized) ``spindle/imu`` and ``body/imu``, drained every
``drain_s`` by a timer (:func:`common.take_raw`, :func:`messages.decode_imu_batch`:
one wake-up per burst, not one executor callback per message), the two
channels merged in stamp order; aligns the two channels onto one sample
grid (:class:`align.SampleAligner`: late, duplicate, malformed and non-finite
samples are logged and skipped, holes and restarts start a new segment) and
publishes

* ``accel/block`` — the aligned accelerations, channels
  ``spindle_accel|body_accel`` [m/s²] (what the identifier consumes);
* ``motion/block`` — :class:`nifo_core.signal.integrate.StreamingIntegrator` output,
  channels ``spindle_vel|spindle_disp|body_vel|body_disp|rel_vel|rel_disp``
  [m/s, m] (rel = body − spindle, integrated from ẍ2 − ẍ1 as the contract
  says).

Phase and band: the integrator is the offline :func:`nifo_core.signal.integrate.integrate`
in streaming form — the same linear-phase FIR, zero phase once its delay of
``(taps-1)/2`` samples is removed, band ``[f_lo, f_hi]`` with raised-cosine
edges (``f_lo/2..f_lo``, ``f_hi..1.25·f_hi``), zero outside. Motion samples
carry the stamps of the acceleration samples they belong to, so they are
published ``delay_samples`` (= 16/f_lo seconds / 2) after those arrived. The
first ``delay_samples`` of each segment are start-up transients (zero history,
as the batch form's edges); the last ``delay_samples`` of a segment are
published (zero-padded, as the batch form does) only when the segment ends.

Parameters: ``fs_hz`` (0: infer from the first 64 spindle stamps, snapped to
1 mHz), ``integration_band_hz`` (an edge 0: :func:`nifo_core.signal.integrate.default_band`'s; also read as
``f_lo_hz``/``f_hi_hz``),
``block_s`` (samples per published block, as seconds), ``flush_s`` (publish a
partial block after this much wall time), ``max_lag_s`` (how long a missing
sample is waited for), ``restart_s``, ``qos_depth``, ``axis``, ``input_reliability`` (``best_effort``:
sensor-data QoS, the vehicle; ``reliable``: lossless replay with ``nifo replay
--reliable``, see the QoS matrix in :mod:`common`), ``drain_s`` (how often the
input is drained; the best-effort history ``qos_depth`` must hold that long
of samples).
"""

from __future__ import annotations

import numpy as np

from nifo_core.errors import ConfigError, NifoError

from .align import SampleAligner
from .common import (INTEGRATION_BAND_PARAMS, RELIABILITIES, TOPICS, Diagnostics, Param, block_qos,
                     declare_parameters, input_qos, integration_edges, polled_group, publish_blocking, run_node,
                     take_raw)
from .messages import Block, block_to_msg, decode_imu_batch

__all__ = ["IntegratorNode", "main", "ACCEL_CHANNELS", "MOTION_CHANNELS"]

ACCEL_CHANNELS = ("spindle_accel", "body_accel")
MOTION_CHANNELS = ("spindle_vel", "spindle_disp", "body_vel", "body_disp", "rel_vel", "rel_disp")
_INFER_N = 64
_STARTUP_ONLY = ("fs_hz", *INTEGRATION_BAND_PARAMS, "axis", "qos_depth", "input_reliability", "drain_s")
#: most messages taken per channel per drain (bounds one timer callback)
_TAKE_MAX = 20_000

#: the integrator's parameters (descriptors: ``ros2 param describe /nifo/integrator <name>``)
PARAMS = {
    "fs_hz": Param(0.0, "sample rate [Hz]; 0: infer from the first 64 spindle stamps", 0.0, 1e6, read_only=True),
    **INTEGRATION_BAND_PARAMS,
    "block_s": Param(0.1, "samples per published block [s of data]", 1e-4, 60.0),
    "flush_s": Param(0.2, "publish a partial block after this long without a full one [s, wall]", 1e-3, 60.0),
    "max_lag_s": Param(0.25, "how long a missing sample is waited for before a gap is declared [s of data]",
                       1e-4, 60.0),
    "restart_s": Param(1.0, "stamps going back further than this: the publisher restarted [s]", 1e-3, 3600.0),
    "qos_depth": Param(2000, "Imu subscription history (best effort input) [messages]", 1, 100_000, read_only=True),
    "axis": Param("z", "Imu linear_acceleration axis: x, y or z", read_only=True),
    "input_reliability": Param("best_effort", "best_effort (vehicle, sensor-data QoS) or reliable (lossless "
                               "replay: nifo replay --reliable, keep all)", read_only=True),
    "drain_s": Param(0.01, "how often the Imu subscriptions are drained [s]", 1e-4, 0.1, read_only=True),
}

try:
    from rclpy.node import Node
except ImportError:  # pragma: no cover - documented: the nodes need rclpy
    Node = object


class IntegratorNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("integrator", **kwargs)
        from rcl_interfaces.msg import SetParametersResult
        from sensor_msgs.msg import Imu
        from std_msgs.msg import Float64MultiArray

        self._SetParametersResult = SetParametersResult
        declare_parameters(self, PARAMS, self._problems)
        self.add_on_set_parameters_callback(self._check_params)
        self._fs = float(self.get_parameter("fs_hz").value)
        self._axis = str(self.get_parameter("axis").value)
        self._aligner: SampleAligner | None = None
        self._early: list[tuple[int, int, float]] = []
        self._malformed = 0
        self._seq = {"accel": 0, "motion": 0}
        self._segment: int | None = None
        self._integrators = None
        depth = int(self.get_parameter("qos_depth").value)
        # lossless input → lossless output: keep-all blocks, publish waits for a slow identifier (backpressure)
        self._lossless = self.get_parameter("input_reliability").value == "reliable"
        self._pub_accel = self.create_publisher(Float64MultiArray, TOPICS["accel"],
                                                block_qos(keep_all=self._lossless))
        self._pub_motion = self.create_publisher(Float64MultiArray, TOPICS["motion"], block_qos())
        # the slow one-off set-up (scipy import ≈ 1 s, FIR taps) happens here, before subscribing: done
        # lazily in the first drain it stalled the input for a second and the best-effort history overflowed
        import nifo_core.signal.integrate  # noqa: F401
        if self._fs > 0:
            self._start(self._fs)
        qos, group = input_qos(str(self.get_parameter("input_reliability").value), depth), polled_group()
        self._subs = [self.create_subscription(Imu, TOPICS[role], lambda raw: None, qos, raw=True,
                                               callback_group=group)
                      for role in ("spindle", "body")]
        self._received = [0, 0]
        self._rates = _Rates()
        self._diag = Diagnostics(self, 1.0, self._diagnostics)
        self._drain_timer = self.create_timer(float(self.get_parameter("drain_s").value), self._drain)
        self._timer = self.create_timer(float(self.get_parameter("flush_s").value), self._publish)

    # ------------------------------------------------------------------ parameters
    @staticmethod
    def _problems(v: dict) -> str:
        bad = []
        if v.get("fs_hz", 0) < 0:
            bad.append(f"fs_hz={v['fs_hz']} must be >= 0 (0: infer)")
        for k in ("block_s", "flush_s", "max_lag_s", "restart_s", "drain_s"):
            if k in v and not v[k] > 0:
                bad.append(f"{k}={v[k]} must be > 0")
        if "qos_depth" in v and not 1 <= v["qos_depth"] <= 100_000:
            bad.append(f"qos_depth={v['qos_depth']} must be in 1..100000")
        if "axis" in v and v["axis"] not in ("x", "y", "z"):
            bad.append(f"axis={v['axis']!r} must be x, y or z")
        try:
            integration_edges(v)
        except ConfigError as err:
            bad.append(err.message)
        if "input_reliability" in v and v["input_reliability"] not in RELIABILITIES:
            bad.append(f"input_reliability={v['input_reliability']!r} must be one of {', '.join(RELIABILITIES)}")
        if "drain_s" in v and v["drain_s"] > 0.1:
            bad.append(f"drain_s={v['drain_s']} must be <= 0.1 (the input history has to hold a drain's worth)")
        return "; ".join(bad)

    def _check_params(self, params):
        bad = self._problems({p.name: p.value for p in params})
        if not bad and any(p.name in _STARTUP_ONLY for p in params):
            bad = f"{', '.join(_STARTUP_ONLY)} are read at start-up only; restart the node to change them"
        return self._SetParametersResult(successful=not bad, reason=bad)

    def _diagnostics(self) -> tuple[int, str, dict]:
        counts = dict(self._aligner.counts) if self._aligner is not None else {}
        rates = self._rates.update(self._received)
        values = {"fs_hz": self._fs, "input_reliability": self.get_parameter("input_reliability").value,
                  "spindle_msgs": self._received[0], "body_msgs": self._received[1],
                  "spindle_rate_hz": rates[0], "body_rate_hz": rates[1], "malformed": self._malformed,
                  "segment": self._segment or 0, **{f"aligned_{k}": v for k, v in counts.items()}}
        if self._aligner is None:
            return Diagnostics.OK, "waiting for samples (sample rate not known yet)", values
        bad = {k: counts.get(k, 0) for k in ("gap", "restart", "nonfinite", "late", "duplicate")}
        bad["malformed"] = self._malformed
        if any(bad.values()):
            what = ", ".join(f"{v} {k}" for k, v in bad.items() if v)
            return Diagnostics.WARN, f"stream problems so far: {what} (gaps start a new segment)", values
        return Diagnostics.OK, f"{rates[0]:.0f} + {rates[1]:.0f} samples/s, no gaps", values

    # ------------------------------------------------------------------ input
    def _drain(self) -> int:
        """Take every waiting Imu message of both channels, decode them in one go, push in stamp order;
        returns how many messages were taken (decodable or not)."""
        stamps, values, chans = [], [], []
        taken = 0
        for ch, sub in enumerate(self._subs):
            raws = take_raw(sub, _TAKE_MAX)
            taken += len(raws)
            st, v, bad = decode_imu_batch(raws, self._axis)
            for _, reason in bad:
                self._malformed += 1
                self.get_logger().warning(f"{TOPICS[('spindle', 'body')[ch]]}: malformed message skipped "
                                          f"({reason}; {self._malformed} so far)", throttle_duration_sec=5.0)
            self._received[ch] += len(raws)
            stamps.append(st)
            values.append(v)
            chans.append(np.full(st.size, ch))
        # interleave the channels by stamp, keeping each channel's arrival order (late samples stay late)
        key = np.concatenate([np.maximum.accumulate(st) if st.size else st for st in stamps])
        rank = np.concatenate([np.arange(st.size) for st in stamps])
        order = np.lexsort((np.concatenate(chans), rank, key))
        for ch, stamp, value in zip(np.concatenate(chans)[order].tolist(), np.concatenate(stamps)[order].tolist(),
                                    np.concatenate(values)[order].tolist()):
            self._on_sample(ch, stamp, value)
        return taken

    def _on_sample(self, channel: int, stamp: int, value: float) -> None:
        if self._aligner is None:
            self._infer(channel, stamp, value)
            return
        self._aligner.push(channel, stamp, value)
        if self._aligner.pending >= self._block_n:
            self._publish()

    def _infer(self, channel: int, stamp: int, value: float) -> None:
        from nifo_core.signal.timebase import sample_rate_from_stamps

        self._early.append((channel, stamp, value))
        st = sorted({s for c, s, _ in self._early if c == 0})
        if len(st) < _INFER_N:
            return
        try:
            fs = sample_rate_from_stamps(np.array(st), source="integrator", channel=TOPICS["spindle"])
        except NifoError as err:
            self.get_logger().warning(f"cannot infer the sample rate yet ({err}); retrying",
                                      throttle_duration_sec=5.0)
            self._early = self._early[len(self._early) // 2:]
            return
        self._start(round(fs * 1000) / 1000)

    def _start(self, fs: float) -> None:
        self._fs = fs
        lag = max(2, int(round(float(self.get_parameter("max_lag_s").value) * fs)))
        self._block_n = max(1, int(round(float(self.get_parameter("block_s").value) * fs)))
        # reliable input (lossless replay): in order and nothing dropped in transit, but one channel may run
        # far ahead of the other; a hole is a gap only when the lacking channel itself moved past it
        self._aligner = SampleAligner(fs, 2, max_lag=lag, ordered=self._lossless, max_wait=int(round(60 * fs)),
                                      restart_s=float(self.get_parameter("restart_s").value),
                                      log=lambda m: self.get_logger().warning(m))
        self.get_logger().info(f"sample rate {fs:g} Hz, blocks of {self._block_n} samples")
        early, self._early = self._early, []
        for ig in self._new_integrators():  # computes (and caches) the FIR taps, warms the FFT path
            ig.push(np.zeros(1))
        for ch, st, v in sorted(early, key=lambda e: e[1]):
            self._aligner.push(ch, st, v)

    # ------------------------------------------------------------------ output
    def _new_integrators(self):
        from nifo_core.signal.integrate import IntegrationBand, StreamingIntegrator, default_band

        lo, hi = integration_edges({k: self.get_parameter(k).value for k in INTEGRATION_BAND_PARAMS})
        d = default_band(self._fs)
        band = IntegrationBand(lo or d.f_lo_hz, hi or d.f_hi_hz)
        return [StreamingIntegrator(self._fs, band) for _ in range(3)]

    def _publish(self) -> None:
        if self._aligner is None:
            return
        for run in self._aligner.take():
            if run.segment != self._segment:
                self._end_segment()
                self._segment = run.segment
                self._integrators = self._new_integrators()
                self._motion_stamp, self._motion_n = run.stamp_ns, 0
            self._send("accel", Block(run.stamp_ns, self._fs, ACCEL_CHANNELS, run.rows))
            x1, x2 = run.rows[:, 0], run.rows[:, 1]
            self._send_motion([ig.push(a) for ig, a in zip(self._integrators, (x1, x2, x2 - x1))])

    def _end_segment(self) -> None:
        if self._integrators is not None:
            self._send_motion([ig.flush() for ig in self._integrators])
        self._integrators = None

    def _send_motion(self, outs) -> None:
        n = outs[0][0].size
        if n == 0:
            return
        cols = np.column_stack([c for vx in outs for c in vx])
        stamp = self._motion_stamp + int(round(self._motion_n * 1e9 / self._fs))
        self._motion_n += n
        self._send("motion", Block(stamp, self._fs, MOTION_CHANNELS, cols))

    def _send(self, what: str, block: Block) -> None:
        from dataclasses import replace

        block = replace(block, seq=self._seq[what], segment=self._segment or 0)
        self._seq[what] += 1
        pub, msg = (self._pub_accel if what == "accel" else self._pub_motion), block_to_msg(block)
        if self._lossless and what == "accel":
            publish_blocking(pub, msg)
        else:
            pub.publish(msg)

    def close(self) -> None:
        """Publish what is still buffered (end of a replay or shutdown), and see it delivered.

        The blocks are reliable: wait (bounded) until subscribers acknowledged them,
        else destroying the node right after could drop the last ones on a busy machine.
        """
        from rclpy.duration import Duration

        try:
            while self._drain():  # everything still waiting in the input histories
                pass
            self._publish()
            self._end_segment()
            for pub in (self._pub_accel, self._pub_motion):
                if not pub.wait_for_all_acked(Duration(seconds=4.0)):
                    self.get_logger().warning(f"{pub.topic_name}: last blocks not acknowledged on shutdown")
        except Exception as err:  # shutting down: report, do not mask the shutdown
            self.get_logger().warning(f"could not flush on shutdown: {err}")


class _Rates:
    """Messages per second per channel since the previous call (wall clock: a rate is a wall-clock matter)."""

    def __init__(self) -> None:
        import time

        self._clock = time.monotonic
        self._t, self._n = self._clock(), [0, 0]

    def update(self, counts: list[int]) -> list[float]:
        t = self._clock()
        dt = max(t - self._t, 1e-9)
        rates = [(c - n) / dt for c, n in zip(counts, self._n)]
        self._t, self._n = t, list(counts)
        return rates


def main(args: list[str] | None = None) -> int:
    return run_node(IntegratorNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
