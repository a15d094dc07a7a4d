"""nifo fleet on a real Dask LocalCluster (2 worker processes) with a simulated fleet of real bags.

The fleet: 10 vehicles × 2 bags × 40 s (nifo_core.simulate.quarter_car, saved as .mcap
bags), every parameter of every vehicle varied ±10 %, v01 with a worn damper
(C2 -30 %), v06 with the damper knee moved (0.03 → 0.06 m/s); plus a truncated
bag in v02's folder and a missing bag of a vehicle v99. (The full 20 × 10
fleet is in benchmarks/bench_fleet.py.)
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from nifo.cli import main
from nifo.io.results import read_json, read_model

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as c:
        yield c


@pytest.fixture(scope="module")
def fleet(tmp_path_factory, cluster) -> Path:
    from distributed import Client

    from nifo.fleet.simulated import write_simulated_fleet

    root = tmp_path_factory.mktemp("fleet")
    with Client(cluster) as client:   # the bags are simulated on the cluster too
        manifest = write_simulated_fleet(root, n_vehicles=10, bags_per_vehicle=2, duration_s=40.0, worn=(1,),
                                         knee_moved=(6,), block=4096, seed=2,
                                         mapper=lambda f, xs: client.gather(client.map(f, xs)))
    # vmix: a nominal vehicle whose bags differ in length (30 s and 45 s): its integration band is set
    # by the shorter one, as in nifo identify, so the longer one is accumulated twice
    from nifo.fleet.simulated import NOMINAL_DEADZONE, NOMINAL_KNEE, _write_bag
    from nifo_core.kinds.describing import Term
    from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, StrutForce

    strut = (StrutForce(Term("velocity_deadzone", {"knee": NOMINAL_KNEE}), NOMINAL_DEADZONE),)
    (root / "vmix" / "FL").mkdir(parents=True)
    for b, dur in enumerate((30.0, 45.0)):
        _write_bag({"config": SimConfig(strut=strut, road=RandomRoad(0.0025), duration_s=dur), "seed": 90 + b,
                    "path": str(root / "vmix" / "FL" / f"bag0{b}.mcap")})
    good = root / "v02" / "FL" / "bag00.mcap"
    bad = root / "v02" / "FL" / "bag_truncated.mcap"
    bad.write_bytes(good.read_bytes()[: good.stat().st_size * 6 // 10])
    m2 = json.loads((root / "fleet_truth.json").read_text())["v02"]["vehicle"]["m2"]
    with manifest.open("a", newline="") as f:
        w = csv.writer(f)
        w.writerow(["v02", "FL", "2026-02-01", "v02/FL/bag_truncated.mcap", f"{m2:.6g}"])
        w.writerow(["v99", "FL", "2026-02-01", "v99/FL/never_copied.mcap", ""])
        for b in range(2):
            w.writerow(["vmix", "FL", "2026-02-02", f"vmix/FL/bag0{b}.mcap", "300"])
    return root


@pytest.fixture(scope="module")
def result(fleet, cluster, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("out") / "fleet_out"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["fleet", str(fleet / "manifest.csv"), "--model", str(fleet / "model.yaml"), "--out", str(out),
                   "--scheduler", cluster.scheduler_address, "--quiet", "--json"])
    assert rc == 0
    doc = json.loads(buf.getvalue())   # --json: one document on stdout (tests/test_cli.py checks the others)
    assert doc["command"] == "fleet" and doc["ok"] and doc["out"] == str(out) and doc["bags_failed"] >= 1
    return out


def _groups(out: Path) -> dict:
    t = pq.read_table(out / "fleet.parquet").to_pylist()
    return {r["vehicle"]: r for r in t}


def test_fleet_writes_every_output_and_flags_exactly_the_planted_struts(result):
    assert {p.name for p in result.iterdir()} >= {"fleet.parquet", "fleet.csv", "bags.parquet", "bags.csv",
                                                 "fleet.json", "fleet.html", "t21.png", "coefficients.png",
                                                 "t21.svg", "coefficients.svg", "fleet.rrd"}
    g = _groups(result)
    assert {v for v, r in g.items() if r["flagged"]} == {"v01", "v06"}
    assert g["v01"]["c2_z"] < -3.5 and "c2 = " in g["v01"]["flag_evidence"]
    assert g["v06"]["c_velocity_deadzone_z"] < -3.5
    for v, r in g.items():
        if r["status"] == "ok":
            assert r["n_bags"] == 2 and r["c2_lo"] < r["c2"] < r["c2_hi"]
            assert r["t21_10hz_mag_lo"] < r["t21_10hz_mag"] < r["t21_10hz_mag_hi"]
    html = (result / "fleet.html").read_text()
    assert "v01/FL" in html and "[N·s/m]" in html
    doc = read_json(result / "fleet.json", what="fleet")
    assert doc["units"]["c2"] == "N·s/m" and doc["units"]["k2_over_m2"] == "1/s²"


def test_fleet_coefficients_are_close_to_the_simulated_truth(result, fleet):
    truth = json.loads((fleet / "fleet_truth.json").read_text())
    g = _groups(result)
    for v in ("v00", "v01", "v03", "v08"):
        for name in ("k2", "c2"):
            assert g[v][name] == pytest.approx(truth[v][name], rel=0.04), (v, name)


def test_a_bad_bag_is_recorded_with_its_reason_and_the_fleet_goes_on(result):
    bags = {Path(r["path"]).name: r for r in pq.read_table(result / "bags.parquet").to_pylist()}
    assert bags["bag_truncated.mcap"]["status"] == "failed"
    assert "bag_truncated.mcap" in bags["bag_truncated.mcap"]["reason"]
    assert "\n" not in bags["bag_truncated.mcap"]["reason"]
    assert bags["never_copied.mcap"]["status"] == "failed"
    assert "no such file or directory" in bags["never_copied.mcap"]["reason"]
    g = _groups(result)
    assert g["v02"]["status"] == "ok" and g["v02"]["n_bags"] == 2 and g["v02"]["n_bags_failed"] == 1
    assert g["v99"]["status"] == "failed" and g["v99"]["reason"] == "no usable bag"


@pytest.mark.parametrize("vehicle", ["v01", "v03", "vmix"])
def test_group_coefficients_equal_nifo_identify_on_the_groups_bags(result, fleet, tmp_path, vehicle):
    bags = sorted((fleet / vehicle / "FL").glob("bag0*.mcap"))
    out = tmp_path / "ident"
    assert main(["identify", *map(str, bags), "--model", str(fleet / "model.yaml"), "--out", str(out),
                 "--no-plots", "--quiet", "--no-settings-from-data"]) == 0   # the fleet's settings: file, defaults
    doc = read_json(out / "identify.json", what="identify")
    model, _ = read_model(out)
    g = _groups(result)[vehicle]
    ident = {"k2_over_m2": model.body.k, "c2_over_m2": model.body.c,
             "c_over_m2_velocity_deadzone": doc["summary"]["terms"][0]["c_over_m2"]}
    for name, v in ident.items():
        assert g[name] == pytest.approx(v, rel=1e-9, abs=0), name
    assert g["n_avg"] == doc["summary"]["n_avg"]
    if vehicle == "vmix":     # its two bags in one task: the band fixed there, as identify does, each read once
        passes = {Path(r["path"]).name: r["passes"] for r in pq.read_table(result / "bags.parquet").to_pylist()
                  if r["vehicle"] == "vmix"}
        assert passes == {"bag00.mcap": 1, "bag01.mcap": 1}


def test_settings_flags_given_to_nifo_fleet_reach_every_group_as_they_reach_nifo_identify(fleet, cluster, tmp_path):
    """nifo fleet takes the settings flags of every command, resolved once over the model file's (issue 57: the
    fleet and the node take the same object): a group's set-up and its coefficients are nifo identify's with the
    same flags."""
    rows = [r for r in csv.DictReader((fleet / "manifest.csv").open()) if r["vehicle"] == "v03"]
    part = tmp_path / "v03.csv"
    with part.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows([{**r, "path": str(fleet / r["path"])} for r in rows])
    flags = ["--analysis-band", "3", "20", "--block", "2048", "--cond-limit", "1e7"]
    out = tmp_path / "out"
    assert main(["fleet", str(part), "--model", str(fleet / "model.yaml"), "--out", str(out), "--scheduler",
                 cluster.scheduler_address, "--quiet", "--no-plots", "--no-rerun", "--no-cache", *flags]) == 0
    doc = read_json(out / "fleet.json", what="fleet")
    setup = doc["settings"]["groups"]["v03/FL"]
    assert setup["analysis_band_hz"] == [3.0, 20.0] and setup["spectral"]["block"] == 2048
    assert setup["cond_limit"] == 1e7
    bags = sorted((fleet / "v03" / "FL").glob("bag0*.mcap"))
    ident = tmp_path / "ident"
    assert main(["identify", *map(str, bags), "--model", str(fleet / "model.yaml"), "--out", str(ident),
                 "--no-plots", "--quiet", "--no-settings-from-data", *flags]) == 0
    model, _ = read_model(ident)
    g = _groups(out)["v03"]
    assert g["k2_over_m2"] == pytest.approx(model.body.k, rel=1e-9, abs=0)
    assert g["c2_over_m2"] == pytest.approx(model.body.c, rel=1e-9, abs=0)
    assert g["n_avg"] == read_json(ident / "identify.json", what="identify")["summary"]["n_avg"]


def test_a_batch_of_several_bags_gives_the_partials_of_one_bag_per_task(fleet, tmp_path):
    from nifo.fleet.manifest import load_fleet_input
    from nifo.fleet.runner import base_setups, fleet_settings
    from nifo.fleet.tasks import compute_batch, group_setup, merge_outcomes

    entries = [e for e in load_fleet_input(fleet / "manifest.csv", default_model=fleet / "model.yaml")
               if e.vehicle == "vmix"]
    g = entries[0].group
    base = base_setups(entries, fleet_settings(entries), opts={}, chunk_samples=2 ** 18)[g]
    bags = [(i, str(e.path)) for i, e in enumerate(entries)]
    batch = compute_batch([(g, base, bags, True)], str(tmp_path / "batched"))
    # the group's set-up (band of the 30-s bag) fixed in the task, as nifo identify fixes it
    probes = {i: st.probe for i, st in batch.status}
    fixed, left = group_setup(base, probes, label="vmix")
    assert not left and {st.setup_hash for _, st in batch.status} == {
        next(iter(batch.parts))[2]} and len(batch.parts) == 1
    alone = [compute_batch([(g, fixed, [b], False)], str(tmp_path / "alone")) for b in bags]
    part = next(iter(batch.parts))
    merged = merge_outcomes(*alone, part=part)
    assert merged.ok and [b.path for b in merged.bags] == [p for _, p in bags]
    a, b = batch.parts[part].state, merged.state
    assert a.keys() == b.keys()
    for k in a:
        if np.asarray(a[k]).dtype.kind in "fc":
            np.testing.assert_allclose(a[k], b[k], rtol=1e-13, atol=0, err_msg=k)
        else:
            assert np.array_equal(a[k], b[k]), k
    for x, y in zip(batch.parts[part].bags, merged.bags):
        assert x.coefs == pytest.approx(y.coefs, rel=1e-12)
    # one cache entry per bag (named by its key), the same key whether batched or alone
    entries_b = sorted(p.stem for p in (tmp_path / "batched").rglob("*.npz"))
    entries_a = sorted(p.stem for p in (tmp_path / "alone").rglob("*.npz"))
    assert entries_b == entries_a == sorted(st.key for _, st in batch.status) and len(entries_b) == 2
    # the whole group's rates, lengths and channels in one note; bags cut over tasks in one note each
    assert len(list((tmp_path / "batched" / "notes").glob("*.json"))) == 1
    assert len(list((tmp_path / "alone" / "notes").glob("*.json"))) == 2
    import nifo.fleet.tasks as tasks

    def no_open(*a, **k):
        raise AssertionError("a finished bag was opened again")

    opener, tasks._open = tasks._open, no_open
    try:                                   # a rerun: every bag from the cache, none opened
        again = compute_batch([(g, base, bags, True)], str(tmp_path / "batched"))
    finally:
        tasks._open = opener
    assert all(st.cached for _, st in again.status)
    np.testing.assert_array_equal(again.parts[part].state["acc.sum"], a["acc.sum"])
    for x, y in zip(again.parts[part].bags, batch.parts[part].bags):
        assert x.coefs == y.coefs           # a bag's own coefficients: the same from its cached partial


def test_one_bag_per_task_accumulates_again_the_bags_whose_set_up_differs(fleet, cluster):
    from distributed import Client

    from nifo.fleet.manifest import load_fleet_input
    from nifo.fleet.runner import FleetSettings, fleet_settings, run_fleet

    entries = [e for e in load_fleet_input(fleet / "manifest.csv", default_model=fleet / "model.yaml")
               if e.vehicle in ("vmix", "v00")]
    analysis = fleet_settings(entries)
    with Client(cluster) as client:
        one = run_fleet(client, entries, analysis=analysis, opts={}, settings=FleetSettings(batch=1), quiet=True)
        batched = run_fleet(client, entries, analysis=analysis, opts={}, settings=FleetSettings(), quiet=True)
    # split over tasks, vmix's 45-s bag first takes its own band, then its group's (the 30-s bag's)
    assert {Path(b["path"]).name: b["passes"] for b in one.bags if b["vehicle"] == "vmix"} == {
        "bag00.mcap": 1, "bag01.mcap": 2}
    assert all(b["passes"] == 1 for b in batched.bags)
    for g, r in batched.groups.items():
        assert r.ok and one.groups[g].n_avg == r.n_avg
        for name, c in r.coefficients.items():
            assert one.groups[g].coefficients[name].value == pytest.approx(c.value, rel=1e-12), (g, name)


def test_a_killed_fleet_run_resumes_without_recomputing_finished_bags(result, fleet, tmp_path):
    rows = list(csv.DictReader((fleet / "manifest.csv").open()))
    part = tmp_path / "part.csv"          # 4 vehicles, 8 bags: enough to kill mid-way
    with part.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows([{**r, "path": str(fleet / r["path"])} for r in rows if r["vehicle"] in ("v00", "v01", "v03",
                                                                                            "v04")])
    out, cache = tmp_path / "out", tmp_path / "cache"
    cmd = [sys.executable, "-m", "nifo", "fleet", str(part), "--model", str(fleet / "model.yaml"),
           "--out", str(out), "--cache", str(cache), "--workers", "1", "--quiet", "--no-plots", "--no-rerun",
           "--min-groups", "3"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    t0 = time.monotonic()
    while len(list(cache.rglob("*.npz"))) < 2:
        assert proc.poll() is None, "the fleet run ended before it could be killed"
        assert time.monotonic() - t0 < 240
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    before = {p.stem: p.stat().st_mtime_ns for p in cache.rglob("*.npz")}
    assert 2 <= len(before) < 8 and not out.exists()
    # again, with its summary text (the global --quiet silences it)
    rc = subprocess.run([c for c in cmd if c != "--quiet"], env=env, capture_output=True, text=True, timeout=300)
    assert rc.returncode == 0, rc.stderr
    bags = pq.read_table(out / "bags.parquet").to_pylist()
    assert all(r["status"] == "ok" for r in bags) and len(bags) == 8
    assert {r["key"] for r in bags if r["cached"]} == set(before)
    assert {p.stem: p.stat().st_mtime_ns for p in cache.rglob("*.npz") if p.stem in before} == before
    assert f"{len(before)} from the cache" in rc.stdout
    # every per-group number equals the uninterrupted run's (health columns depend on the fleet: left out)
    full, resumed = _groups(result), _groups(out)
    for v, rb in resumed.items():
        for k, va in full[v].items():
            if k.endswith("_z") or k in ("flagged", "flag_evidence", "health_note", "n_bags_cached",
                                         "n_bags_failed", "n_bags"):
                continue
            if isinstance(va, float) and np.isfinite(va):
                assert rb[k] == pytest.approx(va, rel=1e-12), (v, k)
            elif isinstance(va, float):     # NaN: not computed in either run (e.g. the loop's scores without --loop)
                assert isinstance(rb[k], float) and np.isnan(rb[k]), (v, k)
            else:
                assert rb[k] == va, (v, k)


def test_an_unreachable_scheduler_is_one_line_and_its_exit_code(fleet, capsys):
    rc = main(["fleet", str(fleet / "manifest.csv"), "--model", str(fleet / "model.yaml"), "--out",
               str(fleet / "never"), "--scheduler", "tcp://127.0.0.1:9", "--connect-timeout", "2", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 20 and err.count("\n") == 1
    assert "cannot reach the Dask scheduler tcp://127.0.0.1:9" in err and "Fix:" in err
    assert not (fleet / "never").exists()


def test_a_bag_too_short_to_integrate_fails_alone_in_its_groups_task(fleet, tmp_path):
    from nifo.fleet.manifest import load_fleet_input
    from nifo.fleet.runner import base_setups, fleet_settings
    from nifo.fleet.simulated import NOMINAL_DEADZONE, NOMINAL_KNEE, _write_bag
    from nifo.fleet.tasks import compute_batch
    from nifo_core.kinds.describing import Term
    from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, StrutForce

    short = tmp_path / "short.mcap"
    strut = (StrutForce(Term("velocity_deadzone", {"knee": NOMINAL_KNEE}), NOMINAL_DEADZONE),)
    _write_bag({"config": SimConfig(strut=strut, road=RandomRoad(0.0025), duration_s=4.0), "seed": 7,
                "path": str(short)})
    e = [x for x in load_fleet_input(fleet / "manifest.csv", default_model=fleet / "model.yaml")
         if x.vehicle == "v00"][0]
    base = base_setups([e], fleet_settings([e]), opts={}, chunk_samples=2 ** 18)[e.group]
    out = compute_batch([(e.group, base, [(0, str(e.path)), (1, str(short))], True)], None)
    st = dict(out.status)
    assert st[0].ok and not st[1].ok and "too short" in st[1].reason and "\n" not in st[1].reason
    assert len(out.parts) == 1
