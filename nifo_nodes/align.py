"""Put per-sample messages of several channels onto one sample grid, in order, and say where it breaks.

Per-sample messages arrive per channel, possibly reordered, duplicated, late,
missing (a stalled publisher, a NaN burst), or starting over (a restarted
publisher or a looped replay). :class:`SampleAligner` turns them into
contiguous runs of rows (one value per channel) and starts a new *segment*
wherever the stream cannot be joined, so nothing downstream ever computes
across a hole. This is bookkeeping, not signal processing: samples are placed
on the grid ``t0 + round(k·1e9/fs)`` and passed through unchanged.

Rules (each event is counted in :attr:`SampleAligner.counts` and reported by
the callback ``log``):

* a stamp more than half a period off the grid is still rounded onto it;
* NaN/inf value → treated as missing (``nonfinite``);
* index already emitted, up to ``restart_s`` back → dropped (``late``);
  duplicate of a waiting sample → dropped (``duplicate``);
* ``restart_count`` consecutive samples more than ``restart_s`` back → the
  publisher restarted: new grid anchored there, new segment (``restart``;
  ordered: ``restart_count`` on every channel);
* a hole that stays open while another channel is ``max_lag`` samples past it
  → the hole is skipped, new segment from the next complete row (``gap``).

``ordered=True`` is for a lossless, in-order transport (reliable keep-all: the
lossless replay). Each channel's samples then arrive in order and none is
dropped in transit, but the channels are separate streams and one may run far
ahead of the other (thousands of samples when a replay goes as fast as the
graph allows). A hole is then declared only when the channel lacking the sample
has itself delivered a later one (the sample is missing at the source), or
when another channel is ``max_wait`` samples past it (a channel that died); how
far another channel is ahead alone is no evidence of loss.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

__all__ = ["SampleAligner", "Run"]


@dataclass
class Run:
    """Contiguous rows of one segment: row i is at ``stamp_ns + round(i·1e9/fs)``."""

    stamp_ns: int
    segment: int
    rows: np.ndarray  # (n, c)


@dataclass
class SampleAligner:
    fs_hz: float
    n_channels: int
    max_lag: int = 256
    restart_s: float = 1.0
    restart_count: int = 8
    log: Callable[[str], None] = print
    ordered: bool = False
    max_wait: int = 0  #: ordered: a hole other channels are this far past is skipped (0: 100·max_lag)
    counts: dict = field(default_factory=lambda: dict.fromkeys(
        ("nonfinite", "late", "duplicate", "restart", "gap", "samples"), 0))

    def __post_init__(self) -> None:
        self._period_ns = 1e9 / self.fs_hz
        self._t0: int | None = None
        self._head = 0
        self._newest = -1
        self._newest_ch = [-1] * self.n_channels
        if self.ordered and self.max_wait <= 0:
            self.max_wait = 100 * self.max_lag
        self._store: list[dict[int, float]] = [{} for _ in range(self.n_channels)]
        self._stamps: dict[int, int] = {}
        self._back: list[tuple[int, int, float]] = []
        self.segment = 0
        self._broken = False
        self._run_start: int | None = None
        self._run_stamp = 0
        self._rows: list[tuple[float, ...]] = []
        self._runs: list[Run] = []

    # ------------------------------------------------------------------ input
    def push(self, channel: int, stamp_ns: int, value: float) -> None:
        if not np.isfinite(value):
            self.counts["nonfinite"] += 1
            if self.counts["nonfinite"] in (1, 10, 100) or self.counts["nonfinite"] % 1000 == 0:
                self.log(f"channel {channel}: non-finite sample at stamp {stamp_ns} ns skipped "
                         f"({self.counts['nonfinite']} so far)")
            return
        if self._t0 is None:
            self._t0 = stamp_ns
        k = int(round((stamp_ns - self._t0) / self._period_ns))
        if k < self._head:
            if (self._head - k) * self._period_ns > self.restart_s * 1e9:
                self._back.append((channel, stamp_ns, value))
                if self._restarted():
                    self._restart()
                return
            self.counts["late"] += 1
            if self.counts["late"] in (1, 10, 100) or self.counts["late"] % 1000 == 0:
                self.log(f"channel {channel}: late/out-of-order sample at stamp {stamp_ns} ns dropped "
                         f"({self.counts['late']} so far)")
            return
        if not self.ordered:  # ordered: another channel may still be delivering the old stream's tail
            self._back.clear()
        store = self._store[channel]
        if k in store:
            self.counts["duplicate"] += 1
            return
        store[k] = value
        self._newest = max(self._newest, k)
        if k > self._newest_ch[channel]:
            self._newest_ch[channel] = k
        if channel == 0 or k not in self._stamps:
            self._stamps[k] = stamp_ns
        self._advance()

    def _restarted(self) -> bool:
        """Enough samples went back to call it a restarted publisher. Ordered: every channel must have
        gone back (a channel still delivering the old stream's tail would otherwise lose it)."""
        if not self.ordered:
            return len(self._back) >= self.restart_count
        per = [0] * self.n_channels
        for ch, _, _ in self._back:
            per[ch] += 1
        return min(per) >= self.restart_count

    def _restart(self) -> None:
        back, self._back = self._back, []
        self._end_run()
        self.counts["restart"] += 1
        self.log(f"stamps went back by more than {self.restart_s:g} s: publisher restarted; new segment "
                 f"from stamp {back[0][1]} ns")
        self._t0 = back[0][1]
        self._head = 0
        self._newest = -1
        self._newest_ch = [-1] * self.n_channels
        self._store = [{} for _ in range(self.n_channels)]
        self._stamps = {}
        self.segment += 1
        self._broken = False
        for ch, st, v in back:
            self.push(ch, st, v)

    # ------------------------------------------------------------------ alignment
    def _advance(self) -> None:
        stores, h = self._store, self._head
        while True:
            if all(h in s for s in stores):
                if self._run_start is None:
                    self._run_start = h
                    self._run_stamp = self._stamps[h]
                self._rows.append(tuple(s.pop(h) for s in stores))
                self._broken = False
                self._stamps.pop(h, None)
                h += 1
                continue
            newest = self._newest
            if self.ordered:
                # in order, nothing dropped in transit: missing only if the lacking channel has moved past it
                passed = all(self._newest_ch[c] > h for c, st in enumerate(stores) if h not in st)
                if not passed and newest - h < self.max_wait:
                    break
            elif newest - h < self.max_lag:
                break
            # the hole at h will not be filled: skip to the next complete row
            common = set(stores[0])
            for s in stores[1:]:
                common &= set(s)
            if common:
                j = min(common)
            else:  # ordered: step past the hole sample by sample (each checked as above)
                j = h + 1 if self.ordered else newest - self.max_lag + 1
            for s in stores:
                for k in [k for k in s if k < j]:
                    del s[k]
            for k in [k for k in self._stamps if k < j]:
                del self._stamps[k]
            if not self._broken:  # one segment change per hole, however long it stays open
                self.counts["gap"] += 1
                self.log(f"gap in the samples at stamp ≈ {self._t0 + int(h * self._period_ns)} ns "
                         "(missing, stalled or non-finite samples): new segment")
                self._end_run()
                self.segment += 1
                self._broken = True
            h = j
        self._head = h

    def _end_run(self) -> None:
        if self._rows:
            self._runs.append(Run(self._run_stamp, self.segment, np.array(self._rows, np.float64)))
            self.counts["samples"] += len(self._rows)
        self._rows = []
        self._run_start = None

    # ------------------------------------------------------------------ output
    @property
    def pending(self) -> int:
        """Rows ready but not yet taken."""
        return len(self._rows) + sum(r.rows.shape[0] for r in self._runs)

    def take(self) -> list[Run]:
        """All complete rows so far, as runs (a new run starts at every segment change)."""
        self._end_run()
        runs, self._runs = self._runs, []
        return runs
