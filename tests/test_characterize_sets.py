"""characterize names what is there and nothing else (issue 28): the paper's damper knee beside another kind,
four road levels, 2 % noise on every channel; the full table is benchmarks/bench_characterize_sets.py."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_characterize_sets import simulate_case  # noqa: E402

from nifo_core.characterize.automatic import characterize  # noqa: E402


@pytest.mark.parametrize("kind,seed", [("quadratic_damping", 1), ("bump_stop", 2), ("knee_only", 2)])
def test_characterize_suggests_exactly_the_true_set(kind, seed):
    recs, m2, truth = simulate_case(kind, seed, duration=60.0)
    ch = characterize(recs, m2_kg=m2)
    got = sorted(c.kind for c in ch.suggested)
    print(kind, seed, "suggested", [c.term.label for c in ch.suggested], "true", truth)
    assert got == truth
    # what stands in for a suggested term is named as its alternative, not suggested beside it
    alt = {c.kind: c.status for c in ch.candidates}
    if "velocity_deadzone" in truth and "coulomb" not in truth:
        assert alt["coulomb"] in ("alternative", "redundant", "weak")
