"""The acquisition node: a :mod:`~nifo_nodes.sources` source in, per-sample messages out.

Publishes ``spindle/imu`` and ``body/imu`` (``sensor_msgs/msg/Imu``, value in
``linear_acceleration.<axis>``) and, when the source has one,
``tire_patch/displacement`` (``geometry_msgs/msg/PointStamped``, ``point.<axis>``),
at sensor-data QoS, stamped with the source's sample times. Messages are
serialized from a template (:class:`messages.ImuEncoder`, byte-identical to
rclpy's serializer and to the bags of :mod:`nifo.io.bag`).

Parameters: ``source`` (``simulator`` | ``file`` | ``module:Class``), ``path``,
``source_options`` (JSON), ``speed`` (× real time), ``loop``, ``fs_hz`` and
``seed`` (simulator), ``poll_s`` (how often the source is polled), ``axis``,
``qos_depth``, ``wait_for_subscribers_s`` (hold a file/simulator source up to
this long until both Imu topics have a subscriber; 0: start at once). The node ends (exit 0) when a non-looping source is exhausted.
"""

from __future__ import annotations

from .common import TOPICS, Param, declare_parameters, run_node, sensor_qos
from .messages import ImuEncoder, PointEncoder

__all__ = ["AcquisitionNode", "main"]

#: after both Imu topics have subscribers, wait this long for them to match us too
_MATCH_GRACE_S = 0.5

#: the acquisition node's parameters (all read at start-up; ``ros2 param describe``)
PARAMS = {
    "source": Param("simulator", "simulator | file | your_pkg.module:YourDaqSource", read_only=True),
    "path": Param("", "for source: file, the CSV, MAT or bag file", read_only=True),
    "source_options": Param("", "JSON keyword arguments for the source", read_only=True),
    "speed": Param(1.0, "playback speed [x real time]", 1e-3, 1e3, read_only=True),
    "loop": Param(False, "file source: start over at the end", read_only=True),
    "fs_hz": Param(600.0, "simulator sample rate [Hz]", 1.0, 1e6, read_only=True),
    "seed": Param(0, "simulator seed", 0, 2**31 - 1, read_only=True),
    "poll_s": Param(0.01, "how often the source is polled [s]", 1e-4, 1.0, read_only=True),
    "axis": Param("z", "Imu linear_acceleration axis carrying the value: x, y or z", read_only=True),
    "qos_depth": Param(100, "publisher history (sensor-data QoS) [messages]", 1, 100_000, read_only=True),
    "wait_for_subscribers_s": Param(0.0, "hold the source until the Imu topics have subscribers, up to [s]",
                                    0.0, 3600.0, read_only=True),
}

try:
    from rclpy.node import Node
except ImportError:  # pragma: no cover
    Node = object


class AcquisitionNode(Node):
    def __init__(self, *, source=None, **kwargs) -> None:
        super().__init__("acquisition", **kwargs)
        from geometry_msgs.msg import PointStamped
        from rcl_interfaces.msg import SetParametersResult
        from sensor_msgs.msg import Imu

        from .sources import make_source

        self._SetParametersResult = SetParametersResult
        v = declare_parameters(self, PARAMS, self._problems)
        self.add_on_set_parameters_callback(
            lambda ps: SetParametersResult(successful=False, reason="acquisition parameters are read at start-up"))
        self._source = source or make_source(v["source"], path=v["path"], speed=v["speed"], loop=v["loop"],
                                             options=v["source_options"], fs_hz=v["fs_hz"], seed=v["seed"])
        qos = sensor_qos(int(v["qos_depth"]))
        axis = v["axis"]
        self._out = [(self.create_publisher(Imu, TOPICS["spindle"], qos), ImuEncoder("spindle", axis)),
                     (self.create_publisher(Imu, TOPICS["body"], qos), ImuEncoder("body", axis))]
        self._tire = None
        if getattr(self._source, "has_tire_patch", False):
            self._tire = (self.create_publisher(PointStamped, TOPICS["tire_patch"], qos),
                          PointEncoder("tire_patch", axis))
        self.published = 0
        self._wait_until = self.get_clock().now().nanoseconds + int(float(v["wait_for_subscribers_s"]) * 1e9)
        self._ready_at = None if float(v["wait_for_subscribers_s"]) > 0 else 0
        self._timer = self.create_timer(float(v["poll_s"]), self._poll)
        self.get_logger().info(f"source {v['source']} at {self._source.fs_hz:g} Hz")

    @staticmethod
    def _problems(v: dict) -> str:
        bad = []
        if not v["speed"] > 0:
            bad.append(f"speed={v['speed']} must be > 0")
        if not v["fs_hz"] > 0:
            bad.append(f"fs_hz={v['fs_hz']} must be > 0")
        if not 0 < v["poll_s"] <= 1:
            bad.append(f"poll_s={v['poll_s']} must be in (0, 1]")
        if v["axis"] not in ("x", "y", "z"):
            bad.append(f"axis={v['axis']!r} must be x, y or z")
        return "; ".join(bad)

    def _poll(self) -> None:
        if self._wait_until is not None:  # optionally hold the source until the subscribers are matched
            now = self.get_clock().now().nanoseconds
            if self._ready_at is None and all(p.get_subscription_count() > 0 for p, _ in self._out):
                # the publisher sees a subscriber a little before that subscriber has matched the
                # publisher: best-effort samples sent in between are lost (as in nifo replay)
                self._ready_at = now + int(_MATCH_GRACE_S * 1e9)
            if now < (self._ready_at or self._wait_until):
                return
            self._wait_until = None
        s = self._source.poll()
        if s is None:
            self.get_logger().info(f"source exhausted after {self.published} samples")
            self._timer.cancel()
            raise KeyboardInterrupt  # ends spin; main() then closes cleanly
        (pub1, enc1), (pub2, enc2) = self._out
        tp = self._tire if s.tire_patch_disp is not None else None
        for i, stamp in enumerate(s.stamp_ns.tolist()):
            pub1.publish(enc1.encode(stamp, float(s.spindle_accel[i])))
            pub2.publish(enc2.encode(stamp, float(s.body_accel[i])))
            if tp is not None:
                tp[0].publish(tp[1].encode(stamp, float(s.tire_patch_disp[i])))
        self.published += s.n

    def close(self) -> None:
        self._source.close()


def main(args: list[str] | None = None) -> int:
    return run_node(AcquisitionNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
