"""Property tests (hypothesis, fixed seed, bounded) for CSV, MAT and model files and output paths.

Each generated input either reads correctly — checked against an
independent reading of what was generated — or fails with one
:class:`NifoError` line naming the file and the fix; never a traceback, a
hang or a silently wrong result. The issue's cases are pinned as examples.
"""

from __future__ import annotations

import csv
import errno
import io
import math
import os
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import yaml
from hypothesis import HealthCheck, example, given, settings, strategies as st

from nifo.io.atomic import INCOMPLETE, staged_dir, staged_file, staged_run
from nifo.io.loader import load_record
from nifo.io.modelfile import load_model_spec
from nifo_core.errors import ConfigError, DataFileError, NifoError, OutputError

from fuzz_engine import Tally, classify, guarded, names_file_and_fix

#: fixed seed (derandomize) and a bounded number of examples: the same cases on every run, seconds each
FUZZ = settings(derandomize=True, max_examples=int(os.environ.get("NIFO_FUZZ_EXAMPLES", 100)), deadline=None,
                suppress_health_check=list(HealthCheck), database=None)

_NAMES = ["time", "spindle_accel", "body_accel", "tire_patch_disp", "t", "x", ""]
_cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64).map(repr),
                   st.integers(-10**30, 10**30).map(str), st.sampled_from(["", "nan", "abc", " 1 ", "1e400", "-0"]))


def _uniform_times(n: int, fs: float) -> list[str]:
    return [repr(i / fs) for i in range(n)]


@st.composite
def csv_tables(draw) -> str:
    """Mostly near-valid tables (so successes happen), with damaged rows, headers and values."""
    n = draw(st.integers(0, 40))
    fs = draw(st.sampled_from([100.0, 600.0, 1e-300, 1e300, 2441.40625]))
    header = draw(st.one_of(st.just(["time", "spindle_accel", "body_accel"]),
                            st.lists(st.sampled_from(_NAMES), min_size=1, max_size=5)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    rows = []
    times = _uniform_times(n, fs)
    for i in range(n):
        row = [times[i] if h in ("time", "t") else repr(float(rng.standard_normal())) for h in header]
        rows.append(row)
    for _ in range(draw(st.integers(0, 3))):   # damage
        if not rows:
            break
        i = draw(st.integers(0, len(rows) - 1))
        what = draw(st.sampled_from(["extra", "missing", "cell", "scale"]))
        if what == "extra":
            rows[i] = rows[i] + [draw(_cells)]
        elif what == "missing" and len(rows[i]) > 1:
            rows[i] = rows[i][:-1]
        elif what == "cell":
            rows[i][draw(st.integers(0, len(rows[i]) - 1))] = draw(_cells)
        elif what == "scale":
            rows[i][-1] = "1e200"
    delim = draw(st.sampled_from([",", ";", "\t"]))
    return "\n".join(delim.join(r) for r in [header, *rows]) + "\n"


def _expected_csv(path: Path) -> dict[str, np.ndarray] | str:
    """An independent reading: the numeric columns by name, or why the table must be refused."""
    text = path.read_text()
    delim = max((",", ";", "\t"), key=lambda d: text.splitlines()[0].count(d)) if text.strip() else ","
    rows = [r for r in csv.reader(io.StringIO(text), delimiter=delim) if r and not r[0].startswith("#")]
    header, data = [h.strip() for h in rows[0]], rows[1:]
    if any(len(r) != len(header) for r in data):
        return "ragged"
    cols = {}
    for j, h in enumerate(header):
        try:
            cols[h] = np.array([float(r[j]) for r in data])
        except ValueError:
            cols[h] = None
    return cols


def _check_csv(path: Path):
    def check(rec) -> str | None:
        exp = _expected_csv(path)
        if exp == "ragged":
            return "a table with a row of the wrong width was accepted"
        for name, got in (("spindle_accel", rec.spindle_accel), ("body_accel", rec.body_accel)):
            want = exp.get(name)
            if want is None or want.size != got.size or not np.array_equal(want, got):
                return f"{name} differs from the file's column"
        if not (1e-3 <= rec.fs_hz <= 1e8) or not np.all(np.abs(rec.body_accel) <= 1e15):
            return f"accepted fs={rec.fs_hz} or huge values"
        return None
    return check


@FUZZ
@given(csv_tables())
@example("time,spindle_accel,body_accel\n0,1,2\n0.01,2,3,4\n0.02,3,1\n")      # a row with an extra cell
@example("time,spindle_accel,body_accel\n0,1,2\n1e-300,2,3\n2e-300,3,1\n")   # fs 1e300
@example("time,spindle_accel,body_accel\n0,1,2\n1e300,2,3\n2e300,3,1\n")     # fs 1e-300, ns overflow
@example("time,spindle_accel,body_accel\n0,1e200,2\n0.01,2,3\n0.02,3,1\n")   # huge values
@example("time,spindle_accel,body_accel\n0,0,0\n0.01,0,0\n0.02,0,0\n")       # all zeros
def test_csv_tables_read_right_or_fail_clearly(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("csv") / "t.csv"
    path.write_text(text)
    tally = Tally()
    outcome, value = guarded(lambda: load_record(path), limit_s=20)
    classify(tally, "csv", path, outcome, value, _check_csv(path))
    assert tally.bad == 0, tally.failures


@st.composite
def mat_files(draw) -> dict:
    n = draw(st.integers(0, 30))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    arr = st.sampled_from(["vec", "short", "long", "nan", "big", "matrix", "empty", "int", "bool", "zeros"])

    def value(kind: str):
        return {"vec": rng.standard_normal(n), "short": rng.standard_normal(max(n - 3, 0)),
                "long": rng.standard_normal(n + 2), "nan": np.full(n, np.nan), "big": np.full(n, 1e200),
                "matrix": rng.standard_normal((3, n)), "empty": np.zeros(0), "int": np.arange(n),
                "bool": np.ones(n, bool), "zeros": np.zeros(n)}[kind]

    doc = {"spindle_accel": value(draw(st.sampled_from(["vec", "vec", "vec"]) | arr)),
           "body_accel": value(draw(st.sampled_from(["vec", "vec"]) | arr))}
    fs = draw(st.sampled_from([600.0, 0.0, -1.0, 1e300, 1e-300, np.nan, None, "time", "time_short", "empty"]))
    if fs == "time":
        doc["time"] = np.arange(n) / 600.0
    elif fs == "time_short":
        doc["time"] = np.arange(max(n - 2, 0)) / 600.0
    elif fs == "empty":
        doc["fs"] = np.zeros(0)
    elif fs is not None:
        doc["fs"] = np.float64(fs)
    if draw(st.booleans()):
        doc["t0_ns"] = draw(st.sampled_from([np.float64(np.nan), np.int64(5), np.float64(1e30), np.uint64(2**63 + 5),
                                             np.zeros(2)]))
    return doc


def _check_mat(doc: dict):
    def check(rec) -> str | None:
        for name in ("spindle_accel", "body_accel"):
            want = np.asarray(doc[name], dtype=float).ravel()
            got = getattr(rec, name)
            if want.size != got.size or not np.array_equal(want, got):
                return f"{name}: {got.size} samples read, the file holds {want.size}"
        if "time" in doc and np.size(doc["time"]) != rec.n:
            return f"{np.size(doc['time'])} time values but {rec.n} samples read"
        return None
    return check


@FUZZ
@given(mat_files())
def test_mat_files_read_right_or_fail_clearly(tmp_path_factory, doc):
    path = tmp_path_factory.mktemp("mat") / "m.mat"
    scipy.io.savemat(str(path), doc)
    tally = Tally()
    outcome, value = guarded(lambda: load_record(path), limit_s=20)
    classify(tally, "mat", path, outcome, value, _check_mat(doc))
    assert tally.bad == 0, tally.failures


def test_mat_issue_cases_are_refused(tmp_path):
    n = 100
    rng = np.random.default_rng(0)
    base = {"spindle_accel": rng.standard_normal(n), "body_accel": rng.standard_normal(n)}
    cases = [({**base, "time": np.arange(n - 10) / 600.0}, r"90 time stamps for 100 samples"),
             ({**base, "fs": 600.0, "t0_ns": np.nan}, r"t0_ns.*not a time in ns"),
             ({**base, "fs": 1e300}, r"sample rate 1e\+300 Hz is outside"),
             ({**base, "fs": 1e-300}, r"sample rate 1e-300 Hz is outside")]
    for doc, msg in cases:
        path = tmp_path / "m.mat"
        scipy.io.savemat(str(path), doc)
        with pytest.raises(NifoError, match=msg) as info:
            load_record(path)
        assert names_file_and_fix(info.value, path)


# -----------------------------------------------------------------------------
# model files
# -----------------------------------------------------------------------------

_kinds = st.sampled_from(["velocity_deadzone", "clearance", "backlash", "coulomb", "bump_stop", "cubic_stiffness",
                          "warp", "knee", ""])
_scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**400, 10**400), st.floats(), st.text(max_size=8),
                     st.sampled_from([0, 0.03, -1, "0.03", "compression"]))
_values = st.recursive(_scalars, lambda inner: st.lists(inner, max_size=3) | st.dictionaries(
    st.sampled_from(["knee", "gap", "deadband", "eps", "side", "x"]), inner, max_size=3), max_leaves=8)


@st.composite
def model_docs(draw):
    def term():
        return draw(st.one_of(_kinds, st.fixed_dictionaries({"kind": _kinds, "params": _values}),
                              st.dictionaries(_kinds, _values, min_size=1, max_size=1), _values))

    doc = {}
    if draw(st.booleans()):
        doc["nifo_model"] = draw(st.sampled_from([1, 99, True, "1", 1.0]))
    if draw(st.booleans()):
        doc["nonlinearities"] = [term() for _ in range(draw(st.integers(0, 3)))] if draw(st.booleans()) else term()
    else:
        doc["steps"] = [{"name": draw(_values), "nonlinearities": [term()], "data": draw(_values)}
                        for _ in range(draw(st.integers(0, 2)))]
    if draw(st.booleans()):
        doc["settings"] = draw(st.dictionaries(st.sampled_from(["block", "overlap", "window", "band_hz",
                                                                "freq_range_hz", "other"]),
                                               st.one_of(_values, st.sampled_from([4000000000, 6144, [0.5, 200],
                                                                                   "hann", [2, 1]])), max_size=4))
    if draw(st.booleans()):
        doc[draw(st.sampled_from(["note", "extra", "suggested_by"]))] = draw(_values)
    return doc


def _check_model(spec) -> str | None:
    for t in spec.terms:
        for k, v in t.params.items():
            if isinstance(v, bool) or (isinstance(v, float) and not (math.isfinite(v) and (k == "offset" or v >= 0))):
                return f"accepted {t.kind}.{k}={v!r}"
    b = spec.settings.get("block")
    if b is not None and (isinstance(b, bool) or not 8 <= b <= 1 << 22):
        return f"accepted block={b!r}"
    return None


@FUZZ
@given(model_docs())
@example({"nifo_model": 1, "nonlinearities": [{"velocity_deadzone": {"knee": 0}}]})
@example({"nifo_model": 1, "nonlinearities": [{"velocity_deadzone": {"knee": True}}]})
@example({"nifo_model": 99, "nonlinearities": ["coulomb"]})
@example({"nonlinearities": [{"kind": "coulomb", "params": 3}]})
@example({"nonlinearities": ["coulomb"], "settings": {"block": 4000000000}})
def test_model_documents_load_right_or_fail_clearly(tmp_path_factory, doc):
    path = tmp_path_factory.mktemp("model") / "m.yaml"
    path.write_text(yaml.safe_dump(doc))
    tally = Tally()
    outcome, value = guarded(lambda: load_model_spec(path), limit_s=10)
    classify(tally, "model", path, outcome, value, _check_model)
    assert tally.bad == 0, (doc, tally.failures)


def test_model_alias_bomb_and_huge_files_are_refused_fast(tmp_path):
    bomb = "a: &a [x,x,x,x,x,x,x,x,x]\n" + "".join(
        f"{c}: &{c} [*{p},*{p},*{p},*{p},*{p},*{p},*{p},*{p},*{p}]\n" for p, c in zip("abcdefgh", "bcdefghi"))
    path = tmp_path / "bomb.yaml"
    path.write_text("nifo_model: 1\nsteps:\n  - name: *i\n" + bomb)
    outcome, err = guarded(lambda: load_model_spec(path), limit_s=5)
    assert outcome == "error" and isinstance(err, ConfigError) and "aliases" in str(err)
    path.write_text("note: " + "x" * (2 << 20))
    with pytest.raises(ConfigError, match="a model file is at most"):
        load_model_spec(path)


# -----------------------------------------------------------------------------
# output paths
# -----------------------------------------------------------------------------

_layouts = st.sampled_from(["absent", "file", "empty_dir", "result_dir", "foreign_dir", "under_file", "fifo"])
_faults = st.sampled_from([None, errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EDQUOT])


def _make(layout: str, out: Path) -> None:
    if layout == "file":
        out.write_text("keep me")
    elif layout == "empty_dir":
        out.mkdir()
    elif layout == "result_dir":
        out.mkdir()
        (out / "identify.json").write_text("{}")
    elif layout == "foreign_dir":
        out.mkdir()
        (out / "run1.mcap").write_text("user data")
    elif layout == "under_file":
        out.parent.mkdir(exist_ok=True)
    elif layout == "fifo":
        os.mkfifo(out)


@FUZZ
@given(layout=_layouts, fault=_faults, helper=st.sampled_from(["dir", "file", "run"]))
def test_output_paths_are_refused_or_written_whole(tmp_path_factory, monkeypatch, layout, fault, helper):
    root = tmp_path_factory.mktemp("out")
    out = (root / "f" / "out") if layout == "under_file" else root / "out"
    if layout == "under_file":
        (root / "f").write_text("a file")
    else:
        _make(layout, out)
    before = {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
              for p in root.rglob("*") if not p.is_fifo()}

    def write(tmp: Path) -> None:
        if fault is not None:
            raise OSError(fault, os.strerror(fault))
        if helper == "file":
            tmp.write_text("new")
        else:
            (tmp / "identify.json").write_text('{"new": 1}')

    cm = {"dir": staged_dir, "file": staged_file, "run": staged_run}[helper]
    with monkeypatch.context():
        outcome, value = guarded(lambda: _use(cm, out, write), limit_s=10)
    after = {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
             for p in root.rglob("*") if not p.is_fifo()}
    assert outcome in ("ok", "error"), (layout, fault, helper, outcome, value)
    if outcome == "error":
        assert isinstance(value, OutputError) and names_file_and_fix(value, out), value
        assert after == before, "a refused or failed write changed what was there"
    else:
        assert layout not in ("file", "foreign_dir", "under_file", "fifo") or helper == "file" and layout == "file"
        assert not any(".partial-" in k or ".old-" in k or INCOMPLETE in k for k in after), after


def _use(cm, out: Path, write) -> None:
    with cm(out) as tmp:
        write(tmp)


def test_out_naming_an_existing_file_is_refused_by_identify_and_loop(tmp_path):
    from fuzz_engine import cli

    f = tmp_path / "results.txt"
    f.write_text("keep")
    for cmd in (["identify", "nope.mcap", "--model", "m.yaml"], ["loop", "nope.mcap"], ["characterize", "x.mcap"],
                ["predict", "x.mcap", "--model", "m"]):
        code, _, err = cli([*cmd, "--out", str(f)])
        assert code == OutputError.exit_code and f.read_text() == "keep", (cmd, err)
        assert f"{f}: exists and is a regular file" in err and "Fix:" in err


def test_staged_dir_refuses_a_regular_file_before_any_work(tmp_path):
    f = tmp_path / "out"
    f.write_text("keep")
    with pytest.raises(OutputError, match=r"exists and is a regular file.*Fix: give a directory name"):
        with staged_dir(f):
            raise AssertionError("the block must not run")
    assert f.read_text() == "keep"
