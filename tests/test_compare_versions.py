"""benchmarks/compare_versions.py: an earlier commit against this checkout, each really running its own code, and
their JSON outputs compared with paths and clocks aside (the tool itself is run by hand: a fresh tree compiles its
kernels first, half a minute; its figures are in the closing notes of issue 29)."""

from __future__ import annotations

import json
import sys

import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import compare_versions as cv  # noqa: E402


def _write(root, name, doc):
    p = root / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(doc))


def test_outputs_that_differ_only_in_their_folder_and_clocks_are_identical_and_a_number_is_not(tmp_path):
    old, new = tmp_path / "old", tmp_path / "new"
    for out, took in ((old, 1.5), (new, 2.5)):
        _write(out, "identify/identify.json", {"out": f"{out}/identify", "took_s": took, "theta": [1.0, 2.0]})
        _write(out, "loop/loop.json", {"model": f"{out}/loop/model.json", "nmse": 0.5 if out is old else 0.5000001})
    _write(new, "predict/predict.json", {})
    lines = cv.compare_outputs(old, new, {"new": REPO})
    assert lines == ["  identify/identify.json: identical",
                     "  loop/loop.json: differs at /nmse: 0.5 != 0.5000001",
                     "  predict/predict.json: written by new only"]


def test_paths_in_keys_csv_tables_and_ignored_clock_columns_are_compared_as_the_user_expects(tmp_path):
    old, new = tmp_path / "old", tmp_path / "new"
    for out, took, k2 in ((old, "0.35", "64.46982577918239"), (new, "0.19", "64.46982577918239")):
        _write(out, "run/settings.json", {"inputs": {f"{out}/bags/road_1mm": "from the data"}})
        (out / "fleet").mkdir()
        (out / "fleet" / "bags.csv").write_text(f"vehicle,seconds,k2\nv00,{took},{k2}\n")
    (new / "fleet" / "fleet.csv").write_text("vehicle,k2\nv00,1\n")
    (old / "fleet" / "fleet.csv").write_text("vehicle,k2\nv00,1.0000000000000002\n")
    lines = cv.compare_outputs(old, new, {"new": REPO}, ignore=frozenset({"seconds"}))
    assert lines == ["  fleet/bags.csv: identical",
                     "  fleet/fleet.csv: differs at [0]/k2: '1.0000000000000002' != '1'",
                     "  run/settings.json: identical"]
    assert "differs at [0]/seconds" in cv.compare_outputs(old, new, {"new": REPO})[0]


def test_a_version_that_imports_another_trees_code_is_refused(tmp_path):
    # started from a checkout, `python -m nifo` imports that checkout whatever PYTHONPATH says: the trap the tool
    # avoids by an empty working directory, and checks
    with pytest.raises(SystemExit, match="not its own code"):
        cv._check_imports(tmp_path, REPO)
