"""Output-error refinement (nifo_core.predict.refine) and the band-limited prediction metric it minimises.

Every accuracy figure is printed beside the NIFO start and the linear model of the same run.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

from nifo_core.kinds.describing import Term
from nifo_core.errors import ConfigError, InputError
from nifo_core.predict.linear_part import BodyModel
from nifo_core.predict.model import IdentifiedModel, predict_body
from nifo_core.nifo.identify import identify_nifo
from nifo_core.predict.prediction_error import band_nmse
from nifo_core.predict.refine import model_nmse, refine_model
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

FS = 600.0


def _nmse(y, yhat) -> float:
    return float(100 * np.mean((y - yhat) ** 2) / np.var(y))


# ---------------------------------------------------------------------------------------------
# the metric
# ---------------------------------------------------------------------------------------------
def test_band_nmse_is_zero_for_a_perfect_prediction_one_hundred_for_none_and_ignores_out_of_band_error():
    rng = np.random.default_rng(0)
    t = np.arange(6000) / FS          # 0.1 Hz lines: 5 Hz and 100 Hz fall on lines
    y = np.sin(2 * np.pi * 5 * t) + 0.1 * rng.standard_normal(t.size)
    assert band_nmse(y, y, FS, band_hz=(2, 30)) == 0.0
    assert band_nmse(y, np.zeros_like(y), FS, band_hz=(2, 30)) == pytest.approx(100.0)
    off_band = y + 0.5 * np.sin(2 * np.pi * 100 * t)          # error only at 100 Hz
    assert band_nmse(y, off_band, FS, band_hz=(2, 30)) < 1e-3
    assert band_nmse(y, off_band, FS, band_hz=(2, 150)) > 10


def test_band_nmse_of_periodic_data_scores_the_period_average_after_the_skipped_transient():
    rng = np.random.default_rng(1)
    period = rng.standard_normal(512)
    y = np.tile(period, 5)
    yhat = y.copy()
    yhat[:512] += 3.0 * rng.standard_normal(512)               # a start-up transient in the first period
    yhat[512:] += 0.05 * rng.standard_normal(4 * 512)          # noise that averaging over 4 periods reduces
    with_transient = band_nmse(y, yhat, FS, band_hz=(1, 290))
    steady = band_nmse(y, yhat, FS, band_hz=(1, 290), period_samples=512, skip_samples=512)
    assert steady < 0.15 * 100 * 0.05 ** 2 / np.var(period) * 4 and steady < 0.01 * with_transient


def test_band_nmse_says_what_is_wrong():
    y = np.ones(100)
    with pytest.raises(InputError, match="no whole period"):
        band_nmse(y, y, FS, band_hz=(1, 10), period_samples=200)
    with pytest.raises(ConfigError, match="holds no spectral line"):
        band_nmse(np.arange(100.0), np.arange(100.0), FS, band_hz=(1.0, 1.1))
    with pytest.raises(InputError, match="differ in length"):
        band_nmse(y, y[:50], FS, band_hz=(1, 10))


# ---------------------------------------------------------------------------------------------
# refinement on simulated truth
# ---------------------------------------------------------------------------------------------
def _identified(strut, rms, duration_s, *, noise=0.02, rng=1):
    sim = simulate(SimConfig(strut=strut, road=RandomRoad(rms), duration_s=duration_s, fs_hz=FS,
                             noise=SensorNoise(relative=noise)), rng=rng)
    res = identify_nifo(sim.record, [s.term for s in strut])
    return sim, IdentifiedModel.from_nifo(res), IdentifiedModel.from_nifo(res, source="h1")


def test_refinement_recovers_coulomb_friction_from_noisy_data_and_never_ends_worse_than_its_starts():
    strut = (StrutForce(Term("coulomb", {"eps": 0.005}), 30.0),)
    sim, model, linear = _identified(strut, 0.0005, 60.0)
    m2 = sim.truth.vehicle.m2
    ref = refine_model(model, [sim.record], linear=linear)
    c_nifo, c_ref = model.c_over_m2[0] * m2, ref.model.c_over_m2[0] * m2
    print(f"\nCoulomb 30 N, 60 s at 0.5 mm, 2 % noise: NIFO {c_nifo:.2f} N, refined {c_ref:.2f} N "
          f"(from the {ref.start} start, {ref.evaluations} simulations); band NMSE {ref.nmse_before} → {ref.nmse}")
    assert abs(c_ref / 30.0 - 1) < 0.05
    for before in ref.nmse_before.values():          # never worse than where it started, on the data it was given
        assert sum(ref.nmse) <= sum(before) + 1e-12
    assert ref.model.provenance["refined"]["start"] == ref.start
    # the refined model round-trips through JSON with its provenance
    back = IdentifiedModel.from_dict(json.loads(json.dumps(ref.model.to_dict())))
    assert np.allclose(back.c_over_m2, ref.model.c_over_m2)
    assert model_nmse(back, [sim.record], band_hz=back.analysis_band_hz,
                      skip_samples=ref.model.provenance["refined"]["skip_samples"]) == pytest.approx(ref.nmse, rel=1e-9)


def test_refinement_needs_a_term_and_records():
    sim, model, linear = _identified((StrutForce(Term("coulomb", {"eps": 0.005}), 30.0),), 0.0005, 30.0)
    with pytest.raises(ConfigError, match="no nonlinear term"):
        refine_model(linear, [sim.record])
    with pytest.raises(InputError, match="at least one record"):
        refine_model(model, [])


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["cubic", "bump stop"])
def test_noisy_identification_refined_predicts_other_levels_at_the_noise_floor(kind):
    """Issue 10: with 2 % sensor noise NIFO's coefficient is biased low (noise integrated twice into z);
    refined, the model predicts as well as the true model does on the same noisy test data (the floor:
    2 % noise on both accelerometers; noise-free, test_predict_engine holds the 1 % bound)."""
    if kind == "cubic":
        strut, rms = (StrutForce(Term("cubic_stiffness", {}), 2e8),), 0.005
    else:
        strut, rms = (StrutForce(Term("bump_stop", {"gap": 0.008, "side": "compression"}), 2e5),), 0.005
    sim, model, linear = _identified(strut, rms, 180.0)
    ref = refine_model(model, [sim.record], linear=linear)
    car = sim.truth.vehicle
    truth = IdentifiedModel.from_body(BodyModel(car.k2 / car.m2, car.c2 / car.m2), [s.term for s in strut],
                                      [s.coefficient / car.m2 for s in strut], fs_hz=FS)
    print(f"\n{kind}: coefficient true {strut[0].coefficient:.4g}, NIFO {model.c_over_m2[0] * car.m2:.4g}, "
          f"refined {ref.model.c_over_m2[0] * car.m2:.4g}; {ref.message}")
    for test_rms in (rms, rms / 2):
        test = simulate(SimConfig(strut=strut, road=RandomRoad(test_rms), duration_s=120, fs_hz=FS,
                                  noise=SensorNoise(relative=0.02)), rng=7)
        a1, y = test.record.spindle_accel, test.record.body_accel
        e = {}
        for name, m in (("true model", truth), ("linear", linear), ("NIFO", model), ("refined", ref.model)):
            p = predict_body(m, a1, FS)
            e[name] = _nmse(y[p.valid], p.body_accel[p.valid])
        print(f"  predicting {test_rms * 1e3:g} mm seed 7: " + ", ".join(f"{k} {v:.3f} %" for k, v in e.items()))
        assert e["refined"] < 1.1 * e["true model"] and e["refined"] < 0.6 * e["linear"]
        if test_rms == rms:          # where the nonlinearity acts most, NIFO's bias shows; below, all sit at the floor
            assert e["refined"] < e["NIFO"]
    assert abs(ref.model.c_over_m2[0] * car.m2 / strut[0].coefficient - 1) < 0.25


def test_identify_refine_writes_the_refined_model_and_predict_takes_it(tmp_path):
    strut = (StrutForce(Term("coulomb", {"eps": 0.005}), 30.0),)
    sim = simulate(SimConfig(strut=strut, road=RandomRoad(0.0005), duration_s=40, fs_hz=FS,
                             noise=SensorNoise(relative=0.02)), rng=3)
    from nifo.io.results import read_model
    from nifo.io.tabular import write_csv
    data = tmp_path / "road.csv"
    write_csv(data, sim.record)
    spec = tmp_path / "m.yaml"
    spec.write_text("nifo_model: 1\nnonlinearities: [{kind: coulomb, params: {eps: 0.005}}]\n")
    out = tmp_path / "id"
    run = subprocess.run([sys.executable, "-m", "nifo", "--json", "identify", str(data), "--model", str(spec),
                          "--out", str(out), "--no-plots", "--refine", "--refine-seconds", "30"],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    doc = json.loads((out / "identify.json").read_text())
    ref = doc["summary"]["refinement"]
    model, _ = read_model(out)
    assert model.provenance["refined"]["start"] == ref["start"]
    c = ref["parameters"][0]["after"] * sim.truth.vehicle.m2
    print(f"\nnifo identify --refine: Coulomb {ref['parameters'][0]['before'] * sim.truth.vehicle.m2:.2f} N → "
          f"{c:.2f} N (true 30 N)")
    assert abs(c / 30 - 1) < 0.1
    pred = subprocess.run([sys.executable, "-m", "nifo", "predict", str(data), "--model", str(out), "--out",
                           str(tmp_path / "pred"), "--no-plots"], capture_output=True, text=True, timeout=600)
    assert pred.returncode == 0, pred.stderr


@pytest.mark.slow
def test_refined_bounds_cover_the_coulomb_force_over_seeds_and_say_what_they_miss():
    """95 % Gauss-Newton bounds of the refined parameters, 6 seeds of 40 s at 0.5 mm with 2 % noise.

    Measured: the Coulomb coefficient is covered in 6/6 (±0.6 %); the body stiffness carries a small
    bias from the noise on the measured input (−0.6 % on average) that its random-error bound
    (±0.7 %) does not always hold — printed, asserted only loosely."""
    strut = (StrutForce(Term("coulomb", {"eps": 0.005}), 30.0),)
    hits = {"coulomb": [], "k": [], "c": []}
    for seed in range(6):
        sim = simulate(SimConfig(strut=strut, road=RandomRoad(0.0005), duration_s=40, fs_hz=FS,
                                 noise=SensorNoise(relative=0.02)), rng=100 + seed)
        res = identify_nifo(sim.record, [s.term for s in strut])
        ref = refine_model(IdentifiedModel.from_nifo(res), [sim.record],
                           linear=IdentifiedModel.from_nifo(res, source="h1"))
        car = sim.truth.vehicle
        by_name = {p["name"]: p for p in ref.parameters}         # the friction's eps is refined too (issue 54)
        for key, name, truth in (("coulomb", "c/M2 of coulomb", 30.0 / car.m2),
                                 ("k", "k = K2/M2 (nominal body)", car.k2 / car.m2),
                                 ("c", "c = C2/M2 (nominal body)", car.c2 / car.m2)):
            p = by_name[name]
            hits[key].append(p["half_width_95"] is not None and abs(p["after"] - truth) <= p["half_width_95"])
    print("\nrefined 95 % bounds hold the truth in: " + ", ".join(f"{k} {sum(v)}/{len(v)}" for k, v in hits.items()))
    assert sum(hits["coulomb"]) >= 5 and sum(hits["c"]) >= 4 and sum(hits["k"]) >= 2


def test_a_rational_linear_part_misfitted_by_ten_percent_is_refined_jointly_with_the_term():
    """linear_residues: the residues of a rational linear part join θ (poles kept). Coulomb friction (a bounded
    force: no θ can destabilise the model) identified with a rational linear part whose residues are then put 10 %
    off: the joint refinement predicts a held-out record as well as the refinement of the well-fitted model, the
    coefficient-only refinement does not; a linear model refines the same way and never ends worse."""
    from dataclasses import replace

    from nifo_core.predict.refine_space import parameter_space

    strut = (StrutForce(Term("coulomb", {"eps": 0.005}), 30.0),)
    sim, _, _ = _identified(strut, 0.001, 40.0, noise=0.0)
    res = identify_nifo(sim.record, [s.term for s in strut])
    good = IdentifiedModel.from_nifo(res, linear_form="rational", order=6)
    lin = good.linear
    off = lambda r, p: r * (1.1 + 0.05j * np.sign(p.imag))                          # noqa: E731
    bad = replace(good, linear=replace(lin, residues=off(lin.residues, lin.poles)))
    test = simulate(SimConfig(strut=strut, road=RandomRoad(0.001), duration_s=40.0, fs_hz=FS), rng=9).record
    score = lambda m: model_nmse(m, [test], band_hz=(2, 30))[0]                     # noqa: E731
    rec = [sim.record]
    joint = refine_model(bad, rec, band_hz=(2, 30), linear_residues=True, shape=False, linear_params=False)
    coef_only = refine_model(bad, rec, band_hz=(2, 30), shape=False, linear_params=False)
    well = refine_model(good, rec, band_hz=(2, 30), shape=False, linear_params=False)
    e = {"well fitted, refined": score(well.model), "10 % off": score(bad), "10 % off, coefficient refined":
         score(coef_only.model), "10 % off, residues and coefficient refined": score(joint.model)}
    print("\nheld-out band NMSE: " + ", ".join(f"{k} {v:.4f} %" for k, v in e.items()) + f"; {joint.message}")
    assert "residue pairs" in joint.message and joint.model.linear.stable
    np.testing.assert_allclose(joint.model.linear.poles, lin.poles)
    assert abs(np.sum(joint.model.linear.residues)) < 1e-9 * np.abs(lin.residues).sum()     # relative degree 2
    assert e["10 % off, residues and coefficient refined"] < 2 * e["well fitted, refined"] + 0.01
    assert e["10 % off, residues and coefficient refined"] < 0.5 * e["10 % off, coefficient refined"]
    assert joint.model.c_over_m2[0] * sim.truth.vehicle.m2 == pytest.approx(30.0, rel=0.1)
    space = parameter_space(joint.model)                   # the covariance rebuilds the refined model itself
    if space is not None:
        to_model, theta, cov = space.to_model, space.theta, space.cov
        assert cov.shape == (theta.size, theta.size) and theta.size == 1 + 2 * (lin.order // 2)
        np.testing.assert_allclose(to_model(theta).linear.residues, joint.model.linear.residues, atol=1e-12)
    linear = IdentifiedModel.from_nifo(res, source="h1", linear_form="rational", order=6)
    linear_bad = replace(linear, linear=replace(linear.linear, residues=off(linear.linear.residues,
                                                                             linear.linear.poles)))
    lref = refine_model(linear_bad, rec, band_hz=(2, 30), linear_residues=True)
    assert not lref.model.terms and "residue pairs" in lref.message
    assert np.sum(lref.nmse) <= np.sum(lref.nmse_before["nifo"]) + 1e-12


def test_the_joint_refinement_nests_the_equally_refined_linear_model_and_keeps_its_poles():
    """refine_jointly (nifo identify --refine-linear): the linear model's residues refined alone are the
    baseline; a play (an unbounded force) added to that linear part as its bounded remainder, refined with the
    residues from NIFO's coefficient and from zero, the better kept. On the records it never does worse than the
    baseline (the zero start is the baseline itself), the poles stay, and on a held-out level it predicts a
    play the data hold better than the baseline does."""
    from nifo_core.predict.refine import refine_jointly

    strut = (StrutForce(Term("backlash", {"deadband": 0.00043}), 8e3),)
    sim, _, _ = _identified(strut, 0.0005, 40.0, noise=0.0)
    res = identify_nifo(sim.record, [s.term for s in strut])
    model = IdentifiedModel.from_nifo(res, linear_form="rational", order=6)
    linear = IdentifiedModel.from_nifo(res, source="h1", linear_form="rational", order=6)
    rec = [sim.record.slice(0, int(20 * FS))]
    kw = dict(band_hz=(2, 30), max_iterations=15)
    lin = refine_model(linear, rec, linear_residues=True, **kw)
    joint = refine_jointly(model, lin, rec, **kw)
    test = simulate(SimConfig(strut=strut, road=RandomRoad(0.0002), duration_s=20.0, fs_hz=FS), rng=9).record
    held = {"linear, residues refined": model_nmse(lin.model, [test], band_hz=(2, 30))[0],
            "play, joint": model_nmse(joint.model, [test], band_hz=(2, 30))[0]}
    print(f"\n{joint.message}\nheld-out level (0.2 mm): " + ", ".join(f"{k} {v:.4f} %" for k, v in held.items()))
    assert set(joint.nmse_before) == {"nifo", "linear"} and "residue pairs" in joint.message
    assert joint.nmse_before["linear"] == pytest.approx(lin.nmse, rel=1e-9)     # zero start = the baseline
    assert sum(joint.nmse) <= sum(lin.nmse) + 1e-12
    np.testing.assert_allclose(joint.model.linear.poles, lin.model.linear.poles)
    assert joint.model.linear.stable and held["play, joint"] < 0.5 * held["linear, residues refined"]
    with pytest.raises(ConfigError, match="rational linear part"):
        refine_jointly(model, refine_model(model, rec, linear=linear, **kw), rec)
