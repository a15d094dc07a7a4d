"""The describing-function library: shapes, parameters, the play operator, errors."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from nifo_core.kinds.describing import KINDS, Term, kind, make_term, play_operator
from nifo_core.errors import ConfigError


def _params(k):
    return {n: (d if d is not None else 1e-3) for n, (d, _) in k.params.items()}


@pytest.mark.parametrize("name", list(KINDS))
def test_every_kind_is_zero_at_rest_and_finite(name):
    t = Term(name, _params(KINDS[name]))
    z = np.zeros(10)
    assert np.all(t.evaluate(z, z) == 0)
    x = np.linspace(-0.02, 0.02, 101)
    assert np.all(np.isfinite(t.evaluate(x, x)))


def test_static_forms_match_their_formulas():
    x = np.linspace(-2e-3, 2e-3, 9)
    np.testing.assert_allclose(Term("clearance", {"gap": 1e-3}).evaluate(x, 0 * x),
                               np.sign(x) * np.maximum(np.abs(x) - 1e-3, 0))
    np.testing.assert_allclose(Term("velocity_deadzone", {"knee": 1e-3}).evaluate(0 * x, x),
                               np.sign(x) * np.maximum(np.abs(x) - 1e-3, 0))
    np.testing.assert_allclose(Term("bump_stop", {"gap": 1e-3}).evaluate(x, 0 * x), np.minimum(x + 1e-3, 0))
    np.testing.assert_allclose(Term("asymmetric_damping").evaluate(0 * x, x), np.maximum(x, 0))
    np.testing.assert_allclose(Term("quadratic_damping").evaluate(0 * x, x), x * np.abs(x))


def test_play_operator_stays_within_half_deadband_and_sticks_inside():
    t = np.linspace(0, 4 * np.pi, 4001)
    z = 1e-3 * np.sin(t)
    y = play_operator(z, 4.3e-4)
    assert np.all(np.abs(y - z) <= 2.15e-4 + 1e-15)
    # at the top of each cycle the output sticks for a while (hysteresis)
    top = np.argmax(z[:2000])
    assert np.ptp(y[top:top + 100]) == 0
    # a motion smaller than the deadband never moves the output
    assert np.ptp(play_operator(1e-4 * np.sin(t), 4.3e-4)) == 0


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1e-2, 1e-2), min_size=2, max_size=200), st.floats(1e-5, 5e-3))
def test_play_operator_is_rate_independent(zs, deadband):
    z = np.array(zs)
    y1 = play_operator(z, deadband)
    y2 = play_operator(np.repeat(z, 3), deadband)[2::3]
    np.testing.assert_allclose(y1, y2)


def test_aliases_and_short_forms_resolve():
    assert kind("friction").name == "coulomb"
    assert make_term({"deadzone": {"gap": 1e-3}}) == Term("clearance", {"gap": 1e-3})
    assert make_term({"kind": "knee", "params": {"knee": 0.03}}).kind == "velocity_deadzone"


def test_bad_specs_say_what_to_write():
    with pytest.raises(ConfigError, match="unknown nonlinearity kind 'spring'.*use one of"):
        Term("spring")
    with pytest.raises(ConfigError, match="needs parameter 'knee'"):
        Term("velocity_deadzone")
    with pytest.raises(ConfigError, match="has no parameter"):
        Term("coulomb", {"knee": 1})
    with pytest.raises(ConfigError, match=r"clearance.gap=-1 must be positive \[m\]"):
        Term("clearance", {"gap": -1})
