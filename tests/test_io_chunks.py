"""Reading records chunk by chunk (nifo.io.loader.iter_record_chunks, nifo.io.bag.iter_bag_chunks)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nifo.io.bag import IMU, TopicData, write_channels
from nifo.io.loader import iter_record_chunks, load_record, save_record
from nifo_core.errors import TimestampError
from nifo_core.signal.record import Record

SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "sample" / "road_1mm"


def test_bag_chunks_concatenate_to_the_whole_record():
    whole = load_record(SAMPLE)
    chunks = list(iter_record_chunks(SAMPLE, chunk_samples=9000))
    assert [c.meta["chunk"]["index"] for c in chunks] == list(range(len(chunks)))
    assert all(c.n == 9000 for c in chunks[:-1]) and chunks[-1].meta["chunk"]["total_samples"] == whole.n
    assert chunks[0].fs_hz == whole.fs_hz and chunks[0].t0_ns == whole.t0_ns
    for ch in ("spindle_accel", "body_accel", "tire_patch_disp"):
        np.testing.assert_array_equal(np.concatenate([getattr(c, ch) for c in chunks]), getattr(whole, ch))
    assert chunks[1].t0_ns == whole.t0_ns + round(9000 * 1e9 / whole.fs_hz)


def test_csv_chunks_are_slices_of_the_whole_file(tmp_path):
    rng = np.random.default_rng(1)
    rec = Record(100.0, rng.normal(size=1050), rng.normal(size=1050))
    save_record(tmp_path / "r.csv", rec)
    chunks = list(iter_record_chunks(tmp_path / "r.csv", chunk_samples=500))
    assert [c.n for c in chunks] == [500, 500, 50]
    np.testing.assert_allclose(np.concatenate([c.body_accel for c in chunks]), rec.body_accel)


def test_streamed_bag_with_a_gap_raises_timestamp_error(tmp_path):
    n, fs = 3000, 100.0
    stamps = np.rint(np.arange(n) * 1e9 / fs).astype(np.int64)
    stamps[2000:] += int(5e8)                                   # half a second missing
    vals = np.sin(np.arange(n) / 7.0)
    path = write_channels(tmp_path / "gap.mcap", [TopicData("/nifo/spindle/imu", IMU, "spindle", stamps, vals),
                                                  TopicData("/nifo/body/imu", IMU, "body", stamps, vals)])
    with pytest.raises(TimestampError, match="not uniform"):
        list(iter_record_chunks(path, chunk_samples=500))
