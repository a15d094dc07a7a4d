"""Issue 28: a Coulomb friction identified at 2.5 mm road predicts 0.5 mm within 1 % NMSE, noise on both sensors.

The user's commands in order (`nifo identify --refine`, then `nifo predict` on a record the model never saw:
another road level, another seed), on a simulated strut whose truth is in the model family — the paper's damper
knee (-700 N·s/m beyond 0.03 m/s) and a 30 N Coulomb friction — with 2 % white noise on the spindle and the body
accelerometers. At 0.5 mm the friction dominates the strut force (it is where the linear model is worst), so
this is the hardest extrapolation of the family: from five times the amplitude, downwards.
"""

from __future__ import annotations

import json
import warnings

import pytest

from nifo.cli import main
from nifo.io.loader import save_record
from nifo_core.kinds.describing import Term
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

KNEE = Term("velocity_deadzone", {"knee": 0.03})
COULOMB = Term("coulomb", {"eps": 0.005})


def _record(path, rms: float, seconds: float, seed: int):
    strut = (StrutForce(KNEE, -700.0), StrutForce(COULOMB, 30.0))
    sim = simulate(SimConfig(strut=strut, road=RandomRoad(rms), duration_s=seconds, fs_hz=600.0,
                             noise=SensorNoise(relative=0.02)), rng=seed)
    return save_record(path, sim.record)


def _nifo(argv) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return main([str(a) for a in argv])


@pytest.mark.slow
def test_coulomb_30_n_identified_at_2p5_mm_predicts_0p5_mm_within_one_percent(tmp_path):
    fit = _record(tmp_path / "road_2p5mm.mcap", 0.0025, 300.0, 1)
    test = _record(tmp_path / "road_0p5mm.mcap", 0.0005, 120.0, 7)
    model = tmp_path / "strut.yaml"
    model.write_text("nifo_model: 1\nnonlinearities:\n  - {kind: velocity_deadzone, params: {knee: 0.03}}\n"
                     "  - {kind: coulomb, params: {eps: 0.005}}\n")
    assert _nifo(["identify", fit, "--model", model, "--out", tmp_path / "id", "--refine", "--no-plots", "-q"]) == 0
    assert _nifo(["predict", test, "--model", tmp_path / "id" / "model.json", "--out", tmp_path / "pred",
                  "--no-plots", "-q"]) == 0
    rec = json.loads((tmp_path / "pred" / "predict.json").read_text())["records"][0]
    model_pct, linear_pct = rec["model"]["band_nmse"]["percent"], rec["linear"]["band_nmse"]["percent"]
    print(f"\nCoulomb 30 N beside the knee, identified at 2.5 mm (2 % noise on both sensors), predicting 0.5 mm "
          f"(seed 7): band NMSE {model_pct:.3f} % (± {rec['model']['parameter_bounds']['band_nmse_half_width_pct']:.3f}"
          f" %) vs linear {linear_pct:.2f} %; all frequencies {rec['model']['whole_signal']['nmse_percent']:.3f} %")
    assert model_pct < 1.0 and rec["model"]["whole_signal"]["nmse_percent"] < 1.0
    assert model_pct < 0.05 * linear_pct
