"""nifo.settings: the data probed for the settings once per run, again when a file changes.

``nifo run``'s steps each resolve their settings from the same files; inside
:func:`nifo.io.memo.reuse_reads` (what ``nifo run`` opens) a file is read for
that once. Counted here by the files the loader opens for probing (a real
read of real records, the counter wraps the loader's chunk iterator).
"""

from __future__ import annotations

import pytest

import nifo.settings as settings
from nifo.io.loader import save_record
from nifo.io.memo import reuse_reads
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate


@pytest.fixture()
def records(tmp_path):
    paths = []
    for k, rms in enumerate((1e-3, 2.5e-3)):
        sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=20.0, road=RandomRoad(rms)), rng=k + 1)
        paths.append(save_record(tmp_path / f"road{k}.mcap", sim.record))
    return paths


@pytest.fixture()
def reads(monkeypatch):
    opened = []
    real = settings.iter_record_chunks

    def counting(path, **kw):
        opened.append(path)
        return real(path, **kw)

    monkeypatch.setattr(settings, "iter_record_chunks", counting)
    return opened


def test_inside_a_run_each_file_is_probed_once_and_the_settings_are_the_same(records, reads):
    plain = settings.resolve(records)
    assert len(reads) == 2
    settings.resolve(records)
    assert len(reads) == 4                      # outside the memo every resolve reads
    with reuse_reads():
        first = settings.resolve(records)
        again = [settings.resolve(records) for _ in range(3)]
        assert len(reads) == 6                  # once per file
    assert first == plain and all(a == plain for a in again)
    settings.resolve(records)
    assert len(reads) == 8                      # the memo ends with its block


def test_a_file_that_changes_inside_the_memo_is_probed_again(records, reads, tmp_path):
    with reuse_reads():
        before = settings.resolve([records[0]])
        sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=30.0, road=RandomRoad(5e-3)), rng=9)
        save_record(records[0], sim.record)     # the same path, another record
        after = settings.resolve([records[0]])
    assert len(reads) == 2
    assert before.excitation.band_hz != after.excitation.band_hz or before.band != after.band
