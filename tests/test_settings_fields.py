"""One validator per setting: the command line, a model file and the loader refuse the same values with the same words.

On a99f355 the copies disagreed: ``period_samples`` ≥ 8 for the settings but ≥ 1 for the loader (a period of 4
samples loaded and was cut into periods), the block limit (2^22) held for model files only, and a model file's
overlap that leaves no hop was accepted where ``--overlap`` was refused. Each value now has its rule in one place
(:class:`nifo_core.settings.GivenSettings`, :class:`nifo_core.signal.spectral.SpectralSettings`), which every
source calls.
"""

from __future__ import annotations

import pytest

from nifo.io.loader import load_record, save_record
from nifo.io.modelfile import load_model_spec
from nifo_core.errors import ConfigError
from nifo_core.settings import GivenSettings
from nifo_core.signal.spectral import MAX_BLOCK
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate


def _from_model_file(tmp_path, settings: str) -> str:
    path = tmp_path / "m.yaml"
    path.write_text(f"nifo_model: 1\nnonlinearities: [coulomb]\nsettings: {settings}\n")
    with pytest.raises(ConfigError) as err:
        load_model_spec(path)
    return err.value.message


def _given(**kw) -> str:
    with pytest.raises(ConfigError) as err:
        GivenSettings(**kw)
    return err.value.message


@pytest.mark.parametrize("given, written", [
    ({"block": MAX_BLOCK * 2}, f"{{block: {MAX_BLOCK * 2}}}"),
    ({"block": 4}, "{block: 4}"),
    ({"overlap": 0.999, "block": 8}, "{overlap: 0.999, block: 8}"),
    ({"overlap": 1.5}, "{overlap: 1.5}"),
    ({"window": "triangle"}, "{window: triangle}"),
    ({"analysis_band_hz": (30.0, 2.0)}, "{freq_range_hz: [30, 2]}"),
    ({"band_hz": (0.0, 200.0)}, "{band_hz: [0, 200]}"),
])
def test_the_command_line_and_a_model_file_refuse_a_setting_with_the_same_words(tmp_path, given, written):
    said = _given(**given)
    assert said in _from_model_file(tmp_path, written)


def test_a_block_beyond_the_limit_is_refused_on_the_command_line_too():
    with pytest.raises(ConfigError, match=f"8 to {MAX_BLOCK} samples"):
        GivenSettings(block=MAX_BLOCK + 1)
    assert GivenSettings(block=MAX_BLOCK).block == MAX_BLOCK


def test_the_loader_refuses_a_period_the_settings_refuse(tmp_path):
    sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=5.0, road=RandomRoad(1e-3)), rng=1)
    path = save_record(tmp_path / "r.csv", sim.record)
    said = _given(period_samples=4)
    with pytest.raises(ConfigError) as err:
        load_record(path, period_samples=4)
    assert err.value.message == said and err.value.source == str(path)
    with pytest.raises(ConfigError) as err:
        load_record(path, skip_seconds=-1.0)
    assert err.value.message == _given(skip_seconds=-1.0)
    assert load_record(path, period_samples=8).n == sim.record.n
