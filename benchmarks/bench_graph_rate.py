#!/usr/bin/env python3
"""Highest per-channel sample rate the node graph sustains with no lost samples, and its CPU cost.

For each rate (ascending) a synthetic two-channel record of ``--seconds`` is written as a bag and
played by the real acquisition node (``source: file``, real time) → integrator → identifier, each a
separate process on an isolated ROS_DOMAIN_ID. A sample is lost when the integrator's aligned
``accel/block`` stream (collected here) is not exactly the record: fewer rows, or more than one
segment (a gap). The sensor stream is the vehicle's: best effort (sensor-data QoS), so loss is
real loss. CPU is each process's user+system time over the run, as % of one core (acquisition:
sampled until just before it exits). Each rate runs on its own claimed ROS_DOMAIN_ID.

    python benchmarks/bench_graph_rate.py                     # 1, 2, 3, 4, 6 kHz
    python benchmarks/bench_graph_rate.py --rates 2000 --seconds 20
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nifo_nodes.launcher import CONFIG_DIR, NodeSpec, claim_domain_id, start, stop  # noqa: E402


def cpu_s(pid: int) -> float:
    """user + system CPU seconds of a live process (Linux /proc)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_rate(fs: float, seconds: float, tmp: Path, a_poll_s: float = 0.002) -> dict:
    with claim_domain_id() as dom:
        return _run_rate(fs, seconds, tmp, dom, a_poll_s)


def _run_rate(fs: float, seconds: float, tmp: Path, dom: int, a_poll_s: float) -> dict:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64MultiArray

    from nifo.io.loader import save_record
    from nifo_core.record import Record
    from nifo_nodes.common import block_qos
    from nifo_nodes.messages import block_from_msg

    rng = np.random.default_rng(0)
    n = int(fs * seconds)
    rec = Record(fs, rng.standard_normal(n), rng.standard_normal(n), t0_ns=1_700_000_000 * 10**9)
    bag = tmp / f"bench_{int(fs)}.mcap"
    save_record(bag, rec)
    env = dict(os.environ, ROS_DOMAIN_ID=str(dom), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONPATH=str(Path(__file__).resolve().parents[1]) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    node = rclpy.create_node("bench_collector", namespace="/nifo", context=ctx)
    got = {"rows": 0, "segments": set(), "blocks": 0}

    def on_block(m):
        b = block_from_msg(m)
        got["rows"] += b.n
        got["segments"].add(b.segment)
        got["blocks"] += 1

    node.create_subscription(Float64MultiArray, "accel/block", on_block, block_qos())
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    def spin():
        while ctx.ok():
            try:
                ex.spin_once(timeout_sec=0.05)
            except Exception:  # the context shut down under us at the end
                break

    th = threading.Thread(target=spin, daemon=True)
    th.start()
    cfg = lambda name: (str(CONFIG_DIR / f"{name}.yaml"),)  # noqa: E731
    procs = {}
    try:
        procs["integrator"] = start(NodeSpec("integrator", params_files=cfg("integrator"), params={"fs_hz": float(fs)}),
                                    env=env, log_dir=tmp / f"logs_{int(fs)}")
        procs["identifier"] = start(NodeSpec("identifier", params_files=cfg("identifier"),
                                             params={"model_file": str(CONFIG_DIR / "model.yaml")}),
                                    env=env, log_dir=tmp / f"logs_{int(fs)}")
        time.sleep(3.0)  # discovery
        procs["acquisition"] = start(NodeSpec("acquisition", params_files=cfg("acquisition"),
                                              params={"source": "file", "path": str(bag),
                                                      "wait_for_subscribers_s": 10.0, "poll_s": a_poll_s}),
                                     env=env, log_dir=tmp / f"logs_{int(fs)}")
        t0 = time.monotonic()
        c0 = {k: cpu_s(p.pid) for k, p in procs.items()}
        acq, a_cpu, end = procs["acquisition"], c0["acquisition"], time.monotonic() + seconds + 60
        while acq.poll() is None and time.monotonic() < end:  # its CPU, sampled until it exits
            try:
                a_cpu, a_wall = cpu_s(acq.pid), time.monotonic() - t0
            except (OSError, IndexError, ValueError):
                break
            time.sleep(0.1)
        time.sleep(1.0)
        wall = time.monotonic() - t0
        c1 = {k: cpu_s(p.pid) for k, p in procs.items() if k != "acquisition"}
        cpu = {k: 100 * (c1[k] - c0[k]) / wall for k in ("integrator", "identifier")}
        cpu["acquisition"] = 100 * (a_cpu - c0["acquisition"]) / a_wall
    finally:
        stop(list(procs.values()))
        ctx.try_shutdown()
        th.join(2)
    lost = n - got["rows"]
    return {"fs_hz": fs, "samples": n, "received": got["rows"], "lost": lost, "segments": len(got["segments"]),
            "ok": lost == 0 and len(got["segments"]) == 1, "cpu_pct": cpu, "wall_s": wall}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rates", type=float, nargs="+", default=[1000.0, 2000.0, 3000.0, 4000.0, 6000.0])
    p.add_argument("--seconds", type=float, default=10.0)
    a = p.parse_args(argv)
    best = 0.0
    with tempfile.TemporaryDirectory() as d:
        for fs in a.rates:
            r = run_rate(fs, a.seconds, Path(d))
            print(f"{fs:7.0f} Hz x 2 channels: {r['received']}/{r['samples']} samples, {r['segments']} segment(s) "
                  f"-> {'OK' if r['ok'] else 'LOST'}; CPU acquisition {r['cpu_pct']['acquisition']:.0f} %, "
                  f"integrator {r['cpu_pct']['integrator']:.0f} %, identifier {r['cpu_pct']['identifier']:.0f} % "
                  "of a core", flush=True)
            if not r["ok"]:
                break
            best = fs
    print(f"highest sustained per-channel rate with no lost samples: {best:g} Hz (2 channels, {os.cpu_count()} cores)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
