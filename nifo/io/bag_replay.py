"""Publish a recorded rosbag2 bag into the graph, paced by its log times (``nifo replay``).

The serialized messages go out exactly as stored (``Publisher.publish(bytes)``:
no decode, no re-encode), so the stamps in their headers are the recorded
ones and the live nodes cannot tell a replay from the vehicle. Topics keep
their recorded (absolute) names. ``ros2 bag play BAG`` is the vehicle-side
equivalent.

Two QoS modes (matrix in :mod:`nifo_nodes.common`; the profiles in :mod:`nifo.io.ros_qos`):

* default — the sensor-data profile (best effort) with a deep history, as the
  vehicle publishes. When the process falls behind schedule (descheduled on a
  loaded machine) it slips its clock rather than publishing a catch-up burst,
  which a best-effort transport would drop; samples can still be lost.
* ``reliable=True`` (``nifo replay --reliable``) — for identification, where
  losing samples is wrong: reliable, keep-all publishers
  (:func:`common.reliable_input_qos`; subscribers must be reliable too, e.g.
  the integrator with ``input_reliability: reliable``). A subscriber that
  falls behind fills the histories and ``publish`` blocks
  (:func:`common.publish_blocking`): the replay slows down, nothing is lost.
  The replay catches up after such a pause, and before it returns waits until
  every subscriber has acknowledged everything.
"""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from nifo_core.errors import ConfigError, DataFileError

from .ros_qos import publish_blocking, reliable_input_qos, sensor_qos

__all__ = ["ReplayStats", "replay_bag", "message_class"]

#: how far behind schedule the replay may fall before it slips its clock instead of bursting
_MAX_BEHIND_S = 0.02


@dataclass
class ReplayStats:
    messages: int = 0
    loops: int = 0
    by_topic: dict = field(default_factory=dict)
    wall_s: float = 0.0


def message_class(msgtype: str):
    """``"sensor_msgs/msg/Imu"`` to the rclpy message class (must be installed)."""
    pkg, _, name = msgtype.rpartition("/")
    try:
        return getattr(importlib.import_module(pkg.replace("/", ".")), name)
    except (ImportError, AttributeError) as err:
        raise ConfigError(f"message type {msgtype} is not available to rclpy",
                          hint=f"install its Python package (pip install ros-jazzy-{pkg.split('/')[0].replace('_', '-')})"
                          ) from err


def _storage(path: Path) -> Path:
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        mcaps = sorted(path.glob("*.mcap"))
        if len(mcaps) == 1:
            return mcaps[0]
    return path


def _awaited(pubs: dict, wait_for: Sequence[str] | None) -> list[str]:
    """The published topics the start waits for: ``wait_for`` (each must be published), or all of them."""
    if wait_for is None:
        return list(pubs)
    missing = [t for t in wait_for if t not in pubs]
    if missing:
        raise ConfigError(f"--wait-for {' '.join(missing)}: not a topic this replay publishes",
                          hint=f"it publishes {' '.join(sorted(pubs))}")
    return list(wait_for)


def replay_bag(path: str | Path, *, rate: float = 1.0, loop: bool = False, start_s: float = 0.0,
               topics: list[str] | None = None, wait_s: float = 0.0, depth: int = 1000,
               reliable: bool = False, node_name: str = "nifo_replay", log: Callable[[str], None] = print,
               should_stop: Callable[[], bool] = lambda: False,
               wait_for: Sequence[str] | None = None) -> ReplayStats:
    """Publish the bag's messages at ``rate`` × recorded speed (``rate=0``: as fast as possible).

    Needs ``rclpy.init()`` done by the caller. ``start_s`` skips the first
    seconds of the bag; ``wait_s`` waits up to that long for a subscriber on
    every topic of ``wait_for`` (default: every topic published) before starting, and says so through ``log``
    when one has none by then (the replay starts anyway); ``topics`` restricts what is published;
    ``reliable`` selects the lossless QoS (module docstring).

    ``wait_for`` is what a pipeline consumes: the nodes take the two Imu topics, and a bag's other topics (the
    tire-patch displacement of a simulated run) have no subscriber, so waiting for every topic waited the whole
    ``wait_s``. Measured with ``run_pipeline.py --bag`` of a simulated 6 s bag at ``--rate 3`` (``--wait 15``): the
    replay began publishing 15.5 s after its process started, and 1.1 s (its start-up and the 0.5 s settling) once
    it waited for the Imu topics alone; the whole launch 28.6 → 14.2 s.
    """
    import rclpy  # optional dependency (nifo[ros]): imported here so the shell loads without ROS
    from rclpy.node import Node
    from rclpy.duration import Duration
    from rosbags.rosbag2 import Reader

    if rate < 0:
        raise ConfigError(f"{rate=} must be >= 0 (0: as fast as possible)", channel="--rate")
    src = str(path)
    path = Path(path)
    if not path.exists():
        raise DataFileError("no such file or directory", source=src, hint="check the path")
    stats = ReplayStats()
    node = Node(node_name)
    try:
        try:
            reader = Reader(_storage(path))
            reader.open()
        except Exception as err:
            raise DataFileError(f"cannot open the bag ({err})", source=src,
                                hint="pass a rosbag2 directory or an .mcap file") from err
        try:
            conns = [c for c in reader.connections if topics is None or c.topic in topics]
            if not conns:
                raise DataFileError("no matching topics in the bag", source=src,
                                    hint=f"the bag has {sorted({c.topic for c in reader.connections})}")
            pubs = {}
            qos = reliable_input_qos() if reliable else sensor_qos(depth)
            for c in conns:
                if c.topic not in pubs:
                    pubs[c.topic] = node.create_publisher(message_class(c.msgtype), c.topic, qos)
            awaited = _awaited(pubs, wait_for)
            deadline = time.monotonic() + wait_s
            while wait_s > 0 and not should_stop():
                if all(pubs[t].get_subscription_count() > 0 for t in awaited):
                    # the publisher sees the subscriber a little before the subscriber has matched
                    # the publisher: best-effort messages sent in between are lost
                    time.sleep(0.5)
                    break
                if time.monotonic() >= deadline:
                    alone = [t for t in awaited if pubs[t].get_subscription_count() == 0]
                    log(f"nifo replay: no subscriber on {', '.join(alone)} after {wait_s:g} s; replaying anyway")
                    break
                time.sleep(0.02)
            first = reader.start_time + int(start_s * 1e9)
            while True:
                t_wall0 = time.monotonic()
                for conn, t_ns, raw in reader.messages(connections=conns, start=first):
                    if rate > 0:
                        due = t_wall0 + (t_ns - first) / 1e9 / rate
                        delay = due - time.monotonic()
                        if delay > 0.0005:
                            time.sleep(delay)
                        elif delay < -_MAX_BEHIND_S and not reliable:
                            # descheduled: slip instead of catching up in a burst that best-effort
                            # transports drop (the stamps, not the wall clock, carry the time)
                            t_wall0 -= delay
                    if reliable:
                        if not publish_blocking(pubs[conn.topic], bytes(raw), should_stop=should_stop):
                            return stats
                    else:
                        pubs[conn.topic].publish(bytes(raw))
                    stats.messages += 1
                    stats.by_topic[conn.topic] = stats.by_topic.get(conn.topic, 0) + 1
                    if should_stop():
                        return stats
                stats.loops += 1
                if not loop or not rclpy.ok() or should_stop():
                    break
            if reliable:  # the history still holds what was not acknowledged: deliver it before leaving
                for topic, pub in pubs.items():
                    if not pub.wait_for_all_acked(Duration(seconds=30)):
                        log(f"nifo replay: {topic}: not every sample was acknowledged within 30 s")
            return stats
        finally:
            reader.close()
    finally:
        stats.wall_s = time.monotonic() - (locals().get("t_wall0") or time.monotonic())
        node.destroy_node()
