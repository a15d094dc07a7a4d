"""nifo fleet on force-driven rigs (a real Dask LocalCluster, 2 worker processes): the measured force is used, as
``nifo identify`` uses it, with a fixed spindle (a shaker table's CSV files, ``spindle_accel=fixed``) and with a
moving one (.mcap bags with the ``/nifo/force`` topic).

Before the fleet accumulated through the core's identification engine (:mod:`nifo_core.nifo.engine`) its workers
built their own accumulators without the force and without the fixed spindle (issue 57): measured on the commit
before, the shaker's group failed ("no usable bag") and the moving rig's came out with K2/M2 = 4701 1/s² for a true
15791, silently.

Truth: a single mass on a cubic spring driven by a force (:func:`test_force_input._forced`: 2 kg, 20 Hz, 5 %
damping, b = 1e9 N/m³).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from nifo.cli import main
from nifo.io.loader import save_record
from nifo.io.results import read_json, read_model
from test_force_input import B3, K, M, _forced

pytestmark = pytest.mark.slow

#: vehicle → (spindle rms [m/s²] (0: fixed), file suffix, seeds of its bags)
RIGS = {"shaker": (0.0, ".csv", (11, 12)), "rig": (20.0, ".mcap", (13, 14))}
#: the CSV files' columns (bags take their topics; the option does not apply to them)
COLUMNS = "time=time,body_accel=body_accel,force=force,spindle_accel=fixed"
MODEL = ("nifo_model: 1\nnonlinearities:\n  - {kind: cubic_stiffness}\n"
         "settings: {block: 4096, overlap: 0.5, window: hann, freq_range_hz: [2, 80]}\n")


@pytest.fixture(scope="module")
def rigs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("rigs")
    rows = []
    for vehicle, (spindle_rms, suffix, seeds) in RIGS.items():
        (root / vehicle / "FL").mkdir(parents=True)
        for b, seed in enumerate(seeds):
            rec = _forced(seed, force_rms=40.0, spindle_rms=spindle_rms, seconds=60.0)
            path = save_record(root / vehicle / "FL" / f"bag{b:02d}{suffix}", rec)
            rows.append([vehicle, "FL", f"2026-03-0{b + 1}", path.relative_to(root).as_posix(), ""])
    with (root / "manifest.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["vehicle", "corner", "date", "path", "m2_kg"])
        w.writerows(rows)
    (root / "model.yaml").write_text(MODEL)
    return root


@pytest.fixture(scope="module")
def fleet_out(rigs, tmp_path_factory) -> Path:
    from distributed import LocalCluster

    out = tmp_path_factory.mktemp("out") / "fleet_out"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            rc = main(["fleet", str(rigs / "manifest.csv"), "--model", str(rigs / "model.yaml"), "--out", str(out),
                       "--scheduler", cluster.scheduler_address, "--columns", COLUMNS, "--quiet", "--json"])
    assert rc == 0, buf.getvalue()
    assert json.loads(buf.getvalue())["ok"]
    return out


@pytest.mark.parametrize("vehicle", list(RIGS))
def test_a_force_driven_rig_is_identified_with_its_force_as_nifo_identify_does(rigs, fleet_out, tmp_path, vehicle):
    group = {r["vehicle"]: r for r in pq.read_table(fleet_out / "fleet.parquet").to_pylist()}[vehicle]
    assert group["status"] == "ok" and group["n_bags"] == 2, group
    bags = sorted((rigs / vehicle / "FL").glob("bag*"))
    out = tmp_path / "ident"
    assert main(["identify", *map(str, bags), "--model", str(rigs / "model.yaml"), "--out", str(out), "--no-plots",
                 "--columns", COLUMNS, "--quiet", "--no-settings-from-data"]) == 0
    doc = read_json(out / "identify.json", what="identify")
    assert doc["summary"]["force"]["spindle_fixed"] is (RIGS[vehicle][0] == 0.0)   # identify took the force
    model, _ = read_model(out)
    ident = {"k2_over_m2": model.body.k, "c2_over_m2": model.body.c,
             "c_over_m2_cubic_stiffness": doc["summary"]["terms"][0]["c_over_m2"]}
    for name, v in ident.items():         # the fleet's group = nifo identify on the group's bags
        assert group[name] == pytest.approx(v, rel=1e-9, abs=0), name
    assert group["n_avg"] == doc["summary"]["n_avg"]
    # and both are the rig's truth (without the force, the shaker's spindle is zero: nothing to regress on)
    assert group["k2_over_m2"] == pytest.approx(K / M, rel=0.04)
    assert group["c_over_m2_cubic_stiffness"] == pytest.approx(B3 / M, rel=0.08)
