"""A fleet worker starts warm: forked from the fork server that imported nifo.fleet.preload once.

Real LocalClusters in fresh processes (the fork server is one per process), no mocks: the
first run on an empty numba cache compiles the bag path's kernels and writes the cache; the
next run's workers have it loaded from the cache (numba's dispatcher statistics), spent
well under a second of CPU to start, run BLAS on one thread, and their first bag imports
no module (everything it needs came with the fork).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys
from nifo.fleet.cluster import fleet_client
from nifo.fleet.manifest import load_fleet_input
from nifo.fleet.runner import base_setups, fleet_settings

root = sys.argv[1]
entries = load_fleet_input(root + "/manifest.csv", default_model=root + "/model.yaml")
e = entries[0]
setup = base_setups([e], fleet_settings([e]), opts={"topics": None, "columns": None, "fs_hz": None, "axis": "z"},
                    chunk_samples=2 ** 18)[e.group]


def probe(path, group, setup):
    import os, resource, sys, time
    from nifo.fleet.preload import WARM, kernel_stats
    from nifo.fleet.tasks import compute_batch
    from threadpoolctl import threadpool_info

    r = resource.getrusage(resource.RUSAGE_SELF)
    cpu = r.ru_utime + r.ru_stime
    before = set(sys.modules)
    t0 = time.perf_counter()
    out = compute_batch([(group, setup, [(0, path)], True)], None)
    return {"cpu_s": cpu, "kernels": kernel_stats(), "omp": os.environ.get("OMP_NUM_THREADS"),
            "blas_threads": sorted({i["num_threads"] for i in threadpool_info()}), "failed": WARM["failed"],
            "new_modules": sorted(set(sys.modules) - before), "first_bag_s": time.perf_counter() - t0,
            "bag_ok": out.status[0][1].ok}


with fleet_client(workers=1, dashboard_address=None) as client:
    (res,) = client.run(probe, str(e.path), e.group, setup).values()
print(json.dumps(res))
"""


@pytest.fixture(scope="module")
def one_bag(tmp_path_factory) -> Path:
    from nifo.fleet.simulated import write_simulated_fleet

    root = tmp_path_factory.mktemp("one_bag")
    write_simulated_fleet(root, n_vehicles=1, bags_per_vehicle=1, duration_s=30.0, worn=(), knee_moved=(),
                          block=2048, seed=3)
    return root


def _worker(root: Path, numba_dir: Path) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(numba_dir),
           "PYTHONPATH": os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])}
    out = subprocess.run([sys.executable, "-c", CHILD, str(root)], env=env, capture_output=True, text=True,
                         timeout=300, check=False)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_fleet_worker_starts_warm_with_the_kernels_loaded_from_numbas_cache(one_bag, tmp_path):
    first = _worker(one_bag, tmp_path / "numba")       # first run on this "machine": an empty numba cache
    assert len(first["kernels"]) == 2     # the spectral engine's block products, the play operator
    for k_first in first["kernels"].values():
        assert k_first["cache_misses"] == 1 and k_first["signatures"]      # compiled once, in the fork server
    assert any((tmp_path / "numba").rglob("*.nbi"))                        # and written where the next run reads

    later = _worker(one_bag, tmp_path / "numba")
    for k in later["kernels"].values():
        assert k["signatures"] and k["cache_hits"] == 1 and k["cache_misses"] == 0   # loaded, not compiled
    assert later["failed"] == []
    assert later["cpu_s"] < 1.0, later          # a forked worker's own start-up (spawned: ~2-4 s of imports)
    assert later["omp"] == "1" and later["blas_threads"] == [1]


def test_a_warm_workers_first_bag_imports_no_module(one_bag, tmp_path):
    res = _worker(one_bag, tmp_path / "numba")
    assert res["bag_ok"]
    assert res["new_modules"] == [], "add these to nifo.fleet.preload.LAZY_MODULES"
