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
