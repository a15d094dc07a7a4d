"""The result recorder node: the identifier's results and ``/diagnostics`` into a rosbag2 MCAP bag.

``ros2 bag record`` for a machine with only pip rclpy: subscribes (serialized,
no decode) to ``identifier/transmissibility``, ``identifier/coefficients``,
``identifier/status`` (reliable, transient local: it gets the latest on start)
and ``/diagnostics``, and on shutdown writes every message it received to
``--out`` atomically (rosbag2 metadata v8 + MCAP, zstd chunks, message
definitions embedded — Foxglove, ``ros2 bag`` and any MCAP reader decode it;
log time = receive time, as ``ros2 bag record``)::

    python -m nifo_nodes.recorder --ros-args -r __ns:=/nifo -- --out results.mcap
    python launch_scripts/run_pipeline.py --bag run1.mcap --reliable --record results.mcap

The bag is written with rosbags (nifo's bag library); the ``nifo_msgs``
definitions are registered from the installed package's ``.msg`` files.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from .common import DIAGNOSTICS_TOPIC, TOPICS, result_qos, run_node

__all__ = ["RecorderNode", "main", "write_messages", "RESULT_TOPICS"]

#: relative topic name -> message type recorded
RESULT_TOPICS = {TOPICS["transmissibility"]: "nifo_msgs/msg/Transmissibility",
                 TOPICS["coefficients"]: "nifo_msgs/msg/Coefficients",
                 TOPICS["status"]: "nifo_msgs/msg/LoopStatus",
                 DIAGNOSTICS_TOPIC: "diagnostic_msgs/msg/DiagnosticArray"}

try:
    from rclpy.node import Node
except ImportError:  # pragma: no cover - documented: the nodes need rclpy
    Node = object


def _typestore():
    """rosbags' Jazzy type store plus the nifo_msgs definitions (from the installed .msg files)."""
    import nifo_msgs
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    share = Path(os.environ.get("AMENT_PREFIX_PATH", sys.prefix).split(os.pathsep)[0]) / "share" / "nifo_msgs"
    candidates = [share / "msg", Path(sys.prefix) / "share" / "nifo_msgs" / "msg",
                  Path(nifo_msgs.__file__).resolve().parents[4] / "share" / "nifo_msgs" / "msg"]
    msgdir = next((d for d in candidates if d.is_dir()), None)
    if msgdir is None:
        from nifo_core.errors import ConfigError
        raise ConfigError("the nifo_msgs message definitions (.msg) are not installed",
                          hint="rebuild them: ros2_ws/build_msgs.sh .venv")
    types = {}
    for f in sorted(msgdir.glob("*.msg")):
        types.update(get_types_from_msg(f.read_text(), f"nifo_msgs/msg/{f.stem}"))
    ts.register(types)
    return ts


def write_messages(path: str | Path, messages: list[tuple[str, str, int, bytes]]) -> Path:
    """``(topic, msgtype, log_ns, serialized)`` rows to a rosbag2 MCAP bag at ``path`` (atomic).

    ``path`` ending in ``.mcap`` gives a single MCAP file, anything else a bag directory.
    """
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

    from nifo.io.atomic import staged_file
    from nifo.io.bag import BAG_VERSION

    ts = _typestore()
    final = Path(path)
    with staged_file(final) as tmp:
        bagdir = tmp.parent / "bag" / final.stem if final.suffix == ".mcap" else tmp
        bagdir.parent.mkdir(parents=True, exist_ok=True)
        writer = Writer(bagdir, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        with writer:
            writer.set_custom_data("generator", "nifo result recorder")
            conns = {}
            for topic, msgtype, log_ns, raw in sorted(messages, key=lambda m: m[2]):
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
                writer.write(conns[topic], int(log_ns), raw)
        if final.suffix == ".mcap":
            os.replace(bagdir / f"{final.stem}.mcap", tmp)
    return final


class RecorderNode(Node):
    def __init__(self, out: str, **kwargs) -> None:
        super().__init__("recorder", **kwargs)
        from diagnostic_msgs.msg import DiagnosticArray

        from .results import msg_types

        Transmissibility, Coefficients, LoopStatus = msg_types()

        classes = {"nifo_msgs/msg/Transmissibility": Transmissibility, "nifo_msgs/msg/Coefficients": Coefficients,
                   "nifo_msgs/msg/LoopStatus": LoopStatus, "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray}
        self._out = out
        self._rows: list[tuple[str, str, int, bytes]] = []
        _typestore()  # fail at start-up, not at the end, if the definitions are missing
        for topic, msgtype in RESULT_TOPICS.items():
            qos = 10 if topic == DIAGNOSTICS_TOPIC else result_qos()
            full = self.resolve_topic_name(topic)
            self.create_subscription(classes[msgtype], topic,
                                     lambda raw, t=full, m=msgtype: self._rows.append((t, m, time.time_ns(), raw)),
                                     qos, raw=True)
        self.create_timer(0.5, lambda: None)  # wakes the executor so SIGINT is handled promptly

    def close(self) -> None:
        try:
            write_messages(self._out, self._rows)
            self.get_logger().info(f"wrote {len(self._rows)} messages to {self._out}")
        except Exception as err:  # noqa: BLE001 - shutting down: say it, do not mask the shutdown
            self.get_logger().error(f"could not write {self._out}: {err}")


def main(args: list[str] | None = None) -> int:
    from rclpy.utilities import remove_ros_args

    argv = list(sys.argv if args is None else args)
    parser = argparse.ArgumentParser(prog="recorder", description=__doc__.split("\n", 1)[0])
    parser.add_argument("--out", required=True, help="bag to write (.mcap file or bag directory)")
    opts = parser.parse_args([a for a in remove_ros_args(argv)[1:] if a != "--"])
    return run_node(lambda: RecorderNode(opts.out), argv)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
