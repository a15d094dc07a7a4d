"""The identification engine (nifo_core.nifo.engine): one set-up decision, one accumulator, one push, for every
shell (CLI, fleet, node, viewer); the conditioning and usability summaries on the result."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nifo_core.errors import IllConditionedError, InputError, RecordTooShortError, SampleRateError
from nifo_core.kinds.describing import Term
from nifo_core.nifo.engine import IdentifySetup, RecordProbe, accumulate_record
from nifo_core.nifo.identify import identify_nifo
from nifo_core.signal.record import Record
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate
from nifo_core.signal.spectral import SpectralSettings

DZ = Term("velocity_deadzone", {"knee": 0.03})
SETTINGS = SpectralSettings(block=2048, window="hann", overlap=0.5)


@pytest.fixture(scope="module")
def rec() -> Record:
    return simulate(SimConfig(strut=preset("paper_deadzone"), road=RandomRoad(0.0025), duration_s=120, fs_hz=400.0),
                    rng=7).record


def _probe(**kw) -> RecordProbe:
    return RecordProbe(**{"fs_hz": 400.0, "n_samples": 40_000, **kw})


def test_the_set_up_takes_the_force_when_every_record_has_one_and_then_not_the_tire_patch():
    s = IdentifySetup.for_probes([_probe(has_force=True, has_tire_patch=True)] * 2, [DZ])
    assert s.with_force and not s.with_tire_patch and not s.spindle_fixed
    s = IdentifySetup.for_probes([_probe(has_force=True), _probe()], [DZ])
    assert not s.with_force                                   # one record without: none taken
    fixed = IdentifySetup.for_probes([_probe(has_force=True, spindle_fixed=True)], [DZ])
    assert fixed.spindle_fixed and fixed.with_force
    acc = fixed.accumulator()
    assert acc.with_force and acc.spindle_fixed and acc.cond_limit == fixed.cond_limit


def test_the_set_up_refuses_records_that_cannot_be_identified_together_naming_them():
    with pytest.raises(SampleRateError, match=r"a\.csv 400 Hz, b\.csv 500 Hz"):
        IdentifySetup.for_probes([_probe(), _probe(fs_hz=500.0)], [DZ], sources=["a.csv", "b.csv"])
    with pytest.raises(InputError, match="fixed spindle and some a measured one"):
        IdentifySetup.for_probes([_probe(has_force=True, spindle_fixed=True), _probe(has_force=True)], [DZ])
    with pytest.raises(InputError, match="force in every record, missing in \\['b'\\]"):
        IdentifySetup.for_probes([_probe(has_force=True), _probe()], [DZ], sources=["a", "b"], use_force=True)
    with pytest.raises(InputError, match="fixed spindle need their measured force"):
        IdentifySetup(fs_hz=400.0, terms=(DZ,), spectral=SETTINGS, band=None, spindle_fixed=True)


def test_the_band_is_the_shortest_records_default_and_its_error_names_that_record():
    long, short = _probe(n_samples=400_000), _probe(n_samples=40_000)
    assert IdentifySetup.for_probes([long, short], [DZ]).band == IdentifySetup.for_probes([short], [DZ]).band
    with pytest.raises(Exception) as err:
        IdentifySetup.for_probes([long, _probe(n_samples=50)], [DZ], sources=["long.mcap", "tiny.mcap"])
    assert "tiny.mcap" in str(err.value)


def test_a_record_in_chunks_with_an_offset_equals_identify_nifo_on_the_whole_record(rec):
    setup = IdentifySetup.for_probes([RecordProbe.of(rec, whole=True)], [DZ], spectral=SETTINGS)
    edges = [0, 1, 777, 5000, 5001, 23_456, rec.n]           # ragged chunks
    shifted = replace(rec, spindle_accel=rec.spindle_accel + 3.0, body_accel=rec.body_accel - 1e3)   # offsets
    seen = []
    acc, n = accumulate_record((shifted.slice(a, b) for a, b in zip(edges, edges[1:])), setup,
                               on_chunk=lambda a, c: seen.append(c.n))
    assert n == rec.n and seen == list(np.diff(edges))
    batch = identify_nifo(rec.centred(), [DZ], settings=SETTINGS)
    res = acc.result()
    assert np.allclose(res.static.c_over_m2, batch.static.c_over_m2, rtol=1e-9, atol=0)
    m = res.in_band   # the pooled T21 (the per-line free fit amplifies the offsets' float64 rounding far out of band)
    assert np.allclose(res.static.t21[m], batch.static.t21[m], rtol=1e-9, atol=0)
    with pytest.raises(RecordTooShortError, match="no samples"):
        accumulate_record(iter(()), setup, source="empty.csv")
    with pytest.raises(RecordTooShortError, match="too short for NIFO") as err:
        accumulate_record([rec.slice(0, 100)], setup, source="short.csv")
    assert "short.csv" in str(err.value)


def test_conditioning_and_usability_are_summarised_on_the_result(rec):
    res = identify_nifo(rec, [DZ], settings=SETTINGS, on_ill_conditioned="ignore")
    c = res.cond[res.in_band]
    got = res.conditioning(cond_limit=float(np.median(c)))
    assert got.median == np.median(c) and got.max == np.max(c)
    assert got.ill_fraction == pytest.approx(np.mean(c > np.median(c)))
    assert res.conditioning(cond_limit=np.inf).ill_fraction == 0.0
    res.check_usable(1e4)
    with pytest.raises(IllConditionedError, match="ill-conditioned on every line"):
        res.check_usable(float(np.min(c)) / 2)
    res.check_usable(float(np.min(c)) / 2, periodic=True)       # periodic data: the pooled fit decides


def test_the_viewer_replays_with_the_identifications_conditioning_limit_and_channels(rec):
    from nifo.viz.offline import _replay_setup

    res = identify_nifo(rec, [DZ], settings=SETTINGS)
    setup = _replay_setup(res, {"summary": {"cond_limit": 55.0}}, [rec])
    assert setup.cond_limit == 55.0 and setup.band == res.band and setup.spectral == res.settings
    assert not setup.with_force
