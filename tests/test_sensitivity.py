"""The refinement's Jacobian from one march (nifo_core.predict.sensitivity) against differences of whole simulations.

Each column is compared with central differences of :func:`~nifo_core.predict.refine.prediction_residual` at a
step small enough that their truncation error stays below the tolerance (the march differentiates the engine's own
discrete step, kinks included on the side the step lies on), and small enough that no kink lies within it: 1e-6 of
the parameter (at 1e-5, once the decimation's rounding moved by 1e-16, a contact of the play-stop case's backlash
fell inside the step: its deadband column 6.9e-4 from the quotient, 1.2e-7 at 1e-6; the rounding error of a
quotient at 1e-6 is ~1e-10).
"""

from dataclasses import replace

import numpy as np
import pytest

from nifo_core.kinds.describing import Term
from nifo_core.nifo.identify import identify_nifo
from nifo_core.predict import refine as R
from nifo_core.predict.refine_space import space_for
from nifo_core.predict.model import IdentifiedModel
from nifo_core.predict.sensitivity import residual_jacobian
from nifo_core.signal.record import Record
from nifo_core.simulate.quarter_car import RandomRoad, SensorNoise, SimConfig, StrutForce, simulate

FS = 600.0


def _case(strut, rms=0.002, duration_s=30.0):
    sim = simulate(SimConfig(strut=strut, road=RandomRoad(rms), duration_s=duration_s, fs_hz=FS,
                             noise=SensorNoise(relative=0.01)), rng=3)
    res = identify_nifo(sim.record, [s.term for s in strut])
    return sim.record, IdentifiedModel.from_nifo(res)


def _columns(model, rec, *, track):
    sp = space_for(model, model, shape=True, linear_params=True, track_absorbed=track)
    x = sp.x0(np.asarray(model.c_over_m2, float))
    m = sp.model(x)
    band = model.analysis_band_hz
    skip = R.start_up_samples(m, rec)
    jac = residual_jacobian(m, rec, sp.march_parameters(m), band_hz=band, skip_samples=skip)
    diff = []
    for k in range(x.size):
        h = 1e-6 * max(1.0, abs(x[k]))
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        diff.append((R.prediction_residual(sp.model(xp), rec, band_hz=band, skip_samples=skip)
                     - R.prediction_residual(sp.model(xm), rec, band_hz=band, skip_samples=skip)) / (2 * h))
    return sp, jac, np.stack(diff, axis=1)


@pytest.mark.parametrize("strut", [
    (StrutForce(Term("velocity_deadzone", {"knee": 0.03}), -700.0), StrutForce(Term("cubic_stiffness"), 2e8),
     StrutForce(Term("coulomb", {"eps": 0.005}), 60.0)),
    (StrutForce(Term("backlash", {"deadband": 0.0008}), 4000.0),
     StrutForce(Term("bump_stop", {"gap": 0.003, "side": "compression"}), 5e4),
     StrutForce(Term("quadratic_damping"), 800.0)),
], ids=["knee-cubic-friction", "play-stop-quadratic"])
def test_every_column_of_the_march_is_the_difference_quotient_of_whole_simulations(strut):
    rec, model = _case(strut)
    for track in (False, True):
        sp, jac, diff = _columns(model, rec, track=track)
        assert jac.shape == diff.shape
        for k, (name, _) in enumerate(sp.names()):
            err = np.linalg.norm(jac[:, k] - diff[:, k]) / np.linalg.norm(diff[:, k])
            print(f"track={track} {name}: relative difference {err:.1e}")
            assert err < 1e-4, name


def test_a_measured_forces_gain_has_its_column_too():
    """A force on the body moves the input v by its gain: the column is the input's derivative marched through."""
    rec, model = _case((StrutForce(Term("cubic_stiffness"), 1e8),), duration_s=30.0)
    rng = np.random.default_rng(7)
    force = np.convolve(rng.standard_normal(rec.body_accel.size), np.ones(25) / 25, mode="same") * 200.0
    rec = Record(rec.fs_hz, rec.spindle_accel, rec.body_accel, force=force, source="forced")
    model = replace(model, force_gain=1.0 / 300.0)
    sp, jac, diff = _columns(model, rec, track=False)
    assert sp.force
    k = [n for n, _ in sp.names()].index("1/M2 (gain of the measured force)")
    err = np.linalg.norm(jac[:, k] - diff[:, k]) / np.linalg.norm(diff[:, k])
    print(f"force gain: relative difference {err:.1e}")
    assert err < 1e-4
