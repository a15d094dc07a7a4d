"""The fleet and the identifier node take the same settings object as every command, resolved once.

``nifo fleet`` resolves the settings of each model file once (:func:`nifo.fleet.runner.fleet_settings`, through
:func:`nifo.settings.resolve`, the precedence function of every command) and hands the
:class:`~nifo_core.settings.AnalysisSettings` to :func:`~nifo.fleet.runner.run_fleet`, whose set-ups take it as it is
(:func:`~nifo.fleet.runner.base_setups` resolves nothing). The identifier node resolves its parameters and model file
once at start-up by the same function and builds its accumulator from that object when the stream's rate is known.
On cb7fa7a the fleet resolved inside ``run_fleet`` (the caller could not give the settings, nor ``nifo fleet`` take a
settings flag), and the node resolved twice (at start-up for the blocks, again at its first block for the bands).
Counted by the core's one merge, :func:`nifo_core.settings.resolve_settings`, under both names it is called by.
"""

from __future__ import annotations

import pytest

import nifo.settings
import nifo_core.settings
from nifo_core.settings import GivenSettings

MODEL = ("nifo_model: 1\nnonlinearities:\n  - {kind: cubic_stiffness}\n"
         "settings: {block: 4096, overlap: 0.5, window: hann, freq_range_hz: [3, 25]}\n")


def _counted(monkeypatch) -> list[int]:
    calls = [0]
    real = nifo_core.settings.resolve_settings

    def counting(*args, **kw):
        calls[0] += 1
        return real(*args, **kw)

    monkeypatch.setattr(nifo.settings, "resolve_settings", counting)
    monkeypatch.setattr(nifo_core.settings, "resolve_settings", counting)
    return calls


@pytest.fixture
def entries(tmp_path):
    from nifo.fleet.manifest import BagEntry

    (tmp_path / "strut.yaml").write_text(MODEL)
    (tmp_path / "other.yaml").write_text(MODEL.replace("[3, 25]", "[2, 30]"))
    return [BagEntry(vehicle=v, corner=c, path=tmp_path / f"{v}{c}.mcap", model=tmp_path / m)
            for v, c, m in (("v1", "FL", "strut.yaml"), ("v1", "FR", "strut.yaml"), ("v2", "FL", "other.yaml"),
                            ("v2", "FL", "other.yaml"))]


def test_the_fleet_resolves_each_model_files_settings_once_and_its_set_ups_take_them_as_given(entries, monkeypatch):
    from nifo.fleet.runner import base_setups, fleet_settings

    calls = _counted(monkeypatch)
    analysis = fleet_settings(entries, given=GivenSettings(cond_limit=1e7))
    assert calls[0] == 2                      # two model files, one resolution each
    strut = analysis[entries[0].model]
    assert strut.analysis_band_hz == (3.0, 25.0) and strut.spectral.block == 4096 and strut.cond_limit == 1e7
    assert strut.source_of("analysis_band_hz") == "model file" and strut.source_of("cond_limit") == "command line"
    # the set-ups take the object handed to them, and resolve nothing themselves
    setups = base_setups(entries, analysis, opts={}, chunk_samples=2 ** 16)
    assert calls[0] == 2
    assert set(setups) == {("v1", "FL"), ("v1", "FR"), ("v2", "FL")}
    for e in entries:
        s, a = setups[e.group], analysis[e.model]
        assert (s.spectral, s.band, s.analysis_band_hz, s.cond_limit) == (a.spectral, a.band, a.analysis_band_hz,
                                                                           a.cond_limit)
    assert setups[("v2", "FL")].analysis_band_hz == (2.0, 30.0)


def test_the_fleet_refuses_a_model_file_whose_settings_it_was_not_given(entries):
    from nifo.fleet.runner import base_setups, fleet_settings
    from nifo_core.errors import ConfigError

    analysis = fleet_settings(entries[:2])
    with pytest.raises(ConfigError, match="no resolved settings"):
        base_setups(entries, analysis, opts={}, chunk_samples=2 ** 16)


def test_nifo_fleet_takes_the_settings_flags_of_every_command(tmp_path):
    """The fleet's command line has the settings flags of every command (one name each, old names as aliases),
    except the one that reads settings off the data, which the fleet never does."""
    import argparse

    from nifo.commands import fleet
    from nifo.settings import given_from_args

    p = argparse.ArgumentParser()
    fleet.add_arguments(p)
    args = p.parse_args([str(tmp_path), "--out", str(tmp_path / "o"), "--freq-range", "3", "20", "--block", "2048",
                         "--integration-band", "0.5", "80"])
    assert given_from_args(args) == GivenSettings(block=2048, analysis_band_hz=(3.0, 20.0),
                                                  integration_band_hz=(0.5, 80.0))
    with pytest.raises(SystemExit):
        p.parse_args([str(tmp_path), "--out", str(tmp_path / "o"), "--no-settings-from-data"])


@pytest.fixture
def node_context():
    rclpy = pytest.importorskip("rclpy")
    pytest.importorskip("nifo_msgs.msg")
    from nifo_nodes.launcher import claim_domain_id

    with claim_domain_id() as domain:
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        try:
            yield ctx
        finally:
            rclpy.shutdown(context=ctx)


def test_the_identifier_node_resolves_its_settings_once_and_builds_its_accumulator_from_them(node_context, tmp_path,
                                                                                           monkeypatch):
    from rclpy.parameter import Parameter

    from nifo_nodes.identifier import IdentifierNode

    (tmp_path / "strut.yaml").write_text(MODEL)
    calls = _counted(monkeypatch)
    overrides = [Parameter("model_file", value=str(tmp_path / "strut.yaml")),
                 Parameter("analysis_band_hz", value=[4.0, 20.0]), Parameter("f_hi_hz", value=90.0)]
    node = IdentifierNode(context=node_context, parameter_overrides=overrides)
    try:
        acc = node._new_nifo(600.0)           # the first block's rate is known
        assert calls[0] == 1
        from nifo_nodes.identifier import identify_setup

        st = node._settings
        # node parameter > model file > default, by the precedence function of every command
        assert st.analysis_band_hz == (4.0, 20.0) and st.source_of("analysis_band_hz") == "command line"
        assert (st.spectral.block, st.spectral.window) == (4096, "hann") and st.source_of("spectral") == "model file"
        assert st.band is None                # open until the rate is known: its default at 600 Hz, f_hi given alone
        setup = identify_setup(st, node._terms, 600.0, edges=(0.0, 90.0))
        assert (setup.band.f_lo_hz, setup.band.f_hi_hz) == (0.5, 90.0)
        assert acc.same_setup(setup.accumulator(on_ill_conditioned="ignore"))
        assert acc.cond_limit == st.cond_limit
    finally:
        node.destroy_node()


def test_the_node_and_the_fleet_build_the_same_set_up_from_the_same_settings(entries):
    """A model file identified live and in the fleet: the node's set-up and the fleet worker's (a bag of the two
    accelerations at 600 Hz, its default band) are the same object."""
    from dataclasses import replace

    from nifo.fleet.runner import base_setups, fleet_settings
    from nifo_core.signal.integrate import default_band
    from nifo_nodes.identifier import identify_setup

    analysis = fleet_settings(entries[:1])
    group = base_setups(entries[:1], analysis, opts={}, chunk_samples=2 ** 16)[entries[0].group]
    fleet = replace(group, band=default_band(600.0), with_tire_patch=False).engine(600.0)
    assert identify_setup(analysis[entries[0].model], group.terms, 600.0) == fleet


def test_the_model_files_analysis_band_reaches_the_node_when_its_parameter_is_not_given(
        node_context, tmp_path):
    # before, the node's analysis_band_hz parameter defaulted to [2, 30], which counted as given: a model file's band
    # never reached the live identification, and nothing said so (cond_limit likewise counted as given: now 0 = not)
    from rclpy.parameter import Parameter

    from nifo_nodes.identifier import IdentifierNode

    (tmp_path / "strut.yaml").write_text(MODEL)
    node = IdentifierNode(context=node_context,
                          parameter_overrides=[Parameter("model_file", value=str(tmp_path / "strut.yaml"))])
    try:
        st = node._settings
        assert st.analysis_band_hz == (3.0, 25.0) and st.source_of("analysis_band_hz") == "model file"
    finally:
        node.destroy_node()
    node = IdentifierNode(context=node_context, parameter_overrides=[])    # no model file: the defaults
    try:
        from nifo_core.defaults import DEFAULT_ANALYSIS_BAND_HZ, DEFAULT_COND_LIMIT

        assert node._settings.analysis_band_hz == tuple(DEFAULT_ANALYSIS_BAND_HZ)
        assert node._settings.cond_limit == DEFAULT_COND_LIMIT
    finally:
        node.destroy_node()
