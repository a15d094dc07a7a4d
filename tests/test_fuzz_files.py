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
import json
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
        header = [h.strip() for h in path.read_text().splitlines()[0].replace(";", ",").replace("\t", ",").split(",")]
        dup = [h for h in ("time", "spindle_accel", "body_accel", "tire_patch_disp") if header.count(h) > 1]
        if dup:
            return f"a table with column {dup[0]!r} twice was accepted (which one was read?)"
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
@example("time,spindle_accel,body_accel,body_accel\n0,1,2,5\n0.01,2,3,4\n0.02,3,1,2\n")   # a duplicated column
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
    fs = draw(st.sampled_from([600.0, 0.0, -1.0, 1e300, 1e-300, np.nan, None, "time", "time_short", "empty",
                               "logical", "array", "matrix11"]))
    if fs == "time":
        doc["time"] = np.arange(n) / 600.0
    elif fs == "time_short":
        doc["time"] = np.arange(max(n - 2, 0)) / 600.0
    elif fs == "empty":
        doc["fs"] = np.zeros(0)
    elif fs == "logical":              # MATLAB fs = true: read as 1 Hz before issue 26
        doc["fs"] = np.bool_(True)
    elif fs == "array":
        doc["fs"] = np.array([600.0, 600.0])
    elif fs == "matrix11":
        doc["fs"] = np.array([[600.0]])
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
        fs = doc.get("fs")
        if fs is not None and np.asarray(fs).dtype == bool:
            return f"a logical fs was read as {rec.fs_hz} Hz"
        if fs is not None and np.size(fs) != 1:
            return f"an fs of {np.size(fs)} values was read as {rec.fs_hz} Hz"
        if fs is not None and "time" not in doc and rec.fs_hz != float(np.ravel(fs)[0]):
            return f"fs {float(np.ravel(fs)[0])} stored, {rec.fs_hz} Hz read"
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
             ({**base, "fs": 1e-300}, r"sample rate 1e-300 Hz is outside"),
             ({**base, "fs": True}, r"key 'fs' is a logical \(true/false\) array, not the sample rate"),
             ({**base, "fs": np.array([600.0, 600.0])}, r"key 'fs' should hold one finite number, it holds 2")]
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


# -----------------------------------------------------------------------------
# issue 26: output folders holding foreign files, long names, tiny bands, model.json fields,
# duplicate columns, logical and array fs
# -----------------------------------------------------------------------------

#: suffixes of files people keep (and nifo's own, which prove nothing in a folder nifo did not mark)
COMMON_SUFFIXES = [".yaml", ".yml", ".txt", ".png", ".jpg", ".tex", ".bib", ".json", ".md", ".pdf", ".svg", ".csv",
                   ".tsv", ".mat", ".mcap", ".db3", ".docx", ".xlsx", ".html", ".rrd", ".npz", ".npy", ".parquet",
                   ".log", ".py", ".ipynb", ".zip", ""]
_settings_foreign = st.sampled_from(["plain", "marked_unlisted", "legacy_result", "marked_subfolder", "bag_like"])


@st.composite
def foreign_folders(draw) -> tuple[str, list[tuple[str, bytes]]]:
    """A setting (how the folder looks to nifo) and the user's files in it (relative path, content)."""
    names = draw(st.lists(st.tuples(st.sampled_from(["notes", "model", "photo", "data", "a b", ".hidden", "x" * 60]),
                                    st.sampled_from(COMMON_SUFFIXES), st.booleans()), min_size=1, max_size=4,
                          unique_by=lambda t: t[:2]))
    files = [((("sub/" if nested else "") + stem + suffix), draw(st.binary(max_size=64)))
             for stem, suffix, nested in names]
    return draw(_settings_foreign), files


def _lay_out(out: Path, setting: str, files: list[tuple[str, bytes]]) -> None:
    from nifo.io.ownership import write_marker

    out.mkdir()
    if setting == "legacy_result":   # an old nifo identify folder, plus the user's files
        (out / "identify.json").write_text('{"nifo_identify": 1, "nifo_version": "0.0.9", "figures": ["t.png"]}')
        (out / "t.png").write_bytes(b"\x89PNG")
    if setting in ("marked_unlisted", "marked_subfolder"):
        (out / "loop.json").write_text('{"nifo_version": "0.1.0"}')
        write_marker(out)            # lists loop.json only: the user's files come after
    for rel, content in files:
        where = out / "res" / rel if setting == "marked_subfolder" else out / rel
        where.parent.mkdir(parents=True, exist_ok=True)
        if setting == "marked_subfolder" and not (out / "res" / ".nifo-output").exists():
            write_marker(out / "res")
        where.write_bytes(content)
    if setting == "bag_like":
        (out / "metadata.yaml").write_text("rosbag2_bagfile_information: {custom_data: {generator: someone}}\n")


@FUZZ
@given(foreign_folders(), st.sampled_from(["dir", "run", "check", "bag"]))
@example(("plain", [("model.yaml", b"nifo_model: 1\n")]), "dir")                     # --model cfg/model.yaml --out cfg
@example(("plain", [("vehicle_setup.yaml", b"m2: 400\n")]), "run")
@example(("bag_like", [("data.mcap", b"\x89MCAP0\r\n"), ("thesis.docx", b"PK")]), "bag")   # simulate --out DIR
@example(("marked_unlisted", [("notes.txt", b"mine")]), "dir")
def test_output_folders_holding_foreign_files_are_never_replaced(tmp_path_factory, case, helper):
    """0 deleted foreign files: whatever the folder holds besides what nifo wrote, it is refused whole."""
    from nifo.io.atomic import check_output

    setting, files = case
    root = tmp_path_factory.mktemp("foreign")
    out = root / "out"
    _lay_out(out, setting, files)
    before = {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in root.rglob("*")}

    def attempt() -> None:
        if helper == "check":
            check_output(out)
        elif helper == "bag":
            with staged_file(out, kind="bag") as tmp:
                tmp.mkdir()
        else:
            with (staged_dir if helper == "dir" else staged_run)(out) as tmp:
                (tmp / "identify.json").write_text("{}")

    outcome, value = guarded(attempt, limit_s=10)
    after = {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in root.rglob("*")}
    assert outcome == "error" and isinstance(value, OutputError), (setting, files, helper, outcome, value)
    assert names_file_and_fix(value, out) and "left untouched" in str(value), value
    assert after == before, "a refused write changed the folder"


@FUZZ
@given(st.lists(st.integers(1, 400), min_size=1, max_size=3), st.sampled_from(["dir", "file", "run"]))
@example([300], "dir")
@example([300, 5], "file")
@example([230], "dir")
@example([229], "run")
def test_long_output_names_are_written_or_refused_in_one_line(tmp_path_factory, lengths, helper):
    root = tmp_path_factory.mktemp("long")
    out = root.joinpath(*("n" * k for k in lengths))
    tally = Tally()

    def write() -> None:
        with {"dir": staged_dir, "file": staged_file, "run": staged_run}[helper](out) as tmp:
            (tmp if helper == "file" else tmp / "a.json").write_text("{}")

    outcome, value = guarded(write, limit_s=10)
    fits = all(k <= 255 for k in lengths[:-1]) and lengths[-1] <= 229
    classify(tally, "long name", out, outcome, value,
             lambda _: None if fits else f"a name of {max(lengths)} characters was accepted")
    assert tally.bad == 0, tally.failures
    assert (outcome == "ok") == fits, (lengths, outcome, value)
    if outcome == "error":
        assert isinstance(value, OutputError) and "bytes long" in str(value)
        assert [p.name for p in root.iterdir()] == [], "a refused name left something behind"


@FUZZ
@given(st.floats(-320, 0.5).map(lambda e: 10.0 ** e), st.integers(100, 200_000), st.sampled_from([100.0, 600.0, 5e4]))
@example(1e-300, 36_000, 600.0)
@example(1e-9, 36_000, 600.0)
@example(1e-6, 36_000, 600.0)
@example(1e-4, 36_000, 600.0)
@example(1e-3, 36_000, 600.0)
def test_tiny_integration_bands_are_refused_before_allocation_or_integrated(f_lo, n, fs):
    """Refused (saying the lowest resolvable edge) in well under a second, or integrated with taps that fit."""
    import time
    import tracemalloc

    from nifo_core.signal.integrate import IntegrationBand, integrate, integrator_taps

    band = IntegrationBand(f_lo, min(200.0, fs / 2.5))
    a = np.sin(np.arange(n) * 0.01)
    tracemalloc.start()
    t = time.perf_counter()
    outcome, value = guarded(lambda: integrate(a, fs, band=band), limit_s=20)
    took, peak = time.perf_counter() - t, tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert outcome in ("ok", "error"), (outcome, value)
    if outcome == "error":
        assert isinstance(value, ConfigError) and ". Fix: raise the band's lower edge to at least" in str(value)
        assert "can resolve" in str(value) or "nifo designs at most" in str(value), value
        assert took < 1.0 and peak < 4 << 20, (took, peak)
    else:
        assert integrator_taps(fs, band)[0].size <= n and np.isfinite(value.displacement).all()


def _model_json(tmp: Path, kind: str) -> Path:
    """A model.json nifo wrote: a one-mass body, or a rational linear part, with a damper knee."""
    from dataclasses import replace

    from nifo.io.results import write_model
    from nifo_core.kinds.describing import make_term
    from nifo_core.predict.linear_part import LinearPart
    from nifo_core.predict.model import BodyModel, IdentifiedModel

    from nifo_core.signal.spectral import SpectralSettings

    m = IdentifiedModel.from_body(BodyModel(98.7, 4.5), [make_term({"velocity_deadzone": {"knee": 0.03}})], [-2.2],
                                  fs_hz=600.0, settings=SpectralSettings(block=64))   # 33 lines: a fast case
    if kind == "rational":
        m = replace(m, linear=LinearPart("rational", poles=np.array([-2.25 + 9.7j, -2.25 - 9.7j]),
                                         residues=np.array([-0.051j, 0.051j]), band_hz=(2.0, 30.0)))
    return write_model(tmp / "model.json", m, linear=m)


def _paths(doc, prefix=()) -> list[tuple]:
    out = []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.append((*prefix, k))
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list) and doc:
        for i in sorted({0, len(doc) - 1}):
            out.append((*prefix, i))
            out += _paths(doc[i], (*prefix, i))
    return out


_WRONG = [None, "x", "1", True, [], {}, -1.0, 0, 1e308, [None], {"re": [], "im": []}]


@FUZZ
@given(st.sampled_from(["body", "rational"]), st.integers(0, 10**6), st.sampled_from(["null", "delete", "wrong"]),
       st.integers(0, len(_WRONG) - 1))
@example("body", 0, "null", 0)
def test_model_json_fields_null_missing_or_mistyped_read_right_or_fail_clearly(tmp_path_factory, kind, pick, how,
                                                                              wrong):
    """Every field of a model.json nifo wrote, made null, removed or of another type: one line naming the file and
    the field (exit 9), or a model whose linear part can be simulated (finite poles): never a LinAlgError."""
    from nifo.io.results import read_model

    path = _model_json(tmp_path_factory.mktemp("mj"), kind)
    doc = json.loads(path.read_text())
    paths = _paths(doc)
    where = paths[pick % len(paths)]
    if kind == "body" and pick == 0 and how == "null":
        where = ("linear_part", "body", "c")   # the issue's case
    parent = doc
    for k in where[:-1]:
        parent = parent[k]
    if how == "delete":
        del parent[where[-1]]
    else:
        parent[where[-1]] = None if how == "null" else _WRONG[wrong]
    path.write_text(json.dumps(doc))
    tally = Tally()

    def usable(pair) -> str | None:
        model, _ = pair
        poles = model.linear.all_poles()
        hz = model.linear.hz(np.array([1.0, 5.0, 20.0]))
        ok = np.isfinite(poles).all() and np.isfinite(hz).all() and np.isfinite(model.c_over_m2).all()
        return None if ok else f"{'.'.join(map(str, where))} = {how}: a model with non-finite parts was accepted"

    outcome, value = guarded(lambda: read_model(path), limit_s=10)
    if outcome == "ok":   # accepted: it must be usable all the way (prediction builds from these)
        outcome, value = guarded(lambda: (usable(value), value)[::-1], limit_s=10)
        value = value[1] if outcome == "ok" else value
        classify(tally, f"model.json {where} {how}", path, "ok" if outcome == "ok" else outcome, value,
                 lambda v: v)
    else:
        classify(tally, f"model.json {where} {how}", path, outcome, value, lambda v: None)
        assert outcome != "error" or isinstance(value, ConfigError), value
    assert tally.bad == 0, tally.failures


def test_a_null_band_of_a_linear_part_reads_as_one_not_stated(tmp_path):
    """The document's schema lets ``band_hz`` of a linear part be null, as it lets either value be; the reader took
    only the values (found by the test above: ``linear_h1.linear_part.band_hz`` null ended in an error naming no field
    nor fix). Read as a missing band is: NaN, NaN."""
    from nifo.io.results import read_model

    path = _model_json(tmp_path, "rational")
    doc = json.loads(path.read_text())
    for part in (doc["linear_part"], doc["linear_h1"]["linear_part"]):
        part["band_hz"] = None
    path.write_text(json.dumps(doc))
    model, linear = read_model(path)
    for m in (model, linear):
        assert np.isnan(m.linear.band_hz).all() and np.isfinite(m.linear.all_poles()).all()


def test_a_csv_with_a_duplicated_column_is_refused_naming_it(tmp_path):
    path = tmp_path / "dup.csv"
    path.write_text("time,spindle_accel,body_accel,body_accel\n0,1,2,5\n0.01,2,3,4\n0.02,3,1,2\n")
    with pytest.raises(DataFileError, match=r"column 'body_accel' appears 2 times in the header \(columns 3, 4\)") as info:
        load_record(path)
    assert names_file_and_fix(info.value, path)


@pytest.mark.parametrize("cell,why", [("1_000", "digit-group underscores"), ('"1.5"', "quoted"),
                                      ("١٢", "digits other than 0-9"), ("n/a", "")])
def test_a_csv_cell_that_is_not_a_plain_number_names_row_and_column(tmp_path, cell, why):
    path = tmp_path / "c.csv"
    path.write_text(f"time,spindle_accel,body_accel\n0,1,2\n0.01,{cell},3\n0.02,3,1\n", encoding="utf-8")
    with pytest.raises(DataFileError, match=rf"column spindle_accel: row 3, column 2: cell .* is not a number") as info:
        load_record(path)
    assert why in str(info.value) and names_file_and_fix(info.value, path) and "write plain numbers" in str(info.value)


def test_a_latin1_csv_says_which_encoding_was_expected_and_how_to_convert(tmp_path):
    path = tmp_path / "export.csv"
    path.write_bytes("# Messung Fahrzeug Größe\ntime,spindle_accel,body_accel\n0,1,2\n0.01,2,3\n0.02,3,1\n"
                     .encode("latin-1"))
    with pytest.raises(DataFileError, match=r"not UTF-8 text .*Latin-1.*Fix: convert it, e\.g\. iconv -f latin1 "
                                            r"-t utf-8 export\.csv") as info:
        load_record(path)
    assert names_file_and_fix(info.value, path)


def test_an_unquoted_yaml_exponent_read_as_text_says_how_to_write_it(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text("nifo_model: 1\nnonlinearities: [{backlash: {deadband: 4e-4}}]\nsettings: {band_hz: [1e-1, 200]}\n")
    with pytest.raises(ConfigError, match=r"deadband='4e-4' must be a number .*was read as text.*write 4\.0e-4"):
        load_model_spec(path)
    path.write_text("nifo_model: 1\nnonlinearities: [coulomb]\nsettings: {band_hz: [1e-1, 200]}\n")
    with pytest.raises(ConfigError, match=r"settings\.band_hz\[0\].*'1e-1' was read as text.*write 1\.0e-1"):
        load_model_spec(path)


@pytest.mark.parametrize("version", ["true", "1.0", "'1'", "yes"])
def test_nifo_model_must_be_the_integer_1(tmp_path, version):
    path = tmp_path / "m.yaml"
    path.write_text(f"nifo_model: {version}\nnonlinearities: [coulomb]\n")
    with pytest.raises(ConfigError, match=r"nifo_model: must be the integer 1") as info:
        load_model_spec(path)
    assert names_file_and_fix(info.value, path)


@pytest.fixture(scope="module")
def short_record(tmp_path_factory) -> Path:
    from nifo.io.loader import save_record
    from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate

    sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=30.0, road=RandomRoad(2.5e-3)), rng=7)
    return save_record(tmp_path_factory.mktemp("rec") / "r30.mcap", sim.record)


@pytest.mark.parametrize("f_lo", ["1e-300", "1e-9", "1e-6", "1e-4", "1e-3"])
def test_tiny_bands_on_the_command_line_or_in_a_model_file_are_one_line_before_any_work(short_record, tmp_path, f_lo):
    """The issue's cases: --band 1e-300 200 (TypeError in log2), 1e-9 / 1e-6 Hz (512 TiB / 512 GiB), 1e-4 Hz
    (4 GiB after 12-27 s), 1e-3 Hz (MemoryError); and the same in settings.band_hz of a model file."""
    import time

    from fuzz_engine import cli

    model = tmp_path / "m.yaml"
    model.write_text("nifo_model: 1\nnonlinearities: [{velocity_deadzone: {knee: 0.03}}]\n")
    banded = tmp_path / "banded.yaml"
    banded.write_text(f"nifo_model: 1\nnonlinearities: [{{velocity_deadzone: {{knee: 0.03}}}}]\n"
                      f"settings: {{band_hz: [{float(f_lo):.1e}, 200.0]}}\n")   # 1.0e-300: a YAML number
    rec, out = str(short_record), str(tmp_path / "o")
    for argv in (["identify", rec, "--model", str(model), "--band", f_lo, "200", "--out", out],
                 ["loop", rec, "--model", str(model), "--band", f_lo, "200", "--out", out],
                 ["characterize", rec, "--band", f_lo, "200", "--out", out],
                 ["identify", rec, "--model", str(banded), "--out", out],
                 ["loop", rec, "--model", str(banded), "--out", out]):
        t = time.perf_counter()
        code, _, err = cli(argv)
        lines = err.strip().splitlines()
        assert code == ConfigError.exit_code and len(lines) == 1, (argv, err)
        assert "r30.mcap" in lines[0] and "the lowest edge this record length can resolve is 0.534 Hz" in lines[0]
        assert "Fix: raise the band's lower edge to at least 0.534 Hz" in lines[0], lines[0]
        assert time.perf_counter() - t < 10 and not Path(out).exists()
