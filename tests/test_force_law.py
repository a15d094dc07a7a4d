"""The strut's force law (:mod:`nifo_core.predict.force_law`): analytic cases."""

import numpy as np
import pytest

from nifo_core.errors import ConfigError
from nifo_core.kinds.describing import Term
from nifo_core.predict.force_law import StrutLaw, characteristic, motion_range, truth_law
from nifo_core.signal.integrate import IntegrationBand
from nifo_core.signal.record import Record


def test_a_linear_strut_gives_straight_lines_k_z_and_c_zdot():
    law = StrutLaw((), (), k=70.0, c=4.0)
    x = np.linspace(-0.01, 0.01, 11)
    (z,) = characteristic(law, x, "z")
    (v,) = characteristic(law, x, "zdot", scale=300.0)
    np.testing.assert_allclose(z.total, 70.0 * x)
    np.testing.assert_allclose(v.total, 300.0 * 4.0 * x)
    assert z.branch == "any" and z.terms.shape == (0, 11)


def test_each_term_acts_on_its_own_variable_only():
    law = StrutLaw((Term("velocity_deadzone", {"knee": 0.03}), Term("cubic_stiffness")), (-2.0, 1e5), k=1.0, c=1.0)
    x = np.linspace(-0.1, 0.1, 21)
    (z,) = characteristic(law, x, "z")
    (v,) = characteristic(law, x, "zdot")
    np.testing.assert_allclose(z.terms[0], 0.0)
    np.testing.assert_allclose(z.terms[1], 1e5 * x ** 3)
    np.testing.assert_allclose(v.terms[0], -2.0 * np.sign(x) * np.maximum(np.abs(x) - 0.03, 0.0))
    np.testing.assert_allclose(v.terms[1], 0.0)


def test_a_play_has_two_branches_half_its_width_either_side_of_z():
    law = StrutLaw((Term("backlash", {"deadband": 0.002}),), (10.0,), k=0.0, c=0.0)
    x = np.linspace(-0.01, 0.01, 201)
    down, up = characteristic(law, x, "z")
    assert (down.branch, up.branch) == ("decreasing", "increasing")
    away = np.abs(x) < 0.008           # away from the turns at the grid's ends
    np.testing.assert_allclose(up.total[away], 10.0 * (x[away] - 0.001), atol=1e-12)
    np.testing.assert_allclose(down.total[away], 10.0 * (x[away] + 0.001), atol=1e-12)


def test_truth_law_is_per_kg_of_the_simulators_body_mass():
    law = truth_law({"m2": 300.0, "k2": 22000.0, "c2": 1400.0},
                    [{"kind": "velocity_deadzone", "params": {"knee": 0.03}, "coefficient": -700.0}])
    assert law.k == pytest.approx(22000 / 300) and law.gammas == pytest.approx((-700 / 300,))


def test_motion_range_of_a_sine_is_its_amplitude():
    fs, f = 200.0, 4.0
    t = np.arange(int(60 * fs)) / fs
    z = 0.002 * np.sin(2 * np.pi * f * t)
    body = -(2 * np.pi * f) ** 2 * z                     # ẍ2 with the spindle still: z = x2
    rec = Record(fs, np.zeros_like(body), body)
    got = motion_range([rec], IntegrationBand(1.0, 40.0))
    np.testing.assert_allclose(got["deflection_m"], [-0.002, 0.002], rtol=0.02)
    np.testing.assert_allclose(got["velocity_m_s"], [-0.002 * 2 * np.pi * f, 0.002 * 2 * np.pi * f], rtol=0.02)


def test_a_grid_that_is_not_ascending_is_refused():
    with pytest.raises(ConfigError, match="ascending"):
        characteristic(StrutLaw((), (), 1.0, 1.0), np.array([0.0, -1.0]), "z")
