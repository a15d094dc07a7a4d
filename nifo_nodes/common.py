"""What every nifo node shares: QoS profiles, topic names, parameter checks and ``main``.

Topic names are relative (remappable, namespaced: the launch files run the
nodes in ``/nifo``, giving the bag's ``/nifo/spindle/imu`` etc.).

=================================  ==================================  ==========================================
topic (relative)                   type                                QoS
=================================  ==================================  ==========================================
``spindle/imu``, ``body/imu``      ``sensor_msgs/msg/Imu``             sensor data (best effort, volatile);
                                                                       replay for identification: reliable, keep all
``tire_patch/displacement``        ``geometry_msgs/msg/PointStamped``  sensor data
``accel/block``                    ``std_msgs/msg/Float64MultiArray``  reliable, volatile, keep last ``BLOCK_DEPTH``
                                                                       (keep all with reliable input; identifier
                                                                       reads keep all)
``motion/block``                   ``std_msgs/msg/Float64MultiArray``  reliable, volatile, keep last ``BLOCK_DEPTH``
``identifier/transmissibility``    ``nifo_msgs/msg/Transmissibility``  reliable, transient local, depth 1
``identifier/coefficients``        ``nifo_msgs/msg/Coefficients``      reliable, transient local, depth 1
``identifier/status``              ``nifo_msgs/msg/LoopStatus``        reliable, transient local, depth 1
``/diagnostics`` (absolute)        ``diagnostic_msgs/DiagnosticArray`` reliable, volatile, depth 10 (every node, 1 Hz)
=================================  ==================================  ==========================================

QoS matrix of the per-sample input (the integrator's ``input_reliability``
against the publisher; DDS request/offer rules):

=======================  ==========================  =====================================
publisher                subscriber ``best_effort``  subscriber ``reliable``
=======================  ==========================  =====================================
sensor data (vehicle,    matched; samples may be     NOT matched (no data; rclpy logs an
acquisition, default     dropped under load          incompatible-QoS warning)
``nifo replay``)
``nifo replay            matched, best effort        matched, lossless: a slow subscriber
--reliable``             (drops possible)            blocks the replay (backpressure)
=======================  ==========================  =====================================
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Callable

from nifo.io.ros_qos import publish_blocking, reliable_input_qos, sensor_qos  # shared with nifo replay

__all__ = ["TOPICS", "sensor_qos", "reliable_input_qos", "input_qos", "block_qos", "result_qos", "run_node", "declare_parameters",
           "BLOCK_DEPTH", "IDENTIFIER_BLOCK_DEPTH", "RELIABILITIES", "polled_group", "take_raw", "publish_blocking", "Param",
           "DIAGNOSTICS_TOPIC", "Diagnostics", "INTEGRATION_BAND_PARAMS", "integration_edges"]

#: values of the integrator's ``input_reliability`` parameter
RELIABILITIES = ("best_effort", "reliable")

TOPICS = {
    "spindle": "spindle/imu",
    "body": "body/imu",
    "tire_patch": "tire_patch/displacement",
    "accel": "accel/block",
    "motion": "motion/block",
    "transmissibility": "identifier/transmissibility",
    "coefficients": "identifier/coefficients",
    "status": "identifier/status",
}

#: where every node publishes its ``diagnostic_msgs/DiagnosticArray`` (rqt_robot_monitor, Foxglove)
DIAGNOSTICS_TOPIC = "/diagnostics"

#: blocks kept for a slow subscriber (at 10 blocks/s: 10 s of data)
BLOCK_DEPTH = 100
#: the identifier's block history: 10 000 s of data at 10 blocks/s (it never falls that far behind;
#: if it did, the loss would be a counted gap)
IDENTIFIER_BLOCK_DEPTH = 100_000


def input_qos(reliability: str, depth: int):
    """The per-sample input QoS for ``reliability`` in :data:`RELIABILITIES` (see the matrix above)."""
    if reliability not in RELIABILITIES:
        raise ValueError(f"reliability={reliability!r} must be one of {RELIABILITIES}")
    return reliable_input_qos() if reliability == "reliable" else sensor_qos(depth)


def polled_group():
    """A callback group the executor never runs: its subscriptions are drained with :func:`take_raw`.

    The executor rebuilds its wait set and runs one Python callback per
    message (≈250 µs each); a timer draining a whole burst per wake-up costs
    a few µs per message instead.
    """
    from rclpy.callback_groups import CallbackGroup

    class _Polled(CallbackGroup):
        def can_execute(self, entity) -> bool:
            return False

    return _Polled()


def take_raw(sub, limit: int) -> list[bytes]:
    """Up to ``limit`` serialized messages waiting on a ``raw=True`` subscription, oldest first.

    What the executor's ``_take_subscription`` does per message, in a loop.
    """
    from rclpy.exceptions import InvalidHandle

    out: list[bytes] = []
    try:
        with sub.handle:
            take, mtype = sub.handle.take_message, sub.msg_type
            while len(out) < limit:
                got = take(mtype, True)
                if got is None:
                    break
                out.append(got[0])
    except InvalidHandle:  # destroyed while shutting down
        pass
    return out


def block_qos(*, keep_all: bool = False, depth: int = 0):
    """Sample blocks between our nodes: reliable, volatile, keep last :data:`BLOCK_DEPTH` — or keep all.

    The lossless path needs the integrator's writer keep-all in reliable mode (a keep-last writer
    overwrote blocks not yet acknowledged when the identifier fell behind: whole blocks lost when a
    replay ran as fast as the graph goes) and the identifier's reader deep (``depth``: keep last that
    many; a keep-all reader lost the tail of a stream under load with Fast DDS, measured). History is
    not part of QoS matching, so all of these match each other.
    """
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    if keep_all:
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth or BLOCK_DEPTH),
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def result_qos():
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


@dataclass(frozen=True)
class Param:
    """A node parameter: default, description (with unit) and the range ``ros2 param describe`` shows.

    ``lo``/``hi`` become the descriptor's integer or floating-point range (enforced
    by rclpy); ``read_only`` parameters are read at start-up only.
    """

    default: object
    description: str
    lo: float | None = None
    hi: float | None = None
    read_only: bool = False


#: the integration band's parameter (the setting's one name) and, after it, its old names, still read
INTEGRATION_BAND_PARAMS = {
    "integration_band_hz": Param([0.0, 0.0], "[lo, hi] integration band for z, zdot [Hz]; an edge 0: its default "
                                 "(0.5 Hz; min(200, fs/2.5)); also read as f_lo_hz/f_hi_hz", read_only=True),
    "f_lo_hz": Param(0.0, "old name of integration_band_hz[0] [Hz]", 0.0, 1e5, read_only=True),
    "f_hi_hz": Param(0.0, "old name of integration_band_hz[1] [Hz]", 0.0, 1e5, read_only=True),
}


def integration_edges(p: dict) -> tuple[float, float]:
    """The integration band's edges from a node's parameters (0: that edge's default): ``integration_band_hz``, or
    its old names ``f_lo_hz``/``f_hi_hz``; :class:`ConfigError` when both are given or the pair is not two edges."""
    from nifo_core.errors import ConfigError

    new = [float(x) for x in p.get("integration_band_hz", (0.0, 0.0))]
    old = (float(p.get("f_lo_hz", 0.0)), float(p.get("f_hi_hz", 0.0)))
    if len(new) != 2 or min(new) < 0:
        raise ConfigError(f"integration_band_hz={new} must be two edges [lo, hi] >= 0 [Hz] (0: the default edge)",
                          channel="integration_band_hz")
    if any(new) and any(old):
        raise ConfigError("integration_band_hz and f_lo_hz/f_hi_hz are one setting (the old names): give it once, "
                          "as integration_band_hz", channel="integration_band_hz")
    return (new[0], new[1]) if any(new) else old


def _descriptor(name: str, p: Param):
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    d = ParameterDescriptor(name=name, description=p.description, read_only=p.read_only)
    if p.lo is not None and p.hi is not None:
        if isinstance(p.default, bool):
            pass
        elif isinstance(p.default, int):
            d.integer_range = [IntegerRange(from_value=int(p.lo), to_value=int(p.hi), step=0)]
        elif isinstance(p.default, float):
            d.floating_point_range = [FloatingPointRange(from_value=float(p.lo), to_value=float(p.hi), step=0.0)]
    return d


def declare_parameters(node, params: dict, problems: Callable[[dict], object]) -> dict:
    """Declare ``params`` (name → :class:`Param`) with descriptors on ``node``, read the values back
    (parameter files and overrides applied) and validate them with ``problems`` (returns what is wrong,
    empty when fine); raise :class:`ConfigError` naming the node otherwise. Returns ``{name: value}``."""
    from rclpy.exceptions import InvalidParameterValueException, ParameterException

    from nifo_core.errors import ConfigError

    for name, p in params.items():
        try:
            node.declare_parameter(name, p.default, _descriptor(name, p))
        except (InvalidParameterValueException, ParameterException, TypeError) as err:
            why = f"{name} must be in {p.lo:g}..{p.hi:g}" if p.lo is not None else f"{name}: {err}"
            raise ConfigError(f"invalid parameters: {why}", source=node.get_name(),
                              hint="fix the parameter file") from None
    values = {name: node.get_parameter(name).value for name in params}
    bad = problems(values)
    if bad:
        raise ConfigError(f"invalid parameters: {bad}", source=node.get_name(), hint="fix the parameter file")
    return values


class Diagnostics:
    """One ``DiagnosticStatus`` per node on :data:`DIAGNOSTICS_TOPIC`, what ``rqt_robot_monitor`` and
    Foxglove's diagnostics panels show: name ``nifo/<node>``, level OK/WARN/ERROR, a one-line message
    and key/value pairs (counters, rates)."""

    OK, WARN, ERROR = 0, 1, 2

    def __init__(self, node, period_s: float, collect: Callable[[], tuple[int, str, dict]]) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self._node, self._collect = node, collect
        self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._name = f"nifo/{node.get_name()}"
        self._timer = node.create_timer(period_s, self.publish)

    def publish(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        level, message, values = self._collect()
        st = DiagnosticStatus(level=bytes([level]), name=self._name, message=message,
                              hardware_id=self._node.get_namespace().strip("/") or "nifo",
                              values=[KeyValue(key=k, value=_fmt(v)) for k, v in values.items()])
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(msg)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def run_node(factory: Callable[[], object], args: list[str] | None = None) -> int:
    """Jazzy's ``main``: ``rclpy.init()`` → spin → ``destroy_node()`` → ``rclpy.shutdown()``.

    SIGINT/SIGTERM end the spin cleanly; the node's ``close()`` (if any) runs
    before it is destroyed (the identifier writes its checkpoint there).
    """
    import signal

    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from nifo_core.errors import NifoError
    from rclpy.signals import SignalHandlerOptions

    stopping = {"asked": False}

    def _interrupt(signum, frame):
        # the first SIGINT/SIGTERM asks the spin loop to end between callbacks: raised inside one, it would
        # throw away what the callback had taken (measured: the integrator lost 3211 samples taken from its
        # input but not yet aligned when SIGINT arrived mid-drain). A second signal interrupts at once.
        if stopping["asked"]:
            raise KeyboardInterrupt
        stopping["asked"] = True

    # Python's own handlers, so close() still has a live context to publish the last block and write the
    # checkpoint
    rclpy.init(args=args if args is not None else sys.argv, signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    node = None
    try:
        try:
            node = factory()
        except NifoError as err:  # a user's mistake (parameters, model file): one line, no traceback
            print(f"[nifo] {err}", file=sys.stderr)
            return err.exit_code
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        while not stopping["asked"] and rclpy.ok():
            ex.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            close = getattr(node, "close", None)
            if close is not None:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
