"""Several models of one record marched together (nifo_core.predict.timesim_lanes) give each model's own
simulation to the last bit: the refinement's Jacobian columns, and so the refinement itself, are unchanged. So does
one model on several records of one length (predict_records: the bias correction's synthetic records, the held-out
parts).

The lanes differ as a refinement's models do (coefficients, key parameters, the body's k and c, the absorbed
linear part); one of them diverges half-way; and where lanes cannot share a march (different kinds, feedback
paths) they are simulated one by one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nifo_core.kinds.describing import Term
from nifo_core.predict import refine as refine_mod
from nifo_core.predict.refine_space import Space
from nifo_core.predict.linear_part import BodyModel, LinearPart
from nifo_core.predict.model import (IdentifiedModel, PredictionDivergedError, predict_bodies, predict_body,
                                     predict_records)
from nifo_core.predict.timesim import simulate_response
from nifo_core.predict.timesim_lanes import simulate_responses
from nifo_core.signal.parallel import forward_jacobian
from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, StrutForce, preset, simulate

FS = 600.0
FIELDS = ("z", "zdot", "zddot", "body_accel", "force", "diverged_at")


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in FIELDS)


@pytest.fixture
def marches(monkeypatch):
    """How many lane marches ran (so that a test cannot pass by simulating one by one)."""
    from nifo_core.predict import timesim_lanes

    count = []
    real = timesim_lanes._run_lanes

    def counted(*args):
        count.append(args[2].shape[0])
        return real(*args)

    monkeypatch.setattr(timesim_lanes, "_run_lanes", counted)
    return count


@pytest.fixture(scope="module")
def drive():
    sim = simulate(SimConfig(strut=preset("all"), road=RandomRoad(0.0025), duration_s=20.0, fs_hz=FS), rng=3)
    return sim


TERM_SETS = {
    "none": [],
    "knee": [Term("velocity_deadzone", {"knee": 0.03})],
    "knee + cubic + coulomb": [Term("velocity_deadzone", {"knee": 0.03}), Term("cubic_stiffness"),
                               Term("coulomb", {"eps": 0.005})],
    "backlash + bump stop": [Term("backlash", {"deadband": 4e-4}),
                             Term("bump_stop", {"gap": 0.004, "side": "compression"})],
}
GAMMAS = {"none": [], "knee": [-2.3], "knee + cubic + coulomb": [-2.3, 6e5, 0.3],
          "backlash + bump stop": [30.0, 600.0]}


@pytest.mark.parametrize("name", list(TERM_SETS))
def test_lanes_are_each_simulation_to_the_last_bit_and_a_diverging_lane_stops_alone(drive, name, marches):
    a1 = drive.record.spindle_accel
    terms, g = TERM_SETS[name], np.array(GAMMAS[name])
    body = BodyModel(k=(2 * np.pi * 1.4) ** 2, c=2.5)
    lanes = [(LinearPart.from_body(body), g)]
    lanes.append((LinearPart.from_body(BodyModel(k=body.k * 1.001, c=body.c)), g))        # the body's k
    lanes.append((LinearPart.from_body(body, absorbed=(3.0, -0.5)), g * 1.001))           # absorbed part, γ
    lanes.append((LinearPart.from_body(BodyModel(k=body.k, c=body.c * 0.999)), g * 0.5))  # c, γ
    shifted = [Term(t.kind, {k: (v * 1.01 if isinstance(v, float) else v) for k, v in t.params.items()})
               for t in terms]                                                             # the key parameters
    term_lists = [terms, terms, terms, shifted]
    single = [simulate_response(lin, t, gg, a1, FS, spindle_accel=a1, oversample=4)
              for (lin, gg), t in zip(lanes, term_lists)]
    peak = float(np.max(np.abs(single[2].z)))
    limits = [np.inf, np.inf, 0.5 * peak, np.inf]      # lane 2 "diverges" where |z| first passes half its peak
    single[2] = simulate_response(lanes[2][0], terms, lanes[2][1], a1, FS, spindle_accel=a1, oversample=4,
                                  z_limit=limits[2])
    together = simulate_responses([lin for lin, _ in lanes], term_lists, [gg for _, gg in lanes], a1, FS,
                                  spindle_accel=a1, oversample=4, z_limits=limits)
    assert single[2].diverged_at > 0 and marches == [4]
    assert all(_same(s, t) for s, t in zip(single, together))


def test_models_that_cannot_share_a_march_are_simulated_one_by_one_with_the_same_results(drive, marches):
    a1 = drive.record.spindle_accel
    lin = LinearPart.from_body(BodyModel(k=(2 * np.pi * 1.4) ** 2, c=2.5))
    terms = [TERM_SETS["knee"], TERM_SETS["backlash + bump stop"]]      # different kinds
    gammas = [GAMMAS["knee"], GAMMAS["backlash + bump stop"]]
    together = simulate_responses([lin, lin], terms, gammas, a1, FS, spindle_accel=a1, oversample=4)
    single = [simulate_response(lin, t, g, a1, FS, spindle_accel=a1, oversample=4) for t, g in zip(terms, gammas)]
    assert all(_same(s, t) for s, t in zip(single, together)) and not marches


def test_predict_bodies_is_predict_body_of_each_and_puts_a_divergence_in_its_place(drive, marches):
    a1 = drive.record.spindle_accel
    base = IdentifiedModel.from_body(BodyModel(k=(2 * np.pi * 1.4) ** 2, c=2.5), TERM_SETS["knee + cubic + coulomb"],
                                     GAMMAS["knee + cubic + coulomb"], fs_hz=FS)
    soft = replace(base, c_over_m2=np.array([-2.3, -8e7, 0.3]))      # softening: runs away at this level
    models = [base, replace(base, c_over_m2=base.c_over_m2 * 1.001), soft]
    got = predict_bodies(models, a1, FS, label="road")
    for m, g in zip(models[:2], got[:2]):
        p = predict_body(m, a1, FS, label="road")
        assert all(np.array_equal(getattr(p, k), getattr(g, k)) for k in ("body_accel", "z", "zdot"))
        assert (p.method, p.edge_samples, p.oversample) == (g.method, g.edge_samples, g.oversample)
    with pytest.raises(PredictionDivergedError) as err:
        predict_body(soft, a1, FS, label="road")
    assert isinstance(got[2], PredictionDivergedError) and str(got[2]) == str(err.value) and marches == [3]


def test_predict_records_is_predict_body_of_each_record_the_records_of_one_length_marched_together(drive, marches):
    """One model on seven records: five of one length (four marched together, the fifth alone: MAX_LANES), one
    shorter, one at another rate. Each prediction is predict_body's to the last bit; a record on which the softening
    model runs away gets its error in its place while the others of its march go on."""
    a1 = np.asarray(drive.record.spindle_accel, float)
    base = IdentifiedModel.from_body(BodyModel(k=(2 * np.pi * 1.4) ** 2, c=2.5), TERM_SETS["knee + cubic + coulomb"],
                                     GAMMAS["knee + cubic + coulomb"], fs_hz=FS)
    soft = replace(base, c_over_m2=np.array([-2.3, -8e7, 0.3]))      # runs away at the drive's full level
    n = 3000
    drives = [0.05 * a1[k * 1000:k * 1000 + n] for k in range(5)]
    drives[1] = a1[1000:1000 + n]                                     # the full level: diverges
    drives += [0.05 * a1[:n // 2], 0.01 * a1[:n]]
    rates = [FS] * 6 + [FS / 2]
    got = predict_records(soft, drives, rates, labels=[f"r{i}" for i in range(7)])
    assert marches == [4]       # the first four of one length and rate; the fifth, the shorter, the slower alone
    for a, fs, g, i in zip(drives, rates, got, range(7)):
        try:
            p = predict_body(soft, a, fs, label=f"r{i}")
        except PredictionDivergedError as err:
            assert i == 1 and isinstance(g, PredictionDivergedError) and str(g) == str(err)
            continue
        assert all(np.array_equal(getattr(p, k), getattr(g, k)) for k in ("body_accel", "z", "zdot")), i
        assert (p.method, p.edge_samples, p.oversample) == (g.method, g.edge_samples, g.oversample)


def test_a_forward_jacobian_of_points_marched_together_is_the_column_by_column_one():
    fun = lambda x: np.array([np.sin(x[0]) * x[1], x[1] ** 3, np.exp(0.1 * x[2]) + x[0]])
    x0, h = np.array([0.3, -1.2, 2.0]), np.array([1e-3, -1.2e-3, 2e-3])
    f0 = fun(x0)
    seen = []

    def together(points):
        seen.append(len(points))
        return [fun(p) for p in points]

    assert np.array_equal(forward_jacobian(fun, x0, f0, h, together=together), forward_jacobian(fun, x0, f0, h))
    assert sum(seen) == 3


def test_the_refinement_with_its_columns_marched_together_is_the_one_by_one_refinement(monkeypatch, marches):
    """The whole output-error refinement (knee + cubic, 30 s) by forward differences (as where the residues move:
    the sensitivity march is turned off here): the same coefficients, costs and covariance to the last bit whether
    each Jacobian's simulations of a record are marched together or one by one."""
    monkeypatch.setattr(Space, "march_parameters", lambda self, model: None)
    strut = (StrutForce(Term("velocity_deadzone", {"knee": 0.03}), -700.0), StrutForce(Term("cubic_stiffness"), 2e8))
    sim = simulate(SimConfig(strut=strut, road=RandomRoad(0.004), duration_s=30.0, fs_hz=FS), rng=8)
    car = sim.truth.vehicle
    model = IdentifiedModel.from_body(BodyModel(car.k2 / car.m2 * 1.05, car.c2 / car.m2 * 0.9),
                                      [s.term for s in strut], [s.coefficient / car.m2 * 0.8 for s in strut],
                                      fs_hz=FS)
    together = refine_mod.refine_model(model, [sim.record], max_iterations=4)
    marched = sum(marches)          # every Jacobian's columns, in at most two batches (threads) per record

    def one_by_one(models, record, **kw):
        out = []
        for m in models:
            try:
                out.append(refine_mod.prediction_residual(m, record, **kw))
            except PredictionDivergedError:
                out.append(None)
        return out

    monkeypatch.setattr(refine_mod, "prediction_residuals", one_by_one)
    alone = refine_mod.refine_model(model, [sim.record], max_iterations=4)
    assert together.evaluations == alone.evaluations > 2 * (1 + len(together.parameters))
    assert marched >= 2 * len(together.parameters) and sum(marches) == marched   # none marched one by one
    assert np.array_equal(together.model.c_over_m2, alone.model.c_over_m2)
    assert together.nmse == alone.nmse and together.parameters == alone.parameters
    assert together.model.provenance["refined"]["covariance"] == alone.model.provenance["refined"]["covariance"]
