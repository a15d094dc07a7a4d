"""Rerun recordings: every written ``.rrd`` read back with Rerun's own reader (``rerun.chunk.RrdReader``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nifo.cli import main

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from test_run_cmd import SAMPLE_RECORDS, pipeline  # noqa: E402

VIEWS = {  # space origin -> view class the blueprint must lay out
    "/accel": "TimeSeries", "/restoring/velocity": "2D", "/restoring/displacement": "2D",
    "/convergence/n_avg": "TimeSeries", "/convergence/cond_median": "TimeSeries",
    "/transmissibility/magnitude_db": "BarChart", "/transmissibility/phase_deg": "BarChart",
    "/transmissibility/coherence": "BarChart", "/coefficients": "BarChart", "/loop/nmse": "BarChart",
    "/loop/rounds": "TextDocument", "/summary": "TextDocument",
}


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    return pipeline(tmp_path_factory)


def _entities(path: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    for c in RrdReader(path).stream().to_chunks():
        out.setdefault(c.entity_path, []).append(c)
    return out


def _views(path: Path) -> dict[str, str]:
    """space origin -> view class of the blueprint stored in the file."""
    reader = RrdReader(path)
    (bp,) = reader.blueprints()
    views = {}
    for c in reader.stream(store=bp).to_chunks():
        b = c.to_record_batch()
        if "ViewBlueprint:space_origin" in b.schema.names:
            origin = b.column("ViewBlueprint:space_origin").to_pylist()[-1]
            cls = b.column("ViewBlueprint:class_identifier").to_pylist()[-1]
            views["/" + str(origin[0] if isinstance(origin, list) else origin).lstrip("/")] = cls[0] if isinstance(cls, list) else cls
    return views


def _check(path: Path, records: list[str], terms: int) -> dict[str, list]:
    ents = _entities(path)
    for rec in records:
        for e in (f"/accel/{rec}", f"/restoring/velocity/{rec}", f"/restoring/displacement/{rec}"):
            assert e in ents, e
    for e in ("/transmissibility/magnitude_db/h1", "/transmissibility/phase_deg/h1", "/transmissibility/coherence/h1",
              "/transmissibility/coherence/multiple", "/convergence/n_avg", "/convergence/cond_median", "/summary"):
        assert e in ents, e
    if terms:
        assert "/transmissibility/magnitude_db/nifo" in ents
        assert sum(e.startswith("/coefficients/") and e.endswith("/re") for e in ents) == terms
    timelines = {t for cs in ents.values() for c in cs for t in c.timeline_names}
    assert timelines == {"stamp"}, "only the data's stamps index the recording (no wall clock)"
    views = _views(path)
    for origin, cls in VIEWS.items():
        assert views.get(origin) == cls, (origin, views.get(origin))
    return ents


def test_run_recording_has_the_expected_entities_and_blueprint(ran):
    out, _, _ = ran
    ident = json.loads((out / "identify" / "identify.json").read_text())
    _check(out / "recording" / "nifo.rrd", SAMPLE_RECORDS, len(ident["result"]["terms"]))


def test_view_saves_the_same_layout_from_result_directories(ran, tmp_path):
    from nifo.commands.run import SAMPLE_DIR

    out, _, _ = ran
    # the run's identification is two-step (logged as its final estimate); a one-step identification is replayed
    # along its data
    ident = tmp_path / "identify"
    assert main(["-q", "identify", str(SAMPLE_DIR / "road_1mm"), "--model",
                 str(out / "characterize" / "suggested_model.yaml"), "--out", str(ident)]) == 0
    rrd = tmp_path / "v.rrd"
    assert main(["view", str(ident), str(out / "characterize"), "--save", str(rrd)]) == 0
    ents = _check(rrd, SAMPLE_RECORDS, len(json.loads((ident / "identify.json").read_text())["result"]["terms"]))
    # the estimate is replayed along the data: several updates, the last one at the last sample's stamp
    n_avg = ents["/convergence/n_avg"]
    rows = sum(c.num_rows for c in n_avg)
    assert rows >= 3


def test_view_of_a_loop_result_logs_its_rounds(ran, tmp_path):
    out, _, _ = ran
    if not (out / "loop" / "loop.json").is_file():
        pytest.skip("nifo loop is not part of this build")
    rrd = tmp_path / "l.rrd"
    assert main(["view", str(out / "loop"), "--save", str(rrd), "--no-data"]) == 0
    assert "/loop/rounds" in _entities(rrd)


def test_view_without_reachable_data_still_logs_the_estimate(ran, tmp_path):
    out, _, _ = ran
    rrd = tmp_path / "nodata.rrd"
    assert main(["view", str(out / "identify"), "--save", str(rrd), "--no-data"]) == 0
    ents = _entities(rrd)
    assert "/transmissibility/magnitude_db/h1" in ents and not any(e.startswith("/accel/") for e in ents)


def test_view_rejects_a_directory_without_results(tmp_path, capsys):
    assert main(["view", str(tmp_path), "--save", str(tmp_path / "x.rrd")]) != 0
    assert "no result document" in capsys.readouterr().err
    assert not (tmp_path / "x.rrd").exists()


def test_log_functions_write_what_the_live_node_publishes(tmp_path):
    """The live node's path: a result table at a data stamp, through the same log_* functions."""
    from nifo.viz import rerun_log as rl

    rrd = tmp_path / "live.rrd"
    rec = rr.RecordingStream(rl.APP_ID)
    rl.use_data_stamps(rec)
    rec.save(rrd, default_blueprint=rl.blueprint())
    f = np.linspace(0, 50, 257)
    stamp = 1_700_000_000_000_000_000
    rl.log_accelerations("live", stamp + np.arange(600) * 1_666_667, np.zeros(600), np.ones(600), recording=rec)
    rl.log_transmissibility(stamp, f, {"nifo": np.ones(f.size, complex)}, coherence={"h1": np.ones(f.size)},
                            recording=rec)
    rl.log_coefficients(stamp, f, ["coulomb"], np.ones((1, f.size), complex), recording=rec)
    rl.log_convergence(stamp, n_avg=3, cond_median=12.0, recording=rec)
    rec.flush()
    rec.disconnect()
    ents = _entities(rrd)
    assert {"/accel/live", "/transmissibility/magnitude_db/nifo", "/coefficients/coulomb/re",
            "/convergence/n_avg"} <= set(ents)


def test_live_viewer_node_logs_the_pipeline_topics_with_the_shared_layout(ran, tmp_path):
    """The node's callbacks, fed the messages the integrator and identifier publish (no graph needed)."""
    rclpy = pytest.importorskip("rclpy")
    from nifo_msgs.msg import LoopStatus

    from nifo.viz import rerun_log as rl
    from nifo_nodes.messages import Block, block_to_msg
    from nifo_nodes.rerun_viewer import RerunViewerNode

    out, _, _ = ran
    doc = json.loads((out / "identify" / "identify.json").read_text())["result"]
    rrd = tmp_path / "live.rrd"
    rec = rr.RecordingStream(rl.APP_ID)
    rl.use_data_stamps(rec)
    rec.save(rrd, default_blueprint=rl.blueprint())
    rclpy.init(args=[])
    try:
        node = RerunViewerNode(rec)
        t0, fs, n = 1_700_000_000_000_000_000, 600.0, 600
        rng = np.random.default_rng(0)
        a = rng.standard_normal((n, 2))
        node._on_accel(block_to_msg(Block(t0, fs, ("spindle_accel", "body_accel"), a)))
        motion = rng.standard_normal((n, 6))
        node._on_motion(block_to_msg(Block(t0, fs, ("spindle_vel", "spindle_disp", "body_vel", "body_disp",
                                                    "rel_vel", "rel_disp"), motion)))
        # the identifier's status message names its result document (a file, never a JSON topic)
        res_file = tmp_path / "result.json"
        res_file.write_text(json.dumps({**doc, "stamp_ns": t0 + 10**9}))
        st = LoopStatus(state="accumulating", message="live", n_avg=int(doc["n_avg"]), samples_used=n,
                        samples_lost=0, gaps=0, result_file=str(res_file))
        st.header.stamp.sec, st.header.stamp.nanosec = divmod(t0 + 10**9, 10**9)
        node._on_status(st)
        (tmp_path / "bad.json").write_text("not json")
        node._on_status(LoopStatus(state="accumulating", result_file=str(tmp_path / "bad.json")))  # logged, skipped
        node.destroy_node()
    finally:
        rclpy.shutdown()
    rec.flush()
    rec.disconnect()
    ents = _entities(rrd)
    assert {"/accel/live", "/restoring/velocity/live", "/restoring/displacement/live",
            "/transmissibility/magnitude_db/h1", "/convergence/n_avg"} <= set(ents)
    assert _views(rrd)["/transmissibility/magnitude_db"] == "BarChart"
