"""nifo.io.results.write_json: strict JSON (non-finite values as null) whether they sit in arrays or not."""

from __future__ import annotations

import json
import math

import numpy as np

from nifo.io.results import write_json


def _strict(text: str):
    def refuse(name):
        raise AssertionError(f"{name} in strict JSON")
    return json.loads(text, parse_constant=refuse)


def test_non_finite_values_are_null_in_arrays_scalars_and_nested_lists(tmp_path):
    doc = {"t21": np.array([1.0, np.nan, np.inf, -2.5]), "n": np.int64(3), "ok": np.bool_(True),
           "k": np.float64(-np.inf), "nested": {"xs": [1.0, float("nan")], "m": np.array([[np.nan, 1.0]])},
           "msg": "3 samples are NaN, [1, NaN]"}
    got = _strict(write_json(tmp_path / "a.json", doc).read_text())
    assert got == {"t21": [1.0, None, None, -2.5], "n": 3, "ok": True, "k": None,
                   "nested": {"xs": [1.0, None], "m": [[None, 1.0]]}, "msg": "3 samples are NaN, [1, NaN]"}
    clean = {"t21": np.array([1.0, 2.0]), "x": 0.1}
    text = write_json(tmp_path / "b.json", clean, indent=1).read_text()
    assert _strict(text) == {"t21": [1.0, 2.0], "x": 0.1} and text.startswith("{\n")
    assert math.isclose(_strict(text)["x"], 0.1)
