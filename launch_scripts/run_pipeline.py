#!/usr/bin/env python3
"""Run the nifo pipeline as separate processes on a machine with only the pip rclpy (no ros2 launch).

Starts the same nodes, namespace and YAML parameter files as ``ros2 launch nifo_ros
pipeline.launch.py`` / ``analysis.launch.py``:

    # a recorded bag through integrator -> identifier (nifo replay plays it)
    python launch_scripts/run_pipeline.py --bag run1.mcap --model model.yaml --rate 2
    # ... lossless (reliable, keep-all end to end; a slow node slows the replay): the live estimate
    # then equals `nifo identify` on the same bag
    python launch_scripts/run_pipeline.py --bag run1.mcap --model model.yaml --reliable --rate 0 --linger 3
    # the virtual test vehicle (acquisition node with the simulator) in real time
    python launch_scripts/run_pipeline.py --source simulator --model model.yaml
    # a CSV/MAT/bag file through the acquisition node
    python launch_scripts/run_pipeline.py --source file --path run1.csv --model model.yaml
    # ... watched live in Rerun: spawn a viewer, connect to a running one, or save a recording
    python launch_scripts/run_pipeline.py --bag run1.mcap --rerun spawn
    python launch_scripts/run_pipeline.py --bag run1.mcap --rerun save=live.rrd --linger 5
    # ... and the results (typed nifo_msgs + /diagnostics) recorded into a bag Foxglove opens
    python launch_scripts/run_pipeline.py --bag run1.mcap --reliable --rate 0 --linger 3 --record results.mcap

Ctrl-C (or SIGTERM) stops every process cleanly (SIGINT, then SIGTERM, then SIGKILL after
timeouts); the identifier writes its checkpoint on the way out. With ``--bag`` and
``--linger S`` the pipeline stops by itself S seconds after the replay ended.
Node logs go to ``--log-dir`` (default: the terminal).

At the end it says what was identified and where the result is, in one short block on stdout: the
identifier's estimate (averages, samples used and lost, each term's c/M2, the nominal T21's median
coherence), its result file (``--result-file``; default beside the checkpoint, else
``$ROS_HOME/nifo/identifier_result.json``), the recording (``--record``) and the Rerun file (``--rerun
save=PATH``). ``--json``: the same as one JSON document on stdout (the nodes' and this script's lines on stderr).

Exit code: 0 when every node ended cleanly; otherwise the first failure's code
(a node that died — e.g. killed, -9 → 1 — or exited non-zero, or a failed
replay), each named on stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from nifo_nodes.launcher import CONFIG_DIR, NodeSpec, dds_env, start, stop  # noqa: E402
from nifo_nodes.identifier import default_result_file  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group()
    src.add_argument("--bag", help="replay this rosbag2 bag (directory or .mcap) into the pipeline")
    src.add_argument("--source", choices=["simulator", "file"], help="run the acquisition node with this source")
    p.add_argument("--path", default="", help="file for --source file")
    p.add_argument("--model", default=str(CONFIG_DIR / "model.yaml"), help="model file for the identifier")
    p.add_argument("--rate", type=float, default=1.0,
                   help="replay/acquisition speed (x real time; with --bag --reliable, 0 = as fast as the graph goes)")
    p.add_argument("--reliable", action="store_true",
                   help="with --bag: lossless replay (reliable, keep-all publishers and integrator input); "
                        "a slow node slows the replay instead of losing samples")
    p.add_argument("--checkpoint", default="", help="identifier checkpoint file (.npz)")
    p.add_argument("--config-dir", default=str(CONFIG_DIR), help="directory of the YAML parameter files")
    p.add_argument("--namespace", default="/nifo")
    p.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID for every process (default: inherited)")
    p.add_argument("--log-dir", help="write each node's output to DIR/<node>.log")
    p.add_argument("--linger", type=float, default=None, metavar="S",
                   help="with --bag: stop S seconds after the replay ended (default: run until Ctrl-C)")
    p.add_argument("--record", default=None, metavar="OUT.mcap",
                   help="record the identifier's results and /diagnostics into this bag (written on shutdown; "
                        "Foxglove opens it)")
    p.add_argument("--result-file", default=None, metavar="PATH",
                   help="the identifier's full result document (JSON; default: beside the checkpoint, else "
                        "$ROS_HOME/nifo/identifier_result.json)")
    p.add_argument("--json", action="store_true",
                   help="end with what was identified and where as one JSON document on stdout")
    p.add_argument("--rerun", default=None, metavar="spawn|connect[=URL]|save=PATH",
                   help="also run the Rerun viewer node: spawn a viewer, connect to one (optionally at URL), "
                        "or save a .rrd recording")
    return p.parse_args(argv)


def rerun_args(mode: str) -> tuple[str, ...]:
    """Rerun's own script options (rr.script_add_args) for a ``--rerun`` value."""
    kind, _, value = mode.partition("=")
    if kind == "spawn" and not value:
        return ()
    if kind == "connect":
        return ("--connect",) + (("--url", value) if value else ())
    if kind == "save" and value:
        return ("--save", value)
    raise SystemExit(f"run_pipeline: --rerun {mode!r}: use spawn, connect, connect=URL or save=PATH")


def wait_for_graph(namespace: str, env: dict, *, block_readers: int = 1, timeout_s: float,
                   should_stop=lambda: False) -> bool:
    """Until the integrator subscribes to both Imu topics and ``block_readers`` nodes (identifier, viewer)
    to ``accel/block``."""
    import rclpy

    ctx = rclpy.Context()
    dom = env.get("ROS_DOMAIN_ID")
    rclpy.init(context=ctx, domain_id=int(dom) if dom else None)
    try:
        node = rclpy.create_node("run_pipeline_wait", context=ctx)
        need = {f"{namespace}/spindle/imu": 1, f"{namespace}/body/imu": 1, f"{namespace}/accel/block": block_readers}
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and not should_stop():
            if all(node.count_subscribers(t) >= k for t, k in need.items()):
                time.sleep(0.5)  # the publishers see the subscription a little after the graph does
                return True
            time.sleep(0.05)
        return False
    finally:
        ctx.try_shutdown()


def main(argv=None) -> int:
    a = parse_args(argv)
    env = dds_env(dict(os.environ))     # the nodes' and the replay's Fast DDS profile (nifo_nodes.launcher)
    if a.domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(a.domain_id)
    repo = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = repo + os.pathsep + env.get("PYTHONPATH", "")
    cfg = Path(a.config_dir)

    def spec(name, **params):
        return NodeSpec(name, namespace=a.namespace, params_files=(str(cfg / f"{name}.yaml"),), params=params)

    if a.reliable and a.bag is None:
        raise SystemExit("run_pipeline: --reliable needs --bag (a live sensor stream stays best effort)")
    integ = {"input_reliability": "reliable"} if a.reliable else {}
    result_file = Path(a.result_file or default_result_file(a.checkpoint)).resolve()
    specs = [spec("integrator", **integ), spec("identifier", model_file=a.model, checkpoint_file=a.checkpoint,
                                               result_file=str(result_file))]
    if a.rerun is not None:
        specs.append(NodeSpec("rerun_viewer", namespace=a.namespace, args=rerun_args(a.rerun)))
    if a.record is not None:  # first to stop (stop() signals in order): it still sees the last results
        specs.append(NodeSpec("recorder", namespace=a.namespace, args=("--out", str(Path(a.record).resolve()))))
    if a.bag is None:
        specs.insert(0, spec("acquisition", source=a.source or "simulator", path=a.path, speed=a.rate))
    procs: list[subprocess.Popen] = []
    stopping = False

    def on_signal(signum, frame):
        nonlocal stopping
        stopping = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    failures: list[tuple[str, int]] = []
    names: dict[int, str] = {}
    codes: list = []
    try:
        for s in specs:
            procs.append(start(s, env=env, log_dir=a.log_dir))
            names[procs[-1].pid] = s.node
            print(f"run_pipeline: started {s.node} (pid {procs[-1].pid})", file=sys.stderr)
        replay = None
        if a.bag is not None:
            # the integrator AND the identifier must listen before the first sample goes out: a block
            # published before the identifier subscribed is gone (volatile) - measured: 65 samples at the
            # start of the bundled bag when the identifier was slow to start on a loaded machine
            if not wait_for_graph(a.namespace, env, block_readers=1 + (a.rerun is not None), timeout_s=60.0,
                                  should_stop=lambda: stopping):
                print("run_pipeline: the nodes did not come up within 60 s (see their logs); replaying anyway",
                      file=sys.stderr)
            imu = [f"{a.namespace}/spindle/imu", f"{a.namespace}/body/imu"]
            # the start waits for the topics the integrator takes: nothing here listens to a bag's others (the
            # tire patch of a simulated run), and waiting for them too held every replay the whole 15 s
            cmd = [sys.executable, "-m", "nifo", "replay", a.bag, "--rate", str(a.rate), "--wait", "15",
                   "--wait-for", *imu]
            if a.reliable:  # only the sensor topics the integrator takes: nobody acknowledges the others
                cmd += ["--reliable", "--topics", *imu]
            replay = subprocess.Popen(cmd, env=env, start_new_session=True)
            procs.append(replay)
            print(f"run_pipeline: replaying {a.bag} (pid {replay.pid})", file=sys.stderr)
            names[replay.pid] = "replay"
        ended_at = None
        while not stopping:
            time.sleep(0.2)
            dead = [p for p in procs if p is not replay and p.poll() is not None]
            if dead:
                for p in dead:
                    failures.append((names[p.pid], p.returncode))
                    print(f"run_pipeline: node {names[p.pid]} (pid {p.pid}) died: {_how(p.returncode)}; "
                          "stopping the others", file=sys.stderr)
                break
            if replay is not None and replay.poll() is not None and ended_at is None:
                ended_at = time.monotonic()
                print(f"run_pipeline: replay finished (exit {replay.returncode})", file=sys.stderr)
                if replay.returncode != 0:
                    failures.append(("replay", replay.returncode))
            if ended_at is not None and a.linger is not None and time.monotonic() - ended_at >= a.linger:
                break
    finally:
        # upstream first (replay/acquisition, integrator, identifier, then viewer and recorder): each
        # hands on what it still holds before the next one stops
        order = ["replay", "acquisition", "integrator", "identifier", "rerun_viewer", "recorder"]
        ranked = sorted(procs, key=lambda p: order.index(names.get(p.pid, "recorder")))
        codes_by_pid = {p.pid: c for p, c in zip(ranked, stop(ranked, timeout_s=30.0, in_order=True))}
        codes = [codes_by_pid[p.pid] for p in procs]
        print(f"run_pipeline: stopped (exit codes {codes})", file=sys.stderr)
    seen = {n for n, _ in failures}
    for p, code in zip(procs, codes):  # a node that failed on the way out (not our own SIGINT ending it)
        if names.get(p.pid) not in seen | {"replay"} and code not in (0, None):
            failures.append((names.get(p.pid, str(p.pid)), code))
            print(f"run_pipeline: node {names.get(p.pid)} ended badly: {_how(code)}", file=sys.stderr)
    found = summary(result_file, record=a.record, rerun=a.rerun, failures=failures)
    if a.json:
        print(json.dumps(found))
    else:
        print("\n".join(found["lines"]))
    if failures:
        name, code = failures[0]
        print(f"run_pipeline: FAILED: {', '.join(f'{n} ({_how(c)})' for n, c in failures)}", file=sys.stderr)
        return code if code and code > 0 else 1
    return 0


def summary(result_file: Path, *, record: str | None, rerun: str | None, failures) -> dict:
    """What was identified and where it is: the identifier's last estimate read from its result file, the result
    file, the recording; ``lines``: the same in words (a few lines)."""
    out = {"ok": not failures, "result_file": str(result_file), "identified": None,
           "recording": str(Path(record).resolve()) if record else None,
           "rerun_file": str(Path(rerun.partition("=")[2]).resolve()) if rerun and rerun.startswith("save=") else None,
           "failed": [{"node": n, "how": _how(c)} for n, c in failures]}
    lines = ["nifo pipeline:"]
    try:
        doc = json.loads(result_file.read_text())
    except (OSError, ValueError) as err:
        why = "not written: the identifier made no estimate (too little data?)" if isinstance(err, OSError) else \
            f"unreadable ({err})"
        lines.append(f"  identified  nothing: the result file {result_file} is {why}")
    else:
        stream = doc.get("stream") or {}
        terms = [(t.get("kind"), t.get("params") or {}) for t in doc.get("terms") or []]
        coefs = (doc.get("static") or {}).get("c_over_m2") or []
        coh = [c for c in doc.get("coherence_h1") or [] if c is not None]
        found = {"n_avg": doc.get("n_avg"), "samples_used": stream.get("samples_used", doc.get("n_samples")),
                 "samples_lost": stream.get("samples_lost"), "gaps": stream.get("gaps"),
                 "terms": [{"kind": k, "params": p, "c_over_m2": c} for (k, p), c in zip(terms, coefs)],
                 "stamp_ns": doc.get("stamp_ns")}
        out["identified"] = found
        what = "; ".join(f"{k}({', '.join(f'{n}={v:.4g}' for n, v in p.items() if isinstance(v, float))}): "
                         f"c/M2 {c:.4g}" for (k, p), c in zip(terms, coefs)) or "the linear model (no terms declared)"
        lines.append(f"  identified  {what}")
        lines.append(f"              from {found['n_avg']} spectral averages over {found['samples_used']} samples "
                     f"({found['samples_lost'] or 0} lost, {found['gaps'] or 0} gaps)"
                     + (f"; median coherence {sorted(coh)[len(coh) // 2]:.3f}" if coh else ""))
        lines.append(f"  result      {result_file}")
    if out["recording"]:
        lines.append(f"  recording   {out['recording']}   <- Foxglove, ros2 bag")
    if out["rerun_file"]:
        lines.append(f"  rerun       {out['rerun_file']}   <- rerun {out['rerun_file']}")
    out["lines"] = lines
    return out


def _how(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name} ({code})"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"

if __name__ == "__main__":
    raise SystemExit(main())
