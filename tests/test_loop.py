"""Closing the loop (nifo_core.loop.closing, ``nifo loop``): residual → missing effect → add → error before and after.

The project's simulator at the paper's settings (fs 600 Hz, random road; 150 s records, half the paper's 300 s,
where the claims were measured to hold on three seeds: ``SECONDS``) with 2 % sensor noise on every channel.
Each hidden effect (present in the data, absent from the declared model) must be the first one added, with its key
parameter within 25 % of the truth, and the held-out NMSE must fall. Negative controls add nothing. Simulations
and loop results are shared through one module-scoped cache (each scenario runs once).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from nifo.cli import main
from nifo.io.loader import save_record
from nifo.io.modelfile import load_model_spec
from nifo_core.kinds.describing import Term
from nifo_core.errors import ConfigError
from nifo_core.loop.closing import close_loop
from nifo_core.loop.settings import LoopSettings
from nifo_core.loop.words import NOTHING_MISSING
from nifo_core.signal.record import Record
from nifo_core.signal.integrate import IntegrationBand
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

M2 = 300.0  # QuarterCar default sprung mass [kg]


def _sf(kind: str, coef: float, **params) -> StrutForce:
    return StrutForce(Term(kind, params), coef)


# name: (strut in the data, declared terms, road RMS [m], tire lift-off)
SCENARIOS = {
    "cubic": ((_sf("cubic_stiffness", 2e8),), (), 0.0025, False),
    "coulomb": ((_sf("cubic_stiffness", 2e8), _sf("coulomb", 100.0, eps=0.005)), (Term("cubic_stiffness"),),
                0.0025, False),
    "asymmetric": ((_sf("asymmetric_damping", 700.0, side="rebound"),), (), 0.0025, False),
    "quadratic": ((_sf("quadratic_damping", 2000.0),), (), 0.0025, False),
    "bump_stop": ((_sf("bump_stop", 50e3, gap=0.008, side="compression"), _sf("coulomb", 100.0, eps=0.005)),
                  (Term("coulomb", {"eps": 0.005}),), 0.007, False),
    "knee": ((_sf("velocity_deadzone", -700.0, knee=0.03),), (), 0.0025, False),
    "linear": ((), (), 0.0025, False),
    "declared_only": ((_sf("coulomb", 100.0, eps=0.005),), (Term("coulomb", {"eps": 0.005}),), 0.0025, False),
    "lift_off": ((), (), 0.006, True),
    "two_hidden": ((_sf("coulomb", 100.0, eps=0.005), _sf("bump_stop", 50e3, gap=0.004, side="compression")), (),
                   0.0025, False),
}


#: record length [s]: 150 s, half the paper's 300 s (issue 58: half the CPU), where every assertion on the scenario
#: held on seeds 11-13 (measured 2026-12-06; key parameter / truth on 150 s, on 300 s seed 11 in brackets): cubic
#: 0.966-0.993 (1.010), Coulomb 1.044-1.050 (1.040), asymmetric 0.998-1.001 (0.998), quadratic 0.998-1.002 (1.001),
#: bump stop gap 0.973-0.983 (0.979); linear and lift-off add nothing on all three; both hidden effects found in
#: rounds 1 and 2 on all three, the stop's gap / truth 0.877-0.949 (0.905), Coulomb 1.044-1.050 (1.040). The paper's
#: 300 s where 150 s did not hold: the knee (seed 12 adds a Coulomb friction first) and the declared-only control
#: (seed 11 adds nothing but leaves nothing_missing false)
SECONDS = {**{name: 150.0 for name in SCENARIOS}, "knee": 300.0, "declared_only": 300.0}


@pytest.fixture(scope="module")
def scenario():
    cache: dict = {}

    def get(name: str):
        if name not in cache:
            strut, declared, rms, lift = SCENARIOS[name]
            cfg = SimConfig(strut=strut, tire_lift_off=lift, road=RandomRoad(rms_m=rms), duration_s=SECONDS[name],
                            fs_hz=600.0, noise=SensorNoise(relative=0.02))
            sim = simulate(cfg, rng=11)
            cache[name] = (sim, close_loop(sim.record, declared, m2_kg=M2))
        return cache[name]

    return get


# --------------------------------------------------------------------------------------------
# each hidden effect is the first one added, with its key parameter, and the held-out error falls
# --------------------------------------------------------------------------------------------
HIDDEN = {
    # name: (kind, side or None, key ('coefficient' or a parameter), truth)
    "cubic": ("cubic_stiffness", None, "coefficient", 2e8),
    "coulomb": ("coulomb", None, "coefficient", 100.0),
    "asymmetric": ("asymmetric_damping", "rebound", "coefficient", 700.0),
    "quadratic": ("quadratic_damping", None, "coefficient", 2000.0),
    "bump_stop": ("bump_stop", "compression", "gap", 0.008),
    "knee": ("velocity_deadzone", None, "knee", 0.03),
}


@pytest.mark.parametrize("name", list(HIDDEN))
def test_a_hidden_effect_is_the_first_added_with_its_key_parameter_and_the_heldout_error_falls(scenario, name):
    _, res = scenario(name)
    kind, side, key, truth = HIDDEN[name]
    assert res.added, res.report()
    first = res.added[0]
    assert first.kind == kind, res.report()
    if side is not None:
        assert first.term.params["side"] == side
    value = first.coefficient if key == "coefficient" else first.term.params[key]
    assert value == pytest.approx(truth, rel=0.25), res.report()
    r1 = res.rounds[0]
    # one metric on both sides: the held-out PREDICTION error falls, and so does the equation error
    assert r1.before.prediction_nmse_pct is not None and r1.after.prediction_nmse_pct is not None
    assert r1.after.prediction_nmse_pct < r1.before.prediction_nmse_pct
    assert r1.after.equation_nmse_pct < r1.before.equation_nmse_pct
    assert res.final.prediction_nmse_pct < res.initial.prediction_nmse_pct
    assert r1.added.candidate.p_value < 1e-3 and r1.added.accepted
    assert "Round 1: added" in res.report()


def test_the_declared_terms_are_kept_and_the_hidden_one_is_added_after_them(scenario):
    _, res = scenario("bump_stop")
    assert res.terms[0].kind == "coulomb" and res.terms[1].kind == "bump_stop"
    assert len(res.declared) == 1


# --------------------------------------------------------------------------------------------
# negative controls
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["linear", "declared_only"])
def test_nothing_undeclared_adds_nothing_and_says_so(scenario, name):
    _, res = scenario(name)
    assert res.added == (), res.report()
    assert res.nothing_missing
    assert NOTHING_MISSING in res.report()
    assert [t.kind for t in res.terms] == [t.kind for t in res.declared]


def test_tire_lift_off_is_not_blamed_on_the_strut(scenario):
    sim, res = scenario("lift_off")
    assert sim.truth.lift_off_fraction > 0.005  # the wheel does leave the road
    assert res.added == (), res.report()
    assert res.nothing_missing


# --------------------------------------------------------------------------------------------
# two hidden effects: both found, one per round
# --------------------------------------------------------------------------------------------
def test_two_hidden_effects_are_found_in_two_rounds(scenario):
    _, res = scenario("two_hidden")
    kinds = [c.kind for c in res.added]
    assert sorted(kinds[:2]) == ["bump_stop", "coulomb"], res.report()
    assert len(kinds) == 2, res.report()
    assert [r.index for r in res.rounds if r.added] == [1, 2]
    bump = res.added[kinds.index("bump_stop")]
    assert bump.term.params["gap"] == pytest.approx(0.004, rel=0.25)
    assert res.added[kinds.index("coulomb")].coefficient == pytest.approx(100.0, rel=0.25)
    nm = [res.initial.prediction_nmse_pct] + [r.after.prediction_nmse_pct for r in res.rounds if r.added]
    assert nm[0] > nm[1] > nm[2]


# --------------------------------------------------------------------------------------------
# report and serialisation
# --------------------------------------------------------------------------------------------
def test_report_holds_the_errors_per_band_and_level_and_serialises(scenario):
    _, res = scenario("cubic")
    doc = json.loads(json.dumps(res.to_dict()))
    assert set(doc["errors_before"]["band_residual_db"]) == {"2-5", "5-10", "10-20", "20-30"}
    assert doc["errors_before"]["transmissibility_error_pct"][0]["error_pct"] > 0
    assert doc["effects_added"][0]["kind"] == "cubic_stiffness"
    assert doc["rounds"][0]["ranked"][0]["kind"] == "cubic_stiffness"
    ev = doc["rounds"][0]["evidence"]
    assert len(ev["bins"]) == len(ev["residual_before"]) == len(ev["residual_after"])
    # the residual bends like the missing effect before, and is flat after
    assert np.nanstd(ev["residual_after"]) < 0.5 * np.nanstd(ev["residual_before"])
    text = res.report()
    assert "held-out prediction NMSE" in text and "held-out equation error" in text
    assert "heldout_nmse_pct" not in doc["errors_before"]  # no metric that stands for another


def test_loop_settings_refuse_bad_values():
    with pytest.raises(ConfigError, match="max_rounds"):
        LoopSettings(max_rounds=0)
    with pytest.raises(ConfigError, match="fit_fraction"):
        LoopSettings(fit_fraction=0.99)
    with pytest.raises(ConfigError, match="prediction"):
        LoopSettings(prediction="magic")


def test_close_loop_refuses_no_records_and_a_bad_mass():
    with pytest.raises(ConfigError, match="m2_kg"):
        close_loop(Record(600.0, np.zeros(10), np.zeros(10)), m2_kg=-1.0)


# --------------------------------------------------------------------------------------------
# the command
# --------------------------------------------------------------------------------------------
def test_loop_command_writes_json_model_and_plots(scenario, tmp_path, capsys):
    sim, _ = scenario("cubic")
    data = save_record(tmp_path / "run.mat", sim.record)
    model = tmp_path / "declared.yaml"
    model.write_text("nifo_model: 1\nnonlinearities: []\n")
    out = tmp_path / "out"
    rc = main(["loop", str(data), "--model", str(model), "--out", str(out), "--m2", "300", "--max-rounds", "2"])
    assert rc == 0
    doc = json.loads((out / "loop.json").read_text())
    assert doc["effects_added"][0]["kind"] == "cubic_stiffness"
    assert doc["declared_model"] == []
    spec = load_model_spec(out / "refined_model.yaml")
    assert [t.kind for t in spec.terms] == ["cubic_stiffness"]
    assert yaml.safe_load((out / "refined_model.yaml").read_text())["suggested_by"].startswith("nifo loop")
    assert (out / "loop_errors.png").stat().st_size > 0 and (out / "loop_round1.png").stat().st_size > 0
    printed = capsys.readouterr().out
    assert "Round 1: added" in printed and NOTHING_MISSING in printed
    assert "model.json" in printed
    # the loop's model.json goes straight into nifo predict: no identify step in between
    rc = main(["predict", str(data), "--model", str(out / "model.json"), "--out", str(tmp_path / "pred"),
               "--no-plots"])
    assert rc == 0
    pred = json.loads((tmp_path / "pred" / "predict.json").read_text())
    rec = pred["records"][0]
    assert [t["kind"] for t in json.loads((out / "model.json").read_text())["terms"]] == ["cubic_stiffness"]
    assert rec["model"]["whole_signal"]["nmse_percent"] < rec["linear"]["whole_signal"]["nmse_percent"]


# --------------------------------------------------------------------------------------------
# short records: test engineers record 30-60 s runs
# --------------------------------------------------------------------------------------------
def _four_short_records(duration_s: float, strut=()) -> list[Record]:
    out = []
    for i, rms in enumerate((1.5e-3, 2.0e-3, 2.5e-3, 3.0e-3)):
        cfg = SimConfig(strut=strut, road=RandomRoad(rms_m=rms), duration_s=duration_s, fs_hz=600.0,
                        noise=SensorNoise(relative=0.02))
        out.append(simulate(cfg, rng=20 + i).record)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("duration_s", [60.0, 30.0])
def test_four_short_records_find_a_hidden_asymmetric_damper(duration_s):
    recs = _four_short_records(duration_s, (_sf("asymmetric_damping", 700.0, side="rebound"),))
    res = close_loop(recs, (), m2_kg=M2)
    assert [c.kind for c in res.added] == ["asymmetric_damping"], res.report()
    assert res.added[0].term.params["side"] == "rebound"
    assert res.added[0].coefficient == pytest.approx(700.0, rel=0.1)
    assert res.final.prediction_nmse_pct < 0.5 * res.initial.prediction_nmse_pct
    assert all(t > 5.0 for t in res.test_seconds)


def test_thirty_second_records_say_what_was_adapted_and_a_linear_strut_adds_nothing():
    # a band from 1 Hz (the four records together suggest 1.6 Hz, what 30 s records need: nothing would be adapted)
    res = close_loop(_four_short_records(30.0), (), m2_kg=M2, band=IntegrationBand(1.0, 200.0))
    assert res.added == (), res.report()
    text = res.report()
    assert "lower edge raised" in text and "30 s" in text  # the band adapted, and it says so
    assert "spectral block 6144 →" in text                  # and so did the averages
    assert res.band.f_lo_hz == pytest.approx(1.6, abs=0.05)


# --------------------------------------------------------------------------------------------
# what the data could not reveal: detection limits hold, confounding is named
# --------------------------------------------------------------------------------------------
def _coulomb_run(force_n: float | None, seed: int = 5):
    strut = () if force_n is None else (_sf("coulomb", force_n, eps=0.005),)
    cfg = SimConfig(strut=strut, road=RandomRoad(rms_m=0.0025), duration_s=120.0, fs_hz=600.0,
                    noise=SensorNoise(relative=0.02))
    return close_loop(simulate(cfg, rng=seed).record, (), m2_kg=M2,
                      settings=LoopSettings(max_rounds=1, kinds=("coulomb", "cubic_stiffness", "backlash")))


@pytest.mark.slow
def test_the_coulomb_detection_limit_separates_what_is_found_from_what_is_not():
    clean = _coulomb_run(None)
    assert clean.added == () and clean.nothing_missing, clean.report()
    lim = {d.term.kind: d for d in clean.detection_limits}
    assert "coulomb" in lim and "could not have been seen" in clean.report().lower()
    y = lim["coulomb"].coefficient
    assert 0 < y < 100.0, clean.report()                 # a strut's friction is tens to ~150 N
    above, below = _coulomb_run(3.0 * y, seed=6), _coulomb_run(0.3 * y, seed=7)
    assert [c.kind for c in above.added] == ["coulomb"], above.report()
    assert below.added == (), below.report()
    doc = json.loads(json.dumps(clean.to_dict()))
    assert {d["kind"] for d in doc["detection_limits"]} >= {"coulomb"}


def test_a_play_and_a_knee_are_named_as_confounded_where_nearly_all_motion_is_beyond_both():
    # a 0.05 mm play at 2.5 mm road slides nearly all the time (≈ k·z ∓ k·b/2·sign ż) and ż is far beyond a
    # 0.03 m/s knee (≈ ż ∓ v0·sign ż): beyond z and ż both are sign(ż); a lower level separates them
    from nifo_core.loop.detection import confounded_pairs
    from nifo_core.characterize.restoring import restoring_force

    cfg = SimConfig(strut=(_sf("velocity_deadzone", -700.0, knee=0.03),), road=RandomRoad(rms_m=0.0025),
                    duration_s=60.0, fs_hz=600.0, noise=SensorNoise(relative=0.02))
    rf = restoring_force(simulate(cfg, rng=3).record)
    pairs = confounded_pairs([rf], [Term("velocity_deadzone", {"knee": 0.03})],
                             [Term("backlash", {"deadband": 5e-5})])
    assert len(pairs) == 1, pairs
    c = pairs[0]
    assert abs(c.rho) >= 0.8 and c.separating_scale is not None and c.separating_scale < 1
    assert "cannot be told apart" in c.text() and "add a record at" in c.text()
