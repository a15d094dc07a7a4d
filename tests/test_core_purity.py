"""nifo_core stays pure: importing all of it pulls in no ROS, Rerun, bag or plotting library."""

import subprocess
import sys


def test_importing_nifo_core_pulls_in_no_ros_rerun_or_bag_libraries():
    code = (
        "import pkgutil, importlib, sys, nifo_core\n"
        "for m in pkgutil.walk_packages(nifo_core.__path__, 'nifo_core.'):\n"
        "    importlib.import_module(m.name)\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in "
        "('rclpy', 'rerun', 'rosbags', 'mcap', 'sensor_msgs', 'std_msgs', 'matplotlib')]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
