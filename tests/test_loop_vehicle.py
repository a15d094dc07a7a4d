"""`nifo loop` from the linear model, nothing declared, on a vehicle: four road levels, the paper's damper knee and a
hidden cubic spring, 2 % noise on both sensors (ISO 8608 road spectrum).

Measured (issue 25): the linear model alone predicts better with a rational linear part than with a one-mass body
(44 % against 127 % held out) — a strongly nonlinear quarter car is poorly predicted by any linear model — and the
loop used to keep that choice, drop the one-mass body's significance gates and add terms the strut does not have
(here, with the body never taken back: the cubic, a Coulomb friction in place of the knee and a 48 mm play). Once
the cubic is in, the one-mass body predicts as well (3.1 % against 3.1 %): the loop takes it back and names exactly
the two effects.
"""

from __future__ import annotations

import json

import pytest

from nifo.cli import main as nifo

LEVELS_MM = (1.0, 2.5, 4.0, 6.0)


@pytest.mark.slow
def test_loop_on_a_vehicle_names_the_cubic_and_the_knee_and_nothing_else(tmp_path):
    paths = []
    for r in LEVELS_MM:
        p = tmp_path / f"road_{r:g}.mcap"
        assert nifo(["-q", "simulate", "--out", str(p), "--preset", "paper_deadzone", "--nonlinearity",
                     "cubic_stiffness:coef=2e8", "--road-rms", str(r), "--road-spectrum", "iso8608", "--noise", "0.02",
                     "--seed", "7", "--duration", "150"]) == 0
        paths.append(str(p))
    out = tmp_path / "loop"
    assert nifo(["-q", "loop", *paths, "--out", str(out), "--no-refine"]) == 0
    doc = json.loads((out / "loop.json").read_text())
    added = [e["kind"] for e in doc["effects_added"]]
    print("added:", [e["label"] for e in doc["effects_added"]], "notes:", doc["report"].split("Note:")[1:3])
    assert sorted(added) == ["cubic_stiffness", "velocity_deadzone"], doc["report"]
    knee = next(e for e in doc["effects_added"] if e["kind"] == "velocity_deadzone")
    assert abs(knee["params"]["knee"] - 0.03) < 0.003
    assert doc["final_heldout_prediction_nmse_pct"] < 0.1 * doc["linear_heldout_prediction_nmse_pct"]


@pytest.mark.slow
def test_on_the_rational_part_the_candidate_taken_is_the_best_in_the_form_the_loop_goes_on_with(tmp_path):
    """Held-out fleet case 64 (issue 54), its four records of 273 s (at 150 s the linear choice is already the
    body): a hidden friction 27.9 N (the independent simulator's ż/√(ż² + v_s²), v_s 2.3 mm/s) beside a declared
    cubic; the linear model predicts better on the rational part, so round 1 is judged there. A damper knee at
    3 mm/s (a ramp to ±c·knee: a friction's shape) predicts better than the friction on the rational part (0.98
    against 2.23 %), but once either is in the loop goes on with the one-mass body, where the friction predicts
    better (0.013 against 0.050 %): it is the one added. Fails on cb7fa7a (the knee added)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_physics_fleet import draw_case, simulate_level

    from nifo.io.loader import save_record
    from nifo.io.modelfile import write_model_spec
    from nifo_core.kinds.describing import Term

    case = draw_case(64)
    paths = []
    for j in range(len(case.levels_mm)):
        p = tmp_path / f"level{j}.mcap"
        save_record(p, simulate_level(case, j))
        paths.append(str(p))
    model = write_model_spec(tmp_path / "declared.yaml", [Term("cubic_stiffness")])
    out = tmp_path / "loop"
    assert nifo(["-q", "loop", *paths, "--model", str(model), "--m2", f"{case.corner['m2']:.4g}", "--out", str(out),
                 "--no-refine", "--max-rounds", "1"]) == 0
    doc = json.loads((out / "loop.json").read_text())
    first = {t["candidate"]["kind"]: t for t in doc["rounds"][0]["trials"] if t["accepted"]}
    rational = {k: t["after"]["prediction_nmse_pct"] for k, t in first.items()}
    print("round 1 on the rational part:", rational, "added:", [e["label"] for e in doc["effects_added"]],
          "notes:", [n for n in doc["notes"] if "one-mass body" in n])
    # the case's point: on the rational part the knee predicts better than the friction
    assert rational["velocity_deadzone"] < rational["coulomb"]
    assert [e["kind"] for e in doc["effects_added"]] == ["coulomb"], doc["report"]
    friction = doc["effects_added"][0]
    assert abs(friction["coefficient"] / case.hidden[0].coefficient - 1) < 0.1
