"""Message conventions and sample alignment of the ROS nodes (no graph needed; rclpy's serializer only)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

from nifo_core.errors import InputError  # noqa: E402
from nifo_nodes.align import SampleAligner  # noqa: E402
from nifo_nodes.messages import (Block, ImuEncoder, PointEncoder, block_from_msg, block_to_msg,  # noqa: E402
                                 decode_imu, decode_imu_batch, decode_point)


@pytest.mark.parametrize("frame_id", ["", "spindle", "body", "a_longer_frame_id"])
def test_imu_encoder_matches_rclpy_and_the_bag_writer_and_decodes_back(frame_id):
    from nifo.io.bag.cdr import IMU, payloads as _payloads
    from sensor_msgs.msg import Imu

    stamp = 1_700_000_123_456_789_012
    raw = ImuEncoder(frame_id).encode(stamp, -3.25)
    msg = Imu()
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.orientation.w = 0.0  # as in nifo's bags (orientation "not provided", REP-145)
    msg.orientation_covariance[0] = -1.0
    msg.angular_velocity_covariance[0] = -1.0
    msg.linear_acceleration.z = -3.25
    # rclpy leaves CDR padding bytes unset, so compare decoded messages with it, bytes with the bag writer
    assert deserialize_message(raw, Imu) == deserialize_message(serialize_message(msg), Imu)
    assert raw == _payloads(np.array([stamp]), np.array([-3.25]), frame_id=frame_id, msgtype=IMU,
                            axis="z").tobytes()
    assert decode_imu(raw) == (stamp, -3.25)


def test_point_encoder_round_trips():
    from geometry_msgs.msg import PointStamped

    raw = PointEncoder("tire_patch").encode(42, 0.001)
    assert deserialize_message(raw, PointStamped).point.z == 0.001
    assert decode_point(raw) == (42, 0.001)


@pytest.mark.parametrize("raw", [b"", b"\x00\x01\x00\x00", b"\x01\x00\x00\x00" + bytes(400),
                                 ImuEncoder("x").encode(1, 1.0)[:-8]])
def test_decode_imu_rejects_malformed_bytes(raw):
    with pytest.raises(InputError):
        decode_imu(raw)


def test_decode_imu_batch_equals_decode_imu_message_by_message_and_names_the_malformed():
    enc, other = ImuEncoder("spindle"), ImuEncoder("")
    raws = [enc.encode(1_700_000_000_000_000_000 + k * 1_666_667, 0.25 * k - 3) for k in range(50)]
    raws[3], raws[7], raws[9] = b"", bytes(40), raws[9][:-8]
    raws[11] = other.encode(5, 2.0)  # another frame_id length: still decodable
    stamps, values, bad = decode_imu_batch(raws, "z")
    good = [decode_imu(r) for i, r in enumerate(raws) if i not in (3, 7, 9)]
    assert list(zip(stamps.tolist(), values.tolist())) == good
    assert [i for i, _ in bad] == [3, 7, 9] and "expected layout" in bad[2][1]
    assert decode_imu_batch([], "z")[0].size == 0


def test_block_round_trips_through_float64multiarray():
    data = np.arange(12.0).reshape(6, 2)
    b = Block(1_700_000_000_123_456_789, 600.0, ("spindle_accel", "body_accel"), data, seq=7, segment=2)
    back = block_from_msg(block_to_msg(b))
    assert back.stamp_ns == b.stamp_ns and back.fs_hz == 600.0 and back.seq == 7 and back.segment == 2
    assert back.channels == b.channels
    np.testing.assert_array_equal(back.data, data)


def test_block_from_msg_rejects_a_message_with_the_wrong_layout():
    from std_msgs.msg import Float64MultiArray

    msg = block_to_msg(Block(0, 100.0, ("a", "b"), np.zeros((3, 2))))
    msg.data = list(msg.data)[:-1]
    with pytest.raises(InputError, match="layout"):
        block_from_msg(msg)
    with pytest.raises(InputError, match="not a nifo sample block"):
        block_from_msg(Float64MultiArray(data=[1.0, 2.0]))


def test_result_messages_are_typed_with_a_data_stamped_header_and_survive_serialization(tmp_path):
    """nifo_msgs Transmissibility / Coefficients / LoopStatus carry the estimate exactly (float64), the
    stream accounting, and a header stamped with the data; the full document goes to a file."""
    import json

    from rclpy.serialization import deserialize_message, serialize_message

    from nifo_core.kinds.describing import make_term
    from nifo_core.signal.integrate import IntegrationBand
    from nifo_core.nifo.identify import StreamingNifo
    from nifo_core.simulate.quarter_car import SimConfig, preset, simulate
    from nifo_core.signal.spectral import SpectralSettings
    from nifo_msgs.msg import Coefficients, LoopStatus, Transmissibility
    from nifo_nodes.results import StreamStats, coefficients_msg, status_msg, transmissibility_msg, write_result_file

    rec = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=20.0, fs_hz=200.0), rng=1).record
    s = StreamingNifo(200.0, [make_term({"kind": "velocity_deadzone", "params": {"knee": 0.03}})],
                      settings=SpectralSettings(block=512, overlap=0.5), band=IntegrationBand(2.0, 80.0),
                      on_ill_conditioned="ignore")
    s.push(rec.spindle_accel, rec.body_accel)
    r = s.result()
    stream = StreamStats(samples_received=rec.n, samples_lost=17, gaps=1)
    stamp = 1_700_000_123_456_789_012
    t = deserialize_message(serialize_message(transmissibility_msg(r, stamp_ns=stamp, frame_id="body",
                                                                   stream=stream)), Transmissibility)
    assert (t.header.stamp.sec, t.header.stamp.nanosec, t.header.frame_id) == (1_700_000_123, 456_789_012, "body")
    assert (t.n_avg, t.samples_used, t.samples_lost, t.gaps) == (r.n_avg, r.n_samples, 17, 1)
    np.testing.assert_array_equal(t.freq_hz, r.freq_hz)
    np.testing.assert_array_equal(np.asarray(t.t21_re) + 1j * np.asarray(t.t21_im), r.t21)
    np.testing.assert_array_equal(np.asarray(t.t21_nominal_re) + 1j * np.asarray(t.t21_nominal_im), r.static.t21)
    np.testing.assert_array_equal(t.t21_nominal_abs, np.abs(r.static.t21))
    np.testing.assert_array_equal(t.cond, r.cond)
    c = deserialize_message(serialize_message(coefficients_msg(r, stamp_ns=stamp, frame_id="body")), Coefficients)
    assert list(c.terms) == ["velocity_deadzone(knee=0.03)"]
    np.testing.assert_array_equal(c.c_pooled, r.static.c_over_m2)
    np.testing.assert_array_equal(np.asarray(c.c_re) + 1j * np.asarray(c.c_im), r.c_over_m2[0])
    st = deserialize_message(serialize_message(status_msg(r, stamp_ns=stamp, frame_id="body", stream=stream,
                                                          cond_limit=1e4, result_file="/x.json")), LoopStatus)
    assert st.state in ("estimating", "ill_conditioned") and "1 stream gap" in st.message
    assert st.result_file == "/x.json" and st.n_avg == r.n_avg
    # the full document: to a file, with the stream section
    f = tmp_path / "r.json"
    write_result_file(f, r, stamp_ns=stamp, stream=stream)
    doc = json.loads(f.read_text())
    assert doc["stamp_ns"] == stamp and doc["stream"]["samples_lost"] == 17 and doc["n_avg"] == r.n_avg
    assert len(serialize_message(transmissibility_msg(r, stamp_ns=stamp, frame_id="body", stream=stream))) < 200_000


# ----------------------------------------------------------------------------- alignment
def _rows(aligner):
    runs = aligner.take()
    return runs, (np.concatenate([r.rows for r in runs]) if runs else np.empty((0, 2)))


def _feed(al, stamps, a, b, order=None):
    events = [e for s, x, y in zip(stamps, a, b) for e in ((0, s, x), (1, s, y))]
    if order is not None:
        events = [events[i] for i in order]
    for ch, s, x in events:
        al.push(ch, int(s), float(x))


def test_aligner_pairs_samples_whatever_the_interleaving_of_the_channels():
    rng = np.random.default_rng(0)
    n, fs = 500, 1000.0
    stamps = 10**9 + np.arange(n) * 1_000_000
    a, b = rng.standard_normal(n), rng.standard_normal(n)
    al = SampleAligner(fs, 2, max_lag=50, log=lambda m: None)
    # each topic arrives in order (one DDS writer each), the two interleave arbitrarily (up to 40 apart)
    lag = rng.integers(0, 40, n)
    events = sorted([(k, 0) for k in range(n)] + [(k + int(lag[k]), 1, k) for k in range(n)],
                    key=lambda e: e[0])
    i_b = 0
    for e in events:
        if e[1] == 0:
            al.push(0, int(stamps[e[0]]), float(a[e[0]]))
        else:
            k = i_b  # body samples stay in order
            i_b += 1
            al.push(1, int(stamps[k]), float(b[k]))
    runs, rows = _rows(al)
    assert [r.segment for r in runs] == [0] and runs[0].stamp_ns == stamps[0]
    np.testing.assert_array_equal(rows, np.column_stack([a, b]))
    assert al.counts["late"] == al.counts["gap"] == 0


def test_ordered_aligner_waits_for_a_channel_far_behind_and_still_finds_a_real_hole():
    """Lossless replay as fast as the graph goes: one channel thousands of samples ahead is no loss
    (the best-effort rule would cut a gap every max_lag); a sample missing at the source is a gap as
    soon as its own channel has moved past it."""
    n, fs = 6000, 1000.0
    stamps = 10**9 + np.arange(n) * 1_000_000
    a, b = np.arange(n, dtype=float), -np.arange(n, dtype=float)
    hole = set(range(4000, 4010))  # missing at the source on channel 0
    for ordered, expect_gaps in ((True, 1), (False, None)):
        al = SampleAligner(fs, 2, max_lag=50, ordered=ordered, max_wait=10 * n, log=lambda m: None)
        for k in range(n):              # channel 0 entirely first, then channel 1: n samples apart
            if k not in hole:
                al.push(0, int(stamps[k]), a[k])
        for k in range(n):
            al.push(1, int(stamps[k]), b[k])
        runs, rows = _rows(al)
        if ordered:
            assert al.counts["gap"] == expect_gaps and [r.segment for r in runs] == [0, 1]
            keep = np.array([k not in hole for k in range(n)])
            np.testing.assert_array_equal(rows, np.column_stack([a, b])[keep])
            assert runs[1].stamp_ns == stamps[4010]
        else:  # the vehicle's rule: the channel that fell behind is given up on
            assert al.counts["gap"] >= 1 and rows.shape[0] < n - len(hole)


def test_ordered_aligner_keeps_the_old_stream_tail_of_a_channel_behind_when_the_other_restarts():
    """Replay started over while the body channel is still delivering the first pass's tail: that tail is
    aligned (not lost), and the restart happens once every channel went back."""
    n, fs = 2000, 1000.0
    stamps = 10**9 + np.arange(n) * 1_000_000
    a, b = np.arange(n, dtype=float), -np.arange(n, dtype=float)
    al = SampleAligner(fs, 2, max_lag=50, ordered=True, restart_count=4, log=lambda m: None)
    for k in range(n):
        al.push(0, int(stamps[k]), a[k])
    for k in range(n - 300):
        al.push(1, int(stamps[k]), b[k])
    for k in range(20):                  # channel 0 starts over ...
        al.push(0, int(stamps[k]), a[k])
    for k in range(n - 300, n):          # ... while channel 1's first pass still arrives
        al.push(1, int(stamps[k]), b[k])
    for k in range(20):
        al.push(1, int(stamps[k]), b[k])
    runs, rows = _rows(al)
    assert [r.segment for r in runs] == [0, 1] and al.counts["restart"] == 1 and al.counts["gap"] == 0
    np.testing.assert_array_equal(rows[:n], np.column_stack([a, b]))
    np.testing.assert_array_equal(rows[n:], np.column_stack([a, b])[:20])


def test_aligner_drops_late_and_duplicate_samples_without_a_new_segment():
    msgs = []
    al = SampleAligner(100.0, 2, max_lag=5, log=msgs.append)
    st = np.arange(20) * 10_000_000
    _feed(al, st[:10], np.arange(10.0), np.arange(10.0))
    al.push(0, int(st[3]), 99.0)  # late (already emitted)
    al.push(0, int(st[10]), 10.0)
    al.push(0, int(st[10]), 77.0)  # duplicate
    _feed(al, st[10:], np.arange(10.0, 20), np.arange(10.0, 20))
    runs, rows = _rows(al)
    assert {r.segment for r in runs} == {0}
    np.testing.assert_array_equal(rows[:, 0], np.arange(20.0))
    assert al.counts["late"] == 1 and al.counts["duplicate"] >= 1 and any("late" in m for m in msgs)


def test_aligner_skips_a_nan_burst_and_starts_a_new_segment_after_it():
    al = SampleAligner(100.0, 2, max_lag=5, log=lambda m: None)
    st = np.arange(40) * 10_000_000
    a = np.arange(40.0)
    a[15:20] = np.nan
    _feed(al, st, a, np.arange(40.0))
    runs, rows = _rows(al)
    assert [r.segment for r in runs] == [0, 1]
    np.testing.assert_array_equal(runs[0].rows[:, 0], np.arange(15.0))
    np.testing.assert_array_equal(runs[1].rows[:, 0], np.arange(20.0, 40))
    assert runs[1].stamp_ns == st[20] and np.isfinite(rows).all()
    assert al.counts["nonfinite"] == 5 and al.counts["gap"] == 1


def test_aligner_survives_a_stalled_channel_and_resumes_on_a_new_segment():
    al = SampleAligner(100.0, 2, max_lag=5, log=lambda m: None)
    st = np.arange(100) * 10_000_000
    _feed(al, st[:30], np.arange(30.0), np.arange(30.0))
    for k in range(30, 80):  # the body publisher stalls
        al.push(0, int(st[k]), float(k))
    assert al.pending == 30
    _feed(al, st[80:], np.arange(80.0, 100), np.arange(80.0, 100))
    runs, _ = _rows(al)
    assert [r.segment for r in runs] == [0, 1]
    assert runs[1].stamp_ns == st[80] and runs[1].rows[0, 0] == 80.0


def test_aligner_treats_stamps_jumping_back_as_a_restarted_publisher():
    al = SampleAligner(100.0, 2, max_lag=5, restart_s=1.0, restart_count=4, log=lambda m: None)
    st = 50 * 10**9 + np.arange(300) * 10_000_000
    _feed(al, st, np.arange(300.0), np.arange(300.0))
    restart = 10**9 + np.arange(50) * 10_000_000  # the publisher starts over with earlier stamps
    for k, s in enumerate(restart):
        al.push(0, int(s), -float(k))
        al.push(1, int(s), -float(k))
    runs, _ = _rows(al)
    assert [r.segment for r in runs] == [0, 1]
    assert runs[1].stamp_ns == restart[0]
    np.testing.assert_array_equal(runs[1].rows[:, 0], -np.arange(50.0))
    assert al.counts["restart"] == 1


@pytest.mark.parametrize("node,param", [("integrator", "fs_hz:=-5.0"), ("identifier", "publish_period_s:=0.0")])
def test_a_node_with_an_invalid_parameter_says_so_in_one_line_and_exits_with_the_config_code(node, param):
    import os
    import subprocess
    import sys

    pytest.importorskip("rclpy")
    from nifo_nodes.launcher import claim_domain_id

    with claim_domain_id() as domain:
        out = subprocess.run([sys.executable, "-m", f"nifo_nodes.{node}", "--ros-args", "-p", param],
                             capture_output=True, text=True, timeout=60,
                             env={**os.environ, "ROS_DOMAIN_ID": str(domain)})
    assert out.returncode == 9, out.stderr
    assert "Traceback" not in out.stderr
    assert f"{node}: invalid parameters:" in out.stderr and "Fix:" in out.stderr
