"""Records of the same name never share an output (issue 56).

Before: ``nifo predict day1/rec.csv day2/rec.csv`` exited 0 with predict.json listing ``rec.csv_signals.*`` twice and
one table on disk holding the second record only; ``"rec 1.csv"`` and ``rec_1.csv`` did the same.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pyarrow.parquet as pq
import pytest
from hypothesis import given, strategies as st

from nifo.io.loader import load_record, save_record
from nifo.io.names import file_stems, record_labels
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate

from fuzz_engine import cli
from test_fuzz_files import FUZZ

_parts = st.sampled_from(["day1", "day2", "a b", "A", "a", "x"])
_names = st.sampled_from(["rec.csv", "Rec.csv", "rec 1.csv", "rec_1.csv", "rec-1.csv", "r.mcap", "é.csv", ".csv"])


@FUZZ
@given(st.lists(st.tuples(st.lists(_parts, max_size=3), _names), min_size=1, max_size=6))
def test_labels_and_file_stems_never_repeat_and_unique_names_stay_plain(paths):
    paths = [os.path.join(*folders, name) for folders, name in paths]
    labels = record_labels(paths)
    stems = file_stems(labels)
    assert len({s.casefold() for s in stems}) == len(paths)       # unique even on a case-blind file system
    assert all(s and "/" not in s and s == s.strip(".") for s in stems)
    for p, label in zip(paths, labels):
        name = os.path.basename(p)
        if sum(os.path.basename(q) == name for q in paths) == 1:
            assert label == name                                # users read these: the plain name when unique
        else:
            assert name in label      # told apart by its folders or an index, its name kept
    distinct = {os.path.abspath(p) for p in paths}
    assert len(set(labels)) == len(paths) or len(distinct) < len(paths)


def test_the_issues_names_are_told_apart_the_plain_way():
    assert record_labels(["day1/rec.csv", "day2/rec.csv", "x.csv"]) == ["day1/rec.csv", "day2/rec.csv", "x.csv"]
    assert file_stems(record_labels(["rec 1.csv", "rec_1.csv"])) == ["rec_1.csv", "rec_1.csv-2"]
    assert record_labels(["r.csv", "r.csv"]) == ["r.csv", "r.csv #2"]


@pytest.fixture(scope="module")
def four_records(tmp_path_factory):
    """Four different records named alike, and a linear model of the first."""
    root = tmp_path_factory.mktemp("names")
    paths = [root / "day1" / "rec.csv", root / "day2" / "rec.csv", root / "rec 1.csv", root / "rec_1.csv"]
    for k, p in enumerate(paths):
        p.parent.mkdir(exist_ok=True)
        sim = simulate(SimConfig(strut=preset("linear"), duration_s=30.0, road=RandomRoad(2e-3)), rng=10 + k)
        save_record(p, sim.record)
    model = root / "m.yaml"
    model.write_text("nifo_model: 1\nnonlinearities: []\n")
    code, _, err = cli(["identify", str(paths[0]), "--model", str(model), "--out", str(root / "ident"), "--no-plots",
                        "-q"])
    assert code == 0, err
    return paths, root / "ident"


def test_predict_writes_each_same_named_records_own_signals_and_figures(four_records, tmp_path):
    paths, ident = four_records
    out = tmp_path / "pred"
    code, _, err = cli(["predict", *map(str, paths), "--model", str(ident), "--out", str(out), "-q"])
    assert code == 0, err
    doc = json.loads((out / "predict.json").read_text())
    names = [r["name"] for r in doc["records"]]
    assert names == ["day1/rec.csv", "day2/rec.csv", "rec 1.csv", "rec_1.csv"]
    files = [f for r in doc["records"] for f in (*r["signals"], *r["figures"])]
    assert len(files) == len(set(files)) == 16 and all((out / f).is_file() for f in files)
    for r, p in zip(doc["records"], paths):      # each table holds its own record
        measured = pq.read_table(out / r["signals"][0]).column("body_accel_measured").to_numpy()
        assert np.array_equal(measured, load_record(p).body_accel), r["name"]
