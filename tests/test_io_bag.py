"""rosbag2/MCAP bags: exact round trips, what other tools see in our bags, topic discovery, decoding."""

from __future__ import annotations

from pathlib import Path

import time
from dataclasses import replace

import numpy as np
import pytest
import yaml

from nifo.io.bag import (IMU, POINT_STAMPED, BagTopics, TopicData, read_bag, resolve_topics, write_bag,
                         write_channels)
from nifo.io.bag._mcap import _decode    # the decoder itself, tested inside its package
from nifo.io.loader import load_record, save_record
from nifo_core.errors import DataFileError, MissingChannelError
from nifo_core.signal.record import Record

FS = 600.0


def make_record(n: int = 1200, *, tire: bool = True, t0_ns: int = 1_700_000_000_123_456_789,
                fs: float = FS, seed: int = 0) -> Record:
    rng = np.random.default_rng(seed)
    return Record(fs, rng.standard_normal(n) * 3.0, rng.standard_normal(n),
                  rng.standard_normal(n) * 1e-3 if tire else None, t0_ns=t0_ns, source="test")


def assert_same(a: Record, b: Record) -> None:
    assert a.fs_hz == b.fs_hz
    assert a.t0_ns == b.t0_ns
    assert np.array_equal(a.spindle_accel, b.spindle_accel)
    assert np.array_equal(a.body_accel, b.body_accel)
    assert a.has_tire_patch == b.has_tire_patch
    if a.has_tire_patch:
        assert np.array_equal(a.tire_patch_disp, b.tire_patch_disp)


@pytest.mark.parametrize("tire", [True, False], ids=["tire", "no_tire"])
@pytest.mark.parametrize("name", ["run1", "run1.mcap"], ids=["directory", "mcap_file"])
def test_bag_round_trip_is_exact(tmp_path, name, tire):
    rec = make_record(tire=tire)
    out = save_record(tmp_path / name, rec)
    assert out == tmp_path / name
    back = load_record(out)
    assert_same(rec, back)
    assert back.source == name
    assert back.meta["format"] == "rosbag2" and back.meta["storage"] == "mcap"
    assert back.meta["stamps"] == "header" and back.meta["axis"] == "z"
    assert back.meta["topics"]["spindle"] == "/nifo/spindle/imu"
    assert back.meta["topics"]["tire_patch"] == ("/nifo/tire_patch/displacement" if tire else None)


@pytest.mark.parametrize("fs", [600.0, 2441.40625, 1000.0, 97.5])
def test_bag_round_trip_recovers_the_nominal_rate(tmp_path, fs):
    rec = make_record(n=777, fs=fs, t0_ns=0, tire=False)
    assert_same(rec, read_bag(write_bag(tmp_path / "b", rec, start_ns=0)))
    # by default a record without a start time (t0_ns 0) starts now, not in 1970
    before = time.time_ns()
    back = read_bag(write_bag(tmp_path / "c", rec))
    assert before <= back.t0_ns <= time.time_ns()
    assert_same(replace(rec, t0_ns=back.t0_ns), back)


def test_bag_chunks_carry_crcs_and_an_honest_distro(tmp_path):
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    bag = write_bag(tmp_path / "run", make_record(n=3000))
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["ros_distro"] == "jazzy"
    with (bag / "run.mcap").open("rb") as f:
        records = list(StreamReader(f, skip_magic=False, emit_chunks=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    meta = {r.name: r.metadata for r in records if type(r).__name__ == "Metadata"}
    assert chunks and all(c.uncompressed_crc != 0 for c in chunks)
    assert yaml.safe_load(meta["rosbag2"]["serialized_metadata"])["ros_distro"] == "jazzy"


def test_bag_with_other_axis_and_topics_round_trips(tmp_path):
    rec = make_record()
    topics = BagTopics(spindle="/car/fl/spindle_imu", body="/car/body_imu", tire_patch="/rig/tire_patch")
    path = write_bag(tmp_path / "b", rec, topics=topics, axis="x")
    assert_same(rec, read_bag(path, topics=topics, axis="x"))
    # found by name; nothing on the z axis is a clear error, not a record of zeros
    with pytest.raises(DataFileError, match=r"/car/fl/spindle_imu: all 1200 samples are 0: the sensor recorded "
                                            r"nothing.*--axis"):
        read_bag(path, axis="z")


def test_bag_directory_has_a_metadata_yaml_that_ros2_bag_reads(tmp_path):
    rec = make_record(n=300)
    bag = write_bag(tmp_path / "run1", rec)
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "run1.mcap"]
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 8  # read by Humble and Jazzy
    assert info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == ["run1.mcap"]
    assert info["message_count"] == 900
    assert info["starting_time"]["nanoseconds_since_epoch"] == rec.t0_ns
    assert info["custom_data"]["generator"].startswith("nifo ")  # a map: ros2 bag cannot read null
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert set(topics) == {"/nifo/spindle/imu", "/nifo/body/imu", "/nifo/tire_patch/displacement"}
    for name, t in topics.items():
        md = t["topic_metadata"]
        assert t["message_count"] == 300
        assert md["serialization_format"] == "cdr"
        assert md["type"] == (POINT_STAMPED if "tire" in name else IMU)
        (qos,) = yaml.safe_load(md["offered_qos_profiles"])  # v8: a YAML string holding a list
        assert (qos["history"], qos["depth"], qos["reliability"], qos["durability"]) == (1, 5, 2, 2)
        assert qos["deadline"] == {"sec": 0, "nsec": 0}


def test_independent_mcap_ros2_decoder_reads_our_bag(tmp_path):
    mcap_reader = pytest.importorskip("mcap.reader")
    decoder = pytest.importorskip("mcap_ros2.decoder")
    rec = make_record(n=50)
    path = save_record(tmp_path / "run.mcap", rec)
    got: dict[str, list] = {}
    with path.open("rb") as f:
        reader = mcap_reader.make_reader(f, decoder_factories=[decoder.DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, msg in reader.iter_decoded_messages():
            got.setdefault(channel.topic, []).append((schema.name, message.log_time, msg))
            assert "offered_qos_profiles" in channel.metadata
    assert {k: v[0][0] for k, v in got.items()} == {
        "/nifo/spindle/imu": IMU, "/nifo/body/imu": IMU, "/nifo/tire_patch/displacement": POINT_STAMPED}
    stamps = rec.t0_ns + np.rint(np.arange(rec.n) * 1e9 / FS).astype(np.int64)
    for topic, values, frame in (("/nifo/spindle/imu", rec.spindle_accel, "spindle"),
                                 ("/nifo/body/imu", rec.body_accel, "body")):
        msgs = [m for _, _, m in got[topic]]
        assert [m.header.frame_id for m in msgs] == [frame] * rec.n
        assert np.array_equal([m.linear_acceleration.z for m in msgs], values)
        assert not np.any([[m.linear_acceleration.x, m.linear_acceleration.y] for m in msgs])
        assert np.array_equal([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs], stamps)
        assert np.array_equal([t for _, t, _ in got[topic]], stamps)  # log time = header stamp
        assert all(m.orientation_covariance[0] == -1 for m in msgs)  # REP-145: no orientation
    pts = [m for _, _, m in got["/nifo/tire_patch/displacement"]]
    assert np.array_equal([p.point.z for p in pts], rec.tire_patch_disp)


def test_rclpy_deserializes_our_messages(tmp_path):
    serialization = pytest.importorskip("rclpy.serialization")
    msg_mod = pytest.importorskip("sensor_msgs.msg")
    from rosbags.rosbag2 import Reader

    rec = make_record(n=5)
    with Reader(save_record(tmp_path / "run.mcap", rec)) as reader:
        conn = next(c for c in reader.connections if c.topic == "/nifo/spindle/imu")
        raws = [d for _, _, d in reader.messages([conn])]
    msgs = [serialization.deserialize_message(d, msg_mod.Imu) for d in raws]
    assert np.array_equal([m.linear_acceleration.z for m in msgs], rec.spindle_accel)
    assert msgs[0].header.stamp.sec == rec.t0_ns // 10**9
    assert msgs[0].header.stamp.nanosec == rec.t0_ns % 10**9


def test_payloads_equal_rosbags_serializer():
    from rosbags.typesys import Stores, get_typestore

    from nifo.io.bag.cdr import payloads as _payloads

    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    stamp = np.array([1_700_000_001_000_000_007], np.int64)
    c = np.zeros(9)
    nc = c.copy()
    nc[0] = -1.0
    hdr = T["std_msgs/msg/Header"](T["builtin_interfaces/msg/Time"](1_700_000_001, 7), "body")
    vec = T["geometry_msgs/msg/Vector3"]
    imu = T[IMU](hdr, T["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 0.0), nc, vec(0.0, 0.0, 0.0), nc.copy(),
                 vec(0.0, -2.5, 0.0), c)
    assert _payloads(stamp, np.array([-2.5]), frame_id="body", msgtype=IMU, axis="y").tobytes() == \
        bytes(ts.serialize_cdr(imu, IMU))
    pt = T[POINT_STAMPED](hdr, T["geometry_msgs/msg/Point"](0.0, 0.0, 0.25))
    assert _payloads(stamp, np.array([0.25]), frame_id="body", msgtype=POINT_STAMPED, axis="z").tobytes() == \
        bytes(ts.serialize_cdr(pt, POINT_STAMPED))


def test_fast_decoder_agrees_with_generic_path_for_odd_messages():
    """Mixed frame_id lengths, big-endian and little-endian messages: same stamps and values."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    vec = T["geometry_msgs/msg/Vector3"]
    raws, want_t, want_v = [], [], []
    for i, (frame, le) in enumerate([("imu", True), ("spindle_front_left", True), ("imu", False),
                                     ("a", True), ("imu", True), ("imu", False)]):
        hdr = T["std_msgs/msg/Header"](T["builtin_interfaces/msg/Time"](100 + i, 5 * i), frame)
        m = T[IMU](hdr, T["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0), np.zeros(9), vec(1.0, 2.0, 3.0),
                   np.zeros(9), vec(0.5, -1.5, i + 0.25), np.zeros(9))
        raws.append(bytes(ts.serialize_cdr(m, IMU, little_endian=le)))
        want_t.append((100 + i) * 10**9 + 5 * i)
        want_v.append(i + 0.25)
    stamps, values = _decode(raws, msgtype=IMU, axis="z", typestore=ts)
    assert stamps.tolist() == want_t
    assert values.tolist() == want_v
    _, ys = _decode(raws, msgtype=IMU, axis="y", typestore=ts)
    assert ys.tolist() == [-1.5] * len(raws)


def test_reads_mcap_in_a_directory_without_metadata(tmp_path):
    rec = make_record(n=100, tire=False)
    d = tmp_path / "copied"
    d.mkdir()
    save_record(d / "x.mcap", rec)
    assert_same(rec, load_record(d))


def _stamps(n: int, *, start: int = 0, fs: float = FS, t0: int = 10**18) -> np.ndarray:
    return t0 + np.rint((start + np.arange(n)) * 1e9 / fs).astype(np.int64)


def test_topics_found_by_name_when_defaults_are_absent(tmp_path):
    n = 100
    rng = np.random.default_rng(3)
    s, b, r = rng.standard_normal((3, n))
    path = write_channels(tmp_path / "b.mcap", [
        TopicData("/vehicle/wheel_rr/imu", IMU, "w", _stamps(n), s),
        TopicData("/vehicle/chassis/imu", IMU, "c", _stamps(n), b),
        TopicData("/rig/road_height", POINT_STAMPED, "r", _stamps(n), r),
        TopicData("/vehicle/gps/imu_unrelated", POINT_STAMPED, "g", _stamps(n), r)])
    rec = read_bag(path)
    assert rec.meta["topics"] == {"spindle": "/vehicle/wheel_rr/imu", "body": "/vehicle/chassis/imu",
                                  "tire_patch": "/rig/road_height"}
    assert np.array_equal(rec.spindle_accel, s) and np.array_equal(rec.tire_patch_disp, r)


def test_unsprung_is_spindle_not_body():
    got = resolve_topics({"/unsprung_mass/accel": IMU, "/sprung_mass/accel": IMU}, None, source="x")
    assert got == {"spindle": "/unsprung_mass/accel", "body": "/sprung_mass/accel", "tire_patch": None}


def test_ambiguous_topics_list_the_candidates():
    with pytest.raises(MissingChannelError, match=r"several Imu topics could be the spindle .*"
                                                  r"/fl/wheel_imu, /fr/wheel_imu.*--topics spindle="):
        resolve_topics({"/fl/wheel_imu": IMU, "/fr/wheel_imu": IMU, "/body/imu": IMU}, None, source="x")


def test_explicit_topics_choose_among_several(tmp_path):
    n = 60
    vals = np.arange(4 * n, dtype=float).reshape(4, n)
    path = write_channels(tmp_path / "b", [
        TopicData(f"/{c}/wheel_imu", IMU, c, _stamps(n), v) for c, v in zip(["fl", "fr", "rl"], vals)]
        + [TopicData("/body/imu", IMU, "body", _stamps(n), vals[3])])
    rec = load_record(path, topics=BagTopics.parse("spindle=/fr/wheel_imu,body=/body/imu"))
    assert np.array_equal(rec.spindle_accel, vals[1])
    assert rec.meta["topics"]["tire_patch"] is None


def test_channels_are_trimmed_to_their_common_samples(tmp_path):
    n = 200
    s = np.arange(n, dtype=float)
    path = write_channels(tmp_path / "b", [
        TopicData("/nifo/spindle/imu", IMU, "spindle", _stamps(n), s),
        TopicData("/nifo/body/imu", IMU, "body", _stamps(n - 7, start=3), -s[3:n - 4])])
    rec = read_bag(path)
    assert rec.n == n - 7
    assert rec.t0_ns == _stamps(n)[3]
    assert np.array_equal(rec.spindle_accel, s[3:n - 4])
    assert np.array_equal(rec.body_accel, -s[3:n - 4])
    assert rec.meta["trimmed"] == {"/nifo/spindle/imu": [3, 4]}


def test_zero_header_stamps_fall_back_to_receive_time(tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    from nifo.io.bag.cdr import payloads as _payloads

    ts = get_typestore(Stores.ROS2_JAZZY)
    n = 120
    log = _stamps(n)
    vals = {"/nifo/spindle/imu": np.linspace(0, 1, n), "/nifo/body/imu": np.linspace(1, 2, n)}
    with Writer(tmp_path / "b", version=8, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {t: w.add_connection(t, IMU, typestore=ts) for t in vals}
        rows = {t: _payloads(np.zeros(n, np.int64), v, frame_id="x", msgtype=IMU, axis="z") for t, v in vals.items()}
        for i in range(n):
            for t in vals:
                w.write(conns[t], int(log[i]), rows[t][i].tobytes())
    rec = read_bag(tmp_path / "b")
    assert rec.meta["stamps"] == "receive_time"
    assert rec.fs_hz == FS and rec.t0_ns == log[0]
    assert np.array_equal(rec.body_accel, vals["/nifo/body/imu"])


def test_bag_topics_parse_accepts_channel_names():
    assert BagTopics.parse("spindle_accel=/a, body=/b ,tire_patch=/c") == BagTopics("/a", "/b", "/c")
    assert BagTopics.parse("spindle=/a,body=/b").tire_patch == BagTopics().tire_patch


def test_writing_replaces_an_existing_bag(tmp_path):
    first, second = make_record(n=100, seed=1), make_record(n=150, seed=2)
    save_record(tmp_path / "b", first)
    save_record(tmp_path / "b", second)
    assert_same(second, load_record(tmp_path / "b"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]


def test_bag_paths_are_accepted_as_str(tmp_path):
    rec = make_record(n=64)
    out = save_record(str(tmp_path / "s.mcap"), rec)
    assert isinstance(out, Path)
    assert_same(rec, load_record(str(out)))


@pytest.mark.parametrize("mode", ["none", "storage", "file", "message"])
def test_compressed_bags_read_the_same(tmp_path, mode):
    """zstd chunks go through the indexed fast path; file/message compression through rosbags' reader."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    from nifo.io.bag.cdr import payloads as _payloads

    ts = get_typestore(Stores.ROS2_JAZZY)
    rec = make_record(n=5000, tire=False)
    st = rec.t0_ns + np.rint(np.arange(rec.n) * 1e9 / FS).astype(np.int64)
    w = Writer(tmp_path / "b", version=8, storage_plugin=StoragePlugin.MCAP)
    if mode != "none":
        w.set_compression(CompressionMode[mode.upper()], CompressionFormat.ZSTD)
    with w:
        rows = [(w.add_connection(topic, IMU, typestore=ts), _payloads(st, vals, frame_id="f", msgtype=IMU, axis="z"))
                for topic, vals in (("/nifo/spindle/imu", rec.spindle_accel), ("/nifo/body/imu", rec.body_accel))]
        for i in range(rec.n):
            for conn, r in rows:
                w.write(conn, int(st[i]), r[i].tobytes())
    assert_same(rec, read_bag(tmp_path / "b"))


def test_indexed_mcap_path_agrees_with_rosbags_iteration(tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from nifo.io.bag._read import _iterate, _read_mcap_indexed

    ts = get_typestore(Stores.ROS2_JAZZY)
    n = 3000  # several 1 MiB chunks
    rng = np.random.default_rng(5)
    path = write_channels(tmp_path / "b.mcap", [
        TopicData("/nifo/spindle/imu", IMU, "spindle", _stamps(n), rng.standard_normal(n)),
        TopicData("/nifo/body/imu", IMU, "a_longer_frame_id", _stamps(n, start=5), rng.standard_normal(n)),
        TopicData("/x", POINT_STAMPED, "x", _stamps(n), rng.standard_normal(n))])
    wanted = {"spindle": ("/nifo/spindle/imu", IMU), "body": ("/nifo/body/imu", IMU), "tire_patch": ("/x", POINT_STAMPED)}
    fast = _read_mcap_indexed(path, wanted, expected={r: n for r in wanted}, axis="z", typestore=ts)
    assert _read_mcap_indexed(path, wanted, expected={r: n + 1 for r in wanted}, axis="z", typestore=ts) is None
    with Reader(path) as reader:
        slow = _iterate(reader, reader.connections, wanted, axis="z", typestore=ts)
    for role in wanted:
        for a, b in zip(fast[role], slow[role]):
            assert np.array_equal(a, b)
        assert fast[role][0].size == n
