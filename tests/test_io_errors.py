"""Bad input: each gives its own NifoError subclass, one line naming file, channel and fix, and its exit code.

Every case checks the message (``pytest.raises(match=...)``) and the real
``nifo info FILE`` process: exit code, a single stderr line, no traceback.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from nifo.io.bag import IMU, BagTopics, TopicData, write_channels
from nifo.io.loader import load_record, save_record
from nifo_core.errors import (ConfigError, DataFileError, MissingChannelError, NifoError, NonFiniteError,
                              OutputError, RecordTooShortError, SampleRateError, TimestampError)
from nifo_core.signal.record import Record

from conftest import REPO

FS = 600.0
N = 600
SPINDLE, BODY = "/nifo/spindle/imu", "/nifo/body/imu"


def stamps(n: int = N, *, fs: float = FS, start: int = 0) -> np.ndarray:
    return 10**18 + np.rint((start + np.arange(n)) * 1e9 / fs).astype(np.int64)


def two_imus(path: Path, *, spindle=None, body=None, s_stamps=None, b_stamps=None, **kw) -> Path:
    s = np.zeros(N) if spindle is None else spindle
    b = np.zeros(N) if body is None else body
    return write_channels(path, [
        TopicData(SPINDLE, IMU, "spindle", stamps(s.size) if s_stamps is None else s_stamps, s, **kw),
        TopicData(BODY, IMU, "body", stamps(b.size) if b_stamps is None else b_stamps, b)])


def good_record(n: int = N) -> Record:
    rng = np.random.default_rng(0)
    return Record(FS, rng.standard_normal(n), rng.standard_normal(n), source="good")


def nifo_info(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "nifo", "info", *map(str, args)], capture_output=True,
                          text=True, cwd=REPO, timeout=120)


def check(path: Path, err: type[NifoError], match: str, *, cli_args=(), **load_kw) -> None:
    """``load_record`` raises ``err`` matching ``match``; ``nifo info`` exits with its code, one line."""
    with pytest.raises(err, match=match) as info:
        load_record(path, **load_kw)
    assert type(info.value) is err
    text = str(info.value)
    assert "\n" not in text and "Fix: " in text and Path(path).name in text
    proc = nifo_info(path, *cli_args)
    assert proc.returncode == err.exit_code, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("nifo info: error: ") and "Traceback" not in proc.stderr
    assert re.search(match, lines[0]), lines[0]
    assert proc.stdout == ""


# --- files that cannot be read: DataFileError (3) ------------------------------

def test_missing_path(tmp_path):
    check(tmp_path / "nope.mcap", DataFileError, r"nope\.mcap: no such file or directory\. Fix: check the path")


def test_garbage_file_with_bag_suffix(tmp_path):
    path = tmp_path / "junk.mcap"
    path.write_bytes(b"this is not a bag\n" * 20)
    check(path, DataFileError, r"junk\.mcap: cannot read the bag \(.*magic.*\); the file is damaged or truncated. "
                               r"Fix: re-copy the bag")


def test_file_of_unknown_format(tmp_path):
    path = tmp_path / "blob.bin"
    path.write_bytes(bytes(range(256)))
    check(path, DataFileError, r"blob\.bin: unknown data format\. Fix: give a rosbag2 bag")


def test_truncated_mcap_file(tmp_path):
    good = save_record(tmp_path / "good.mcap", good_record())
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    check(cut, DataFileError, r"cut\.mcap: cannot read the bag .*damaged or truncated.*mcap recover")


def test_truncated_bag_directory(tmp_path):
    bag = save_record(tmp_path / "run", good_record())
    storage = bag / "run.mcap"
    storage.write_bytes(storage.read_bytes()[:5000])
    check(bag, DataFileError, r"run(/run\.mcap)?: cannot read the bag .*damaged or truncated.*ros2 bag reindex")


def test_zero_byte_file(tmp_path):
    path = tmp_path / "empty.mcap"
    path.touch()
    check(path, DataFileError, r"empty\.mcap: the file is empty \(0 bytes\)")


def test_bag_without_messages(tmp_path):
    path = two_imus(tmp_path / "empty_bag.mcap", spindle=np.zeros(0), body=np.zeros(0))
    check(path, DataFileError, r"empty_bag\.mcap: the bag holds no messages\. Fix: record again")


def test_one_topic_without_messages(tmp_path):
    path = two_imus(tmp_path / "silent.mcap", body=np.zeros(0))
    check(path, DataFileError, rf"silent\.mcap: {BODY}: the topic holds no messages")


def test_directory_that_is_not_a_bag(tmp_path):
    (tmp_path / "photos").mkdir()
    check(tmp_path / "photos", DataFileError, r"photos: directory is not a rosbag2 bag")


# --- missing channels: MissingChannelError (4) ------------------------------------

def test_missing_topics_list_the_imu_topics_and_the_fix(tmp_path):
    path = write_channels(tmp_path / "other.mcap", [
        TopicData("/imu_a", IMU, "a", stamps(), np.zeros(N)), TopicData("/imu_b", IMU, "b", stamps(), np.zeros(N))])
    check(path, MissingChannelError,
          r"other\.mcap: spindle: no Imu topic for the spindle; Imu topics in the bag: /imu_a, /imu_b\. "
          r"Fix: name the topics, e\.g\. --topics spindle=/a,body=/b")


def test_named_topic_absent(tmp_path):
    path = two_imus(tmp_path / "b.mcap")
    check(path, MissingChannelError, r"b\.mcap: body: topic /car/body is not in the bag; Imu topics in the bag: "
                                     rf"{BODY}, {SPINDLE}",
          cli_args=("--topics", f"spindle={SPINDLE},body=/car/body"),
          topics=BagTopics(spindle=SPINDLE, body="/car/body"))


def test_csv_missing_column(tmp_path):
    path = tmp_path / "cols.csv"
    path.write_text("time,a_wheel,a_body\n0,1,2\n0.1,2,3\n")
    check(path, MissingChannelError, r"cols\.csv: spindle_accel: no column 'spindle_accel'; the header has "
                                     r"'time', 'a_wheel', 'a_body'\. Fix: .*--columns time=t,spindle_accel=")


def test_csv_without_time_or_rate(tmp_path):
    path = tmp_path / "notime.csv"
    path.write_text("spindle_accel,body_accel\n1,2\n3,4\n")
    check(path, MissingChannelError, r"notime\.csv: time: no time column 'time' and no sample rate.*--fs HZ")


def test_mat_missing_key_lists_the_keys(tmp_path):
    scipy.io.savemat(tmp_path / "f.mat", {"Acceleration": np.zeros((3, 50)), "Fs": 400})
    check(tmp_path / "f.mat", MissingChannelError,
          r"f\.mat: spindle_accel: no key 'spindle_accel'; the file holds Acceleration 3×50, Fs 1×1\. "
          r"Fix: .*spindle_accel=Acceleration\[1\]")


def test_mat_2d_array_without_row(tmp_path):
    scipy.io.savemat(tmp_path / "f.mat", {"Acceleration": np.zeros((3, 50)), "Fs": 400})
    cols = "spindle_accel=Acceleration,body_accel=Acceleration[2],fs=Fs"
    check(tmp_path / "f.mat", MissingChannelError, r"'Acceleration' is a 3×50 array, not a vector.*Acceleration\[i\]",
          cli_args=("--columns", cols), columns=dict(c.split("=") for c in cols.split(",")))


def test_mat_3d_array_says_one_experiment_per_file(tmp_path):
    """A benchmark file may hold several realisations in one 3-D key (channels × samples × experiments)."""
    scipy.io.savemat(tmp_path / "f.mat", {"Acceleration": np.zeros((3, 50, 2)), "Fs": 400})
    cols = "spindle_accel=Acceleration[1],body_accel=Acceleration[2],fs=Fs"
    check(tmp_path / "f.mat", MissingChannelError, r"'Acceleration' is a 3-D array \(shape \(3, 50, 2\)\).*"
          r"Fix: save each experiment as its own file", cli_args=("--columns", cols),
          columns=dict(c.split("=") for c in cols.split(",")))


def test_mat_without_rate(tmp_path):
    scipy.io.savemat(tmp_path / "norate.mat", {"spindle_accel": np.zeros(50), "body_accel": np.zeros(50)})
    check(tmp_path / "norate.mat", MissingChannelError, r"norate\.mat: fs: no sample rate.*--fs HZ")


# --- bad values: NonFiniteError (5) ----------------------------------------------

def test_nan_and_inf_samples_in_a_bag(tmp_path):
    body = np.zeros(N)
    body[300], body[450] = np.nan, -np.inf
    path = two_imus(tmp_path / "nan.mcap", body=body)
    check(path, NonFiniteError, rf"nan\.mcap: {BODY}: 2 of 600 samples are NaN or infinite "
                                r"\(first at t=0\.500 s, sample 300\)\. Fix: cut the record")


def test_nan_in_csv(tmp_path):
    path = tmp_path / "nan.csv"
    path.write_text("time,spindle_accel,body_accel\n0,1,2\n0.01,inf,3\n0.02,1,2\n")
    check(path, NonFiniteError, r"nan\.csv: column spindle_accel: 1 of 3 samples are NaN or infinite "
                                r"\(first at t=0\.010 s")


def test_non_numeric_csv_cell_names_row_and_column(tmp_path):
    path = tmp_path / "text.csv"
    path.write_text("time,spindle_accel,body_accel\n0,1,2\n0.1,2,3\n0.2,1,n/a\n")
    check(path, DataFileError, r"text\.csv: column body_accel: row 4, column 3: cell 'n/a' is not a number\. "
                               r"Fix: fix or delete row 4: write plain numbers")


def test_ragged_csv_row(tmp_path):
    path = tmp_path / "ragged.csv"
    path.write_text("time,spindle_accel,body_accel\n0,1,2\n0.1,2\n")
    check(path, DataFileError, r"ragged\.csv: row 3 has 2 cells but the header has 3")


def test_mat_v73_asks_for_v7(tmp_path):
    head = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    path = tmp_path / "big.mat"
    path.write_bytes(head.ljust(116, b" ") + bytes(8) + b"\x00\x02IM" + bytes(512))
    check(path, DataFileError, r"big\.mat: MATLAB v7\.3 \(HDF5\) files cannot be read\. Fix: re-save .*'-v7'")


def test_truncated_mat(tmp_path):
    good = save_record(tmp_path / "good.mat", good_record())
    cut = tmp_path / "cut.mat"
    cut.write_bytes(good.read_bytes()[:3000])
    check(cut, DataFileError, r"cut\.mat: cannot read the MAT file .*truncated or damaged")


# --- time stamps: TimestampError (6) ------------------------------------------------

def test_non_monotonic_header_stamps(tmp_path):
    st = stamps()
    swapped = st.copy()
    swapped[[100, 101]] = swapped[[101, 100]]
    # the bag's log (receive) time is in order; the sensor's own stamps are not
    path = two_imus(tmp_path / "order.mcap", s_stamps=swapped, log_ns=st)
    check(path, TimestampError, rf"order\.mcap: {SPINDLE}: time stamps are not increasing at sample 101.*"
                                r"Fix: re-record with source stamps, or sort")


def test_gapped_stamps(tmp_path):
    kept = np.delete(np.arange(N), np.arange(300, 312))
    path = two_imus(tmp_path / "gap.mcap", body=np.zeros(kept.size), b_stamps=stamps()[kept])
    check(path, TimestampError, rf"gap\.mcap: {BODY}: time stamps are not uniform: interval of 21\.667 ms "
                                r"at sample 300 .*Fix: split the record at the gap")


def test_channels_on_different_clocks(tmp_path):
    path = two_imus(tmp_path / "clocks.mcap", b_stamps=stamps() + 700_000)
    check(path, TimestampError, rf"clocks\.mcap: {SPINDLE}, {BODY}: the channels are not sampled at the same "
                                rf"instants: at t=0\.000 s {BODY} is \+0\.700 ms off {SPINDLE}.*Fix: resample")


def test_csv_time_going_backwards(tmp_path):
    path = tmp_path / "back.csv"
    path.write_text("time,spindle_accel,body_accel\n0,1,2\n0.1,2,3\n0.05,1,2\n0.3,1,2\n")
    check(path, TimestampError, r"back\.csv: column spindle_accel: time stamps are not increasing at sample 2")


# --- rates: SampleRateError (7) -------------------------------------------------------

def test_channels_at_different_rates(tmp_path):
    path = two_imus(tmp_path / "rates.mcap", body=np.zeros(N // 2), b_stamps=stamps(N // 2, fs=FS / 2))
    check(path, SampleRateError, rf"rates\.mcap: .*channels are sampled at different rates "
                                 rf"\({SPINDLE} 600\.000 Hz, {BODY} 300\.000 Hz\)\. Fix: resample")


def test_declared_rate_contradicting_the_stamps(tmp_path):
    path = save_record(tmp_path / "r.csv", good_record())
    check(path, SampleRateError, r"r\.csv: --fs: the time stamps give 600 Hz but the sample rate was given "
                                 r"as 1000 Hz", cli_args=("--fs", "1000"), fs_hz=1000.0)


# --- too short: RecordTooShortError (8) -------------------------------------------------

def test_record_too_short_for_the_spectral_block(tmp_path):
    rec = good_record(300)
    with pytest.raises(RecordTooShortError, match=r"300 samples \(0\.5 s\) is too short for Welch blocks, "
                                                  r"which needs 1024\. Fix: record longer, or choose a smaller"):
        rec.require_samples(1024, what="Welch blocks")
    rec.require_samples(300, what="Welch blocks")  # exactly enough is enough
    path = save_record(tmp_path / "short.mcap", rec)
    proc = nifo_info(path, "--block", 1024)
    assert proc.returncode == RecordTooShortError.exit_code == 8
    (line,) = proc.stderr.strip().splitlines()
    assert re.search(r"short\.mcap: 300 samples \(0\.5 s\) is too short for spectral blocks of 1024 samples", line)


def test_single_sample_cannot_give_a_rate(tmp_path):
    path = tmp_path / "one.csv"
    path.write_text("time,spindle_accel,body_accel\n0,1,2\n")
    check(path, RecordTooShortError, r"one\.csv: column spindle_accel: 1 sample\(s\): cannot tell the sample rate")


# --- options: ConfigError (9) -------------------------------------------------------------

def test_bad_topics_option(tmp_path):
    path = save_record(tmp_path / "ok.mcap", good_record(50))
    proc = nifo_info(path, "--topics", "spindle:/a")
    assert proc.returncode == ConfigError.exit_code
    assert "--topics: cannot read --topics item 'spindle:/a'" in proc.stderr
    with pytest.raises(ConfigError, match="write --topics spindle=/a,body=/b"):
        BagTopics.parse("spindle:/a")


# --- several files: every file reported, first error's code ---------------------------------

def test_info_reports_good_files_and_exits_with_the_first_error(tmp_path):
    good = save_record(tmp_path / "good.csv", good_record(60))
    proc = nifo_info(tmp_path / "missing.mcap", good, tmp_path / "also_missing.csv")
    assert proc.returncode == DataFileError.exit_code
    assert str(good) in proc.stdout and "60 samples" in proc.stdout
    assert len(proc.stderr.strip().splitlines()) == 2


# --- writing: nothing half-written -----------------------------------------------------------

def _fail_after(k: int, exc: BaseException):
    calls = {"n": 0}

    def hook(*_a, **_k):
        calls["n"] += 1
        if calls["n"] > k:
            raise exc
    return hook


@pytest.mark.parametrize("name", ["out.mcap", "outdir"])
def test_failed_bag_write_leaves_nothing(tmp_path, monkeypatch, name):
    from rosbags.rosbag2 import Writer

    real_write = Writer.write
    fail = _fail_after(500, OSError(28, "No space left on device"))

    def write(self, *a, **k):
        fail()
        return real_write(self, *a, **k)

    monkeypatch.setattr(Writer, "write", write)
    with pytest.raises(OutputError, match=r"cannot write the output \(the disk is full\)"):
        save_record(tmp_path / name, good_record())
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name,target", [("out.csv", "numpy.savetxt"), ("out.mat", "scipy.io.savemat")])
def test_failed_file_write_leaves_nothing_and_keeps_the_old_file(tmp_path, monkeypatch, name, target):
    old = save_record(tmp_path / name, good_record(50))
    before = old.read_bytes()

    def half_then_fail(file, *a, **k):
        Path(file).write_bytes(b"half")
        raise OSError(28, "No space left on device")

    module, func = target.rsplit(".", 1)
    monkeypatch.setattr(f"{module}.{func}", half_then_fail)
    with pytest.raises(OutputError, match=r"cannot write the output \(the disk is full\)"):
        save_record(tmp_path / f"new{old.suffix}", good_record())
    if old.suffix == ".mat":   # a MAT file names its writer (nifo_writer): nifo may replace its own
        with pytest.raises(OutputError, match=r"cannot write the output \(the disk is full\)"):
            save_record(old, good_record())
    else:                      # a CSV table carries no writer's mark: an existing one is never replaced
        with pytest.raises(OutputError, match=r"nifo cannot tell it wrote this file \(a CSV table"):
            save_record(old, good_record())
    assert [p.name for p in tmp_path.iterdir()] == [name]
    assert old.read_bytes() == before


def test_failed_bag_write_keeps_the_old_bag(tmp_path, monkeypatch):
    from nifo.io.bag import _write as bag_mod

    path = save_record(tmp_path / "run", good_record(40))
    real, fail = bag_mod._payloads, _fail_after(1, RuntimeError("boom"))

    def payloads(*a, **k):
        fail()
        return real(*a, **k)

    monkeypatch.setattr(bag_mod, "_payloads", payloads)
    with pytest.raises(RuntimeError, match="boom"):
        save_record(path, good_record())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert load_record(path).n == 40
