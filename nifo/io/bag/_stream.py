"""Reading a bag chunk by chunk (memory bounded by the chunk, not the recording): :func:`iter_bag_chunks`."""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence

import numpy as np

from nifo_core.errors import ConfigError, DataFileError, NifoError, RecordTooShortError, TimestampError
from nifo_core.signal.record import Record

from ..assemble import check_rate_range, check_values, nominal_rate
from ._read import _CHANNEL_OF_ROLE, _is_sqlite, _mcap_file, _open_checked, integrity_meta, read_bag
from ._topics import BagTopics, _topic_table, resolve_topics
from .cdr import Axis
from ._mcap import (_iter_mcap_indexed, _NoUsableIndex, check_metadata_topics, check_structure,
                    indexed_counts, receive_stamps)

__all__ = ["iter_bag_chunks"]

class _ChunkAssembler:
    """Turns per-role message streams into aligned, uniformly sampled :class:`Record` chunks.

    The checks of :func:`nifo.io.loader.assemble_record`, applied as the data
    arrive: the rate comes from the first chunk's stamps (snapped to its short
    decimal form); later stamps must continue it without gaps or reversals;
    roles must share sample instants (within a quarter period). Leading
    samples of a role that started earlier are trimmed, as are trailing ones.
    """

    def __init__(self, roles: Sequence[str], *, chunk_samples: int, src: str, name: str, labels: Mapping[str, str],
                 meta: Mapping, total: int) -> None:
        self.roles, self.chunk, self.src, self.name, self.labels = list(roles), int(chunk_samples), src, name, labels
        self.meta, self.total = dict(meta), int(total)
        self.pending: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {r: [] for r in self.roles}
        self.count = {r: 0 for r in self.roles}
        self.fs: float | None = None
        self.last: int | None = None
        self.emitted = 0
        self.index = 0
        self.aligned = False
        self.first: dict[str, float] = {}   # each channel's first value, and the channels that ever left it
        self.varied: set[str] = set()

    def add(self, role: str, stamps: np.ndarray, values: np.ndarray) -> None:
        if stamps.size:
            self.pending[role].append((stamps, values))
            self.count[role] += stamps.size

    def _take(self, role: str, k: int) -> tuple[np.ndarray, np.ndarray]:
        parts = self.pending[role]
        s = np.concatenate([p[0] for p in parts]) if len(parts) > 1 else parts[0][0]
        v = np.concatenate([p[1] for p in parts]) if len(parts) > 1 else parts[0][1]
        self.pending[role] = [(s[k:], v[k:])] if s.size > k else []
        self.count[role] = s.size - k
        return s[:k], v[:k]

    def _align_start(self) -> None:
        firsts = {r: self.pending[r][0][0][0] for r in self.roles}
        start = max(firsts.values())
        for r in self.roles:
            s = np.concatenate([p[0] for p in self.pending[r]])
            period_guess = float(np.median(np.diff(s[:64]))) if s.size > 1 else 0.0
            drop = int(np.searchsorted(s, start - 0.25 * period_guess, "left"))
            if drop:
                self._take(r, drop)
                self.meta.setdefault("trimmed", {})[self.labels[r]] = [drop, 0]
        self.aligned = True

    def ready(self, final: bool = False) -> "Iterator[Record]":
        from nifo_core.signal.timebase import sample_rate_from_stamps


        if not all(self.count.values()):
            return
        if not self.aligned:
            self._align_start()
        while True:
            n = min(self.count.values())
            if n == 0 or (n < self.chunk and not final):
                return
            k = min(n, self.chunk)
            taken = {r: self._take(r, k) for r in self.roles}
            ref_role = self.roles[0]
            ref = taken[ref_role][0]
            if self.fs is None:
                if ref.size < 2:
                    raise RecordTooShortError(f"{ref.size} sample(s): cannot tell the sample rate", source=self.src,
                                              channel=self.labels[ref_role], hint="record at least a few seconds")
                rate = sample_rate_from_stamps(ref, source=self.src, channel=self.labels[ref_role])
                self.fs = nominal_rate(ref, rate, 1.0)
                check_rate_range(self.fs, source=self.src, channel=self.labels[ref_role])
            period = 1e9 / self.fs
            for r in self.roles:
                s = taken[r][0]
                seq = s if self.last is None else np.concatenate([[self.last], s])
                dt = np.diff(seq)
                bad = (dt <= 0) | (np.abs(dt - period) > 0.5 * period)
                if bad.any():
                    i = int(np.argmax(bad))
                    raise TimestampError(
                        f"time stamps are not uniform or not increasing at "
                        f"t={(seq[i + 1] - seq[0]) / 1e9 + self.emitted / self.fs:.3f} s "
                        f"(interval {dt[i] / 1e6:.3f} ms, sample period {period / 1e6:.3f} ms)",
                        source=self.src, channel=self.labels[r],
                        hint="split the record at the gap (or fill dropped samples) and analyse the pieces")
                if r != ref_role:
                    dev = np.abs(s - ref) > 0.25 * period
                    if dev.any():
                        i = int(np.argmax(dev))
                        raise TimestampError(
                            f"the channels are not sampled at the same instants: at sample {self.emitted + i} "
                            f"{self.labels[r]} is {(s[i] - ref[i]) / 1e6:+.3f} ms off {self.labels[ref_role]}",
                            source=self.src, channel=f"{self.labels[ref_role]}, {self.labels[r]}",
                            hint="resample the channels onto one clock so that each sample has one stamp for all")
            meta = dict(self.meta)
            meta["chunk"] = {"index": self.index, "start": self.emitted, "total_samples": self.total}
            vals = {r: taken[r][1] for r in self.roles}
            for r, v in vals.items():
                if r not in self.varied and v.size:
                    f = self.first.setdefault(r, float(v[0]))
                    if (v != f).any():
                        self.varied.add(r)
            check_values({_CHANNEL_OF_ROLE[r]: v for r, v in vals.items()}, fs=self.fs, source=self.src, constant=False,
                         labels={_CHANNEL_OF_ROLE[r]: self.labels[r] for r in self.roles})
            try:
                rec = Record(self.fs, vals["spindle"], vals["body"], vals.get("tire_patch"), force=vals.get("force"),
                             t0_ns=int(ref[0]),
                             source=self.name, meta=meta)
            except NifoError as err:
                raise err.with_context(source=self.src) from None
            self.last = int(ref[-1])
            self.emitted += k
            self.index += 1
            yield rec


    def check_recorded(self) -> None:
        """After the last chunk: an acceleration channel that never changed recorded nothing (as
        :func:`~nifo.io.assemble.check_values` says of a whole record; chunk by chunk it cannot be told earlier)."""
        for r in self.roles:
            if r != "tire_patch" and self.emitted > 1 and r not in self.varied:
                raise DataFileError(f"all {self.emitted} samples are {self.first.get(r, 0.0):g}: the sensor recorded "
                                    "nothing", source=self.src, channel=self.labels[r],
                                    hint="check the channel mapping (--topics/--columns/--axis) and the sensor")


def iter_bag_chunks(path: str | os.PathLike, *, chunk_samples: int, topics: BagTopics | None = None,
                    axis: Axis = "z") -> "Iterator[Record]":
    """Read a bag as consecutive :class:`Record` chunks of ``chunk_samples`` samples (the last may be shorter).

    For a single indexed MCAP file (what nifo and ``ros2 bag record`` write)
    the MCAP chunks are decoded one at a time with the numpy decoder of
    :func:`read_bag`, so memory is bounded by ``chunk_samples`` whatever the
    recording's length; other bags are read whole and sliced. Chunks carry
    ``meta["chunk"] = {"index", "start", "total_samples"}`` (the expected
    total from the bag's message counts). The same checks as :func:`read_bag`
    apply (rate, gaps, common instants, finiteness), chunk by chunk.
    """
    if isinstance(chunk_samples, bool) or int(chunk_samples) < 2:
        raise ConfigError(f"chunk_samples={chunk_samples!r} must be an integer >= 2")
    chunk_samples = int(chunk_samples)
    path, src, storage = _open_checked(path, axis)
    mcap_file = None
    if not _is_sqlite(storage) and (storage.is_dir() or storage.suffix == ".mcap"):
        try:
            mcap_file = _mcap_file(storage)
        except Exception:  # unreadable metadata: read_bag reports it properly
            mcap_file = None
    if mcap_file is None:
        yield from read_bag(path, topics=topics, axis=axis).chunks(chunk_samples)
        return
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    try:
        check_structure(mcap_file)
        with Reader(storage) as reader:
            conns = list(reader.connections)
            if not conns or reader.message_count == 0:
                raise DataFileError("the bag holds no messages", source=src,
                                    hint="record again and check that the sensor topics were published")
            available = _topic_table(conns)
            if storage.is_dir():
                check_metadata_topics(available, mcap_file, source=src)
            wanted = {r: (t, available[t]) for r, t in resolve_topics(available, topics, source=src).items() if t}
            expected = {r: sum(c.msgcount for c in conns if c.topic == t) for r, (t, _) in wanted.items()}
    except NifoError:
        raise
    except Exception as err:
        raise DataFileError(f"cannot read the bag ({str(err).rstrip('.') or type(err).__name__}); the file is "
                            "damaged or truncated", source=src, hint="re-copy the bag") from err
    try:  # what the file's own message indexes hold, not metadata.yaml's counts (the band depends on it)
        expected = indexed_counts(mcap_file, wanted)
    except _NoUsableIndex:
        pass
    except NifoError:
        raise
    except Exception as err:
        raise DataFileError(f"cannot read the bag's index ({str(err).rstrip('.') or type(err).__name__}); the file "
                            "is damaged or truncated", source=src, hint="re-copy the bag") from err
    for opt in ("tire_patch", "force"):
        if expected.get(opt, 1) == 0:
            del wanted[opt], expected[opt]
    for role in ("spindle", "body"):
        if expected[role] == 0:
            raise DataFileError("the topic holds no messages", source=src, channel=wanted[role][0],
                                hint="record again and check that the sensor published")
    roles = [r for r in ("spindle", "body", "tire_patch", "force") if r in wanted]
    meta = {"format": "rosbag2", "storage": "mcap", "path": src,
            "topics": {role: wanted[role][0] if role in wanted else None for role in _CHANNEL_OF_ROLE
                       if role != "force" or role in wanted},
            "axis": axis, "stamps": "header", "streamed": True, **integrity_meta(storage)}
    asm = _ChunkAssembler(roles, chunk_samples=chunk_samples, src=src, name=path.name,
                          labels={r: wanted[r][0] for r in roles}, meta=meta, total=min(expected.values()))
    use_log: bool | None = None
    it = _iter_mcap_indexed(mcap_file, wanted, axis=axis, typestore=typestore)
    while True:
        try:
            part = next(it)
        except StopIteration:
            break
        except _NoUsableIndex as err:   # no usable index: the whole-bag reader, if nothing was handed out yet
            if asm.index or asm.emitted:
                raise DataFileError(f"cannot read the bag chunk by chunk ({err})", source=src,
                                    hint="read it whole (nifo.io.loader.load_record)") from err
            yield from read_bag(path, topics=topics, axis=axis).chunks(chunk_samples)
            return
        except NifoError:
            raise
        except Exception as err:
            raise DataFileError(f"cannot read the bag ({str(err).rstrip('.') or type(err).__name__}); the file is "
                                "damaged or truncated", source=src,
                                hint="re-copy the bag; 'mcap recover' can often repair a cut recording") from err
        if use_log is None and any(p[0].size for p in part.values()):
            use_log = not any(p[0].any() for p in part.values())
            if use_log:
                asm.meta["stamps"] = "receive_time"
        for role, (s, v, t) in part.items():
            asm.add(role, receive_stamps(t, source=src, channel=wanted[role][0]) if use_log else s, v)
        yield from asm.ready()
    yield from asm.ready(final=True)
    asm.check_recorded()
