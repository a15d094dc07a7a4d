"""What the data's levels cannot reveal (nifo_core.loop.detection.undetermined_terms), on the bundled sample.

The sample's strut holds the paper's play (0.43 mm in series with 8 kN/m) beside a damper knee
(1400 -> 700 N·s/m above 0.03 m/s). At 1 and 2.5 mm road RMS the play is 99.8 % a linear stiffness:
the loop must not say "nothing is missing" but that the play can hardly be told apart at these levels
and which record would pin it; with the 0.5 mm record it has nothing to add.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nifo.io.loader import load_record
from nifo_core.kinds.describing import Term
from nifo_core.loop.detection import undetermined_terms
from nifo_core.signal.integrate import IntegrationBand
from nifo_core.loop.closing import close_loop
from nifo_core.characterize.restoring import restoring_force

SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "sample"
MODEL = (Term("velocity_deadzone", {"knee": 0.0293}), Term("backlash", {"deadband": 0.000419}))


@pytest.fixture(scope="module")
def records():
    return {n: load_record(SAMPLE / n) for n in ("road_0p5mm", "road_1mm", "road_2p5mm")}


def test_a_term_pinned_only_by_more_of_the_same_levels_is_not_reported(records):
    # the knee is pinned to a few % at 1 + 2.5 mm: whatever its bound, nothing to report
    rfs = [restoring_force(records[n], band=IntegrationBand(0.84, 200.0)) for n in ("road_1mm", "road_2p5mm")]
    assert undetermined_terms(rfs, MODEL, [0.05, 0.1]) == ()
    # a wide bound alone is not enough: the knee is limited by noise and length, not by the levels
    assert [u.term.kind for u in undetermined_terms(rfs, MODEL, [0.6, 0.45])] == ["backlash"]


@pytest.fixture(scope="module")
def loop_1_2p5(tmp_path_factory) -> Path:
    """``nifo loop`` on the 1 and 2.5 mm records with the sample's two terms declared: its output directory (read by
    the two tests below)."""
    import yaml

    from nifo.cli import main

    tmp = tmp_path_factory.mktemp("loop_1_2p5")
    model = tmp / "model.yaml"
    model.write_text(yaml.safe_dump({"nifo_model": 1, "nonlinearities": [t.to_dict() for t in MODEL]}))
    out = tmp / "loop"
    assert main(["-q", "loop", str(SAMPLE / "road_1mm"), str(SAMPLE / "road_2p5mm"), "--model", str(model),
                 "--out", str(out)]) == 0
    return out


@pytest.mark.slow
def test_the_loop_on_the_sample_without_its_low_level_names_the_play_it_cannot_pin(loop_1_2p5):
    import json

    doc = json.loads((loop_1_2p5 / "loop.json").read_text())
    assert not doc["nothing_missing"], doc["verdict"]
    (u,) = doc["undetermined"]
    assert u["term"]["kind"] == "backlash" and u["rel_half_width"] > 0.25
    partners = [p["column"] for p in u["partners"]]
    assert partners[0].startswith("the linear stiffness") and any("velocity_deadzone" in n for n in partners)
    # the record that pins it lies below the lowest level (the paper's 0.5 mm record: 0.65 mm z RMS)
    assert u["scale"] < 1 and 0.05e-3 < u["z_rms_at_scale_m"] < 0.8e-3
    assert u["rel_half_width_at_scale"] * 2 <= u["rel_half_width_repeated"]
    assert "can hardly be told apart" in doc["verdict"] and "add a record at" in doc["verdict"]


@pytest.mark.slow
def test_with_the_low_level_record_the_loop_has_nothing_to_add(records):
    res = close_loop(list(records.values()), MODEL)
    assert res.undetermined == () and res.nothing_missing, res.verdict
    assert np.isfinite(res.bounds.half_width).all()


@pytest.mark.slow
def test_the_report_of_the_loop_on_1_and_2p5_mm_says_what_it_cannot_pin(loop_1_2p5, tmp_path):
    from nifo.viz.report_html import write_report
    from nifo.viz.results import read_results

    html = write_report(read_results([loop_1_2p5]), tmp_path / "report.html", levels=False).read_text()
    assert "can hardly be told apart" in html and "add a record at" in html
    assert "nothing significant missing" not in html
    assert "not everything could be told apart" in html
