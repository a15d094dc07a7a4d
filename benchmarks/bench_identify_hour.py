"""``nifo identify`` on a one-hour two-channel 600 Hz bag: wall time and peak memory.

Makes (once, cached under ``--cache``, default /tmp/nifo_bench) a 15-minute
bag simulated with the paper's strut (backlash + velocity deadzone, 2.5 mm
road, 2 % noise) and a one-hour bag of the same record tiled four times
(spindle and body only: two Imu topics, 2.16 M messages each). Writing the
hour bag takes a few minutes; later runs reuse it.

Then runs ``nifo identify`` on each as a child process (streaming: the bag is
decoded MCAP chunk by MCAP chunk and pushed into StreamingNifo, see
``nifo/pipeline/identify.py``) and prints, measured in this run:

- wall time as a fraction of the recording's duration (target ≤ 1 %);
- the child's peak resident memory (``os.wait4`` → ``ru_maxrss``; target
  < 1 GB) for 15 minutes and for one hour (it should not grow with duration).

Usage::

    .venv/bin/python benchmarks/bench_identify_hour.py [--cache /tmp/nifo_bench] [--repeat 1]

Exits 1 when a target is missed.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODEL = """nifo_model: 1
nonlinearities:
  - {kind: velocity_deadzone, params: {knee: 0.03}}
  - {kind: backlash, params: {deadband: 0.00043}}
"""


def make_bags(cache: Path) -> dict[str, Path]:
    import numpy as np

    from nifo.io.loader import save_record
    from nifo_core.signal.record import Record
    from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, preset, simulate

    cache.mkdir(parents=True, exist_ok=True)
    quarter, hour = cache / "quarter_hour_600hz.mcap", cache / "hour_600hz.mcap"
    if quarter.is_file() and hour.is_file():
        return {"15 min": quarter, "60 min": hour}
    t = time.perf_counter()
    sim = simulate(SimConfig(strut=preset("paper"), road=RandomRoad(2.5e-3), duration_s=900.0, fs_hz=600.0,
                             noise=SensorNoise(relative=0.02)), rng=7)
    r = sim.record
    print(f"simulated 900 s in {time.perf_counter() - t:.1f} s", flush=True)
    two = Record(r.fs_hz, r.spindle_accel, r.body_accel, source="quarter_hour")
    t = time.perf_counter()
    save_record(quarter, two)
    print(f"wrote {quarter} ({quarter.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t:.1f} s", flush=True)
    tiled = Record(r.fs_hz, np.tile(r.spindle_accel, 4), np.tile(r.body_accel, 4), source="hour")
    t = time.perf_counter()
    save_record(hour, tiled)
    print(f"wrote {hour} ({hour.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t:.1f} s", flush=True)
    return {"15 min": quarter, "60 min": hour}


def run_identify(bag: Path, model: Path, out: Path) -> tuple[float, float, int]:
    """(wall seconds, peak RSS in MB, exit code) of one ``nifo identify`` child process."""
    cmd = [sys.executable, "-m", "nifo", "identify", str(bag), "--model", str(model), "--out", str(out), "--quiet"]
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t
    proc.returncode = os.waitstatus_to_exitcode(status)
    out_text = proc.stdout.read().decode()
    err_text = proc.stderr.read().decode()
    if proc.returncode:
        print(out_text, err_text, file=sys.stderr)
    peak_mb = usage.ru_maxrss / 1024.0          # Linux: kilobytes
    return wall, peak_mb, proc.returncode


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cache", type=Path, default=Path("/tmp/nifo_bench"))
    p.add_argument("--repeat", type=int, default=1, help="runs per bag (best wall time, worst memory)")
    p.add_argument("--make-only", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.make_only:
        make_bags(a.cache)
        return 0
    # the bags are made in a child: a forked child inherits its parent's resident pages in ru_maxrss,
    # so this process must stay small for the children's peak memory to mean anything
    subprocess.run([sys.executable, __file__, "--make-only", "--cache", str(a.cache)], check=True)
    bags = {"15 min": a.cache / "quarter_hour_600hz.mcap", "60 min": a.cache / "hour_600hz.mcap"}
    model = a.cache / "model.yaml"
    model.write_text(MODEL)
    # warm-up (imports, numba caches) on the bundled sample, not measured
    run_identify(ROOT / "bags" / "sample" / "road_1mm", model, a.cache / "out_warmup")
    rows = {}
    for name, bag in bags.items():
        duration = {"15 min": 900.0, "60 min": 3600.0}[name]
        walls, peaks = [], []
        for k in range(a.repeat):
            wall, peak, rc = run_identify(bag, model, a.cache / f"out_{name.split()[0]}")
            if rc:
                print(f"nifo identify failed on {bag} (exit {rc})", file=sys.stderr)
                return 1
            walls.append(wall)
            peaks.append(peak)
        rows[name] = (min(walls), max(peaks), duration)
        print(f"{name}: {bag.name} ({bag.stat().st_size / 1e6:.0f} MB): wall {min(walls):.1f} s = "
              f"{100 * min(walls) / duration:.2f} % of the recording, peak RSS {max(peaks):.0f} MB", flush=True)
    wall, peak, dur = rows["60 min"]
    growth = rows["60 min"][1] / rows["15 min"][1]
    print(f"one hour: {100 * wall / dur:.2f} % of real time (target <= 1 %), peak {peak:.0f} MB (target < 1024 MB); "
          f"peak 60 min / 15 min = {growth:.2f} (flat = does not grow with duration)")
    ok = wall / dur <= 0.01 and peak < 1024 and growth < 1.3
    if not ok:
        print("TARGET MISSED", file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
