"""Failures a ROS user meets are one clear line and a distinct exit code, never a traceback or a silent 0:
a corrupt identifier checkpoint (ConfigError, exit 9), a pipeline node that died (run_pipeline exits
non-zero and names it)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytestmark = pytest.mark.ros

from nifo_core.errors import ConfigError  # noqa: E402
from nifo_nodes.launcher import CONFIG_DIR, claim_domain_id  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def _checkpoint(path: Path) -> Path:
    from nifo_core.kinds.describing import make_term
    from nifo_core.nifo.identify import StreamingNifo
    from nifo_core.signal.spectral import SpectralSettings
    from nifo_nodes.identifier import save_checkpoint
    from nifo_nodes.results import StreamStats

    s = StreamingNifo(200.0, [make_term({"kind": "cubic_stiffness"})], settings=SpectralSettings(block=256))
    s.push(*np.random.default_rng(0).standard_normal((2, 12000)))
    save_checkpoint(path, s, next_ns=123, stream=StreamStats(samples_received=3000, samples_lost=5, gaps=1))
    return path


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty", "other_npz", "missing_key"])
def test_a_corrupt_checkpoint_is_one_config_error_naming_the_file(tmp_path, damage):
    from nifo_nodes.identifier import load_checkpoint

    good = _checkpoint(tmp_path / "good.npz")
    nifo, next_ns, stream = load_checkpoint(good)  # the undamaged one resumes, accounting included
    assert next_ns == 123 and stream["gaps"] == 1 and stream["samples_lost"] == 5 and nifo.n_avg > 0
    bad = tmp_path / "bad.npz"
    raw = good.read_bytes()
    if damage == "garbage":
        bad.write_bytes(b"PK\x03\x04 not really a zip file" * 10)
    elif damage == "truncated":
        bad.write_bytes(raw[: len(raw) // 2])
    elif damage == "empty":
        bad.write_bytes(b"")
    elif damage == "other_npz":
        np.savez(bad, x=np.arange(3))
    else:
        with np.load(good) as z:
            state = {k: z[k] for k in z.files if not k.startswith("acc.")}
        with open(bad, "wb") as f:
            np.savez(f, **state)
    with pytest.raises(ConfigError) as err:
        load_checkpoint(bad)
    msg = str(err.value)
    assert "bad.npz" in msg and "checkpoint" in msg and "delete it" in msg and "\n" not in msg


def test_the_identifier_refuses_a_corrupt_checkpoint_in_one_line_with_the_config_exit_code(tmp_path):
    ckpt = tmp_path / "id.npz"
    ckpt.write_bytes(b"\x00" * 100)
    with claim_domain_id() as dom:
        r = subprocess.run([sys.executable, "-m", "nifo_nodes.identifier", "--ros-args", "-p",
                            f"checkpoint_file:={ckpt}", "-p", f"model_file:={CONFIG_DIR / 'model.yaml'}"],
                           capture_output=True, text=True, timeout=60,
                           env={**os.environ, "ROS_DOMAIN_ID": str(dom), "ROS_HOME": str(tmp_path)})
    assert r.returncode == ConfigError.exit_code == 9, r.stderr
    assert "Traceback" not in r.stderr and "BadZipFile" not in r.stderr.split("(")[0]
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("[nifo]")]
    assert len(lines) == 1 and str(ckpt) in lines[0] and "delete it" in lines[0], r.stderr
    assert ckpt.read_bytes() == b"\x00" * 100  # left in place for the user to look at


def test_run_pipeline_exits_non_zero_naming_a_node_that_died(tmp_path):
    """kill -9 of the identifier mid-replay: run_pipeline stops the others and exits 1 naming it."""
    with claim_domain_id() as dom:
        p = subprocess.Popen([sys.executable, str(REPO / "launch_scripts" / "run_pipeline.py"), "--bag",
                              str(REPO / "bags" / "sample" / "road_2p5mm"), "--rate", "1", "--domain-id", str(dom),
                              "--log-dir", str(tmp_path)], stderr=subprocess.PIPE, text=True,
                             start_new_session=True, env={**os.environ, "ROS_HOME": str(tmp_path)})
        try:
            err, pid = "", None
            end = time.monotonic() + 60
            while pid is None and time.monotonic() < end:
                line = p.stderr.readline()
                err += line
                m = re.search(r"started identifier \(pid (\d+)\)", line)
                pid = int(m.group(1)) if m else None
            assert pid, err
            time.sleep(3.0)
            os.killpg(pid, signal.SIGKILL)
            err += p.communicate(timeout=60)[1]
        finally:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 1, err
    assert re.search(r"node identifier \(pid \d+\) died: killed by SIGKILL \(-9\)", err), err
    assert "FAILED: identifier (killed by SIGKILL (-9))" in err, err
