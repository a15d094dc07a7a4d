"""``nifo fleet`` on a simulated fleet: speed-up, overhead, scheduler memory, flags, equality, start-up, scaling.

Everything is measured in this run, on this machine, against a baseline measured in the same run:

1. serial baseline: ``nifo identify``'s own work on every vehicle's bags (its
   ``accumulate``, ``result``, ``NifoResult.check_usable``, ``nifo_core.nifo.summary.summarize`` and body model, the
   library calls ``nifo identify`` makes), in this process, no Dask;
2. ``run_fleet`` (what ``nifo fleet`` runs) on an embedded LocalCluster of 1 and on
   one of 2 single-threaded worker processes (``nifo.fleet.cluster.fleet_client``),
   each run with a fresh partial cache (as a user's first run). Cluster start-up
   and first calls (imports, numba) are NOT timed: both clusters are started and
   every worker warmed up first; every bag is read once before anything is timed
   (page cache), so no run pays the disk. (1) and (2) are interleaved for
   ``--rounds`` rounds (default 2) and the best time of each counts (other jobs
   on the machine only ever slow a run down);
3. scheduler memory: a Dask scheduler in its own process (``SubprocessCluster``,
   2 workers; the fleet connects to it as to ``--scheduler``), fresh for each size,
   runs N and 10·N tiny bags (20-s bags hard-linked many times, 20 vehicles;
   the links share the cache entries of their 40 distinct bags, so most are cache hits);
   the scheduler process's RSS (psutil, via ``run_on_scheduler``) after warm-up
   and after the run, and its peak RSS during the run (VmHWM, reset after warm-up), are printed.

4. start-up and scaling (``--scaling-only``: this part alone): in fresh processes, as ``nifo fleet``
   runs, an embedded cluster of 1 and of 2 workers from its start until every worker is warm:
   before (workers spawned, each importing the task path), forked from the fork server
   (:func:`nifo.fleet.cluster.start_worker_server`) started by the command's run(), and now (the
   fork server started at the ``nifo`` CLI's start, before its own imports), least of ``--rounds`` each, after one run with an
   empty numba cache (the first run on a machine); then the fleet on warm workers (1 and 2
   processes, 1 process of 2 threads: processes vs threads). The model, Amdahl's with a start-up
   that grows with the workers::

       T(n) = a + b·n + W/n + S,     efficiency E(n) = T(1) / (n·T(n))

   a, once per run: the longer of the client's cluster start and what the fork server still
   has to import when the cluster starts (its CPU minus the client's between the two: they
   run concurrently), plus one worker's own start-up (workers start in parallel); b, per worker: the client's CPU (nannies, scheduler:
   one event loop) for 2 workers minus for 1; W: the workers' CPU for the whole fleet (the
   larger of 1 and 2 workers); S: the wall time of the 1-worker run with no task running
   (before the first, after the last). CPU seconds, not wall, wherever possible: on a shared
   2-core machine only they compare between runs; the model is that of an idle machine with
   a core per worker. For the 480-bag fleet (2.3 GB, 48 groups: :data:`FULL`) W's bag part
   (the bags' share of the tasks' time) scales with the bytes, its group part and S with the
   groups. Not in the model: the last task's tail (granularity) and the file system.

Prints speed-up 1 → 2 workers (target ≥ 1.8×), the per-bag overhead of the
1-worker fleet against the serial baseline (target ≤ 5 %) with where it goes,
scheduler memory growth from N to 10·N bags (target: flat, ≤ 5 MB), the
flagged vehicles (target: exactly the planted ones), the largest relative
difference of a coefficient from the baseline (target ≤ 1e-9), the start-up per
worker after the first run (b + a worker's own CPU to be warm, target ≤ 1 s) and
the projected efficiency at 16 workers on the 480-bag fleet (target ≥ 75 %), each with the
load average (the speed-up needs two idle cores). BLAS/OpenMP run one thread
per process here as in Dask's workers (set below), so the baseline uses one
core like one worker.

The fleet (20 vehicles × 10 bags of 60-120 s, v03 and v11 with a worn damper,
v07 with the knee moved; made once with :func:`nifo.fleet.simulated.write_simulated_fleet`
under ``--cache``, ~1.3 GB, which takes a few minutes the first time) is reused.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_fleet.py   # ~2.5 min idle, 2 cores, once the fleet exists

    PYTHONPATH=. .venv/bin/python benchmarks/bench_fleet.py --quick --scaling-only   # part 4, ~6 min

Options: ``--quick`` (10 × 3 bags of 60 s: a smoke run, no verdict on flags), ``--full`` (48 × 10
bags of 60-120 s, the 480-bag fleet itself, made once), ``--scaling-only``, ``--no-scaling``,
``--vehicles N`` (first N vehicles only), ``--memory-bags N`` (default 200: N and
10·N), ``--no-memory``. Exits 1 when a target is missed.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):   # before numpy: one thread, as Dask's
    os.environ[_v] = "1"                                                      # nanny sets for its workers

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])  # workers

OPTS = {"topics": None, "columns": None, "fs_hz": None, "axis": "z"}


def load() -> str:
    a, b, c = os.getloadavg()
    return f"load {a:.2f} {b:.2f} {c:.2f} on {os.cpu_count()} cores"


def make_fleet(root: Path, quick: bool, full: bool = False) -> Path:
    from nifo.fleet.cluster import fleet_client
    from nifo.fleet.simulated import write_simulated_fleet

    manifest = root / "manifest.csv"
    if manifest.is_file():
        return manifest
    shape = dict(n_vehicles=10, bags_per_vehicle=3, duration_s=60.0, worn=(3,), knee_moved=(7,)) if quick else \
        dict(n_vehicles=48 if full else 20, bags_per_vehicle=10, duration_s=(60.0, 120.0), worn=(3, 11),
             knee_moved=(7,))
    t0 = time.perf_counter()
    print(f"simulating the fleet once into {root} ...", flush=True)
    with fleet_client(dashboard_address=None) as client:
        write_simulated_fleet(root, seed=0, mapper=lambda f, xs: client.gather(client.map(f, xs)), **shape)
    print(f"simulated the fleet in {time.perf_counter() - t0:.0f} s")
    return manifest


def identify_alone(entries) -> dict:
    """``nifo identify``'s work per vehicle (accumulate; solve, summarize, body model), in this process."""
    import warnings

    from nifo.pipeline.identify import accumulate
    from nifo_core.nifo.summary import summarize
    from nifo.settings import resolve
    from nifo.io.modelfile import load_model_spec
    from nifo_core.predict.model import IdentifiedModel

    groups: dict = {}
    for e in entries:
        groups.setdefault(e.group, []).append(e)
    spec = load_model_spec(entries[0].model)
    cfg = resolve([], file_settings=spec.settings, from_data=False)
    out, t_acc, t_solve = {}, 0.0, 0.0
    for g, es in groups.items():
        t0 = time.perf_counter()
        acc, _, _, _ = accumulate([e.path for e in es], spec.terms, cfg, opts=OPTS, quiet=True)
        t1 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = acc.result()
        res.check_usable(cfg.cond_limit)
        summarize(res, cfg.cond_limit)
        body = IdentifiedModel.from_nifo(res, source="static").body
        t_acc += t1 - t0
        t_solve += time.perf_counter() - t1
        out[g] = {"k2_over_m2": body.k, "c2_over_m2": body.c,
                  "c_over_m2_velocity_deadzone": float(res.static.c_over_m2[0])}
    return {"values": out, "seconds": t_acc + t_solve, "accumulate_s": t_acc, "solve_s": t_solve}


def _warm(path: str, group: tuple, setup) -> bool:
    """On a worker: every import and numba function of a bag's accumulation and a group's solve, once."""
    from nifo.fleet.tasks import compute_batch, solve_group

    b = compute_batch([(group, setup, [(0, path)], True)], None)
    part = next(iter(b.parts))
    solve_group(b, freqs_hz=(2.0,), plot_max_hz=50.0, part=part)
    return True


def warm_up(client, entries) -> None:
    """Run one bag and one group's solve in every worker process, then a small fleet (not timed)."""
    from nifo.fleet.runner import base_setups, fleet_settings

    e = entries[0]
    setup = base_setups([e], fleet_settings([e]), opts=OPTS, chunk_samples=2 ** 18)[e.group]
    client.run(_warm, str(e.path), e.group, setup)
    first = [x for x in entries if x.group == e.group]
    run(client, first)


def run(client, entries, cache_dir=None):
    from nifo.fleet.runner import FleetSettings, fleet_settings, run_fleet

    t0 = time.perf_counter()
    res = run_fleet(client, entries, analysis=fleet_settings(entries), opts=OPTS,
                    settings=FleetSettings(cache_dir=cache_dir), quiet=True)
    return res, time.perf_counter() - t0


def cpu_seconds(client) -> tuple[float, float]:
    """CPU time [s] of (this process: client, scheduler and nannies of an embedded cluster; ``client``'s workers)."""
    import psutil

    workers = 0.0
    for pid in client.run(os.getpid).values():
        workers += sum(psutil.Process(pid).cpu_times()[:2])
    return sum(psutil.Process().cpu_times()[:2]), workers


def timed_fleet(client, entries, cache: Path):
    """(result, wall time [s], CPU time [s] of (client and scheduler, workers)) of one fleet run, fresh cache."""
    shutil.rmtree(cache, ignore_errors=True)
    c0 = cpu_seconds(client)
    res, t = run(client, entries, cache_dir=str(cache))
    c1 = cpu_seconds(client)
    shutil.rmtree(cache, ignore_errors=True)
    failed = [b for b in res.bags if b["status"] != "ok"]
    if failed:
        raise SystemExit(f"{len(failed)} bag(s) failed: {failed[0]['reason']}")
    return res, t, (c1[0] - c0[0], c1[1] - c0[1])


# --- scheduler memory ---------------------------------------------------------------------------
def _scheduler_memory(reset: bool = False) -> tuple[float, float]:
    """In the scheduler's process: (RSS now, peak RSS since the last reset) [MB]; ``reset`` starts a new peak.

    The peak is Linux's VmHWM, reset by writing 5 to /proc/self/clear_refs (else the
    process's lifetime peak, ``getrusage``).
    """
    import resource

    import psutil

    if reset:
        try:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")
        except OSError:
            pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 10
    try:
        with open("/proc/self/status") as f:
            peak = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 2 ** 10
    except (OSError, StopIteration):
        pass
    return psutil.Process().memory_info().rss / 2 ** 20, peak


def tiny_fleet(root: Path):
    """20 vehicles × 2 distinct 20-s bags (block 1024): cheap bags to run thousands of."""
    from nifo.fleet.manifest import load_fleet_input
    from nifo.fleet.simulated import write_simulated_fleet

    if not (root / "manifest.csv").is_file():
        write_simulated_fleet(root, n_vehicles=20, bags_per_vehicle=2, duration_s=20.0, block=1024, worn=(),
                              knee_moved=(), seed=5)
    return load_fleet_input(root / "manifest.csv", default_model=root / "model.yaml")


def linked(root: Path, base, n: int):
    """``n`` bags: the tiny fleet's bags hard-linked under new names, same 20 vehicles (groups)."""
    from nifo.fleet.manifest import BagEntry

    out = []
    for k in range(n):
        e = base[k % len(base)]
        p = root / "links" / f"{k:05d}.mcap"
        if not p.exists():
            p.parent.mkdir(parents=True, exist_ok=True)
            os.link(e.path, p)
        out.append(BagEntry(vehicle=e.vehicle, corner=e.corner, path=p, model=e.model, m2_kg=e.m2_kg))
    return out


def memory_run(base, entries, cache: Path) -> dict:
    import logging

    from distributed.deploy.subprocess import SubprocessCluster

    from nifo.fleet.cluster import fleet_client

    cluster = SubprocessCluster(n_workers=2, threads_per_worker=1, dashboard_address=None,
                                silence_logs=logging.ERROR)
    try:
        with fleet_client(cluster.scheduler_address) as client:     # as nifo fleet --scheduler ADDRESS
            warm_up(client, base)
            rss0, _ = client.run_on_scheduler(_scheduler_memory, reset=True)
            res, t = run(client, entries, cache_dir=str(cache))
            rss1, peak = client.run_on_scheduler(_scheduler_memory)
    finally:
        cluster.close()
    assert all(b["status"] == "ok" for b in res.bags), [b["reason"] for b in res.bags if b["reason"]][:3]
    return {"before": rss0, "after": rss1, "peak": peak, "seconds": t, "n": len(entries)}


# --- 4. start-up per worker, per-bag work, projected efficiency --------------------------------
#: the fleet the projection is for: 480 bags of 48 vehicles, ~12 h of data, 2.3 GB (measured on a 16-core machine)
FULL = {"bags": 480, "groups": 48, "bytes": 2.3e9}
ARGS = None
#: start-up variants: before (spawned workers), the fork server started by the command's run() (first version), and
#: now: the nifo CLI starts the fork server before its own imports (nifo/cli.py)
MODES = ("spawn", "forkserver", "forkserver-at-start")


def _ready() -> dict:
    """On a worker: be warm (import :mod:`nifo.fleet.preload`, a no-op where it is in already); its CPU time so far."""
    import importlib
    import resource

    importlib.import_module("nifo.fleet.preload")
    from nifo.fleet.preload import WARM, kernel_stats

    r = resource.getrusage(resource.RUSAGE_SELF)     # a forked worker's count starts at its fork
    return {"cpu_s": r.ru_utime + r.ru_stime, "server_cpu_s": WARM["process_cpu_s"], "kernels": kernel_stats(),
            "omp": os.environ.get("OMP_NUM_THREADS")}


def _spawn_client(n: int):
    """Before: the embedded cluster as it was, workers spawned as fresh interpreters (Dask's default)."""
    import contextlib
    import logging

    import dask
    from distributed import Client, LocalCluster

    from nifo.fleet.cluster import CLUSTER_CONFIG

    @contextlib.contextmanager
    def cm():
        with dask.config.set({**CLUSTER_CONFIG, "distributed.worker.multiprocessing-method": "spawn"}), \
                LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                             silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
            yield client
    return cm()


def startup_child(mode: str, n: int, root: str) -> dict:
    """In a fresh process, as ``nifo fleet`` runs: its imports, (fork server), manifest, then the cluster until warm.

    ``mode`` "forkserver-at-start": what ``nifo fleet`` does now (:func:`nifo.fleet.cluster.start_worker_server`
    before the CLI imports the command, then the manifest, then :func:`~nifo.fleet.cluster.fleet_client`);
    "forkserver": the server started after the command's import; "spawn": before (workers are fresh
    interpreters that import the task path themselves). Wall and CPU seconds of each step.
    """
    from nifo.fleet.cluster import fleet_client, start_worker_server

    c_fs = time.process_time()
    if mode == "forkserver-at-start":      # now: the nifo CLI starts the fork server before any import
        start_worker_server()
    import nifo.commands.fleet  # noqa: F401 - what the nifo CLI has imported when the command runs

    if mode == "forkserver":
        c_fs = time.process_time()
        start_worker_server()
    from nifo.fleet.manifest import load_fleet_input
    from nifo.fleet.runner import base_setups, fleet_settings

    entries = load_fleet_input(Path(root) / "manifest.csv", default_model=Path(root) / "model.yaml")
    base_setups(entries, fleet_settings(entries), opts=OPTS, chunk_samples=2 ** 18)
    t0, c0 = time.perf_counter(), time.process_time()
    cm = _spawn_client(n) if mode == "spawn" else fleet_client(workers=n, dashboard_address=None)
    with cm as client:
        ready = list(client.run(_ready).values())
        t1, c1 = time.perf_counter(), time.process_time()
    return {"mode": mode, "n": n, "wall_s": t1 - t0, "client_cpu_s": c1 - c0, "between_cpu_s": c0 - c_fs,
            "worker_cpu_s": max(r["cpu_s"] for r in ready), "server_cpu_s": ready[0]["server_cpu_s"],
            "omp": ready[0]["omp"], "kernels": ready[0]["kernels"]}


def run_child(mode: str, n: int, root: Path, numba_dir: Path) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(numba_dir)}    # this benchmark's own numba cache: first run = empty
    out = subprocess.run([sys.executable, __file__, "--startup-child", mode, str(n), str(root)], env=env,
                         capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"start-up child ({mode}, {n}) failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def fixed_part(one: dict, two: dict) -> tuple[float, float]:
    """(a, b) of fixed(n) = a + b·n [s of CPU] from the start-up of 1 and of 2 workers (section 4 of the docstring)."""
    b = max(two["client_cpu_s"] - one["client_cpu_s"], 0.0)       # the client's (nannies', scheduler's) per worker
    late = max(one["server_cpu_s"] - one["between_cpu_s"], 0.0) if one["mode"] != "spawn" else 0.0
    return max(one["client_cpu_s"] - b, late) + one["worker_cpu_s"], b     # the client and the server concurrently


def project(a: float, b: float, work_s: float, serial_s: float, n: int) -> tuple[float, float]:
    """(T(n) [s], efficiency T(1)/(n·T(n))) of the model T(n) = a + b·n + W/n + S."""
    def t(k):
        return a + b * k + work_s / k + serial_s
    return t(n), t(1) / (n * t(n))


def _startup(args, root: Path) -> dict:
    """Start-up of 1 and 2 workers, before (spawn) and now (fork server), fresh processes, least CPU of --rounds."""
    numba_dir = Path(tempfile.mkdtemp(prefix="nifo_bench_numba_"))
    try:
        first = run_child("forkserver", 2, root, numba_dir)     # the first run on a machine: empty numba cache
        kernels = ", ".join(f"{name}: {v['cache_misses']} compiled" for name, v in first["kernels"].items())
        print(f"first run on a machine (empty numba cache): fork server {first['server_cpu_s']:.2f} s CPU, kernels "
              f"{kernels}; 2 workers warm {first['wall_s']:.2f} s after the cluster's start", flush=True)
        st: dict = {}
        for r in range(args.rounds):
            for mode in MODES:
                for n in (1, 2):
                    c = run_child(mode, n, root, numba_dir)
                    cur = st.setdefault((mode, n), dict(c))
                    for k in ("wall_s", "client_cpu_s", "worker_cpu_s", "server_cpu_s"):
                        cur[k] = min(cur[k], c[k])
                    print(f"  round {r + 1}, {mode:19s} {n} worker(s): every worker warm {c['wall_s']:.2f} s after "
                          f"the cluster's start; CPU: client {c['client_cpu_s']:.2f} s, a worker "
                          f"{c['worker_cpu_s']:.2f} s ({load()})", flush=True)
    finally:
        shutil.rmtree(numba_dir, ignore_errors=True)
    later = ", ".join(f"{name}: {v['cache_hits']} loaded from the cache, {v['cache_misses']} compiled"
                      for name, v in st["forkserver", 2]["kernels"].items())
    print(f"later runs: kernels {later}; OMP_NUM_THREADS on a worker {st['forkserver', 2]['omp']}")
    return st


def _work(entries) -> dict:
    """Run time and CPU of the fleet on warm workers: 1 and 2 processes, 1 process of 2 threads; best of --rounds."""
    import contextlib
    import logging

    import psutil
    from distributed import Client, LocalCluster, get_task_stream

    from nifo.fleet.cluster import fleet_client

    tmp = Path(tempfile.mkdtemp(prefix="nifo_bench_fleet_"))
    best: dict = {}
    with contextlib.ExitStack() as stack:
        clients = {w: stack.enter_context(fleet_client(workers=w, dashboard_address=None)) for w in (1, 2)}
        th = stack.enter_context(LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                              dashboard_address=None, silence_logs=logging.ERROR))
        clients["threads"] = stack.enter_context(Client(th))
        for c in clients.values():
            warm_up(c, entries)
        try:
            for r in range(ARGS.rounds):
                for w, c in clients.items():
                    p0, t0 = sum(psutil.Process().cpu_times()[:2]), time.time()
                    with get_task_stream(c) as ts:
                        res, t, (client_cpu, worker_cpu) = timed_fleet(c, entries, tmp / f"w{w}")
                    t1 = time.time()
                    spans = [ss for task in ts.data for ss in task["startstops"] if ss["action"] == "compute"]
                    idle = (min(ss["start"] for ss in spans) - t0) + (t1 - max(ss["stop"] for ss in spans))
                    bags_share = sum(b["seconds"] for b in res.bags) / sum(ss["stop"] - ss["start"] for ss in spans)
                    if w == "threads":          # one process: client, scheduler and the threaded worker
                        client_cpu, worker_cpu = sum(psutil.Process().cpu_times()[:2]) - p0, 0.0
                    cur = best.setdefault(w, {"res": res, "wall": t, "client_cpu": client_cpu,
                                              "worker_cpu": worker_cpu, "idle": idle, "bags_share": bags_share})
                    for k, v in (("wall", t), ("client_cpu", client_cpu), ("worker_cpu", worker_cpu),
                                 ("idle", idle)):
                        cur[k] = min(cur[k], v)
                print(f"  round {r + 1}, fleet on warm workers (wall, best so far): 1 process {best[1]['wall']:.2f} s, "
                      f"2 processes {best[2]['wall']:.2f} s, 1 process of 2 threads {best['threads']['wall']:.2f} s "
                      f"({load()})", flush=True)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return best


def scaling(args, root: Path, entries, verdicts: list) -> None:
    """Part 4: start-up per worker (before/now), per-bag work on 1 and 2 workers, the projection to 16 and 100."""
    global ARGS
    ARGS = args
    st = _startup(args, root)
    best = _work(entries)
    n_bags, n_groups = len(entries), len({e.group for e in entries})
    size = sum(os.path.getsize(e.path) for e in entries)
    w1, w2 = best[1]["worker_cpu"], best[2]["worker_cpu"]
    work = max(w1, w2)                    # the workers' CPU for the whole fleet (the larger: 2 workers share caches)
    serial = best[1]["idle"]              # before the first task and after the last one: nothing runs on a worker
    in_bags = min(best[1]["bags_share"], 1.0) * work     # the bags' share of the tasks' time (the rest: groups)
    th = best["threads"]
    print(f"fleet {n_bags} bags, {n_groups} groups, {size / 1e9:.2f} GB. Wall (under this load): 1 worker "
          f"{best[1]['wall']:.2f} s, 2 workers {best[2]['wall']:.2f} s ({best[1]['wall'] / best[2]['wall']:.2f}x), "
          f"1 process of 2 threads {th['wall']:.2f} s ({best[1]['wall'] / th['wall']:.2f}x). CPU: workers "
          f"{w1:.2f} s on 1, {w2:.2f} s on 2 ({100 * (w2 / w1 - 1):+.1f} %); client and scheduler "
          f"{best[1]['client_cpu']:.2f} s (in parallel with the workers; its share per bag "
          f"{1e3 * best[1]['client_cpu'] / n_bags:.0f} ms: it would keep up with up to "
          f"{work / max(best[1]['client_cpu'], 1e-9):.0f} workers); "
          f"threads: the one process {th['client_cpu']:.2f} s, {th['client_cpu'] / th['wall']:.2f} cores busy of 2")
    # the 480-bag fleet: bag work scales with the bytes read, group work and the client's with the groups
    w480 = in_bags * FULL["bytes"] / size + (work - in_bags) * FULL["groups"] / n_groups
    s480 = serial * FULL["groups"] / n_groups
    print(f"model (CPU seconds): W = {work:.2f} s ({1e3 * in_bags / n_bags:.0f} ms per bag inside bag tasks, "
          f"{(work - in_bags) / n_groups:.2f} s per group), S = {serial:.2f} s (wall: no task running, 1 worker); "
          f"480-bag fleet: W = {w480:.1f} s, "
          f"S = {s480:.1f} s")
    ab = {}
    for mode in MODES:
        a, b = ab[mode] = fixed_part(st[mode, 1], st[mode, 2])
        name = {"spawn": "before (spawn)", "forkserver": "fork server from the command's run()",
                "forkserver-at-start": "now (fork server at the CLI's start)"}[mode]
        print(f"{name}: fixed(n) = a + b·n, a = {a:.2f} s once, b = {b:.2f} s per worker; a worker's own CPU to be "
              f"warm {st[mode, 1]['worker_cpu_s']:.2f} s (wall, this load: {st[mode, 1]['wall_s']:.2f} s for 1, "
              f"{st[mode, 2]['wall_s']:.2f} s for 2)")
        for label, w, s in ((f"this fleet ({n_bags} bags)", work, serial), ("480-bag fleet", w480, s480)):
            cells = "; ".join(f"{k} workers T {project(a, b, w, s, k)[0]:.1f} s, efficiency "
                              f"{100 * project(a, b, w, s, k)[1]:.0f} %" for k in (16, 100))
            print(f"    projected, {label}: T(1) {project(a, b, w, s, 1)[0]:.1f} s; {cells}")
    a, b = ab["forkserver-at-start"]
    per_worker = b + st["forkserver-at-start", 1]["worker_cpu_s"]
    verdicts.append(("start-up per worker after the first run (client's share b + the worker's own)",
                     f"{per_worker:.2f} s (before: {ab['spawn'][1] + st['spawn', 1]['worker_cpu_s']:.2f} s)",
                     "<= 1 s", per_worker <= 1.0, load()))
    e16 = project(a, b, w480, s480, 16)[1]
    verdicts.append(("projected efficiency at 16 workers, 480-bag fleet", f"{100 * e16:.0f} % (before: "
                     f"{100 * project(*ab['spawn'], w480, s480, 16)[1]:.0f} %)", ">= 75 %", e16 >= 0.75, ""))


# --- main ---------------------------------------------------------------------------------------
def main() -> int:
    """The benchmark as a script: make the fleet, run it, print and check every figure. Long because it is the
    measurement protocol, one stage after the other, that docs/fleet.md reports."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/nifo_bench/fleet_20x10"),
                    help="where the simulated fleet is kept (made once)")
    ap.add_argument("--quick", action="store_true", help="a 10 × 3 fleet of 60-s bags (smoke run)")
    ap.add_argument("--vehicles", type=int, metavar="N", help="only the first N vehicles (no flag verdict)")
    ap.add_argument("--memory-bags", type=int, default=200, metavar="N", help="scheduler memory at N and 10·N bags")
    ap.add_argument("--no-memory", action="store_true", help="skip the scheduler-memory part")
    ap.add_argument("--rounds", type=int, default=2, metavar="K",
                    help="rounds of (serial, 1 worker, 2 workers), interleaved; the best of each counts (default 2)")
    ap.add_argument("--full", action="store_true",
                    help="the full-size fleet: 48 vehicles x 10 bags of 60-120 s (~480 bags, made once, ~15 min)")
    ap.add_argument("--scaling-only", action="store_true", help="only part 4: start-up, per-bag work, projection")
    ap.add_argument("--no-scaling", action="store_true", help="skip part 4")
    if sys.argv[1:2] == ["--startup-child"]:          # part 4's fresh process (run_child)
        print(json.dumps(startup_child(sys.argv[2], int(sys.argv[3]), sys.argv[4])))
        return 0
    args = ap.parse_args()
    from nifo.fleet.manifest import load_fleet_input

    t_start = time.perf_counter()
    root = args.cache.with_name(args.cache.name + ("_quick" if args.quick else "_full" if args.full else ""))
    manifest = make_fleet(root, args.quick, args.full)
    entries = load_fleet_input(manifest, default_model=root / "model.yaml")
    truth = json.loads((root / "fleet_truth.json").read_text())
    if args.vehicles:
        keep = sorted(truth)[: args.vehicles]
        entries = [e for e in entries if e.vehicle in keep]
        truth = {v: truth[v] for v in keep}
    n = len(entries)
    print(f"fleet: {len(truth)} vehicles, {n} bags ({load()}); BLAS/OpenMP 1 thread per process")
    verdicts = []

    for e in entries:              # every bag in the page cache first: no run pays the disk and another not
        with open(e.path, "rb") as f:
            while f.read(1 << 24):
                pass

    if args.scaling_only:
        scaling(args, root, entries, verdicts)
        return _verdicts(verdicts, t_start)
    # 1./2. serial baseline and the fleet on 1 and 2 workers, interleaved, best of --rounds each
    import contextlib

    from nifo.fleet.cluster import fleet_client

    identify_alone([e for e in entries if e.group == entries[0].group])    # warm-up: imports, numba
    tmp = Path(tempfile.mkdtemp(prefix="nifo_bench_fleet_"))
    best: dict = {}
    with contextlib.ExitStack() as stack:
        clients = {w: stack.enter_context(fleet_client(workers=w, dashboard_address=None)) for w in (1, 2)}
        for c in clients.values():          # start-up and first calls not timed
            warm_up(c, entries)
        print(f"clusters of 1 and 2 workers started and warmed up (not timed); {args.rounds} round(s), best of each "
              "counts", flush=True)
        try:
            for k in range(args.rounds):
                c0 = time.process_time()
                b = identify_alone(entries)
                b["cpu_s"] = time.process_time() - c0
                runs = {"serial": (b, b["seconds"], (b["cpu_s"], 0.0), load())}
                for w, c in clients.items():
                    res, t, cpu = timed_fleet(c, entries, tmp / f"w{w}")
                    runs[w] = (res, t, cpu, load())
                print(f"round {k + 1}: serial baseline {runs['serial'][1]:.1f} s ({runs['serial'][3]}); "
                      f"fleet, 1 worker "
                      f"{runs[1][1]:.1f} s ({runs[1][3]}); 2 workers {runs[2][1]:.1f} s ({runs[2][3]})", flush=True)
                for key, r in runs.items():
                    if key not in best or r[1] < best[key][1]:
                        best[key] = r
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    base = best["serial"][0]
    times = {w: best[w][1] for w in (1, 2)}
    loads = {w: best[w][3] for w in (1, 2)}
    results = {w: best[w][0] for w in (1, 2)}
    cpus = {w: best[w][2] for w in (1, 2)}
    print(f"serial baseline (nifo identify's work, this process): {base['seconds']:.1f} s = "
          f"{1e3 * base['seconds'] / n:.1f} ms per bag (accumulate {1e3 * base['accumulate_s'] / n:.1f}, "
          f"per-vehicle solve {1e3 * base['solve_s'] / n:.1f}) ({best['serial'][3]})")
    for w in (1, 2):
        print(f"fleet, {w} worker(s): {times[w]:.1f} s = {1e3 * times[w] / n:.1f} ms per bag (fresh cache) "
              f"({loads[w]})")
    speedup = times[1] / times[2]
    verdicts.append(("speed-up 1 -> 2 workers", f"{speedup:.2f}x", ">= 1.8x", speedup >= 1.8, loads[2]))
    overhead = times[1] / base["seconds"] - 1
    in_task = sum(b["seconds"] for b in results[1].bags) / n
    print(f"  where the 1-worker fleet's time goes, per bag: {1e3 * in_task:.1f} ms inside the bag tasks (read, "
          f"accumulate, content hash, per-bag coefficients, cache write; identify's accumulate: "
          f"{1e3 * base['accumulate_s'] / n:.1f}), {1e3 * (times[1] / n - in_task):.1f} ms the rest (per-vehicle "
          f"solves: identify {1e3 * base['solve_s'] / n:.1f}; merges, Dask, client)")
    print(f"  CPU time (also inflated by load): serial baseline {base['cpu_s']:.1f} s; "
          + "; ".join(f"fleet on {w} worker(s): workers {cpus[w][1]:.1f} s "
                      f"({100 * (cpus[w][1] / base['cpu_s'] - 1):+.1f} %)"
                      f" + client and scheduler {cpus[w][0]:.1f} s" for w in (1, 2)))
    verdicts.append(("per-bag overhead, 1-worker fleet vs serial baseline", f"{100 * overhead:+.1f} %", "<= 5 %",
                     overhead <= 0.05, loads[1]))

    # flags and equality, on the 2-worker result
    res = results[2]
    flagged = sorted(g[0] for g, r in res.groups.items() if r.ok and r.health.flagged)
    planted = sorted(v for v, t in truth.items() if t["planted"])
    print(f"flagged: {flagged}; planted: {planted}")
    if not args.quick and not args.vehicles:
        verdicts.append(("flagged = planted", ", ".join(flagged) or "none", ", ".join(planted), flagged == planted,
                         ""))
    worst = max(abs(res.groups[g].coefficients[k].value / v - 1)
                for g, vals in base["values"].items() for k, v in vals.items())
    verdicts.append(("coefficients vs nifo identify, largest rel. difference", f"{worst:.1e}", "<= 1e-9",
                     worst <= 1e-9, ""))

    # 3. scheduler memory
    if not args.no_memory:
        mroot = root.with_name(root.name + "_tiny")
        base_tiny = tiny_fleet(mroot)
        mem = {}
        for k in (args.memory_bags, 10 * args.memory_bags):
            mem[k] = memory_run(base_tiny, linked(mroot, base_tiny, k), mroot / "partials")
            m = mem[k]
            print(f"scheduler process, {k:5d} bags in 20 groups: RSS {m['before']:.1f} MB after warm-up, "
                  f"{m['after']:.1f} MB after the run ({m['after'] - m['before']:+.1f}), "
                  f"peak during the run {m['peak']:.1f} MB; "
                  f"run {m['seconds']:.1f} s ({load()})", flush=True)
        shutil.rmtree(mroot / "links", ignore_errors=True)
        a, b = mem[args.memory_bags], mem[10 * args.memory_bags]
        growth = max(b["after"] - a["after"], b["peak"] - a["peak"])
        verdicts.append((f"scheduler memory, {a['n']} -> {b['n']} bags (after run / peak)",
                         f"{b['after'] - a['after']:+.1f} / {b['peak'] - a['peak']:+.1f} MB", "flat (<= 5 MB)",
                         growth <= 5.0, load()))

    if not args.no_scaling:
        scaling(args, root, entries, verdicts)
    return _verdicts(verdicts, t_start)


def _verdicts(verdicts: list, t_start: float) -> int:
    print(f"\nVERDICTS (whole benchmark {time.perf_counter() - t_start:.0f} s)")
    for name, value, target, ok, ld in verdicts:
        print(f"  {'PASS' if ok else 'FAIL'}  {name}: {value} (target {target})" + (f"  [{ld}]" if ld else ""))
    ok = all(v[3] for v in verdicts)
    print("all targets met" if ok else "TARGET MISSED (a speed-up needs 2 idle cores: check the load averages)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
