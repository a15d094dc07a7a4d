"""The loop's final output-error refinement and its bump stop from the static position (issue 13).

Against simulated truth with 2 % sensor noise on every channel; every figure is printed: the
coefficient at first addition (the loop's equation-error fit), after the refinement, and the
held-out prediction NMSE of both on the loop's one metric.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from nifo.cli import main
from nifo.io.loader import save_record
from nifo.io.results import read_model
from nifo_core.kinds.describing import Term
from nifo_core.errors import ConfigError
from nifo_core.loop.closing import close_loop
from nifo_core.loop.settings import LoopSettings
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

M2 = 300.0  # QuarterCar default sprung mass [kg]
COULOMB_N, STOP_N_M, GAP_M = 30.0, 2e5, 0.008


def _sim(strut, rms_m: float, duration_s: float, rng: int):
    return simulate(SimConfig(strut=strut, road=RandomRoad(rms_m=rms_m), duration_s=duration_s, fs_hz=600.0,
                              noise=SensorNoise(relative=0.02)), rng=rng)


@pytest.fixture(scope="module")
def coulomb():
    sim = _sim((StrutForce(Term("coulomb", {"eps": 0.005}), COULOMB_N),), 0.001, 120.0, 11)
    return sim, close_loop(sim.record, (), m2_kg=M2, settings=LoopSettings(max_rounds=2))


@pytest.fixture(scope="module")
def bump():
    # a stiff stop pushes the mean position into rebound, more at the higher level (0.6 and 1.9 mm here)
    strut = (StrutForce(Term("bump_stop", {"gap": GAP_M, "side": "compression"}), STOP_N_M),)
    sims = [_sim(strut, rms, 120.0, 7 + i) for i, rms in enumerate((0.005, 0.007))]
    return sims, close_loop([s.record for s in sims], (), m2_kg=M2)


def _held_out_line(res) -> str:
    r = res.refinement
    return (f"held-out prediction NMSE {r.heldout_before_pct:.3f} % (equation-error fit) → "
            f"{r.heldout_after_pct:.3f} % (refined), {'refined' if r.kept else 'equation-error fit'} kept")


def _consistent(res) -> None:
    """The model the loop writes is the refined one exactly when its held-out prediction is not worse."""
    r = res.refinement
    assert r is not None and r.unavailable is None, res.report()
    assert r.heldout_before_pct is not None and r.heldout_after_pct is not None
    assert r.kept == (r.heldout_after_pct <= r.heldout_before_pct)
    assert ("refined" in res.model.provenance) == r.kept
    # the "before" is the loop's own final score: one metric on both sides
    assert r.heldout_before_pct == pytest.approx(res.final.prediction_nmse_pct, rel=1e-9)
    assert "Output-error refinement" in res.report() and "held-out prediction NMSE" in r.text()


def test_hidden_coulomb_friction_is_within_10_percent_at_first_addition_and_after_refinement(coulomb):
    _, res = coulomb
    assert [c.kind for c in res.added] == ["coulomb"], res.report()
    first = res.added[0].coefficient
    refined = res.refinement.parameter("coulomb coefficient")["refined_times_m2"]
    print(f"\nCoulomb {COULOMB_N:g} N hidden, 120 s at 1 mm road, 2 % noise: first addition (equation error) "
          f"{first:.2f} N ({100 * (first / COULOMB_N - 1):+.1f} %), refined {refined:.2f} N "
          f"({100 * (refined / COULOMB_N - 1):+.1f} %); {_held_out_line(res)}")
    assert first == pytest.approx(COULOMB_N, rel=0.10)
    assert refined == pytest.approx(COULOMB_N, rel=0.10)
    _consistent(res)


@pytest.mark.slow
def test_bump_stop_gap_from_static_stiffness_refined_and_nothing_spurious(bump):
    sims, res = bump
    assert [c.kind for c in res.added] == ["bump_stop"], res.report()   # no backlash or second stop
    stop = res.added[0]
    assert stop.term.params["side"] == "compression"
    gap, k_eq = stop.term.params["gap"], stop.coefficient
    ref = res.refinement
    gap_ref = ref.parameter("bump_stop.gap")["refined"]
    k_ref = ref.parameter("bump_stop coefficient")["refined_times_m2"]
    true_mean = [float(np.mean(s.truth.z)) for s in sims]
    print(f"\nbump stop {STOP_N_M:.3g} N/m beyond {1e3 * GAP_M:g} mm, 2 × 120 s at 5 and 7 mm road, 2 % noise: "
          f"gap from static {1e3 * gap:.2f} mm at first addition ({100 * (gap / GAP_M - 1):+.1f} %), refined "
          f"{1e3 * gap_ref:.2f} mm ({100 * (gap_ref / GAP_M - 1):+.1f} %); stiffness {k_eq:.4g} N/m "
          f"({100 * (k_eq / STOP_N_M - 1):+.1f} %) → refined {k_ref:.4g} N/m ({100 * (k_ref / STOP_N_M - 1):+.1f} %); "
          f"mean position from static per record {[round(-1e3 * o, 2) for o in stop.offsets]} mm "
          f"(truth {[round(1e3 * m, 2) for m in true_mean]}); {_held_out_line(res)}; "
          f"added: {[c.term.label for c in res.added]}")
    assert gap == pytest.approx(GAP_M, rel=0.10)
    assert gap_ref == pytest.approx(GAP_M, rel=0.10)
    np.testing.assert_allclose(-np.array(stop.offsets), true_mean, atol=0.3e-3)
    assert "from the static position" in res.report()
    assert json.loads(json.dumps(res.to_dict()))["effects_added"][0]["offset_per_record_m"] == list(stop.offsets)
    _consistent(res)
    assert ref.kept, res.report()                       # the refined model predicts the held-out parts better
    assert res.model.provenance["refined"]["start"] in ("nifo", "linear")
    assert k_ref == pytest.approx(STOP_N_M, rel=0.15)


@pytest.mark.slow
def test_bump_stop_stiffness_within_15_percent_at_first_addition(bump):
    # the plain equation-error fit gives 1.56e5 N/m (-22 %; noise-free -12 %: the band-limited z and the noise
    # integrated into it both pull it low); the loop removes that bias by simulating its fit
    _, res = bump
    doc = res.to_dict()
    print(f"\nbump stop {STOP_N_M:.3g} N/m at first addition: {res.added[0].coefficient:.4g} N/m "
          f"({100 * (res.added[0].coefficient / STOP_N_M - 1):+.1f} %), bias-corrected {res.bias_corrected}; "
          f"noise: {[e['text'] for e in doc['noise']]}")
    assert len(doc["noise"]) == 2 and all(e["available"] for e in doc["noise"])
    assert res.added[0].coefficient == pytest.approx(STOP_N_M, rel=0.15)


def test_refinement_can_be_switched_off_and_the_command_says_which_model_it_wrote(coulomb, tmp_path, capsys):
    # switched off through the command (loop.json holds the report close_loop writes): the same facts a close_loop
    # with LoopSettings(refine=False) of its own would show, without a third loop on these data
    sim, _ = coulomb
    short = sim.record.slice(0, int(60 * 600))
    with pytest.raises(ConfigError, match="refine_seconds"):
        LoopSettings(refine_seconds=1.0)
    data = save_record(tmp_path / "run.mat", short)
    for flags, name in (([], "on"), (["--no-refine"], "off")):
        out = tmp_path / name
        rc = main(["loop", str(data), "--out", str(out), "--m2", "300", "--max-rounds", "1",
                   "--kinds", "coulomb,cubic_stiffness", *flags])
        assert rc == 0
        doc = json.loads((out / "loop.json").read_text())
        model, _ = read_model(out)
        if name == "off":
            assert doc["refinement"] is None and "refined" not in model.provenance
            assert "Output-error refinement" not in doc["report"]
            continue
        ref = doc["refinement"]
        assert ref["parameters"][0]["name"] == "coulomb coefficient"
        assert ("refined" in model.provenance) == ref["kept"]
        assert ref["heldout_prediction_nmse_before_pct"] == pytest.approx(
            doc["errors_after"]["prediction_nmse_pct"], rel=1e-9)
        # beside the band figures, both models' held-out whole signal (all frequencies, offset included)
        assert ref["heldout_whole_signal_nmse_before_pct"] == pytest.approx(
            doc["errors_after"]["whole_signal_nmse_pct"], rel=1e-9)
        assert 0 < ref["heldout_whole_signal_nmse_after_pct"] < 100
        assert len(ref["heldout_whole_signal_nmse_after_per_record_pct"]) == 1
        assert ref["heldout_whole_signal_after_prediction"] in ("whole", "band")
        assert "whole signal (all frequencies, offset included)" in ref["text"]
        assert ref["text"] in capsys.readouterr().out


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: beside a declared damper knee (-700 N·s/m beyond 0.03 m/s) at 2.5 mm "
                   "road, Coulomb 30 N is added at 52.2 N (+74 %): beyond the knee both carry a sign(ż) part and "
                   "share it (the knee re-tuned to 0.022 m/s, the friction's eps 0.017 for 0.005); the bias "
                   "correction is refused there (it would move the knee's coefficient by -130 %: confounded); "
                   "the final equation-error fit holds 36.2 N, the refined 33.4 N. Tried (issue 28): the pair fitted "
                   "jointly by output error at first addition (knee, coefficients, k, c free; bias-corrected) lands on "
                   "another explanation that predicts as well: knee 0.056 m/s, its coefficient undetermined (±200 %), "
                   "Coulomb 60 N — at 2 % noise these data do not separate the friction from the knee's sign(ż) part")
def test_coulomb_beside_a_declared_knee_is_within_10_percent_at_first_addition():
    knee = Term("velocity_deadzone", {"knee": 0.03})
    sim = _sim((StrutForce(knee, -700.0), StrutForce(Term("coulomb", {"eps": 0.005}), COULOMB_N)), 0.0025, 120.0, 11)
    res = close_loop(sim.record, (knee,), m2_kg=M2, settings=LoopSettings(max_rounds=3))
    added = [c for c in res.added if c.kind == "coulomb"]
    assert added, res.report()
    ref = res.refinement.parameter("coulomb coefficient")
    print(f"\nCoulomb {COULOMB_N:g} N hidden beside a declared knee, 120 s at 2.5 mm road, 2 % noise: first addition "
          f"{added[0].coefficient:.1f} N, final equation-error fit {ref['equation_error_times_m2']:.1f} N, refined "
          f"{ref['refined_times_m2']:.1f} N; {_held_out_line(res)}")
    assert added[0].coefficient == pytest.approx(COULOMB_N, rel=0.10)


@pytest.fixture(scope="module")
def bump_beside_knee():
    # issue 13's strut: the stop beside a damper knee; the knee is declared, the stop hidden
    knee = Term("velocity_deadzone", {"knee": 0.03})
    strut = (StrutForce(knee, -700.0), StrutForce(Term("bump_stop", {"gap": GAP_M, "side": "compression"}), STOP_N_M))
    sims = [_sim(strut, rms, 120.0, 7 + i) for i, rms in enumerate((0.005, 0.007))]
    return sims, close_loop([s.record for s in sims], (knee,), m2_kg=M2)


@pytest.mark.slow
def test_bump_stop_beside_a_declared_knee_gap_from_static_and_nothing_spurious(bump_beside_knee):
    sims, res = bump_beside_knee
    assert [c.kind for c in res.added] == ["bump_stop"], res.report()
    stop, ref = res.added[0], res.refinement
    gap_ref = ref.parameter("bump_stop.gap")["refined"]
    k_ref = ref.parameter("bump_stop coefficient")["refined_times_m2"]
    knee = ref.parameter("velocity_deadzone coefficient")
    true_mean = [float(np.mean(s.truth.z)) for s in sims]
    print(f"\nbump stop {STOP_N_M:.3g} N/m beyond {1e3 * GAP_M:g} mm beside a declared knee (-700 N·s/m beyond "
          f"0.03 m/s), 2 × 120 s at 5 and 7 mm: gap from static {1e3 * stop.term.params['gap']:.2f} mm at first "
          f"addition, refined {1e3 * gap_ref:.2f} mm; stiffness {stop.coefficient:.4g} N/m "
          f"({100 * (stop.coefficient / STOP_N_M - 1):+.1f} %) → refined {k_ref:.4g} N/m "
          f"({100 * (k_ref / STOP_N_M - 1):+.1f} %); knee coefficient {knee['equation_error_times_m2']:.0f} → "
          f"{knee['refined_times_m2']:.0f} N·s/m; mean position from static {[round(-1e3 * o, 2) for o in stop.offsets]}"
          f" mm (truth {[round(1e3 * m, 2) for m in true_mean]}); {_held_out_line(res)}")
    assert stop.term.params["gap"] == pytest.approx(GAP_M, rel=0.10)
    assert gap_ref == pytest.approx(GAP_M, rel=0.10)
    np.testing.assert_allclose(-np.array(stop.offsets), true_mean, atol=0.4e-3)
    _consistent(res)
    # at 5 and 7 mm nearly all motion is beyond the knee: the knee's coefficient and C2 share their signature there
    # (each refined ± 1.8-2.0 kN·s/m, 95 %), what the data determine is the damping beyond the knee, C2 + c_knee
    # (1400 - 700 N·s/m). Measured: -690 and C2 1406 N·s/m with the spindle's raw mean in the simulation, -628 and
    # 1345 N·s/m with it removed (a bias must not deflect the strut): 716 and 717 N·s/m beyond the knee.
    c2 = ref.parameter("c = C2/M2")["refined_times_m2"]
    print(f"damping beyond the knee C2 + c_knee = {c2 + knee['refined_times_m2']:.0f} N·s/m (truth 700)")
    assert ref.kept and c2 + knee["refined_times_m2"] == pytest.approx(700.0, rel=0.10)
    assert abs(knee["refined_times_m2"] + 700.0) <= knee["refined_half_width_95_times_m2"]


@pytest.mark.slow
def test_bump_stop_beside_a_declared_knee_refined_stiffness_within_15_percent(bump_beside_knee):
    # the plain output-error refinement holds 1.67e5 N/m (-16.5 %, the linear stiffness +12 %): driven by the noisy
    # spindle signal it is biased; the loop removes that bias by simulating the refinement (nifo_core.predict.refine_bias),
    # the knee's parameters, which these data do not determine, held
    _, res = bump_beside_knee
    print(f"\nrefined bump stop beside the knee: {res.refinement.refinement['message']}")
    assert res.refinement.parameter("bump_stop coefficient")["refined_times_m2"] == pytest.approx(STOP_N_M, rel=0.15)
