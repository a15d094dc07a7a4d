"""Streaming NIFO: the one code path that turns samples into NIFO spectra (see :mod:`nifo_core.nifo.identify`).

:class:`StreamingNifo` integrates z, ż from a2 - a1 chunk by chunk, evaluates
the describing functions (play-operator state carried across chunks) and
accumulates [a1, a2, g.., (xb)] in one cross-spectral accumulator; batch
identification is one push per record.
"""

from __future__ import annotations

import json
from typing import Mapping, Sequence

import numpy as np

from ..kinds.describing import Term, make_term, play_operator
from ..errors import ConfigError, InputError, RecordTooShortError
from ..signal.integrate import IntegrationBand, StreamingIntegrator, default_band, integrator_taps
from .estimate import _channel_names, nifo_from_spectra
from .result import DEFAULT_ANALYSIS_BAND_HZ, DEFAULT_COND_LIMIT, XB, FixedTerms, NifoResult, OnIll
from ..signal.spectral import CrossSpectra, CrossSpectralAccumulator, SpectralSettings

__all__ = ["StreamingNifo"]

# ---------------------------------------------------------------------------------------------
# streaming: the one code path
# ---------------------------------------------------------------------------------------------
def _as_terms(terms) -> tuple[Term, ...]:
    if isinstance(terms, (Term, str, Mapping)):
        terms = [terms]
    out = tuple(make_term(t) for t in terms)
    for t in out:
        if t.spec.hysteretic and not t.spec.play_state:
            raise ConfigError(f"{t.label}: streaming NIFO knows how to carry the state of a play operator only")
    return out


class StreamingNifo:
    """Output-only (and input-measured) NIFO fed chunk by chunk; batch is one push per record.

    Parameters
    ----------
    fs_hz : float
        Sample rate [Hz].
    terms : sequence of Term (or specs for :func:`describing.make_term`)
        Describing functions whose coefficients are estimated.
    settings : SpectralSettings, optional
        Spectral block/overlap/window (paper Table 2 by default).
    band : IntegrationBand, optional
        Integration band for z, ż; default ``default_band(fs_hz)`` (0.5 Hz up:
        it must contain body bounce, docs/method.md §3).
    fixed : NifoResult, FixedTerms or sequence of (Term, float), optional
        Terms held fixed at constant c_i/M2 (two-step, paper §3.3).
    with_tire_patch : bool
        Also accumulate the tire-patch displacement for the input-measured
        estimate (paper Eq. 10); :meth:`push` then needs it.
    with_force : bool
        Also accumulate a measured force on the body [N] (one more input of
        Eq. 8: X2 = T21·X1 + T2F·F + Σ B_i·Xn_i); :meth:`push` then needs it.
    spindle_fixed : bool
        The spindle does not move (a single mass driven by the force): its
        column is dropped from the regression instead of inverting a singular
        G_UU. Needs ``with_force``.
    spindle_noise_psd, analysis_band_hz, on_ill_conditioned, cond_limit :
        As in :func:`nifo_from_spectra`.

    Notes
    -----
    Per chunk: z̈ = a2 - a1 goes through a :class:`StreamingIntegrator`; the
    accelerations (and xb) wait ``delay_samples`` in a FIFO so they stay
    aligned with z, ż; the first ``delay_samples`` of a stream are the
    integrator's start-up transient and are dropped (the last ones are never
    released), so the samples used are exactly the ``valid`` part of
    :func:`integrate` on the whole record. Describing functions are evaluated
    on (z, ż) with the play-operator state carried across chunks, and
    [a1, a2, g_fixed.., g.., f, xb] go into one :class:`CrossSpectralAccumulator`.
    """

    def __init__(self, fs_hz: float, terms: Sequence[Term], *, settings: SpectralSettings | None = None,
                 band: IntegrationBand | None = None, fixed: "NifoResult | FixedTerms | Sequence | None" = None,
                 with_tire_patch: bool = False, spindle_noise_psd: float | None = None,
                 analysis_band_hz: tuple[float, float] = DEFAULT_ANALYSIS_BAND_HZ,
                 on_ill_conditioned: OnIll = "warn", cond_limit: float = DEFAULT_COND_LIMIT,
                 with_force: bool = False, spindle_fixed: bool = False) -> None:
        if not (np.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError(f"fs_hz={fs_hz!r} must be a positive sample rate [Hz]")
        if on_ill_conditioned not in ("warn", "raise", "ignore"):
            raise ConfigError(f"on_ill_conditioned={on_ill_conditioned!r} must be 'warn', 'raise' or 'ignore'")
        self.fs_hz = float(fs_hz)
        self.terms = _as_terms(terms)
        self.fixed = FixedTerms.coerce(fixed)
        self.all_terms = (*(self.fixed.terms if self.fixed is not None else ()), *self.terms)
        self.settings = settings or SpectralSettings()
        self.band = (band or default_band(self.fs_hz)).validate(self.fs_hz)
        self.with_tire_patch = bool(with_tire_patch)
        self.with_force = bool(with_force)
        self.spindle_fixed = bool(spindle_fixed)
        if self.spindle_fixed and not self.with_force:
            raise ConfigError("a fixed spindle leaves NIFO without an input", channel="force",
                              hint="give the measured force (with_force=True) or the spindle acceleration")
        if self.with_force and self.fixed is not None:
            raise ConfigError("two-step NIFO (fixed terms) with a measured force is not supported",
                              hint="identify all terms in one step when the force is measured")
        self.spindle_noise_psd = None if spindle_noise_psd is None else float(spindle_noise_psd)
        self.analysis_band_hz = (float(analysis_band_hz[0]), float(analysis_band_hz[1]))
        self.on_ill_conditioned = on_ill_conditioned
        self.cond_limit = float(cond_limit)
        self.delay_samples = (integrator_taps(self.fs_hz, self.band)[0].size - 1) // 2
        self._names = _channel_names(self.all_terms, self.with_tire_patch, self.with_force)
        self._acc = CrossSpectralAccumulator(len(self._names), self.fs_hz, self.settings, names=self._names)
        self._n_used = 0
        self._records = 0
        self._reset_stream()

    # -- stream state ---------------------------------------------------------------------
    def _reset_stream(self) -> None:
        self._integ = StreamingIntegrator(self.fs_hz, self.band)
        self._n_raw = 2 + self.with_tire_patch + self.with_force
        self._hist = np.zeros((self._n_raw, 0))      # last ≤ 2·delay raw samples (a1, a2, xb, f)
        self._n_in = 0                                # raw samples pushed in this stream
        self._play = np.full(len(self.all_terms), np.nan)

    @property
    def min_samples(self) -> int:
        """Samples one record needs for a block after the integrator's edges."""
        return self.settings.block + 2 * self.delay_samples

    @property
    def n_avg(self) -> int:
        """Spectral blocks accumulated so far."""
        return self._acc.n_blocks

    def push(self, spindle_accel: np.ndarray, body_accel: np.ndarray,
             tire_patch_disp: np.ndarray | None = None, force: np.ndarray | None = None) -> int:
        """Feed a chunk of the stream: accelerations [m/s²] (and xb [m], force [N]), each shape (k,).

        Returns the number of spectral blocks completed by this chunk. Inputs are not modified.
        """
        a1 = np.asarray(spindle_accel, dtype=float).ravel()
        a2 = np.asarray(body_accel, dtype=float).ravel()
        chans = [a1, a2]
        if self.with_tire_patch:
            if tire_patch_disp is None:
                raise InputError("this NIFO accumulates the tire patch (with_tire_patch=True) but none was pushed",
                                 channel=XB, hint="push tire_patch_disp with every chunk")
            chans.append(np.asarray(tire_patch_disp, dtype=float).ravel())
        if self.with_force:
            if force is None:
                raise InputError("this NIFO accumulates a measured force (with_force=True) but none was pushed",
                                 channel="force", hint="push the force with every chunk")
            chans.append(np.asarray(force, dtype=float).ravel())
        if len({c.size for c in chans}) != 1:
            raise InputError(f"chunk channels differ in length {[c.size for c in chans]}",
                             hint="push the same samples of every channel")
        raw = np.stack(chans)
        if not np.all(np.isfinite(raw)):
            raise InputError("chunk holds NaN or infinite samples", hint="repair or cut the bad stretch")
        k = raw.shape[1]
        if k == 0:
            return 0
        d = self.delay_samples
        v, x = self._integ.push(a2 - a1)                      # outputs for samples n_out .. n_out+len-1
        n_out_before = max(0, self._n_in - d)
        hist = np.concatenate([self._hist, raw], axis=1)
        self._n_in += k
        pending_before = self._n_in - k - n_out_before        # raw samples that were waiting
        start = hist.shape[1] - k - pending_before
        aligned = hist[:, start:start + v.size]               # raw samples matching v, x
        self._hist = hist[:, -2 * d:].copy() if 2 * d else hist[:, :0].copy()
        drop = max(0, d - n_out_before)                       # the integrator's start-up edge
        if drop:
            v, x, aligned = v[drop:], x[drop:], aligned[:, drop:]
        if v.size == 0:
            return 0
        g = self._evaluate(x, v)
        rows = [aligned[0], aligned[1], *g]
        if self.with_force:
            rows.append(aligned[-1])
        if self.with_tire_patch:
            rows.append(aligned[2])
        self._n_used += v.size
        return self._acc.push(np.stack(rows))

    def _evaluate(self, z: np.ndarray, zdot: np.ndarray) -> list[np.ndarray]:
        out = []
        for i, t in enumerate(self.all_terms):
            if t.spec.hysteretic:   # the play operator's state carries over chunks
                y0 = None if np.isnan(self._play[i]) else float(self._play[i])
                g = play_operator(z, t.params[t.spec.key_param], y0=y0)
                self._play[i] = g[-1]
            else:
                g = t.evaluate(z, zdot)
            out.append(g)
        return out

    def end_record(self) -> None:
        """Close the current stream: later pushes start a new, separate record (fresh integrator)."""
        if self._n_in:
            self._records += 1
        self._acc.drop_pending()                             # drops the partial block, keeps the sums
        self._reset_stream()

    # -- results ------------------------------------------------------------------------------
    def spectra(self, band_hz: tuple[float, float] | None = None) -> CrossSpectra:
        """Cross spectra of [a1, a2, g.., (xb)] so far (only the lines in ``band_hz`` [Hz] when given)."""
        if self._acc.n_blocks == 0:
            raise RecordTooShortError(
                f"no complete spectral block yet: NIFO needs {self.min_samples} samples in one record "
                f"(block={self.settings.block} plus {self.delay_samples} integrator edge samples at each end "
                f"for f_lo={self.band.f_lo_hz:g} Hz)",
                hint="record longer, choose a smaller block, or raise the integration band's lower edge")
        return self._acc.spectra(band_hz)

    def result(self) -> NifoResult:
        """The NIFO estimate from all blocks so far (paper Eq. 8-10)."""
        prov = {"records": self._records + (1 if self._n_in else 0), "samples_used": self._n_used,
                "integrator_edge_samples": self.delay_samples}
        return nifo_from_spectra(self.spectra(), self.terms, band=self.band, fixed=self.fixed,
                                 analysis_band_hz=self.analysis_band_hz, with_tire_patch=self.with_tire_patch,
                                 with_force=self.with_force, spindle_fixed=self.spindle_fixed,
                                 spindle_noise_psd=self.spindle_noise_psd,
                                 on_ill_conditioned=self.on_ill_conditioned, cond_limit=self.cond_limit,
                                 n_samples=self._n_used, provenance=prov)

    def same_setup(self, other: "StreamingNifo") -> bool:
        """True when ``other`` accumulates the same channels the same way (so the two can merge)."""
        return (self.fs_hz, self.all_terms, self.settings, self.band, self.with_tire_patch, self.with_force,
                self.spindle_fixed) == \
            (other.fs_hz, other.all_terms, other.settings, other.band, other.with_tire_patch, other.with_force,
             other.spindle_fixed)

    _same_setup = same_setup   # kept for callers of the earlier private name

    def merge(self, other: "StreamingNifo") -> "StreamingNifo":
        """A new estimator holding the blocks of both (separate records); operands unchanged.

        The merged estimator's stream starts fresh (a further push begins a new record).
        """
        if not isinstance(other, StreamingNifo) or not self.same_setup(other):
            raise ConfigError("cannot merge NIFO accumulators with different sample rates, terms, spectral "
                              "settings, integration bands or channels",
                              hint="accumulate all records with the same set-up")
        out = self._like()
        out._acc = self._acc.merge(other._acc)
        out._n_used = self._n_used + other._n_used
        out._records = self._records + other._records + (1 if self._n_in else 0) + (1 if other._n_in else 0)
        return out

    def _like(self) -> "StreamingNifo":
        return StreamingNifo(self.fs_hz, self.terms, settings=self.settings, band=self.band, fixed=self.fixed,
                             with_tire_patch=self.with_tire_patch, spindle_noise_psd=self.spindle_noise_psd,
                             with_force=self.with_force, spindle_fixed=self.spindle_fixed,
                             analysis_band_hz=self.analysis_band_hz, on_ill_conditioned=self.on_ill_conditioned,
                             cond_limit=self.cond_limit)

    # -- checkpointing -------------------------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        """Complete state as plain numpy arrays (``np.savez``-able); see :meth:`from_state`.

        The integrator's state is carried as the last 2·delay raw samples (it
        is rebuilt by replaying them), so no private state of other classes is needed.
        """
        config = {"fs_hz": self.fs_hz, "terms": [t.to_dict() for t in self.terms],
                  "settings": self.settings.to_dict(), "band": self.band.to_dict(),
                  "with_tire_patch": self.with_tire_patch, "spindle_noise_psd": self.spindle_noise_psd,
                  "with_force": self.with_force, "spindle_fixed": self.spindle_fixed,
                  "analysis_band_hz": list(self.analysis_band_hz),
                  "on_ill_conditioned": self.on_ill_conditioned, "cond_limit": self.cond_limit,
                  "fixed": None if self.fixed is None else self.fixed.to_dict()}
        state = {f"acc.{k}": v for k, v in self._acc.state_dict().items()}
        state.update({"config_json": np.array(json.dumps(config)), "hist": self._hist.copy(),
                      "n_in": np.array(self._n_in), "play": self._play.copy(), "n_used": np.array(self._n_used),
                      "records": np.array(self._records)})
        return state

    @classmethod
    def from_state(cls, state: Mapping[str, np.ndarray]) -> "StreamingNifo":
        """Rebuild from :meth:`state_dict` output; pushing continues where it left off."""
        try:
            c = json.loads(str(state["config_json"]))
            fixed = None if c["fixed"] is None else FixedTerms.from_dict(c["fixed"])
            obj = cls(c["fs_hz"], [make_term(t) for t in c["terms"]],
                      settings=SpectralSettings.from_dict(c["settings"]), band=IntegrationBand(**c["band"]),
                      fixed=fixed, with_tire_patch=c["with_tire_patch"], spindle_noise_psd=c["spindle_noise_psd"],
                      analysis_band_hz=tuple(c["analysis_band_hz"]), on_ill_conditioned=c["on_ill_conditioned"],
                      cond_limit=c["cond_limit"], with_force=c.get("with_force", False),
                      spindle_fixed=c.get("spindle_fixed", False))
            acc = CrossSpectralAccumulator.from_state({k[4:]: v for k, v in state.items() if k.startswith("acc.")})
            hist = np.asarray(state["hist"], float)
            n_in = int(state["n_in"])
            play = np.asarray(state["play"], float)
            n_used, records = int(state["n_used"]), int(state["records"])
        except KeyError as err:
            raise ConfigError(f"NIFO state lacks {err.args[0]!r}", hint="pass what state_dict() returned") from None
        if hist.shape[0] != obj._n_raw or play.shape != obj._play.shape or acc.n_channels != len(obj._names):
            raise ConfigError("NIFO state does not match its own configuration", hint="pass what state_dict() returned")
        obj._acc, obj._hist, obj._n_in, obj._play = acc, hist.copy(), n_in, play.copy()
        obj._n_used, obj._records = n_used, records
        if hist.shape[1]:
            obj._integ.push(hist[1] - hist[0])   # replay: the integrator holds exactly these samples again
        return obj


