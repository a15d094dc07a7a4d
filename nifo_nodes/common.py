"""What every nifo node shares: QoS profiles, topic names, parameter checks and ``main``.

Topic names are relative (remappable, namespaced: the launch files run the
nodes in ``/nifo``, giving the bag's ``/nifo/spindle/imu`` etc.).

=================================  ==================================  ==========================================
topic (relative)                   type                                QoS
=================================  ==================================  ==========================================
``spindle/imu``, ``body/imu``      ``sensor_msgs/msg/Imu``             sensor data (best effort, volatile)
``tire_patch/displacement``        ``geometry_msgs/msg/PointStamped``  sensor data
``accel/block``                    ``std_msgs/msg/Float64MultiArray``  reliable, volatile, keep last ``BLOCK_DEPTH``
``motion/block``                   ``std_msgs/msg/Float64MultiArray``  reliable, volatile, keep last ``BLOCK_DEPTH``
``identifier/transmissibility``    ``std_msgs/msg/Float64MultiArray``  reliable, transient local, depth 1
``identifier/coefficients``        ``std_msgs/msg/Float64MultiArray``  reliable, transient local, depth 1
``identifier/result``              ``std_msgs/msg/String`` (JSON)      reliable, transient local, depth 1
=================================  ==================================  ==========================================
"""

from __future__ import annotations

import sys
from typing import Callable

__all__ = ["TOPICS", "sensor_qos", "block_qos", "result_qos", "run_node", "BLOCK_DEPTH"]

TOPICS = {
    "spindle": "spindle/imu",
    "body": "body/imu",
    "tire_patch": "tire_patch/displacement",
    "accel": "accel/block",
    "motion": "motion/block",
    "transmissibility": "identifier/transmissibility",
    "coefficients": "identifier/coefficients",
    "result": "identifier/result",
}

#: blocks kept for a slow subscriber (at 10 blocks/s: 10 s of data)
BLOCK_DEPTH = 100


def sensor_qos(depth: int = 5):
    """``qos_profile_sensor_data`` (best effort, volatile) with history ``depth``.

    Subscribers use a deeper history than the default 5 so that a burst
    (replay, scheduling hiccup) is not dropped before the executor takes it.
    """
    from rclpy.qos import QoSProfile, qos_profile_sensor_data

    p = QoSProfile(**{k: getattr(qos_profile_sensor_data, k) for k in
                      ("history", "reliability", "durability", "liveliness")}, depth=int(depth))
    return p


def block_qos():
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=BLOCK_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def result_qos():
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def run_node(factory: Callable[[], object], args: list[str] | None = None) -> int:
    """Jazzy's ``main``: ``rclpy.init()`` → spin → ``destroy_node()`` → ``rclpy.shutdown()``.

    SIGINT/SIGTERM end the spin cleanly; the node's ``close()`` (if any) runs
    before it is destroyed (the identifier writes its checkpoint there).
    """
    import signal

    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    def _interrupt(signum, frame):
        raise KeyboardInterrupt

    # Python's own handlers: SIGINT/SIGTERM raise KeyboardInterrupt inside spin, so close() still
    # has a live context to publish the last block and write the checkpoint
    rclpy.init(args=args if args is not None else sys.argv, signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    node = None
    try:
        node = factory()
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        ex.spin()
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
