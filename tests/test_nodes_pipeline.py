"""The real nodes as separate processes (isolated ROS_DOMAIN_ID): replay → integrator → identifier.

Equality with the batch engine: the identifier feeds ``StreamingNifo``, the
code path ``identify_nifo`` runs, with the same samples (bit-exact through the
messages: float64 all the way). The only difference is chunking: the batch
pushes the record in one piece, the node in blocks of ``block_s``; the
streaming integrator's overlap-add FFT convolution then rounds differently,
≈1e-16 relative per sample. We allow rtol 1e-9 on T21/H1/coherence and on
the coefficient functions in the analysis band (lines where G_UU is
ill-conditioned amplify rounding, hence not 1e-15).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytestmark = pytest.mark.ros

from nifo_nodes.launcher import CONFIG_DIR, NodeSpec, busy_core, claim_domain_id, start, stop  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FS = 250.0
BLOCK, OVERLAP, BAND = 512, 0.5, (2.0, 100.0)
TERMS = [{"kind": "velocity_deadzone", "params": {"knee": 0.03}}]
RTOL = 1e-9


# ----------------------------------------------------------------------------- fixtures and helpers
@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    """A 40 s simulated record at 250 Hz (paper damper knee) saved as an MCAP bag, and its model file."""
    from nifo.io.loader import load_record, save_record
    from nifo.io.modelfile import write_model_spec
    from nifo_core.kinds.describing import make_term
    from nifo_core.simulate.quarter_car import SimConfig, preset, simulate

    d = tmp_path_factory.mktemp("nodes")
    sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=40.0, fs_hz=FS), rng=3)
    save_record(d / "run.mcap", sim.record)
    model = write_model_spec(d / "model.yaml", [make_term(t) for t in TERMS],
                             settings={"block": BLOCK, "overlap": OVERLAP, "band_hz": list(BAND)})
    return {"bag": d / "run.mcap", "record": load_record(d / "run.mcap"), "model": model, "dir": d}


def batch_result(record_pieces):
    """The batch engine on one record or on pieces separated by stream gaps."""
    from nifo_core.kinds.describing import make_term
    from nifo_core.signal.integrate import IntegrationBand
    from nifo_core.nifo.identify import StreamingNifo, identify_nifo
    from nifo_core.signal.spectral import SpectralSettings

    kw = dict(settings=SpectralSettings(block=BLOCK, overlap=OVERLAP), band=IntegrationBand(*BAND))
    terms = [make_term(t) for t in TERMS]
    if not isinstance(record_pieces, list):
        return identify_nifo(record_pieces, terms, on_ill_conditioned="ignore", **kw)
    s = StreamingNifo(FS, terms, on_ill_conditioned="ignore", **kw)
    for a1, a2 in record_pieces:
        s.push(a1, a2)
        s.end_record()
    return s.result()


@pytest.fixture
def domain(tmp_path):
    """A domain id no concurrent test run or benchmark holds (a lock file per id), for this test only;
    ROS_HOME in the test's directory (the identifier's default result file goes there)."""
    with claim_domain_id() as d:
        env = dict(os.environ, ROS_DOMAIN_ID=str(d), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   ROS_HOME=str(tmp_path / "ros_home"),
                   PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        yield d, env


def node(name, sample, **params):
    files = (str(CONFIG_DIR / f"{name}.yaml"),)
    if name == "identifier":
        params.setdefault("model_file", str(sample["model"]))
        params.setdefault("publish_period_s", 0.3)
    if name == "integrator":
        params.setdefault("fs_hz", FS)
        params.setdefault("input_reliability", "reliable")  # lossless input: the tests compare with batch
    return NodeSpec(name, params_files=files, params=params)


def replay(bag, env, *, rate=4.0):
    """``nifo replay --reliable``: a CPU-starved node slows the replay down instead of losing samples."""
    return subprocess.Popen([sys.executable, "-m", "nifo", "replay", str(bag), "--rate", str(rate), "--wait", "15",
                             "--reliable", "--topics", "/nifo/spindle/imu", "/nifo/body/imu"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)


class Collector:
    """In-process subscriber (own rclpy context) keeping blocks and the latest results."""

    def __init__(self, domain_id: int):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from diagnostic_msgs.msg import DiagnosticArray
        from std_msgs.msg import Float64MultiArray

        from nifo_msgs.msg import Coefficients, LoopStatus, Transmissibility
        from nifo_nodes.common import block_qos, result_qos
        from nifo_nodes.messages import block_from_msg

        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = rclpy.create_node("collector", namespace="/nifo", context=self.ctx)
        self.blocks = {"accel": [], "motion": []}
        self.latest: dict = {}
        def keep(k, m):
            try:
                self.blocks[k].append(block_from_msg(m))
            except ValueError:  # the robustness test's own malformed block
                pass

        for k in self.blocks:
            self.node.create_subscription(Float64MultiArray, f"{k}/block", lambda m, k=k: keep(k, m), block_qos(keep_all=True))
        for k, t in (("transmissibility", Transmissibility), ("coefficients", Coefficients), ("status", LoopStatus)):
            self.node.create_subscription(t, f"identifier/{k}", lambda m, k=k: self.latest.__setitem__(k, m),
                                          result_qos())
        self.diagnostics: dict = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _on_diag(self, msg):
        for st in msg.status:
            self.diagnostics[st.name] = (st.level[0], st.message, {kv.key: kv.value for kv in st.values})

    def _spin(self):
        while self.ctx.ok():
            try:
                self.ex.spin_once(timeout_sec=0.05)
            except Exception:  # context shut down under us
                break

    def wait_for(self, cond, timeout_s: float, what: str):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if cond():
                return
            time.sleep(0.1)
        raise AssertionError(f"timed out waiting for {what() if callable(what) else what}")

    def wait_pipeline(self, tmp_path, timeout_s: float = 60):
        """Until the integrator listens to the Imu topics and the identifier to accel/block."""
        self.wait_for(lambda: self.node.count_subscribers("/nifo/spindle/imu") >= 1
                      and self.node.count_subscribers("/nifo/body/imu") >= 1
                      and self.node.count_subscribers("/nifo/accel/block") >= 2, timeout_s,
                      lambda: f"the nodes to come up\n{logs(tmp_path)}")

    def done(self, ref) -> bool:
        """The published estimate holds every block and every sample of ``ref`` (the tail adds samples
        without completing a block)."""
        t = self.latest.get("transmissibility")
        return t is not None and t.n_avg == ref.n_avg and t.samples_used == ref.n_samples

    def navg(self) -> int:
        t = self.latest.get("transmissibility")
        return -1 if t is None else t.n_avg

    def got(self) -> str:
        t = self.latest.get("transmissibility")
        return "nothing" if t is None else f"{t.n_avg} blocks, {t.samples_used} samples, {t.gaps} gaps"

    def close(self):
        self.ctx.try_shutdown()
        self.thread.join(2)
        self.node.destroy_node()


def _c(re, im) -> np.ndarray:
    return np.asarray(re) + 1j * np.asarray(im)


def assert_matches_batch(latest, ref, *, rtol=RTOL):
    """The published nifo_msgs estimate equals the batch NifoResult ``ref`` to ``rtol``."""
    t, coef = latest["transmissibility"], latest["coefficients"]
    assert t.n_avg == ref.n_avg and t.samples_used == ref.n_samples
    np.testing.assert_array_equal(t.freq_hz, ref.freq_hz)
    np.testing.assert_allclose(_c(t.t21_re, t.t21_im), ref.t21, rtol=rtol, atol=0)
    np.testing.assert_allclose(_c(t.t21_h1_re, t.t21_h1_im), ref.t21_h1, rtol=rtol, atol=0)
    np.testing.assert_allclose(t.coherence_h1, ref.coherence_h1, rtol=rtol, atol=1e-15)
    band = ref.in_band
    # the nominal (pooled static) estimate nifo identify recommends
    np.testing.assert_allclose(_c(t.t21_nominal_re, t.t21_nominal_im)[band], ref.static.t21[band], rtol=rtol)
    np.testing.assert_allclose(coef.c_pooled, ref.static.c_over_m2, rtol=rtol)
    nf = len(coef.freq_hz)
    np.testing.assert_allclose(_c(coef.c_re, coef.c_im)[:nf][band], ref.c_over_m2[0][band], rtol=rtol)
    np.testing.assert_allclose(_c(coef.b_re, coef.b_im)[:nf][band], ref.b[0][band], rtol=rtol)
    st = latest["status"]
    assert st.n_avg == ref.n_avg and st.result_file
    doc = json.loads(Path(st.result_file).read_text())  # the full document, beside the messages
    assert doc["n_avg"] == ref.n_avg and doc["stream"]["samples_used"] == ref.n_samples


def _by_segment(blocks) -> dict:
    out: dict = {}
    for b in blocks:
        lo, n = out.get(b.segment, (b.stamp_ns, 0))
        out[b.segment] = (min(lo, b.stamp_ns), n + b.n)
    return out


def logs(d: Path) -> str:
    return "\n".join(f"--- {p.name}\n{p.read_text(errors='replace')[-3000:]}" for p in sorted(d.glob("*.log")))


# ----------------------------------------------------------------------------- tests
def test_replayed_bag_through_integrator_and_identifier_equals_the_batch_engine(sample, domain, tmp_path):
    from nifo_core.signal.integrate import IntegrationBand, integrate

    dom, env = domain
    rec = sample["record"]
    procs, col = [], None
    try:
        col = Collector(dom)
        procs += [start(node("integrator", sample, f_lo_hz=BAND[0], f_hi_hz=BAND[1]), env=env, log_dir=tmp_path),
                  start(node("identifier", sample), env=env, log_dir=tmp_path)]
        col.wait_pipeline(tmp_path)
        rp = replay(sample["bag"], env)
        procs.append(rp)
        ref = batch_result(rec)
        col.wait_for(lambda: col.done(ref), 90, f"n_avg={ref.n_avg}, {ref.n_samples} samples (got {col.got()})\n{logs(tmp_path)}")
        assert rp.wait(30) == 0, rp.stdout.read().decode()
        assert_matches_batch(col.latest, ref)
        # the aligned accelerations are the recorded samples, bit for bit
        acc = np.concatenate([b.data for b in col.blocks["accel"]])
        np.testing.assert_array_equal(acc, np.column_stack([rec.spindle_accel, rec.body_accel]))
        assert {b.segment for b in col.blocks["accel"]} == {0}
        # the integrator's motion: the offline zero-phase integration, once the segment is closed at shutdown
        stop(procs[:1])
        col.wait_for(lambda: sum(b.n for b in col.blocks["motion"]) >= rec.n, 10, "the motion tail")
        mot = np.concatenate([b.data for b in col.blocks["motion"]])
        rel = integrate(rec.body_accel - rec.spindle_accel, FS, band=IntegrationBand(*BAND))
        scale = np.abs(rel.displacement).max()
        np.testing.assert_allclose(mot[:, 5], rel.displacement, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(mot[:, 4], rel.velocity, rtol=0, atol=1e-12 * np.abs(rel.velocity).max())
        assert col.blocks["motion"][0].stamp_ns == rec.t0_ns
    finally:
        stop(procs)
        if col:
            col.close()


def test_identifier_killed_mid_run_resumes_from_its_checkpoint_to_the_same_estimate(sample, domain, tmp_path):
    dom, env = domain
    ckpt = tmp_path / "identifier.npz"
    ident = node("identifier", sample, checkpoint_file=str(ckpt), checkpoint_period_s=0.3)
    procs, col = [], None
    try:
        col = Collector(dom)
        integ = start(node("integrator", sample, f_lo_hz=BAND[0], f_hi_hz=BAND[1]), env=env, log_dir=tmp_path)
        first = start(ident, env=env, log_dir=tmp_path)
        procs += [integ, first]
        col.wait_pipeline(tmp_path)
        rp = replay(sample["bag"], env)
        procs.append(rp)
        ref = batch_result(sample["record"])
        col.wait_for(lambda: col.navg() >= 3 and ckpt.exists(), 60, f"a checkpoint\n{logs(tmp_path)}")
        os.killpg(first.pid, signal.SIGKILL)  # no chance to write a last checkpoint
        first.wait(5)
        assert col.latest["transmissibility"].n_avg < ref.n_avg
        rp.wait(60)
        second = start(ident, env=env, log_dir=tmp_path)
        procs.append(second)
        # replay again once the new identifier listens (blocks published before that are not for it)
        col.wait_for(lambda: col.node.count_subscribers("/nifo/accel/block") >= 2, 30, "the restarted identifier")
        time.sleep(1.0)
        procs.append(replay(sample["bag"], env))  # the bag again: the identifier skips what it already has
        col.wait_for(lambda: col.done(ref), 90,
                     lambda: f"n_avg={ref.n_avg}, {ref.n_samples} samples (got {col.got()}); accel blocks by segment "
                     f"{np.unique([b.segment for b in col.blocks['accel']], return_counts=True)}\n{logs(tmp_path)}")
        time.sleep(1.0)  # nothing more may arrive: every sample is used once
        assert_matches_batch(col.latest, ref)
        assert "resumed from" in (tmp_path / "identifier.log").read_text()
    finally:
        stop(procs)
        if col:
            col.close()


def test_malformed_late_nan_stalled_and_restarted_streams_are_logged_and_skipped(sample, domain, tmp_path):
    """A hostile stream: junk bytes, late duplicates, a NaN burst, a 1.5 s stall, a publisher starting over,
    a malformed block. The nodes stay up and the estimate equals the batch engine on the clean pieces."""
    from rclpy.qos import qos_profile_sensor_data  # noqa: F401 - QoS comes from nifo_nodes.common
    from sensor_msgs.msg import Imu
    from std_msgs.msg import Float64MultiArray

    from nifo_nodes.common import block_qos, publish_blocking, reliable_input_qos
    from nifo_nodes.messages import ImuEncoder

    dom, env = domain
    rec = sample["record"]
    a1, a2 = rec.spindle_accel.copy(), rec.body_accel.copy()
    nan0, nan1 = 5000, 5050
    a1[nan0:nan1] = np.nan
    stamps = rec.t0_ns + np.rint(np.arange(rec.n) * 1e9 / FS).astype(np.int64)
    procs, col = [], None
    try:
        col = Collector(dom)
        # reliable keep-all, as nifo replay --reliable: the hostile events are ours, not the machine's load
        pubs = [col.node.create_publisher(Imu, t, reliable_input_qos()) for t in ("spindle/imu", "body/imu")]
        bad_block = col.node.create_publisher(Float64MultiArray, "accel/block", block_qos())
        enc = [ImuEncoder("spindle"), ImuEncoder("body")]
        integ = start(node("integrator", sample, f_lo_hz=BAND[0], f_hi_hz=BAND[1]), env=env, log_dir=tmp_path)
        ident = start(node("identifier", sample), env=env, log_dir=tmp_path)
        procs += [integ, ident]
        # the identifier must listen too: the integrator's blocks are volatile, and the collector's own
        # subscription to accel/block already matches bad_block (CI once lost the first block of 293 rows to
        # an identifier still starting: n_avg one short, no gap counted)
        col.wait_pipeline(tmp_path, 30)
        col.wait_for(lambda: all(p.get_subscription_count() > 0 for p in pubs), 30,
                     lambda: f"the nodes' subscriptions\n{logs(tmp_path)}")
        time.sleep(1.0)  # discovery is matched on both sides only a little after the publisher sees it

        def send(k, values=(a1, a2)):
            for ch in (0, 1):
                publish_blocking(pubs[ch], enc[ch].encode(int(stamps[k]), float(values[ch][k])))

        t0 = time.monotonic()
        for k in range(rec.n):
            send(k)
            if k % 500 == 250:
                publish_blocking(pubs[0], b"\x00\x01\x00\x00garbage")  # malformed
                publish_blocking(pubs[1], bytes(40))                     # malformed (not CDR LE)
            if k % 700 == 350:
                send(k - 3)                                              # late duplicates
            if k == 7000:
                time.sleep(1.5)                                          # stalled publisher
                bad_block.publish(Float64MultiArray(data=[1.0, 2.0, 3.0]))  # malformed block
                t0 += 1.5
            if k % 25 == 0:  # pace at ~1500 messages/s (a stream, not one burst)
                lag = t0 + k / 750 - time.monotonic()
                if lag > 0:
                    time.sleep(lag)
        for k in range(1000):                                            # the publisher starts over
            send(k, (rec.spindle_accel, rec.body_accel))
            if k % 50 == 0:
                time.sleep(0.02)
        ref = batch_result([(a1[:nan0], a2[:nan0]), (a1[nan1:], a2[nan1:])])
        col.wait_for(lambda: col.done(ref), 60, lambda: f"n_avg={ref.n_avg}, {ref.n_samples} samples (got {col.got()}); "
                     f"accel rows by segment {_by_segment(col.blocks['accel'])}; diagnostics {col.diagnostics}\n"
                     f"{logs(tmp_path)}")
        time.sleep(1.5)
        assert integ.poll() is None and ident.poll() is None, logs(tmp_path)
        assert_matches_batch(col.latest, ref)
        # the loss is never silent: counted, published (messages, diagnostics, result file)
        t, st = col.latest["transmissibility"], col.latest["status"]
        assert (t.gaps, t.samples_lost, st.gaps, st.samples_lost) == (1, nan1 - nan0, 1, nan1 - nan0)
        assert "1 stream gap(s), 50 samples lost" in st.message
        col.wait_for(lambda: {"nifo/integrator", "nifo/identifier"} <= set(col.diagnostics), 10, "diagnostics")
        lvl, msg, vals = col.diagnostics["nifo/identifier"]
        assert lvl == 1 and vals["gaps"] == "1" and vals["samples_lost"] == str(nan1 - nan0), (msg, vals)
        lvl, msg, vals = col.diagnostics["nifo/integrator"]
        assert lvl == 1 and int(vals["aligned_gap"]) >= 1 and int(vals["malformed"]) > 0, (msg, vals)
        assert json.loads(Path(st.result_file).read_text())["stream"]["gaps"] == 1
        il = (tmp_path / "integrator.log").read_text()
        for what in ("malformed message skipped", "non-finite sample", "late/out-of-order", "gap in the samples",
                     "publisher restarted"):
            assert what in il, il[-3000:]
        idl = (tmp_path / "identifier.log").read_text()
        assert "malformed block skipped" in idl and "stream gap" in idl, idl[-3000:]
        assert "the first block taken" not in idl, idl[-3000:]  # it listened before the stream began
    finally:
        stop(procs)
        if col:
            col.close()


# ----------------------------------------------------------------------------- acceptance: live = nifo identify
@pytest.mark.slow
def test_bundled_bag_replayed_reliably_with_a_cpu_hog_equals_nifo_identify(domain, tmp_path):
    """run_pipeline.py --bag bags/sample/road_2p5mm --reliable: the final published estimate equals
    ``nifo identify`` on the same bag (rtol 1e-9), no sample lost, no gap, while a CPU hog runs."""
    from nifo_core.nifo.identify import NifoResult

    dom, env = domain
    bag, model = REPO / "bags" / "sample" / "road_2p5mm", CONFIG_DIR / "model.yaml"
    ident = subprocess.run([sys.executable, "-m", "nifo", "identify", str(bag), "--model", str(model), "--out",
                            str(tmp_path / "identify"), "--no-plots", "--quiet", "--no-settings-from-data"], env=env, capture_output=True,
                           text=True, timeout=300)
    assert ident.returncode == 0, ident.stderr
    ref = NifoResult.from_dict(json.loads((tmp_path / "identify" / "identify.json").read_text())["result"])
    # one core kept busy by another process while the graph replays the bag (it must not lose a sample); started
    # after the reference, which it would only slow down
    with contextlib.ExitStack() as stack:
        cpu_hog = stack.enter_context(busy_core())
        col = Collector(dom)
        stack.callback(col.close)
        p = subprocess.run([sys.executable, str(REPO / "launch_scripts" / "run_pipeline.py"), "--bag", str(bag),
                            "--model", str(model), "--reliable", "--rate", "0", "--linger", "3", "--domain-id",
                            str(dom), "--log-dir", str(tmp_path), "--checkpoint", str(tmp_path / "id.npz"),
                            "--record", str(tmp_path / "results.mcap"), "--json"],
                           env=env, capture_output=True, text=True, timeout=400)
        assert p.returncode == 0, p.stderr + logs(tmp_path)
        # it ends saying what was identified and where the result is (--json: one document on stdout)
        found = json.loads(p.stdout)
        assert found["ok"] and found["result_file"] == str((tmp_path / "id.result.json").resolve())
        assert found["recording"] == str((tmp_path / "results.mcap").resolve()) and found["identified"]
        got = [t["c_over_m2"] for t in found["identified"]["terms"]]
        np.testing.assert_allclose(got, ref.static.c_over_m2, rtol=1e-9)
        assert found["identified"]["samples_lost"] == 0 and "identified  velocity_deadzone" in found["lines"][1]
        col.wait_for(lambda: col.done(ref), 20, lambda: f"the final estimate (got {col.got()})\n{p.stderr}\n{logs(tmp_path)}")
        assert_matches_batch(col.latest, ref)
        t = col.latest["transmissibility"]
        assert (t.gaps, t.samples_lost) == (0, 0)
        assert t.header.stamp.sec * 10**9 + t.header.stamp.nanosec == ref.freq_hz.size * 0 + 119_998_333_333
        assert t.header.frame_id == "body"
        assert cpu_hog.poll() is None  # the hog ran throughout
