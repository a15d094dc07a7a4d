"""The colcon workspace (ros2_ws): package.xml valid, colcon build (PyPI colcon-core + colcon-ros) works,
the installed entry points run our nodes; run_pipeline.py drives a bag through the nodes and stops on SIGINT.

What is validated here: colcon-ros builds ``nifo_ros`` with the ``ament_python`` build type (it is a
setuptools build underneath; no ament CMake is involved), installs the console scripts under
``lib/nifo_ros``, the launch and config files under ``share/nifo_ros`` and the ament index marker. The
launch files are only byte-compiled: ``launch``/``launch_ros`` are not installable from PyPI.
"""

from __future__ import annotations

import os
import py_compile
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PKG = REPO / "ros2_ws" / "src" / "nifo_ros"


def test_package_xml_is_a_valid_format_3_ament_python_package():
    from catkin_pkg.package import parse_package

    pkg = parse_package(str(PKG / "package.xml"))
    pkg.validate()
    assert pkg.package_format == 3 and pkg.name == "nifo_ros"
    assert pkg.get_build_type() == "ament_python"
    assert {"rclpy", "sensor_msgs", "std_msgs", "geometry_msgs", "ament_index_python", "nifo_msgs",
            "diagnostic_msgs"} <= {d.name for d in pkg.exec_depends}
    assert {d.name for d in pkg.test_depends} == {"python3-pytest"}
    msgs = parse_package(str(REPO / "ros2_ws" / "src" / "nifo_msgs" / "package.xml"))
    msgs.validate()
    assert msgs.get_build_type() == "ament_cmake" and "rosidl_interface_packages" in [g.name for g in
                                                                                       msgs.member_of_groups]


def test_the_ros_package_own_tests_pass_launch_files_name_only_what_exists():
    """What ``colcon test`` runs for nifo_ros (its python3-pytest test dependency): the launch files parsed,
    every executable, parameter file, parameter, remapped topic and launch argument checked."""
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(PKG / "test")],
                       capture_output=True, text=True, timeout=120, cwd=PKG)
    assert r.returncode == 0 and " passed" in r.stdout and "skipped" not in r.stdout, r.stdout[-3000:] + r.stderr


def test_launch_files_compile_and_config_files_name_existing_parameters():
    import yaml

    for f in (PKG / "launch").glob("*.launch.py"):
        py_compile.compile(str(f), doraise=True)
    for node in ("acquisition", "integrator", "identifier"):
        doc = yaml.safe_load((PKG / "config" / f"{node}.yaml").read_text())
        assert list(doc) == [f"/**/{node}"] and "ros__parameters" in doc[f"/**/{node}"]
    for link in (REPO / "launch_scripts").glob("*.launch.py"):
        assert link.resolve().is_file()


@pytest.mark.ros
def test_colcon_build_installs_entry_points_that_run_the_nodes(tmp_path):
    pytest.importorskip("rclpy")
    colcon = shutil.which("colcon", path=str(Path(sys.executable).parent)) or shutil.which("colcon")
    if colcon is None:
        pytest.skip("colcon not installed (pip install colcon-core colcon-ros)")
    r = subprocess.run([colcon, "--log-base", str(tmp_path / "log"), "build", "--base-paths", str(PKG),
                        "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install")],
                       cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    inst = tmp_path / "install" / "nifo_ros"
    for exe in ("acquisition", "integrator", "identifier", "rerun_viewer"):
        assert (inst / "lib" / "nifo_ros" / exe).is_file()
    share = inst / "share" / "nifo_ros"
    assert (share / "launch" / "pipeline.launch.py").is_file() and (share / "config" / "integrator.yaml").is_file()
    assert (share / "config" / "fastdds_profile.xml").is_file()       # the nodes' Fast DDS profile goes with them
    assert (tmp_path / "install" / "nifo_ros" / "share" / "ament_index" / "resource_index" / "packages"
            / "nifo_ros").is_file()
    # the installed console script runs our integrator node with the installed parameter file
    site = next((inst / "lib").glob("python3*/site-packages"))
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(100, 200)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONPATH=os.pathsep.join([str(site), str(REPO), os.environ.get("PYTHONPATH", "")]))
    p = subprocess.Popen([sys.executable, str(inst / "lib" / "nifo_ros" / "integrator"), "--ros-args",
                          "-r", "__ns:=/nifo", "--params-file", str(share / "config" / "integrator.yaml"),
                          "-p", "fs_hz:=500.0"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         start_new_session=True)
    try:
        out = b""
        end = time.monotonic() + 30
        while time.monotonic() < end and b"sample rate" not in out:
            out += os.read(p.stdout.fileno(), 4096)
        assert b"sample rate 500 Hz" in out
        os.killpg(p.pid, signal.SIGINT)
        assert p.wait(10) == 0
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)


@pytest.mark.ros
def test_the_nodes_get_the_fast_dds_profile_unless_one_is_given_and_fast_dds_reads_it(tmp_path):
    """nifo_nodes.launcher.dds_env: the shipped profile (heartbeats every 100 ms: a stopping node's last messages
    acknowledged at once, not on Fast DDS's 3 s heartbeat) unless a profile file is set already. Fast DDS reads
    it without complaint, where it names a broken one (the control: the check can fail)."""
    pytest.importorskip("rclpy")
    from nifo_nodes.launcher import DDS_PROFILE, dds_env

    assert dds_env({"A": "1"}) == {"A": "1", "FASTRTPS_DEFAULT_PROFILES_FILE": str(DDS_PROFILE)}
    for mine in ({"FASTRTPS_DEFAULT_PROFILES_FILE": "mine.xml"}, {"FASTDDS_DEFAULT_PROFILES_FILE": "mine.xml"}):
        assert dds_env(mine) == mine
    broken = tmp_path / "broken.xml"
    broken.write_text("<profiles><data_writer")
    code = ("import rclpy; from std_msgs.msg import String; rclpy.init(); n = rclpy.create_node('profile_check'); "
            "n.create_publisher(String, 'profile_check', 10); print('publisher made')")

    def publisher(profile: Path) -> str:
        env = {k: v for k, v in os.environ.items() if k not in ("FASTRTPS_DEFAULT_PROFILES_FILE",
                                                                  "FASTDDS_DEFAULT_PROFILES_FILE")}
        env.update(ROS_DOMAIN_ID=str(random.randint(100, 200)), FASTRTPS_DEFAULT_PROFILES_FILE=str(profile))
        r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and "publisher made" in r.stdout, r.stderr
        return r.stdout + r.stderr       # Fast DDS logs on stdout

    assert "XMLPARSER" in publisher(broken)
    assert "Error" not in publisher(DDS_PROFILE)


@pytest.mark.ros
def test_run_pipeline_replays_a_bag_through_the_nodes_into_a_live_rerun_recording(tmp_path):
    pytest.importorskip("rclpy")
    from rerun.chunk import RrdReader

    from nifo.io.loader import save_record
    from nifo_core.simulate.quarter_car import SimConfig, simulate
    from nifo_nodes.launcher import claim_domain_id

    save_record(tmp_path / "short.mcap", simulate(SimConfig(duration_s=6.0, fs_hz=200.0), rng=1).record)
    ckpt, rrd = tmp_path / "id.npz", tmp_path / "live.rrd"
    with claim_domain_id() as domain:
        p = subprocess.Popen([sys.executable, str(REPO / "launch_scripts" / "run_pipeline.py"), "--bag",
                              str(tmp_path / "short.mcap"), "--rate", "3", "--domain-id", str(domain),
                              "--log-dir", str(tmp_path / "logs"), "--checkpoint", str(ckpt), "--linger", "2",
                              "--rerun", f"save={rrd}"],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            out = p.communicate(timeout=120)[0].decode()
        finally:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 0, out
    assert "replay finished (exit 0)" in out and "exit codes [0, 0, 0, 0]" in out, out
    # the replay waited for the Imu topics the nodes take, not for the bag's tire-patch topic nobody takes (which
    # held it the whole --wait 15 before it started)
    assert "no subscriber on" not in out, out
    logs = "".join(f.read_text() for f in (tmp_path / "logs").glob("*.log"))
    assert "XMLPARSER" not in logs, logs        # the nodes' Fast DDS profile (nifo_nodes.launcher.DDS_PROFILE) read
    integ = (tmp_path / "logs" / "integrator.log").read_text()
    assert "sample rate 200 Hz" in integ
    assert ckpt.exists()  # the identifier wrote its checkpoint on the way out (clean SIGINT shutdown)
    # the live view: the viewer node logged the replayed accelerations at the data's stamps
    ents = {c.entity_path for c in RrdReader(rrd).stream().to_chunks()}
    assert "/accel/live" in ents, sorted(ents)
    # the stream's health from the identifier's status (no estimate from 6 s: samples, no gap, no loss)
    assert {"/stream/samples_lost", "/stream/gaps", "/summary"} <= ents, sorted(ents)
