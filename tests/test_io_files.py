"""CSV and MAT files, format dispatch, the F-16 data, and ``nifo info``."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import scipy.io

from nifo.cli import main
from nifo.io.loader import detect_format, load_record, load_records, parse_columns, save_record
from nifo_core.errors import ConfigError, DataFileError, SampleRateError
from nifo_core.signal.record import Record

from conftest import REPO


def make_record(n: int = 1000, *, tire: bool = True, t0_ns: int = 0, fs: float = 600.0, seed: int = 0) -> Record:
    rng = np.random.default_rng(seed)
    return Record(fs, rng.standard_normal(n) * 3.0, rng.standard_normal(n) / 7,
                  rng.standard_normal(n) * 1e-3 if tire else None, t0_ns=t0_ns, source="test")


def assert_same(a: Record, b: Record, *, t0_tol_ns: int = 0) -> None:
    assert a.fs_hz == b.fs_hz
    assert abs(a.t0_ns - b.t0_ns) <= t0_tol_ns
    assert np.array_equal(a.spindle_accel, b.spindle_accel)
    assert np.array_equal(a.body_accel, b.body_accel)
    assert a.has_tire_patch == b.has_tire_patch
    if a.has_tire_patch:
        assert np.array_equal(a.tire_patch_disp, b.tire_patch_disp)


# --- CSV ---------------------------------------------------------------------

@pytest.mark.parametrize("tire", [True, False], ids=["tire", "no_tire"])
@pytest.mark.parametrize("fs", [600.0, 2441.40625, 512.0])
def test_csv_round_trip_is_exact(tmp_path, tire, fs):
    rec = make_record(tire=tire, fs=fs)
    path = save_record(tmp_path / "r.csv", rec)
    header = path.read_text().splitlines()[0]
    assert header == "time,spindle_accel,body_accel" + (",tire_patch_disp" if tire else "")
    back = load_record(path)
    assert_same(rec, back)
    assert back.source == "r.csv"
    assert back.meta["format"] == "csv"
    assert back.meta["columns"]["spindle_accel"] == "spindle_accel"


def test_csv_keeps_an_epoch_start_time_to_a_microsecond(tmp_path):
    rec = make_record(t0_ns=1_700_000_000_123_456_789)
    assert_same(rec, load_record(save_record(tmp_path / "r.csv", rec)), t0_tol_ns=1000)


def test_csv_other_layouts_with_column_mapping(tmp_path):
    t = np.arange(500) / 200.0
    a, b = np.sin(t), np.cos(t)
    path = tmp_path / "logger.csv"
    lines = ["# exported by some logger", "idx;t;a_body;a_wheel"]
    lines += [f"{i};{ti!r};{bi!r};{ai!r}" for i, (ti, ai, bi) in enumerate(zip(t.tolist(), a.tolist(), b.tolist()))]
    path.write_text("\n".join(lines) + "\n")
    rec = load_record(path, columns=parse_columns("time=t,spindle_accel=a_wheel,body_accel=a_body"))
    assert rec.fs_hz == 200.0 and rec.n == 500
    assert np.array_equal(rec.spindle_accel, a) and np.array_equal(rec.body_accel, b)
    assert rec.meta["columns"] == {"time": "t", "spindle_accel": "a_wheel", "body_accel": "a_body"}
    assert rec.meta["delimiter"] == ";"


def test_csv_without_time_column_takes_the_given_rate(tmp_path):
    path = tmp_path / "no_time.csv"
    path.write_text("spindle_accel,body_accel\n1,2\n3,4\n5,6\n")
    rec = load_record(path, fs_hz=100.0)
    assert rec.fs_hz == 100.0 and rec.body_accel.tolist() == [2.0, 4.0, 6.0]


def test_csv_time_column_must_agree_with_a_given_rate(tmp_path):
    path = save_record(tmp_path / "r.csv", make_record())
    assert load_record(path, fs_hz=600.0).fs_hz == 600.0
    with pytest.raises(SampleRateError, match=r"stamps give 600 Hz but the sample rate was given as 500 Hz"):
        load_record(path, fs_hz=500.0)


def test_parse_columns_accepts_aliases_and_rejects_garbage():
    assert parse_columns("t=time, spindle=a, body=b") == {"time": "time", "spindle_accel": "a", "body_accel": "b"}
    with pytest.raises(ConfigError, match="unknown column role 'speed'"):
        parse_columns("speed=v")
    with pytest.raises(ConfigError, match="cannot read --columns item 'spindle_accel'"):
        parse_columns("spindle_accel")


# --- MAT ---------------------------------------------------------------------

@pytest.mark.parametrize("tire", [True, False], ids=["tire", "no_tire"])
def test_mat_round_trip_is_exact(tmp_path, tire):
    rec = make_record(tire=tire, t0_ns=1_700_000_000_123_456_789, fs=2441.40625)
    path = save_record(tmp_path / "r.mat", rec)
    back = load_record(path)
    assert_same(rec, back)
    assert back.meta["format"] == "mat" and back.meta["columns"]["fs"] == "fs"
    keys = {k for k in scipy.io.loadmat(path) if not k.startswith("__")}
    assert keys == {"spindle_accel", "body_accel", "fs", "t0_ns", "nifo_writer"} | ({"tire_patch_disp"} if tire else set())


@pytest.mark.parametrize("layout", ["rows", "columns"])
def test_mat_key_row_syntax_picks_from_2d_arrays(tmp_path, layout):
    acc = np.random.default_rng(1).standard_normal((3, 400))
    scipy.io.savemat(tmp_path / "m.mat", {"Acc": acc if layout == "rows" else acc.T, "Fs": np.uint16(400)})
    rec = load_record(tmp_path / "m.mat", columns={"spindle_accel": "Acc[1]", "body_accel": "Acc[2]", "fs": "Fs"})
    assert rec.fs_hz == 400.0
    assert np.array_equal(rec.spindle_accel, acc[1]) and np.array_equal(rec.body_accel, acc[2])


def test_mat_rate_from_time_vector_or_number(tmp_path):
    t = np.arange(300) / 50.0
    scipy.io.savemat(tmp_path / "t.mat", {"time": t, "x1": np.sin(t), "x2": np.cos(t)})
    cols = {"spindle_accel": "x1", "body_accel": "x2"}
    assert load_record(tmp_path / "t.mat", columns=cols).fs_hz == 50.0
    scipy.io.savemat(tmp_path / "n.mat", {"x1": np.sin(t), "x2": np.cos(t)})
    assert load_record(tmp_path / "n.mat", columns=cols, fs_hz=50.0).fs_hz == 50.0
    assert load_record(tmp_path / "n.mat", columns={**cols, "fs": "50"}).fs_hz == 50.0


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["F16Data_SineSw_Level3.mat", "F16Data_FullMSine_Level1.mat"])
def test_f16_ground_vibration_data_loads_with_a_key_mapping(shared_data, name):
    path = shared_data / "f16" / name
    raw = scipy.io.loadmat(path)
    rec = load_record(path, columns=parse_columns(
        "spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"))
    assert rec.fs_hz == 400.0
    assert rec.n == raw["Acceleration"].shape[1]
    assert np.array_equal(rec.spindle_accel, raw["Acceleration"][1])
    assert np.array_equal(rec.body_accel, raw["Acceleration"][2])
    assert not rec.has_tire_patch
    assert rec.meta["columns"] == {"spindle_accel": "Acceleration[1]", "body_accel": "Acceleration[2]", "fs": "Fs"}
    # the rate may also come as a number
    assert load_record(path, columns={"spindle_accel": "Acceleration[1]", "body_accel": "Acceleration[2]"},
                       fs_hz=400.0).n == rec.n


# --- dispatch ------------------------------------------------------------------

def test_format_is_taken_from_suffix_or_content(tmp_path):
    rec = make_record(n=50, t0_ns=1_700_000_000_000_000_000)  # bags start now when t0_ns is 0
    for name, fmt in [("a.csv", "csv"), ("a.mat", "mat"), ("a.mcap", "bag"), ("bagdir", "bag")]:
        save_record(tmp_path / name, rec)
        assert detect_format(tmp_path / name) == fmt
    (tmp_path / "a.mcap").rename(tmp_path / "renamed.data")
    (tmp_path / "a.mat").rename(tmp_path / "renamed.bin")
    assert detect_format(tmp_path / "renamed.data") == "bag"
    assert detect_format(tmp_path / "renamed.bin") == "mat"
    assert_same(rec, load_record(tmp_path / "renamed.data"))


def test_save_rejects_an_unknown_suffix_and_writes_nothing(tmp_path):
    with pytest.raises(DataFileError, match=r"cannot tell the output format from the suffix '\.xlsx'"):
        save_record(tmp_path / "r.xlsx", make_record(n=10))
    assert list(tmp_path.iterdir()) == []


def test_load_records_keeps_order(tmp_path):
    recs = [make_record(n=40 + k, seed=k) for k in range(3)]
    paths = [save_record(tmp_path / f"r{k}{ext}", r) for k, (r, ext) in enumerate(zip(recs, [".csv", ".mat", ""]))]
    for want, got in zip(recs, load_records(paths)):
        if got.meta["format"] == "rosbag2":   # a bag of a record without t0_ns starts at the time of writing
            want = replace(want, t0_ns=got.t0_ns)
        assert_same(want, got)


# --- nifo info -----------------------------------------------------------------

def test_info_reports_each_file(tmp_path, capsys):
    with_tire = save_record(tmp_path / "a.mcap", make_record(n=1200))
    without = save_record(tmp_path / "b.csv", make_record(n=600, tire=False))
    assert main(["info", str(with_tire), str(without)]) == 0
    out = capsys.readouterr().out
    a, b = out.split(str(without))
    assert "rosbag2 (mcap)" in a and "spindle=/nifo/spindle/imu" in a and "600 Hz" in a
    assert "2.000 s (1200 samples)" in a and "RMS tire_patch_disp" in a and "tire patch   present" in a
    assert "format       csv" in b and "1.000 s (600 samples)" in b and "tire patch   absent" in b
    rms = np.sqrt(np.mean(make_record(n=600, tire=False).body_accel ** 2))
    assert f"RMS body_accel       {rms:.6g} m/s²" in b


def test_info_runs_as_a_process_with_options(tmp_path):
    t = np.arange(100) / 10.0
    scipy.io.savemat(tmp_path / "m.mat", {"A": np.vstack([t, np.sin(t), np.cos(t)]), "rate": 10.0})
    proc = subprocess.run([sys.executable, "-m", "nifo", "info", str(tmp_path / "m.mat"),
                           "--columns", "spindle_accel=A[1],body_accel=A[2],fs=rate", "--block", "32"],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "10 Hz" in proc.stdout and "blocks       3 of 32 samples" in proc.stdout
