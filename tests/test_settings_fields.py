"""One validator and one name per setting: the command line, a model file, the loader and the nodes refuse the same
values with the same words, and take each band under its one name (the old names read as aliases).

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
    ({"integration_band_hz": (0.0, 200.0)}, "{band_hz: [0, 200]}"),
    ({"integration_band_hz": (0.0, 200.0)}, "{integration_band_hz: [0, 200]}"),
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


def test_the_old_flags_are_aliases_of_the_settings_one_name():
    import argparse

    from nifo.settings import add_settings_arguments, given_from_args

    p = argparse.ArgumentParser()
    add_settings_arguments(p)
    old = p.parse_args(["--freq-range", "2", "20", "--band", "0.5", "60"])
    new = p.parse_args(["--analysis-band", "2", "20", "--integration-band", "0.5", "60"])
    assert vars(old) == vars(new)
    assert given_from_args(old) == GivenSettings(analysis_band_hz=(2.0, 20.0), integration_band_hz=(0.5, 60.0))


def test_a_model_file_reads_the_old_keys_as_the_settings_one_name(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text("nifo_model: 1\nnonlinearities: [coulomb]\nsettings: {band_hz: [0.5, 60], freq_range_hz: [2, 20]}\n")
    old = load_model_spec(path).settings
    path.write_text("nifo_model: 1\nnonlinearities: [coulomb]\n"
                    "settings: {integration_band_hz: [0.5, 60], analysis_band_hz: [2, 20]}\n")
    assert old == load_model_spec(path).settings == {"integration_band_hz": [0.5, 60.0], "analysis_band_hz": [2.0, 20.0]}
    assert "give it once" in _from_model_file(tmp_path, "{band_hz: [0.5, 60], integration_band_hz: [0.5, 60]}")


def test_a_node_reads_the_old_edges_as_the_integration_band():
    from nifo_nodes.common import integration_edges

    assert integration_edges({"integration_band_hz": [0.0, 0.0], "f_lo_hz": 1.0, "f_hi_hz": 80.0}) == (1.0, 80.0)
    assert integration_edges({"integration_band_hz": [1.0, 80.0], "f_lo_hz": 0.0, "f_hi_hz": 0.0}) == (1.0, 80.0)
    with pytest.raises(ConfigError, match="give it once"):
        integration_edges({"integration_band_hz": [1.0, 80.0], "f_lo_hz": 1.0, "f_hi_hz": 0.0})
