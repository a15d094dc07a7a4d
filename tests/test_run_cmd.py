"""``nifo run``: the whole job on the bundled sample produces every step's output, the report and the recording.

:func:`pipeline` runs ``nifo --json run`` on the bundled sample once per test run, as ``./nifo.sh`` does (the
three simulated road levels with their truth files), across pytest-xdist's workers too; test_cli.py,
test_figures.py, test_viz.py and test_report_browser.py read the same output.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nifo.cli import main

from conftest import built_once

#: the bundled sample's records, as the run names them
SAMPLE_RECORDS = ["road_0p5mm", "road_1mm", "road_2p5mm"]


def count_resolutions(mp: pytest.MonkeyPatch) -> list[int]:
    """From now on (until ``mp`` undoes it), how many times settings are resolved: the calls of the core's one merge,
    :func:`nifo_core.settings.resolve_settings`, as :mod:`nifo.settings` makes them (``[count]``)."""
    import nifo.settings as settings

    calls, real = [0], settings.resolve_settings

    def counting(*args, **kw):
        calls[0] += 1
        return real(*args, **kw)

    mp.setattr(settings, "resolve_settings", counting)
    return calls


def _build_pipeline(base: Path) -> None:
    """``nifo --json run`` on the bundled sample into ``base/out``: the JSON summary (stdout) goes to
    ``base/run.json``, the human text (stderr under --json) to ``base/run.txt``, the exit code to ``base/exit``, and
    how many times the run resolved its settings (the core's one merge, :func:`nifo_core.settings.resolve_settings`,
    as :mod:`nifo.settings` calls it) to ``base/resolutions`` (tests/test_settings_once.py)."""
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        calls = count_resolutions(mp)
        code = main(["--json", "run", "--out", str(base / "out")])
    (base / "run.json").write_text(out.getvalue())
    (base / "run.txt").write_text(err.getvalue())
    (base / "exit").write_text(str(code))
    (base / "resolutions").write_text(str(calls[0]))


def pipeline(tmp_path_factory) -> tuple[Path, int, str]:
    """The sample's ``nifo --json run``, built once per test run (:func:`conftest.built_once`): (out, exit code,
    the human text)."""
    base = built_once(tmp_path_factory, "sample_run", _build_pipeline)
    return base / "out", int((base / "exit").read_text()), (base / "run.txt").read_text()


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    return pipeline(tmp_path_factory)


def test_run_writes_each_step_in_its_own_directory_with_report_and_recording(ran):
    out, code, _ = ran
    assert code == 0
    for sub, doc in (("characterize", "characterize.json"), ("identify", "identify.json"),
                     ("predict", "predict.json")):
        assert (out / sub / doc).is_file(), sub
    assert (out / "report" / "report.html").stat().st_size > 50_000
    assert (out / "recording" / "nifo.rrd").stat().st_size > 10_000


def test_run_identifies_on_every_level_and_predicts_each_with_the_final_model(ran):
    out, _, _ = ran
    ident = json.loads((out / "identify" / "identify.json").read_text())
    names = [d["name"] for d in ident["data"]] if isinstance(ident["data"], list) else \
        [e["name"] for st in ident["data"]["steps"] for e in st["data"]]
    assert set(names) == set(SAMPLE_RECORDS)
    pred = json.loads((out / "predict" / "predict.json").read_text())
    assert [r["name"] for r in pred["records"]] == SAMPLE_RECORDS
    doc = json.loads((out.parent / "run.json").read_text())
    assert doc["final_model"] == str(out / "loop" / "model.json") and pred["model"] == str(out / "loop")
    # the settings were chosen once from the data and say why
    assert doc["settings"]["choices"]["analysis_band_hz"]["source"] == "data"
    for r in pred["records"]:    # the predicted signals, in the output's unit, for any metric a user prefers
        assert (out / "predict" / r["signals"][0]).is_file() and r["model"]["whole_signal"]["rms_error"] > 0


def test_the_runs_marker_lists_every_file_it_wrote_with_its_content(ran):
    """Every writer of every step claims its files in the run's marker as it writes them (nifo.io.atomic.claim): a
    file one forgot would be the user's to a later run (refused), so the whole job's folder must answer for all."""
    from nifo.io.ownership import MARKER, read_marker, unowned

    out, _, _ = ran
    assert unowned(out, limit=100) == []
    docs = [read_marker(p.parent) for p in out.rglob(MARKER)]
    assert len(docs) >= 7 and all(d["nifo_output"] == 2 and d["complete"] for d in docs)
    assert all(c is not None for d in docs for c in d["content"].values())   # every file hashed once complete


def test_run_runs_the_loop_when_it_is_part_of_the_build(ran):
    from nifo.commands.run import loop_available

    out, _, stdout = ran
    if loop_available():
        assert (out / "loop" / "loop.json").is_file()
        assert "loop" in stdout


def test_a_rounds_coefficient_is_the_final_corrected_one_or_its_plain_fit_said_so(ran):
    """The sample's loop re-tunes its play after the round that added it. That round keeps its plain fit and says so
    (no correction of its own set, issue 58); a round whose term the final model holds unchanged carries the final
    model's bias-corrected coefficient."""
    from nifo.commands.run import loop_available

    if not loop_available():
        pytest.skip("nifo loop is not part of this build")
    doc = json.loads((ran[0] / "loop" / "loop.json").read_text())
    assert doc["bias_corrected"]
    final = {c["name"]: c["value"] for c in doc["coefficients"]}
    texts = {r["round"]: r["text"] for r in doc["rounds"]}
    kinds = {t["kind"] for t in doc["refined_model"]}
    assert {"backlash", "velocity_deadzone"} <= kinds
    seen = set()
    for e in doc["effects_added"]:
        held = e["label"] in final
        assert e["coefficient_bias_corrected"] == held
        if held:
            assert e["theta_per_kg"] == final[e["label"]]
            assert "plain fit" not in texts[e["round"]]
        else:
            assert "that round's plain fit: the term is re-tuned since" in texts[e["round"]]
        seen.add(held)
    assert seen == {True, False}    # both cases on the sample: its knee kept, its play re-tuned


def test_run_prints_where_the_results_are(ran):
    out, _, stdout = ran
    assert str(out / "report" / "report.html") in stdout
    assert str(out / "recording" / "nifo.rrd") in stdout
    assert "nifo run finished in" in stdout


def test_run_without_data_and_without_a_bundled_sample_says_what_to_do(tmp_path, monkeypatch, capsys):
    import nifo.commands.run as run_cmd

    monkeypatch.setattr(run_cmd, "SAMPLE_DIR", tmp_path / "nothing")
    assert main(["run", "--out", str(tmp_path / "o")]) != 0
    assert "nifo run DATA" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_run_defaults_to_the_bundled_sample():
    from nifo.commands.run import sample_data

    assert [p.name for p in sample_data()] == ["road_0p5mm", "road_1mm", "road_2p5mm"]


def test_run_json_is_one_document_naming_every_result(ran):
    out, code, _ = ran
    doc = json.loads((out.parent / "run.json").read_text())
    assert doc["command"] == "run" and doc["ok"] is True and doc["exit_code"] == code == 0
    assert doc["report"] == str(out / "report" / "report.html")
    assert set(doc["results"]) >= {"characterize", "identify", "predict"}
    assert set(doc["timings_s"]) >= {"characterize", "identify", "report"}


# --------------------------------------------------------------------------------------------
# the bundled sample: the main job chooses the paper's two-step model from the levels
# --------------------------------------------------------------------------------------------
def sample_run_once(tmp_path_factory) -> tuple[Path, str]:
    """``nifo run`` on the bundled sample as ``./nifo.sh`` runs it (:func:`pipeline`): (out, what it printed)."""
    out, code, text = pipeline(tmp_path_factory)
    assert code == 0, text[-2000:]
    return out, text


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory):
    return sample_run_once(tmp_path_factory)


def _sample_truth() -> tuple[dict, dict]:
    from nifo.commands.run import SAMPLE_DIR

    doc = json.loads((SAMPLE_DIR / "road_2p5mm.truth.json").read_text())
    return doc["vehicle"], {s["kind"]: s for s in doc["strut"]}


def _coefficients(out: Path) -> dict:
    from nifo.io.results import read_identify

    res, _ = read_identify(out / "identify" / "identify.json")
    return res, {t.kind: float(c) * _sample_truth()[0]["m2"] for t, c in zip(res.terms, res.static.c_over_m2)}


@pytest.mark.slow
def test_the_main_job_names_the_play_from_the_low_level_and_the_knee_from_the_high_one(sample_run):
    out, stdout = sample_run
    assert "two steps" in stdout and "step 1: backlash" in stdout and "step 2: velocity_deadzone" in stdout
    res, coef = _coefficients(out)
    assert set(coef) == {"backlash", "velocity_deadzone"}
    _, strut = _sample_truth()
    play = [t for t in res.terms if t.kind == "backlash"][0]
    assert play.params["deadband"] == pytest.approx(strut["backlash"]["params"]["deadband"], rel=0.1)


@pytest.mark.slow
def test_the_main_job_gets_t21_within_2_percent_and_2_degrees_and_the_knee_within_10_percent(sample_run):
    import numpy as np

    out, _ = sample_run
    res, coef = _coefficients(out)
    v, strut = _sample_truth()
    w = 2 * np.pi * res.freq_hz
    truth = (v["k2"] + 1j * w * v["c2"]) / (-(w ** 2) * v["m2"] + v["k2"] + 1j * w * v["c2"] + v.get("k3", 0.0))
    m = (res.freq_hz >= 2) & (res.freq_hz <= 30)
    ratio = res.static.t21[m] / truth[m]
    med, ph = float(np.median(np.abs(ratio - 1))), float(np.median(np.abs(np.degrees(np.angle(ratio)))))
    print(f"sample two-step: T21 median {100 * med:.2f} %, phase median {ph:.2f} deg, coefficients {coef}")
    assert med < 0.02 and ph < 2.0
    assert coef["velocity_deadzone"] == pytest.approx(strut["velocity_deadzone"]["coefficient"], rel=0.1)


@pytest.mark.slow
def test_the_main_job_model_gets_the_play_the_knee_and_the_body_within_10_percent(sample_run):
    """model.json — what the user takes away — holds the output-error refined model (nifo_core.predict.refine):
    NIFO's step-1 play coefficient is +20 % (noise through z); refined, every parameter is close."""
    from nifo.io.results import read_model

    out, stdout = sample_run
    model, _ = read_model(out / "identify")
    v, strut = _sample_truth()
    _, nifo = _coefficients(out)
    assert "refined" in model.provenance and "output-error refinement" in stdout
    coef = {t.kind: float(c) * v["m2"] for t, c in zip(model.terms, model.c_over_m2)}
    params = {t.kind: dict(t.params) for t in model.terms}
    print(f"play: NIFO {nifo['backlash']:.4g}, refined {coef['backlash']:.4g} N/m (true "
          f"{strut['backlash']['coefficient']:.4g}); knee: NIFO {nifo['velocity_deadzone']:.4g}, refined "
          f"{coef['velocity_deadzone']:.4g} N·s/m; deadband {params['backlash']['deadband'] * 1e3:.3f} mm; "
          f"body k {model.body.k * v['m2']:.5g} N/m, c {model.body.c * v['m2']:.5g} N·s/m")
    for kind in ("backlash", "velocity_deadzone"):
        assert coef[kind] == pytest.approx(strut[kind]["coefficient"], rel=0.1), kind
    assert params["backlash"]["deadband"] == pytest.approx(strut["backlash"]["params"]["deadband"], rel=0.1)
    assert model.body.k * v["m2"] == pytest.approx(v["k2"], rel=0.05)
    assert model.body.c * v["m2"] == pytest.approx(v["c2"], rel=0.05)


@pytest.mark.slow
def test_on_the_sample_1_and_2p5_mm_records_alone_the_loop_finds_the_play_or_names_what_would_separate_it(tmp_path):
    """Issue 13: where nearly all motion is beyond the knee the play and the knee share a sign(ż) part; on the 1 +
    2.5 mm records alone (knee declared) the loop must never say plainly that nothing is missing: it adds the play
    and says how well these levels determine it and which record would pin it down."""
    from nifo.commands.run import SAMPLE_DIR

    model = tmp_path / "knee.yaml"
    model.write_text("nifo_model: 1\nnonlinearities:\n  - kind: velocity_deadzone\n    params: {knee: 0.03}\n")
    out = tmp_path / "loop"
    code = main(["loop", str(SAMPLE_DIR / "road_1mm"), str(SAMPLE_DIR / "road_2p5mm"), "--model", str(model),
                 "--out", str(out), "--m2", "300", "-q"])
    assert code == 0
    doc = json.loads((out / "loop.json").read_text())
    _, strut = _sample_truth()
    added = {e["kind"]: e for e in doc["effects_added"]}
    print(f"\nsample 1 + 2.5 mm, knee declared: added {[e['label'] for e in doc['effects_added']]}; "
          f"{doc['verdict']}")
    assert set(added) == {"backlash"} and not doc["nothing_missing"]
    assert added["backlash"]["params"]["deadband"] == pytest.approx(strut["backlash"]["params"]["deadband"], rel=0.1)
    assert added["backlash"]["coefficient"] == pytest.approx(strut["backlash"]["coefficient"], rel=0.1)
    told = [u for u in doc["undetermined"] if u["term"]["kind"] == "backlash"]
    assert told and "add a record at" in told[0]["text"] and "add a record at" in doc["verdict"]
