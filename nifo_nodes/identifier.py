"""The identifier node: aligned acceleration blocks in, the live NIFO estimate out.

Subscribes ``accel/block`` (from the integrator node) and feeds the samples to
:class:`nifo_core.nifo.StreamingNifo` — the code path ``identify_nifo`` (``nifo
identify``) runs, so the live estimate is the batch one. Every
``publish_period_s`` (when new spectral blocks were averaged) it publishes,
reliable + transient local (a late subscriber gets the latest):

* ``identifier/transmissibility`` — ``Float64MultiArray`` table (layout in
  :mod:`nifo_nodes.messages`), columns ``freq_hz|t21_nominal_re|t21_nominal_im|
  t21_re|t21_im|t21_h1_re|t21_h1_im|coherence_h1|multiple_coherence|cond``:
  the nominal linear T21 (the pooled static fit, what ``nifo identify``
  recommends; the per-line estimate when no term is declared), the per-line
  output-only T21 = X2/X1 (paper Eq. 9), plain H1 and its ordinary coherence,
  the fit's multiple coherence, the condition number of G_UU;
* ``identifier/coefficients`` — columns ``freq_hz`` then, per term i,
  ``c<i>_pooled`` (the pooled constant c_i/M2, unit of c per kg),
  ``c<i>_re|c<i>_im`` (per-line c_i/M2: flat and real for a static
  nonlinearity) and ``b<i>_re|b<i>_im`` (B_i of paper Eq. 8);
* ``identifier/result`` — ``std_msgs/String``: ``NifoResult.to_dict()`` as JSON
  (term labels, settings, band, bounds' random errors: everything).

Stream bookkeeping: samples are identified by their stamps and each stamp is
used once. A block continuing the previous one is pushed; one that starts
later (a gap, a new segment) first closes the current record
(``StreamingNifo.end_record``: no block spans the gap); samples at or before
the newest already used are skipped (a duplicate, a replay started again:
that is how a restarted identifier resumes exactly). To accumulate the same
data again, reset first.

Parameters: ``model_file`` (YAML model file, ``nifo_model: 1``; its
``settings`` give the defaults of the next four), ``block``, ``overlap``,
``window``, ``f_lo_hz``/``f_hi_hz`` (integration band; 0: default),
``analysis_band_hz``, ``publish_period_s``, ``checkpoint_file`` (``""``: none),
``checkpoint_period_s``, ``reset`` (set true to drop everything accumulated;
reads back false). With ``std_srvs`` installed there is also the service
``~/reset`` (``std_srvs/srv/Trigger``).

Checkpoint: an ``.npz`` of ``StreamingNifo.state_dict()`` plus the newest stamp
used, written atomically (:func:`nifo.io.atomic.staged_file`) every
``checkpoint_period_s`` and at shutdown. At start-up an existing checkpoint
with the same terms and settings is resumed; one that does not match is left
in place and the node refuses to start (delete it or point elsewhere).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from nifo_core.errors import ConfigError, NifoError

from .common import TOPICS, block_qos, declare_parameters, result_qos, run_node
from .integrator import ACCEL_CHANNELS
from .messages import block_from_msg, table_to_msg

__all__ = ["IdentifierNode", "main", "load_checkpoint", "save_checkpoint"]

try:
    from rclpy.node import Node
except ImportError:  # pragma: no cover
    Node = object

_CKPT_VERSION = 1


def save_checkpoint(path: str | Path, nifo, *, next_ns: int) -> None:
    """Write ``nifo``'s state and the stream position atomically (``.npz``)."""
    from nifo.io.atomic import staged_file

    state = nifo.state_dict()
    state["node.version"] = np.array(_CKPT_VERSION)
    state["node.next_ns"] = np.array(int(next_ns), np.int64)
    with staged_file(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **state)


def load_checkpoint(path: str | Path):
    """``(StreamingNifo, next_ns)`` from :func:`save_checkpoint`'s file."""
    from nifo_core.nifo import StreamingNifo

    try:
        with np.load(path, allow_pickle=False) as z:
            state = {k: z[k] for k in z.files}
    except (OSError, ValueError) as err:
        raise ConfigError(f"cannot read checkpoint ({err})", source=str(path),
                          hint="delete it to start afresh") from err
    if int(state.pop("node.version", -1)) != _CKPT_VERSION:
        raise ConfigError("not a nifo identifier checkpoint (or another version)", source=str(path),
                          hint="delete it to start afresh")
    next_ns = int(state.pop("node.next_ns"))
    return StreamingNifo.from_state(state), next_ns


class IdentifierNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("identifier", **kwargs)
        from rcl_interfaces.msg import SetParametersResult
        from std_msgs.msg import Float64MultiArray, String

        self._SetParametersResult = SetParametersResult
        defaults = {"model_file": "", "block": 0, "overlap": -1.0, "window": "", "f_lo_hz": 0.0, "f_hi_hz": 0.0,
                    "analysis_band_hz": [2.0, 30.0], "publish_period_s": 2.0, "checkpoint_file": "",
                    "checkpoint_period_s": 10.0, "reset": False}
        p = declare_parameters(self, defaults, self._problems)
        self._terms, self._settings = self._model(p)
        self._analysis = tuple(float(x) for x in p["analysis_band_hz"])
        self._ckpt = Path(p["checkpoint_file"]) if p["checkpoint_file"] else None
        self._nifo = None
        self._next_ns: int | None = None
        self._last_ns = 0
        self._published_navg = -1
        self._dirty = False
        self._skipped = 0
        if self._ckpt is not None and self._ckpt.exists():
            self._resume()
        self.add_on_set_parameters_callback(self._on_params)
        self._pub_t = self.create_publisher(Float64MultiArray, TOPICS["transmissibility"], result_qos())
        self._pub_c = self.create_publisher(Float64MultiArray, TOPICS["coefficients"], result_qos())
        self._pub_r = self.create_publisher(String, TOPICS["result"], result_qos())
        self._String = String
        self._sub = self.create_subscription(Float64MultiArray, TOPICS["accel"], self._on_block, block_qos())
        self._timer = self.create_timer(float(p["publish_period_s"]), self._publish)
        if self._ckpt is not None:
            self._ckpt_timer = self.create_timer(float(p["checkpoint_period_s"]), self._checkpoint)
        self._reset_pending = False
        self._reset_timer = self.create_timer(0.1, self._reset_param_back)
        self._service = None
        try:
            from std_srvs.srv import Trigger
        except ImportError:
            self.get_logger().info("std_srvs not installed: reset with 'ros2 param set <node> reset true'")
        else:
            self._service = self.create_service(Trigger, "~/reset", self._on_reset_service)

    # ------------------------------------------------------------------ set-up
    @staticmethod
    def _problems(p: dict) -> str:
        bad = []
        if p.get("block", 0) < 0 or p.get("block", 0) in range(1, 8):
            bad.append(f"block={p['block']} must be 0 (model file / default) or >= 8")
        if "overlap" in p and not (p["overlap"] == -1.0 or 0 <= p["overlap"] < 1):
            bad.append(f"overlap={p['overlap']} must be -1 (default) or in [0, 1)")
        for k in ("publish_period_s", "checkpoint_period_s"):
            if k in p and not p[k] > 0:
                bad.append(f"{k}={p[k]} must be > 0")
        if "analysis_band_hz" in p:
            ab = list(p["analysis_band_hz"])
            if len(ab) != 2 or not 0 <= ab[0] < ab[1]:
                bad.append(f"analysis_band_hz={ab} must be [lo, hi] with 0 <= lo < hi")
        return "; ".join(bad)

    def _model(self, p: dict):
        from nifo.io.modelfile import load_model_spec
        from nifo_core.spectral import SpectralSettings

        terms, ms = (), {}
        if p["model_file"]:
            spec = load_model_spec(p["model_file"])
            if spec.two_step:
                raise ConfigError("the identifier node runs single-step models only", source=p["model_file"],
                                  hint="identify step 1 offline (nifo identify) and list step 2's terms")
            terms, ms = spec.terms, dict(spec.settings)
        if not terms:
            self.get_logger().warning("no nonlinearities given (model_file): estimating the linear T21 only")
        d = SpectralSettings()
        settings = SpectralSettings(block=int(p["block"] or ms.get("block", d.block)),
                                    overlap=float(p["overlap"] if p["overlap"] >= 0 else ms.get("overlap", d.overlap)),
                                    window=str(p["window"] or ms.get("window", d.window)))
        self._band_hz = (float(p["f_lo_hz"]), float(p["f_hi_hz"]))
        if not any(self._band_hz) and "band_hz" in ms:
            self._band_hz = tuple(float(x) for x in ms["band_hz"])
        return tuple(terms), settings

    def _new_nifo(self, fs_hz: float):
        from nifo_core.integrate import IntegrationBand, default_band
        from nifo_core.nifo import StreamingNifo

        d = default_band(fs_hz)
        band = IntegrationBand(self._band_hz[0] or d.f_lo_hz, self._band_hz[1] or d.f_hi_hz)
        return StreamingNifo(fs_hz, self._terms, settings=self._settings, band=band,
                             analysis_band_hz=self._analysis, on_ill_conditioned="ignore")

    def _resume(self) -> None:
        nifo, next_ns = load_checkpoint(self._ckpt)
        fresh = self._new_nifo(nifo.fs_hz)
        if not fresh._same_setup(nifo):
            raise ConfigError("the checkpoint was made with other terms, spectral settings or band",
                              source=str(self._ckpt), hint="delete it (or set another checkpoint_file) to start afresh")
        self._nifo, self._next_ns = nifo, next_ns
        self._last_ns = next_ns
        self.get_logger().info(f"resumed from {self._ckpt}: {nifo.n_avg} blocks, stream at stamp {next_ns} ns")

    # ------------------------------------------------------------------ input
    def _on_block(self, msg) -> None:
        try:
            b = block_from_msg(msg)
            if b.channels[:2] != ACCEL_CHANNELS:
                raise ConfigError(f"block channels {b.channels} are not {ACCEL_CHANNELS}")
        except NifoError as err:
            self.get_logger().warning(f"{TOPICS['accel']}: malformed block skipped ({err})", throttle_duration_sec=5.0)
            return
        if self._nifo is None:
            self._nifo = self._new_nifo(b.fs_hz)
        if b.fs_hz != self._nifo.fs_hz:
            self.get_logger().error(f"block at {b.fs_hz:g} Hz, the estimate is at {self._nifo.fs_hz:g} Hz: skipped "
                                    "(reset to start over at the new rate)", throttle_duration_sec=5.0)
            return
        rows = b.data
        period = 1e9 / b.fs_hz
        if self._next_ns is not None:
            off = int(round((b.stamp_ns - self._next_ns) / period))
            if off < 0:  # samples already used: keep only the new ones
                rows = rows[-off:]
                self._skipped += min(-off, b.n)
                if rows.shape[0] == 0:
                    return
            elif off > 0:
                self.get_logger().warning(f"stream gap of {off} samples before stamp {b.stamp_ns} ns: "
                                          "closing the record (no spectral block spans a gap)")
                self._nifo.end_record()
            start_ns = b.stamp_ns + int(round(max(0, -off) * period))
        else:
            start_ns = b.stamp_ns
        try:
            self._nifo.push(rows[:, 0], rows[:, 1])
        except NifoError as err:  # non-finite samples: StreamingNifo checks before changing state
            self.get_logger().warning(f"block at stamp {b.stamp_ns} ns skipped ({err}); closing the record")
            self._nifo.end_record()
            return
        self._next_ns = start_ns + int(round(rows.shape[0] * period))
        self._last_ns = self._next_ns - int(round(period))
        self._dirty = True

    # ------------------------------------------------------------------ output
    def _publish(self) -> None:
        if self._nifo is None or self._nifo.n_avg == 0 or self._nifo.n_avg == self._published_navg:
            return
        try:
            r = self._nifo.result()
        except NifoError as err:
            self.get_logger().warning(f"no estimate yet: {err}", throttle_duration_sec=30.0)
            return
        self._published_navg = r.n_avg
        nominal = r.static.t21 if r.static is not None else r.t21
        t = {"freq_hz": r.freq_hz, "t21_nominal_re": nominal.real, "t21_nominal_im": nominal.imag,
             "t21_re": r.t21.real, "t21_im": r.t21.imag, "t21_h1_re": r.t21_h1.real,
             "t21_h1_im": r.t21_h1.imag, "coherence_h1": r.coherence_h1,
             "multiple_coherence": r.multiple_coherence, "cond": r.cond}
        c = {"freq_hz": r.freq_hz}
        for i in range(len(r.terms)):
            pooled = r.static.c_over_m2[i] if r.static is not None else np.nan
            c.update({f"c{i}_pooled": np.full(r.freq_hz.shape, pooled, float),
                      f"c{i}_re": r.c_over_m2[i].real, f"c{i}_im": r.c_over_m2[i].imag,
                      f"b{i}_re": r.b[i].real, f"b{i}_im": r.b[i].imag})
        self._pub_t.publish(table_to_msg(t, stamp_ns=self._last_ns, n_avg=r.n_avg))
        self._pub_c.publish(table_to_msg(c, stamp_ns=self._last_ns, n_avg=r.n_avg))
        doc = r.to_dict()
        doc["stamp_ns"] = int(self._last_ns)
        self._pub_r.publish(self._String(data=json.dumps(doc)))

    def _checkpoint(self) -> None:
        if self._ckpt is None or self._nifo is None or not self._dirty or self._next_ns is None:
            return
        try:
            save_checkpoint(self._ckpt, self._nifo, next_ns=self._next_ns)
            self._dirty = False
        except OSError as err:
            self.get_logger().error(f"cannot write checkpoint {self._ckpt}: {err}", throttle_duration_sec=30.0)

    # ------------------------------------------------------------------ reset
    def reset(self) -> None:
        """Drop everything accumulated (and the checkpoint's content on its next write)."""
        self._nifo = None
        self._next_ns = None
        self._published_navg = -1
        if self._ckpt is not None and self._ckpt.exists():
            self._ckpt.unlink()
        self.get_logger().info("reset: the estimate starts afresh")

    def _on_params(self, params):
        fixed = [q.name for q in params if q.name not in ("reset", "publish_period_s", "checkpoint_period_s")]
        if fixed:
            return self._SetParametersResult(successful=False,
                                             reason=f"{fixed} are read at start-up; restart the node to change them")
        bad = self._problems({q.name: q.value for q in params})
        if bad:
            return self._SetParametersResult(successful=False, reason=bad)
        for q in params:
            if q.name == "reset" and q.value:
                self._reset_pending = True
        return self._SetParametersResult(successful=True)

    def _reset_param_back(self) -> None:
        if self._reset_pending:
            self._reset_pending = False
            self.reset()
            from rclpy.parameter import Parameter
            self.set_parameters([Parameter("reset", Parameter.Type.BOOL, False)])

    def _on_reset_service(self, request, response):
        self.reset()
        response.success = True
        response.message = "estimate reset"
        return response

    def close(self) -> None:
        self._checkpoint()


def main(args: list[str] | None = None) -> int:
    return run_node(IdentifierNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
