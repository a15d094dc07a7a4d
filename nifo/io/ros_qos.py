"""The QoS profiles and the back-pressured publish that ``nifo replay`` (:mod:`nifo.io.bag_replay`) and the
nodes (:mod:`nifo_nodes.common`, which re-exports them) share: the replay lives in the shell, the nodes above it.

rclpy is an optional dependency (``pip install nifo[ros]``): it is imported inside the functions, so importing
this module needs no ROS.
"""

from __future__ import annotations

import time
from typing import Callable

__all__ = ["sensor_qos", "reliable_input_qos", "publish_blocking"]


def sensor_qos(depth: int = 5):
    """``qos_profile_sensor_data`` (best effort, volatile) with history ``depth``.

    Subscribers use a deeper history than the default 5 so that a burst
    (replay, scheduling hiccup) is not dropped before the executor takes it.
    """
    from rclpy.qos import QoSProfile, qos_profile_sensor_data

    p = QoSProfile(**{k: getattr(qos_profile_sensor_data, k) for k in
                      ("history", "reliability", "durability", "liveliness")}, depth=int(depth))
    return p


def reliable_input_qos():
    """Per-sample input for offline replay: reliable, volatile, **keep all** (on both ends).

    Keep-all on both sides is what makes it lossless: when the subscriber's
    history is full the DDS reader stops acknowledging, the publisher's history
    fills and ``publish`` blocks (:func:`publish_blocking`), so a CPU-starved
    subscriber slows the replay down instead of losing samples. (A keep-last
    writer overwrites unacknowledged samples; a keep-last reader overwrites
    untaken ones: both lose data when a node falls behind.)
    """
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def publish_blocking(pub, data, *, timeout_s: float = 60.0, should_stop: Callable[[], bool] = lambda: False,
                     ) -> bool:
    """``pub.publish(data)``, retried while a keep-all reliable history is full (backpressure).

    rmw_fastrtps blocks ``publish`` for a while and then fails with "cannot
    publish data" when the subscriber has not taken enough; we wait and
    retry. Returns False if ``should_stop()`` became true; raises the last
    error after ``timeout_s`` without progress (a subscriber that is stuck).
    """
    from rclpy.impl.implementation_singleton import rclpy_implementation

    RCLError = rclpy_implementation.RCLError
    deadline = None
    while True:
        try:
            pub.publish(data)
            return True
        except RCLError:
            now = time.monotonic()
            deadline = deadline or now + timeout_s
            if now > deadline:
                raise
            if should_stop():
                return False
            time.sleep(0.002)
