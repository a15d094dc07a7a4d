"""``ros2 run nifo_ros <node>``: hand over to ``nifo_nodes`` (installed with ``pip install nifo``)."""

import sys


def _main(module: str) -> int:
    try:
        mod = __import__(f"nifo_nodes.{module}", fromlist=["main"])
    except ImportError as err:
        print(f"nifo_ros: cannot import nifo_nodes ({err}). Install nifo into the ROS Python: "
              "python3 -m pip install /path/to/nifo  (see docs/ros.md)", file=sys.stderr)
        return 1
    return mod.main(sys.argv)


def acquisition() -> int:
    return _main("acquisition")


def integrator() -> int:
    return _main("integrator")


def identifier() -> int:
    return _main("identifier")


def rerun_viewer() -> int:
    return _main("rerun_viewer")
