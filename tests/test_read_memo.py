"""nifo.io.memo: inside ``nifo run`` (``reuse_reads``) a data file is read whole once, again when it changes.

Counted by the reads that reach the file (a real read of a real bag; the counter wraps the loader's reader).
"""

from __future__ import annotations

import numpy as np
import pytest

import nifo.io.loader as loader
from nifo.io.loader import load_record, save_record
from nifo.io.memo import BoundedMemo, reuse_reads
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate


def _sim(seconds: float, rms: float, seed: int):
    return simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=seconds, road=RandomRoad(rms)),
                    rng=seed).record


@pytest.fixture()
def reads(monkeypatch):
    got = []
    real = loader._load

    def counting(path, **kw):
        got.append(str(path))
        return real(path, **kw)

    monkeypatch.setattr(loader, "_load", counting)
    return got


def test_inside_a_job_a_file_is_read_once_and_every_step_gets_the_same_record(tmp_path, reads):
    path = save_record(tmp_path / "road.mcap", _sim(20.0, 2.5e-3, 1))
    plain = load_record(path)
    load_record(path)
    assert len(reads) == 2                          # outside, every call reads
    with reuse_reads():
        first = load_record(path)
        again = [load_record(path) for _ in range(3)]
        assert len(reads) == 3
        assert all(a is first for a in again)
        skipped = load_record(path, skip_seconds=2.0)   # other options: another read
        assert len(reads) == 4 and skipped.n < first.n
    assert np.array_equal(first.body_accel, plain.body_accel) and first.source == plain.source
    assert not first.body_accel.flags.writeable     # shared between steps: nobody can change it
    load_record(path)
    assert len(reads) == 5                          # the memo ends with its block


def test_a_file_rewritten_inside_the_job_is_read_again(tmp_path, reads):
    path = tmp_path / "road.mcap"
    save_record(path, _sim(20.0, 2.5e-3, 1))
    with reuse_reads():
        before = load_record(path)
        save_record(path, _sim(30.0, 5e-3, 9))      # the same path, another record
        after = load_record(path)
    assert len(reads) == 2 and after.n != before.n


def test_the_memo_keeps_the_most_recent_records_within_its_bytes():
    memo = BoundedMemo(max_bytes=3 * 8 * 1000, size=lambda a: a.nbytes)
    for k in range(5):
        memo.put(k, np.zeros(1000))
    assert [memo.get(k) is not None for k in range(5)] == [False, False, True, True, True]
    memo.put("huge", np.zeros(10_000))               # larger than the whole memo: not kept, nothing evicted
    assert memo.get("huge") is None and memo.get(4) is not None
