"""Start nifo nodes as separate processes without ``ros2 launch`` (a machine with only pip rclpy).

The same nodes, namespace and YAML parameter files as ``ros2_ws/.../launch``:
each node is ``python -m nifo_nodes.<node> --ros-args -r __ns:=/nifo
--params-file FILE [-p name:=value ...]``. :func:`stop` ends them the way
``ros2 launch`` does: SIGINT, then SIGTERM, then SIGKILL after timeouts.
"""

from __future__ import annotations

import contextlib
import os
import signal
import tempfile
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["NodeSpec", "NODES", "command", "start", "stop", "CONFIG_DIR", "DDS_PROFILE", "dds_env", "claim_domain_id",
           "busy_core"]

#: node name -> module that runs it
NODES = {"acquisition": "nifo_nodes.acquisition", "integrator": "nifo_nodes.integrator",
         "identifier": "nifo_nodes.identifier", "rerun_viewer": "nifo_nodes.rerun_viewer",
         "recorder": "nifo_nodes.recorder"}

#: the YAML parameter files shipped with the ROS package (shared with ros2 launch)
CONFIG_DIR = Path(__file__).resolve().parents[1] / "ros2_ws" / "src" / "nifo_ros" / "config"


#: Fast DDS profile of the nodes (heartbeats every 100 ms: a node's last messages are acknowledged at once rather
#: than on Fast DDS's default 3 s heartbeat; the file says what was measured)
DDS_PROFILE = CONFIG_DIR / "fastdds_profile.xml"
#: the environment variables Fast DDS reads a default profile file from (2.x, as in Jazzy; 3.x)
_PROFILE_ENV = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def dds_env(env: dict) -> dict:
    """``env`` with :data:`DDS_PROFILE` as Fast DDS's default profile, unless a profile file is given already."""
    if any(env.get(k) for k in _PROFILE_ENV) or not DDS_PROFILE.is_file():
        return env
    return {**env, _PROFILE_ENV[0]: str(DDS_PROFILE)}


@dataclass(frozen=True)
class NodeSpec:
    node: str
    namespace: str = "/nifo"
    params_files: tuple[str, ...] = ()
    params: dict = field(default_factory=dict)
    remaps: dict = field(default_factory=dict)
    #: arguments after the ROS arguments (``-- ...``), e.g. Rerun's ``--save live.rrd`` for the viewer
    args: tuple[str, ...] = ()


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(_value(x) for x in v) + "]"
    if isinstance(v, str):
        return repr(v) if v == "" or v.lower() in ("true", "false") or v.replace(".", "", 1).isdigit() else v
    return repr(v)


def command(spec: NodeSpec) -> list[str]:
    """The command line that runs ``spec``."""
    if spec.node not in NODES:
        raise ValueError(f"unknown node {spec.node!r}; one of {sorted(NODES)}")
    cmd = [sys.executable, "-m", NODES[spec.node], "--ros-args", "-r", f"__ns:={spec.namespace}"]
    for f in spec.params_files:
        cmd += ["--params-file", str(f)]
    for k, v in spec.params.items():
        cmd += ["-p", f"{k}:={_value(v)}"]
    for a, b in spec.remaps.items():
        cmd += ["-r", f"{a}:={b}"]
    if spec.args:
        cmd += ["--", *spec.args]
    return cmd


def start(spec: NodeSpec, *, env: dict | None = None, log_dir: str | Path | None = None) -> subprocess.Popen:
    """Start one node process (its own process group); stdout/stderr to ``log_dir/<node>.log`` if given."""
    out = subprocess.DEVNULL
    if log_dir is not None:
        Path(log_dir).mkdir(parents=True, exist_ok=True)
        out = open(Path(log_dir) / f"{spec.node}.log", "ab")  # noqa: SIM115 - owned by the process
    e = dds_env(dict(os.environ if env is None else env))
    e.setdefault("PYTHONUNBUFFERED", "1")
    e.setdefault("RCUTILS_LOGGING_BUFFERED_STREAM", "0")
    return subprocess.Popen(command(spec), env=e, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)


def stop(procs, *, timeout_s: float = 5.0, in_order: bool = False) -> list[int | None]:
    """Stop processes like ``ros2 launch`` does; returns their exit codes.

    ``in_order``: one after the other, each given ``timeout_s`` after SIGINT to finish — upstream nodes
    first, so each hands everything it still holds to the next before that one is stopped (the
    integrator's last blocks reach the identifier, whose last estimate reaches the recorder).
    """
    if in_order:
        return [stop([p], timeout_s=timeout_s)[0] if p is not None else None for p in procs]
    procs = [p for p in procs if p is not None]
    for sig, wait in ((signal.SIGINT, timeout_s), (signal.SIGTERM, timeout_s), (signal.SIGKILL, 5.0)):
        live = [p for p in procs if p.poll() is None]
        if not live:
            break
        for p in live:
            try:
                os.killpg(p.pid, sig)
            except ProcessLookupError:
                pass
        end = time.monotonic() + wait
        while time.monotonic() < end and any(p.poll() is None for p in live):
            time.sleep(0.05)
    return [p.poll() for p in procs]


@contextlib.contextmanager
def claim_domain_id(*, lo: int = 1, hi: int = 99):
    """A ``ROS_DOMAIN_ID`` in ``lo..hi`` that no other cooperating process holds, while in the block.

    Each id is claimed with an exclusive ``flock`` on ``$TMPDIR/nifo_ros_domains/<id>.lock``
    (released by the kernel even if the process dies), starting from an id
    derived from the pid, so concurrent test runs and benchmarks on one machine
    never share a domain. 1..99 stays inside the range ROS 2 documents as safe
    on Linux and away from 0 (the default domain).
    """
    import fcntl

    d = Path(tempfile.gettempdir()) / "nifo_ros_domains"
    d.mkdir(exist_ok=True)
    n = hi - lo + 1
    for i in range(n):
        dom = lo + (os.getpid() + i) % n
        f = open(d / f"{dom}.lock", "w")  # noqa: SIM115 - held for the block
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            continue
        try:
            yield dom
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)
            f.close()
        return
    raise RuntimeError(f"every ROS_DOMAIN_ID in {lo}..{hi} is claimed (lock files in {d})")


@contextlib.contextmanager
def busy_core(on: bool = True):
    """One process spinning a core (another job on the vehicle PC) while in the block; yields it (or None)."""
    if not on:
        yield None
        return
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)
    try:
        yield hog
    finally:
        os.killpg(hog.pid, signal.SIGKILL)
        hog.wait(5)
