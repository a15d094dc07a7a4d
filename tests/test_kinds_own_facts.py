"""Kinds own their facts (issue 57): one parameter rule for the core and the model file, the registry's grids and
tables, and no kind name written as a string outside ``nifo_core/kinds``."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from nifo.io.modelfile import parse_model_spec
from nifo_core.characterize.automatic import candidate_grid
from nifo_core.errors import ConfigError
from nifo_core.kinds import DEFAULT_KINDS, KINDS, LIBRARY, Term, kind

ROOT = Path(__file__).resolve().parents[1]
#: the code that must not name a kind in a string: every package; the kinds' own package aside
CODE = ("nifo", "nifo_core", "nifo_nodes")


def _kind_literals(path: Path) -> list[tuple[int, str]]:
    """(line, name) of every string constant equal to a registered kind name in a Python file."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value in KINDS]


def test_no_kind_name_is_written_as_a_string_outside_the_kinds_package():
    """A kind's facts live in the kind: code elsewhere asks the kind (``t.spec.positive``, ``k.grid(...)``) or names
    it as data through the registry (``LIBRARY.bump_stop``), so renaming or adding a kind touches one module.
    ``benchmarks/`` is left out: its scenarios (a fleet's hidden effects, a paper's strut) are data read as a user
    would write a model file; tests and docs name kinds on purpose."""
    kinds_dir = ROOT / "nifo_core" / "kinds"
    found = [f"{p.relative_to(ROOT)}:{line}: {name!r}"
             for pkg in CODE for p in sorted((ROOT / pkg).rglob("*.py"))
             if kinds_dir not in p.parents for line, name in _kind_literals(p)]
    assert found == [], "kind names written outside nifo_core/kinds:\n" + "\n".join(found)


def test_the_literal_count_finds_a_kind_name(tmp_path):
    """The counter above is not vacuous: a branch on a kind name is found, a parameter name is not."""
    f = tmp_path / "branch.py"
    f.write_text('def f(t):\n    return t.kind == "bump_stop" and "gap" in t.params\n')
    assert _kind_literals(f) == [(2, "bump_stop")]


def _model_file(kind_name: str, params: dict) -> str:
    body = ", ".join(f"{k}: {v}" for k, v in params.items())
    return f"nifo_model: 1\nnonlinearities:\n  - {{kind: {kind_name}, params: {{{body}}}}}\n"


# (kind, params as YAML text, as Python values, accepted?)
RULES = [
    ("clearance", {"gap": "0.0"}, {"gap": 0.0}, False),        # a clearance of 0 is z: the linear stiffness itself
    ("velocity_deadzone", {"knee": "0.0"}, {"knee": 0.0}, False),   # ż: the linear damping itself
    ("backlash", {"deadband": "0.0"}, {"deadband": 0.0}, False),
    ("saturation", {"limit": "0.0"}, {"limit": 0.0}, False),     # g ≡ 0
    ("coulomb", {"eps": "0.0"}, {"eps": 0.0}, False),            # tanh(ż/0)
    ("clearance", {"gap": "-1.0e-3"}, {"gap": -1e-3}, False),
    ("clearance", {"gap": "1.0e-3"}, {"gap": 1e-3}, True),
    ("bump_stop", {"gap": "0.0"}, {"gap": 0.0}, True),           # a stop touching at the static position
    ("bump_stop", {"gap": "1.0e-3", "offset": "-2.0e-3"}, {"gap": 1e-3, "offset": -2e-3}, True),
    ("bump_stop", {"gap": "1.0e-3", "side": "up"}, {"gap": 1e-3, "side": "up"}, False),
    ("clearance", {"gap": "true"}, {"gap": True}, False),
    ("clearance", {"gap": "'1.0e-3'"}, {"gap": "1.0e-3"}, False),
    ("clearance", {"gap": ".inf"}, {"gap": float("inf")}, False),
]


@pytest.mark.parametrize("name, yaml_params, params, ok", RULES)
def test_the_model_file_and_the_core_apply_the_kinds_one_rule(name, yaml_params, params, ok):
    """``Term`` (the core, the command line) and the model file accept and refuse the same parameters, with the
    same words: the model file validates through ``Kind.check``."""
    text = _model_file(name, yaml_params)
    if ok:
        assert parse_model_spec(text).terms == (Term(name, params),)
        return
    with pytest.raises(ConfigError) as core:
        Term(name, params)
    with pytest.raises(ConfigError) as file:
        parse_model_spec(text)
    assert core.value.message in file.value.message


def test_zero_threshold_is_refused_with_the_reason():
    with pytest.raises(ConfigError, match=r"clearance.gap=0.0 must be positive \[m\] \(0 makes the term the linear"):
        parse_model_spec(_model_file("clearance", {"gap": "0.0"}))


def test_the_default_search_is_the_registry_in_order_without_the_named_equivalents():
    assert DEFAULT_KINDS == ("cubic_stiffness", "quadratic_stiffness", "clearance", "bump_stop", "backlash",
                             "velocity_deadzone", "coulomb", "quadratic_damping", "asymmetric_damping")
    for name in DEFAULT_KINDS:
        eq = KINDS[name].equivalent
        assert eq is None or (eq in KINDS and eq not in DEFAULT_KINDS and KINDS[eq].variable == KINDS[name].variable)


def test_every_kind_grids_its_own_parameter_within_the_check():
    """Every kind's grid gives valid terms of that kind, scaled by its variable's peak; one term without a grid."""
    for name, k in KINDS.items():
        grid = candidate_grid(name, z_range=2e-3, zdot_range=0.2, z_neg=1e-3, z_pos=3e-3, points=5)
        assert {t.kind for t in grid} == {name}
        if k.grid_spec is None:
            assert len(grid) == 1
            continue
        g = k.grid_spec
        vals = np.array([t.params[g.param] for t in grid])
        peak = 0.2 if k.variable == "zdot" else 2e-3
        if g.per_side:
            assert [t.params["side"] for t in grid] == ["compression"] * 5 + ["rebound"] * 5
            np.testing.assert_allclose(vals[5:], np.linspace(g.lo, g.hi, 5) * 3e-3)
        else:
            np.testing.assert_allclose(vals, np.geomspace(g.lo, g.hi, 5) * peak)


def test_a_kind_reports_its_equivalent_and_its_mirror():
    t = Term("clearance", {"gap": 1e-3})
    assert t.spec.canonical(t, 2.0) == (t, 1.0, "saturation(limit=0.001) with the opposite coefficient")
    a = Term("asymmetric_damping", {"side": "rebound"})
    assert kind("asymmetric_damping").canonical(a, -3.0) == (Term("asymmetric_damping", {"side": "compression"}),
                                                             -1.0, None)
    assert LIBRARY.coulomb.positive and not LIBRARY.clearance.positive
    assert {n for n, k in KINDS.items() if k.bounded} == {"coulomb", "saturation", "velocity_saturation"}
