"""Results a ROS user can plot: the typed result topics and /diagnostics recorded from the running pipeline
(run_pipeline.py --record: nifo's result recorder) decode with the independent ``mcap-ros2-support`` reader
(what Foxglove uses: the message definitions embedded in the MCAP file), and the recorded estimate is the
live identifier's, with headers stamped from the data."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
mcap_ros2 = pytest.importorskip("mcap_ros2.reader")
pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[1]
FS = 250.0


def test_result_bag_recorded_from_the_pipeline_decodes_with_mcap_ros2_support(tmp_path):
    from nifo.io.loader import save_record
    from nifo.io.modelfile import write_model_spec
    from nifo_core.kinds.describing import make_term
    from nifo_core.simulate.quarter_car import SimConfig, preset, simulate
    from nifo_nodes.launcher import claim_domain_id

    sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=30.0, fs_hz=FS), rng=5)
    save_record(tmp_path / "run.mcap", sim.record)
    model = write_model_spec(tmp_path / "model.yaml", [make_term({"kind": "velocity_deadzone",
                                                                  "params": {"knee": 0.03}})],
                             settings={"block": 512, "overlap": 0.5, "band_hz": [2.0, 100.0]})
    out = tmp_path / "results.mcap"
    with claim_domain_id() as dom:
        p = subprocess.Popen([sys.executable, str(REPO / "launch_scripts" / "run_pipeline.py"), "--bag",
                              str(tmp_path / "run.mcap"), "--model", str(model), "--reliable", "--rate", "0",
                              "--linger", "3", "--domain-id", str(dom), "--log-dir", str(tmp_path / "logs"),
                              "--checkpoint", str(tmp_path / "id.npz"), "--record", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True,
                             env={**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
        try:
            log = p.communicate(timeout=240)[0].decode()
        finally:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 0, log
    assert out.is_file(), log
    msgs: dict[str, list] = {}
    for m in mcap_ros2.read_ros2_messages(str(out)):
        msgs.setdefault(m.channel.topic, []).append(m)
    assert {"/nifo/identifier/transmissibility", "/nifo/identifier/coefficients", "/nifo/identifier/status",
            "/diagnostics"} <= set(msgs), sorted(msgs)
    assert msgs["/nifo/identifier/transmissibility"][0].schema.name == "nifo_msgs/msg/Transmissibility"
    t = msgs["/nifo/identifier/transmissibility"][-1].ros_msg
    st = msgs["/nifo/identifier/status"][-1].ros_msg
    c = msgs["/nifo/identifier/coefficients"][-1].ros_msg
    # the recorded estimate is the identifier's final one: the result document it wrote says the same
    doc = json.loads(Path(st.result_file).read_text())
    assert t.n_avg == doc["n_avg"] == st.n_avg > 0 and t.samples_used == doc["n_samples"]
    np.testing.assert_array_equal(t.freq_hz, doc["freq_hz"])
    np.testing.assert_array_equal(t.t21_re, doc["t21"]["re"])
    np.testing.assert_array_equal(c.c_pooled, doc["static"]["c_over_m2"])
    assert list(c.terms) == ["velocity_deadzone(knee=0.03)"] and (t.gaps, t.samples_lost) == (0, 0)
    # header: data stamp (the newest sample used: within the record), the body frame
    stamp = t.header.stamp.sec * 10**9 + t.header.stamp.nanosec
    from nifo.io.loader import load_record

    t0 = load_record(tmp_path / "run.mcap").t0_ns   # a record starting at 0 is written to start "now"
    assert t0 < stamp <= t0 + int(30.0 * 1e9) and t.header.frame_id == "body"
    assert stamp == doc["stamp_ns"]
    names = {s.name for m in msgs["/diagnostics"] for s in m.ros_msg.status}
    assert {"nifo/integrator", "nifo/identifier"} <= names
    last = [s for m in msgs["/diagnostics"] for s in m.ros_msg.status if s.name == "nifo/identifier"][-1]
    kv = {k.key: k.value for k in last.values}
    assert kv["gaps"] == "0" and int(kv["n_avg"]) > 0
