#!/usr/bin/env python3
"""Lossless rate limit of the node graph, with and without a busy core, and its CPU cost.

Two figures per condition (``quiet``: the machine as it is; ``busy``: plus one process spinning a core):

1. **vehicle path (best effort, real time)** — the highest per-channel sample rate of the ladder
   ``--rates`` at which every sample arrives (method below);
2. **lossless replay path (reliable, keep all)** — ``nifo replay --reliable --rate 0`` of a
   ``--reliable-seconds`` bag at 4 kHz through integrator (``input_reliability: reliable``) → identifier:
   nothing can be lost (checked: every row arrives, one segment); the figure is the throughput, the
   per-channel rate the graph keeps up with (samples per channel / wall time) and messages/s.

For each rate (ascending) a synthetic two-channel record of ``--seconds`` is written as a bag and
played by the real acquisition node (``source: file``, real time) → integrator → identifier, each a
separate process on an isolated ROS_DOMAIN_ID. A sample is lost when the integrator's aligned
``accel/block`` stream (collected here) is not exactly the record: fewer rows, or more than one
segment (a gap). The sensor stream is the vehicle's: best effort (sensor-data QoS), so loss is
real loss. CPU is each process's user+system time over the run, as % of one core (acquisition:
sampled until just before it exits). Each rate runs on its own claimed ROS_DOMAIN_ID.

    python benchmarks/bench_graph_rate.py                     # 1, 2, 3, 4, 6 kHz; quiet and busy
    python benchmarks/bench_graph_rate.py --rates 2000 --seconds 20 --conditions busy
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nifo_nodes.launcher import CONFIG_DIR, NodeSpec, busy_core, claim_domain_id, start, stop  # noqa: E402


def cpu_s(pid: int) -> float:
    """user + system CPU seconds of a live process (Linux /proc)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _env(dom: int) -> dict:
    return dict(os.environ, ROS_DOMAIN_ID=str(dom), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                PYTHONPATH=str(Path(__file__).resolve().parents[1]) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _collector(dom: int):
    """An in-process subscriber on ``accel/block`` counting rows and segments: ``(got, context, thread)``."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64MultiArray

    from nifo_nodes.common import block_qos
    from nifo_nodes.messages import block_from_msg

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    node = rclpy.create_node("bench_collector", namespace="/nifo", context=ctx)
    got = {"rows": 0, "segments": set(), "blocks": 0}

    def on_block(m):
        b = block_from_msg(m)
        got["rows"] += b.n
        got["segments"].add(b.segment)
        got["blocks"] += 1

    node.create_subscription(Float64MultiArray, "accel/block", on_block, block_qos(keep_all=True))
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
    return got, ctx, th


def run_rate(fs: float, seconds: float, tmp: Path, a_poll_s: float = 0.002) -> dict:
    with claim_domain_id() as dom:
        return _run_rate(fs, seconds, tmp, dom, a_poll_s)


def _run_rate(fs: float, seconds: float, tmp: Path, dom: int, a_poll_s: float) -> dict:
    from nifo.io.loader import save_record
    from nifo_core.signal.record import Record

    rng = np.random.default_rng(0)
    n = int(fs * seconds)
    rec = Record(fs, rng.standard_normal(n), rng.standard_normal(n), t0_ns=1_700_000_000 * 10**9)
    bag = tmp / f"bench_{int(fs)}.mcap"
    save_record(bag, rec)
    env = _env(dom)
    got, ctx, th = _collector(dom)
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
        _finish(procs, ctx, th)
    return {**_loss(n, got), "fs_hz": fs, "cpu_pct": cpu, "wall_s": wall}


def run_reliable(fs: float, seconds: float, tmp: Path) -> dict:
    """``nifo replay --reliable --rate 0`` through integrator (reliable) → identifier: throughput, loss."""
    with claim_domain_id() as dom:
        return _run_reliable(fs, seconds, tmp, dom)


def _run_reliable(fs: float, seconds: float, tmp: Path, dom: int) -> dict:
    from nifo.io.loader import save_record
    from nifo_core.signal.record import Record

    rng = np.random.default_rng(1)
    n = int(fs * seconds)
    bag = tmp / f"reliable_{int(fs)}.mcap"
    save_record(bag, Record(fs, rng.standard_normal(n), rng.standard_normal(n), t0_ns=1_700_000_000 * 10**9))
    env = _env(dom)
    got, ctx, th = _collector(dom)
    cfg = lambda name: (str(CONFIG_DIR / f"{name}.yaml"),)  # noqa: E731
    logs = tmp / f"logs_reliable_{int(fs)}"
    procs = {}
    try:
        procs["integrator"] = start(NodeSpec("integrator", params_files=cfg("integrator"),
                                             params={"fs_hz": float(fs), "input_reliability": "reliable"}),
                                    env=env, log_dir=logs)
        procs["identifier"] = start(NodeSpec("identifier", params_files=cfg("identifier"),
                                             params={"model_file": str(CONFIG_DIR / "model.yaml")}),
                                    env=env, log_dir=logs)
        replay = subprocess.run([sys.executable, "-m", "nifo", "replay", str(bag), "--rate", "0", "--reliable",
                                 "--wait", "20", "--topics", "/nifo/spindle/imu", "/nifo/body/imu"], env=env,
                                capture_output=True, text=True, timeout=600)
        m = [ln for ln in replay.stderr.splitlines() if "published" in ln]
        wall = float(m[-1].rsplit(" in ", 1)[1].split()[0]) if m else float("nan")
        end = time.monotonic() + 20
        while got["rows"] < n and time.monotonic() < end:
            time.sleep(0.1)
    finally:
        _finish(procs, ctx, th)
    r = _loss(n, got)
    return {**r, "ok": r["ok"] and replay.returncode == 0, "fs_hz": fs, "wall_s": wall, "rate_hz": n / wall,
            "msgs_per_s": 2 * n / wall}


def _finish(procs: dict, ctx, th) -> None:
    # upstream first: the integrator publishes what it still holds before anything downstream stops
    stop([procs[k] for k in ("acquisition", "integrator", "identifier") if k in procs], timeout_s=15.0, in_order=True)
    ctx.try_shutdown()
    th.join(2)


def _loss(n: int, got: dict) -> dict:
    """Samples sent vs. aligned rows collected: lossless means every row, in one segment (no gap)."""
    lost = n - got["rows"]
    return {"samples": n, "received": got["rows"], "lost": lost, "segments": len(got["segments"]),
            "ok": lost == 0 and len(got["segments"]) == 1}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rates", type=float, nargs="+", default=[1000.0, 2000.0, 3000.0, 4000.0, 6000.0])
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--reliable-seconds", type=float, default=20.0)
    p.add_argument("--conditions", nargs="+", choices=["quiet", "busy"], default=["quiet", "busy"])
    a = p.parse_args(argv)
    summary = []
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start", flush=True)
    with tempfile.TemporaryDirectory() as d:
        for cond in a.conditions:
            best = 0.0
            with busy_core(cond == "busy"):
                print(f"--- {cond}{' (one core kept busy by another process)' if cond == 'busy' else ''}", flush=True)
                for fs in a.rates:
                    r = run_rate(fs, a.seconds, Path(d))
                    print(f"vehicle path {fs:7.0f} Hz x 2: {r['received']}/{r['samples']} samples, {r['segments']} "
                          f"segment(s) -> {'OK' if r['ok'] else 'LOST'}; CPU acquisition "
                          f"{r['cpu_pct']['acquisition']:.0f} %, integrator {r['cpu_pct']['integrator']:.0f} %, "
                          f"identifier {r['cpu_pct']['identifier']:.0f} % of a core", flush=True)
                    if not r["ok"]:
                        break
                    best = fs
                rr_ = run_reliable(4000.0, a.reliable_seconds, Path(d))
                print(f"lossless replay path: {rr_['received']}/{rr_['samples']} samples per channel, "
                      f"{rr_['segments']} segment(s) -> {'OK' if rr_['ok'] else 'LOST'}; {rr_['wall_s']:.1f} s: "
                      f"{rr_['rate_hz']:.0f} Hz x 2 channels = {rr_['msgs_per_s']:.0f} messages/s", flush=True)
            summary.append((cond, best, rr_))
    print("\nlossless rate limit of the graph (per channel x 2 channels; messages/s = 2 x rate):")
    for cond, best, rr_ in summary:
        print(f"  {cond:5s}: vehicle path (best effort, real time) {best:g} Hz x 2 = {2 * best:g} messages/s; "
              f"lossless replay (reliable) {rr_['rate_hz']:.0f} Hz x 2 = {rr_['msgs_per_s']:.0f} messages/s"
              f"{'' if rr_['ok'] else ' (LOST SAMPLES)'}")
    return 0

if __name__ == "__main__":
    raise SystemExit(main())
