"""``nifo replay BAG``: publish a recorded bag into the ROS 2 graph with its recorded stamps."""

from __future__ import annotations

import argparse
import sys

from nifo.commands import SUMMARIES
from nifo.io.bag_replay import replay_bag
from nifo_core.errors import ConfigError

HELP = SUMMARIES["replay"]
DESCRIPTION = """\
Publish every message of a rosbag2 bag (directory or .mcap) on its recorded
topic, paced by the recorded times, as serialized bytes straight from the bag:
the header stamps are the recorded ones. Needs rclpy (pip install nifo[ros]).
Vehicle-side equivalent: ros2 bag play BAG [--rate R] [--loop].

Examples:
  nifo replay run1.mcap                 real time
  nifo replay run1.mcap --rate 4 --wait 5
  nifo replay run1.mcap --reliable      lossless, for identification (integrator
                                        input_reliability: reliable)
  ROS_DOMAIN_ID=42 nifo replay bags/shaker --loop
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("bag", help="rosbag2 bag directory or .mcap file")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (0: as fast as possible; default 1)")
    p.add_argument("--loop", action="store_true", help="start over at the end (stamps repeat, as ros2 bag play)")
    p.add_argument("--start", type=float, default=0.0, metavar="S", help="skip the first S seconds")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="publish only these topics")
    p.add_argument("--wait", type=float, default=0.0, metavar="S",
                   help="wait up to S seconds for a subscriber on every topic (or those of --wait-for) before "
                        "starting")
    p.add_argument("--wait-for", nargs="+", metavar="TOPIC", dest="wait_for",
                   help="the topics --wait waits for (default: every topic published; a pipeline takes the Imu "
                        "topics and nobody may listen to the others)")
    p.add_argument("--depth", type=int, default=1000,
                   help="best-effort publisher history depth (default 1000; --reliable keeps all)")
    p.add_argument("--reliable", action="store_true",
                   help="reliable keep-all publishers: a slow subscriber slows the replay down instead of losing "
                        "samples (subscribers must be reliable: integrator input_reliability:=reliable)")


def run(args: argparse.Namespace) -> dict:
    try:  # rclpy is optional (nifo[ros]): imported here so the CLI starts without ROS
        import rclpy
        from rclpy.signals import SignalHandlerOptions
    except ImportError:
        raise ConfigError("rclpy is not installed", hint="pip install 'nifo[ros]' or source a ROS 2 setup") from None

    # Python's own SIGINT handling: Ctrl-C raises KeyboardInterrupt in the publishing loop
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    try:
        stats = replay_bag(args.bag, rate=args.rate, loop=args.loop, start_s=args.start, topics=args.topics,
                           wait_s=args.wait, depth=args.depth, reliable=args.reliable,
                           wait_for=getattr(args, "wait_for", None),
                           log=lambda line: print(line, file=sys.stderr))   # stdout: the --json document
    finally:
        rclpy.try_shutdown()
    per = ", ".join(f"{t} {n}" for t, n in stats.by_topic.items())
    print(f"nifo replay: published {stats.messages} messages ({per}) in {stats.wall_s:.1f} s", file=sys.stderr)
    return {"messages": stats.messages, "by_topic": dict(stats.by_topic), "wall_s": stats.wall_s}
