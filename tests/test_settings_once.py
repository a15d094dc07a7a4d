"""One settings path: the settings are resolved once per job and once per command, and say where they came from.

``nifo run`` resolves its settings once (:func:`nifo.settings.resolve`) and hands the one
:class:`~nifo_core.settings.AnalysisSettings` to every step; a step takes them on its own records
(:func:`nifo.settings.for_records`: a level characterized alone, each file predicted), never resolving again. On
a99f355 one ``nifo run`` on the bundled sample resolved 9 times (job 1, characterize 3, identify 1, loop 1, predict 3).
Counted here by the core's one merge, :func:`nifo_core.settings.resolve_settings`, which every resolution goes through,
in the bundled sample's ``nifo --json run`` (three simulated road levels; built once for the whole test run and
counted as it runs: ``tests/test_run_cmd.py``, ``_build_pipeline``).
"""

from __future__ import annotations

import json

import pytest

import nifo.settings as settings
from nifo.cli import main
from nifo.io.loader import save_record
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate

from test_run_cmd import count_resolutions, pipeline


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    """Two road levels of the simulated quarter car (40 s each), for the single commands."""
    base = tmp_path_factory.mktemp("once")
    paths = []
    for k, rms in enumerate((1e-3, 2.5e-3)):
        sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=40.0, road=RandomRoad(rms)), rng=k + 1)
        paths.append(save_record(base / f"road{k}.mcap", sim.record))
    return base, paths


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """The sample's ``nifo --json run``: (out, resolutions counted, exit code, the human text)."""
    out, code, text = pipeline(tmp_path_factory)
    return out, int((out.parent / "resolutions").read_text()), code, text


def test_one_nifo_run_resolves_its_settings_once(job):
    out, calls, code, text = job
    assert code == 0, text[-2000:]
    assert calls == 1
    # every step wrote what it was given: the job's analysis band and blocks, in every step's own document
    band = json.loads((out / "identify" / "identify.json").read_text())["settings"]["analysis_band_hz"]
    assert json.loads((out / "characterize" / "characterize.json").read_text())["settings"]["analysis_band_hz"] == band
    assert json.loads((out / "loop" / "loop.json").read_text())["settings_chosen"]["analysis_band_hz"] == band
    assert json.loads((out / "predict" / "predict.json").read_text())["freq_range_hz"] == band


def test_a_step_of_the_job_says_the_data_chose_what_the_data_chose(job):
    """nifo run once printed "(command line)" for settings it had chosen from the data: each step now prints the
    job's choices with their true source."""
    out, _, _, text = job
    assert "(command line" not in text
    doc = json.loads((out / "loop" / "loop.json").read_text())["settings_chosen"]["choices"]
    assert {doc[k]["source"] for k in ("spectral", "analysis_band_hz", "band")} == {"data"}


@pytest.mark.parametrize("command", ["characterize", "identify", "loop", "predict"])
def test_each_single_command_resolves_its_settings_once(job, records, command, monkeypatch, tmp_path, capsys):
    out, _, code, _ = job
    assert code == 0
    _, paths = records
    data = [str(p) for p in paths]
    argv = {"characterize": ["characterize", *data],
            "identify": ["identify", *data, "--model", str(out / "characterize" / "suggested_model.yaml")],
            "loop": ["loop", *data, "--max-rounds", "1", "--no-refine"],
            "predict": ["predict", *data, "--model", str(out / "identify" / "model.json"), "--no-plots"]}[command]
    calls = count_resolutions(monkeypatch)
    assert main([*argv, "--out", str(tmp_path / command)]) == 0, capsys.readouterr().err[-2000:]
    assert calls[0] == 1


def _periodic_record(path):
    """A multisine spindle (10 periods of 2048 samples at 400 Hz, 1-40 Hz) through a linear body (1.5 Hz, 30 %
    damping), 1 % noise: the settings read a period, its transient and the excited band off it."""
    import numpy as np

    from nifo_core.signal.record import Record

    fs, p = 400.0, 2048
    rng = np.random.default_rng(3)
    f = np.fft.rfftfreq(p, 1 / fs)
    spec = np.where((f > 1.0) & (f < 40.0), np.exp(2j * np.pi * rng.random(f.size)), 0)
    w, wn, z = 2 * np.pi * f, 2 * np.pi * 1.5, 0.3
    h = (2 * z * wn * 1j * w + wn ** 2) / (wn ** 2 - w ** 2 + 2j * z * wn * w)
    scale = np.fft.irfft(spec, p).std()
    u = np.tile(np.fft.irfft(spec, p) / scale, 10) + 0.01 * rng.standard_normal(10 * p)
    y = np.tile(np.fft.irfft(spec * h, p) / scale, 10) + 0.01 * rng.standard_normal(10 * p)
    return save_record(path, Record(fs_hz=fs, spindle_accel=u, body_accel=y, source="multisine"))


def test_a_period_read_off_the_data_is_written_as_the_datas_by_the_step_that_takes_it(tmp_path, capsys):
    """On a99f355 nifo run handed the period it had read off periodic data to predict as a given value, and
    predict.json said "command line" for it (F-16 levels 1 and 3: both records)."""
    from nifo.pipeline.options import PredictOptions
    from nifo.pipeline.predict import run_predict

    path = _periodic_record(tmp_path / "multisine.csv")
    st = settings.resolve([path])
    assert st.period_samples == 2048 and st.choices["period_samples"].source == "data"
    model = tmp_path / "m.yaml"
    model.write_text("nifo_model: 1\nnonlinearities: [cubic_stiffness]\n")
    assert main(["identify", str(path), "--model", str(model), "--out", str(tmp_path / "id"), "--no-plots"]) == 0
    run_predict(PredictOptions(data=[path], model=tmp_path / "id", out=tmp_path / "p", no_plots=True), settings=st)
    written = json.loads((tmp_path / "p" / "predict.json").read_text())["records"][0]["settings"]
    assert written["period_samples"] == st.choices["period_samples"].to_dict()
    assert written["skip_periods"]["source"] == "data"


def test_a_setting_given_on_the_command_line_says_so(records, monkeypatch, tmp_path, capsys):
    """The printed source is true the other way too: what the user typed is "command line"; the rest "data"."""
    _, paths = records
    assert main(["characterize", *map(str, paths), "--freq-range", "3", "20", "--out", str(tmp_path / "c")]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((tmp_path / "c" / "characterize.json").read_text())["settings"]["choices"]
    assert doc["analysis_band_hz"]["source"] == "command line" and doc["band"]["source"] == "data"
    del printed
