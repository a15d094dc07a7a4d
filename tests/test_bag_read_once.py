"""A bag the settings' probe read to its end is not decoded again in the same job (issue 58: work computed twice).

``nifo run`` and ``nifo loop`` choose their settings from the first 2**21 samples of each file, decoded chunk by
chunk; a recording shorter than that was decoded whole a second time when the steps loaded it. Counted by the decodes
that reach the bag reader (a real read of a real bag; the counter wraps the reader).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import nifo.io.loader as loader
from nifo import settings
from nifo.io.loader import load_record, save_record
from nifo.io.memo import reuse_reads
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate

PROBE = {"topics": None, "columns": None, "fs_hz": None, "axis": "z", "period_samples": None}


@pytest.fixture()
def decodes(monkeypatch):
    got = []
    real = loader.bag.read_bag

    def counting(path, **kw):
        got.append(str(path))
        return real(path, **kw)

    monkeypatch.setattr(loader.bag, "read_bag", counting)
    return got


def test_a_bag_probed_to_its_end_is_loaded_without_a_second_decode_and_is_the_same_record(tmp_path, decodes):
    rec = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=30.0, road=RandomRoad(2.5e-3)), rng=4).record
    path = save_record(tmp_path / "road.mcap", rec)
    plain = load_record(path)
    assert len(decodes) == 1                               # outside a job every load decodes
    with reuse_reads():
        probed, total = settings._probe_read(Path(path), PROBE)
        assert probed.n == total == plain.n
        whole = load_record(path)
        skipped = load_record(path, skip_seconds=2.0)      # another load of the same bag: no decode either
        assert len(decodes) == 1
    for name in ("spindle_accel", "body_accel"):
        assert np.array_equal(getattr(whole, name), getattr(plain, name))
    assert whole.fs_hz == plain.fs_hz and whole.source == plain.source and dict(whole.meta) == dict(plain.meta)
    assert skipped.n == plain.n - int(round(2.0 * plain.fs_hz))


def test_a_bag_longer_than_the_probe_is_decoded_whole_when_loaded(tmp_path, decodes, monkeypatch):
    rec = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=20.0, road=RandomRoad(2.5e-3)), rng=5).record
    path = save_record(tmp_path / "road.mcap", rec)
    monkeypatch.setattr(settings, "PROBE_SAMPLES", rec.n // 3)     # the probe stops before the end
    monkeypatch.setattr(settings, "PROBE_CHUNK", rec.n // 4)
    with reuse_reads():
        probed, total = settings._probe_read(Path(path), PROBE)
        assert probed.n < total
        whole = load_record(path)
        assert len(decodes) == 1 and whole.n == total


def test_a_command_on_its_own_decodes_each_bag_once(tmp_path, monkeypatch):
    """Not only ``nifo run``'s steps: every command runs inside :func:`nifo.io.memo.reuse_reads` (nifo/cli.py), so
    ``nifo identify`` decodes a bag once, by the settings' probe, and its streaming estimator takes the chunks of
    that read (before: decoded in chunks twice; ``nifo loop`` on the loop benchmark: in chunks, then whole)."""
    from nifo.cli import main

    reads = []
    chunked, whole = loader.bag.iter_bag_chunks, loader.bag.read_bag

    def counting_chunks(path, **kw):
        reads.append(("chunks", Path(path).name))
        yield from chunked(path, **kw)

    def counting_whole(path, **kw):
        reads.append(("whole", Path(path).name))
        return whole(path, **kw)

    monkeypatch.setattr(loader.bag, "iter_bag_chunks", counting_chunks)
    monkeypatch.setattr(loader.bag, "read_bag", counting_whole)
    rec = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=30.0, road=RandomRoad(2.5e-3)), rng=6).record
    path = save_record(tmp_path / "road.mcap", rec)
    model = tmp_path / "knee.yaml"
    model.write_text("nifo_model: 1\nnonlinearities:\n  - {kind: velocity_deadzone, params: {knee: 0.03}}\n")
    assert main(["-q", "identify", str(path), "--model", str(model), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    assert reads == [("chunks", "road.mcap")]
