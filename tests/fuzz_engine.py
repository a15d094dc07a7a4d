"""The fuzzers shared by ``tests/test_fuzz_*.py`` (fixed seed, bounded) and ``tools/fuzz_release.py`` (larger).

Every case ends in one of: ``ok`` (and then the result must be right: equal
to the truth the case knows), ``error`` (a :class:`NifoError` whose one line
names the file and says ``Fix:``), ``traceback`` (any other exception),
``hang`` (over the time limit), ``wrong`` (success with a wrong result) or
``lost`` (a file nifo did not write, or changed since it wrote it, gone or
replaced: ``tests/hostile_engine.py``). The acceptance is 0 tracebacks, 0
hangs, 0 wrong, 0 unnamed errors, 0 lost.
"""

from __future__ import annotations

import contextlib
import io
import random
import signal
import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from nifo_core.errors import NifoError
from nifo_core.signal.record import Record

__all__ = ["Tally", "guarded", "bag_mutants", "fuzz_bag", "fuzz_metadata", "same_record", "cli"]


class Hang(BaseException):
    """Raised by the alarm when a case runs over its time limit."""


#: the outcomes that fail the acceptance
_BAD = ("traceback", "hang", "wrong", "unnamed", "lost")


@dataclass
class Tally:
    """Counts per outcome and the first few failures (case, detail) for the report."""

    counts: Counter = field(default_factory=Counter)
    failures: list[tuple[str, str]] = field(default_factory=list)

    def add(self, outcome: str, case: str, detail: str = "") -> None:
        self.counts[outcome] += 1
        self.counts["cases"] += 1
        if outcome in _BAD and len(self.failures) < 20:
            self.failures.append((case, f"{outcome}: {detail}"[:500]))

    @property
    def bad(self) -> int:
        return sum(self.counts[k] for k in _BAD)

    def line(self) -> str:
        c = self.counts
        return (f"{c['cases']} cases: {c['ok']} ok, {c['error']} clear errors, {c['traceback']} tracebacks, "
                f"{c['hang']} hangs, {c['wrong']} wrong-with-exit-0, {c['unnamed']} errors not naming file+fix"
                + (f", {c['lost']} with files lost" if c["lost"] else ""))


def _alarm(signum, frame):  # noqa: ARG001
    raise Hang()


def guarded(fn: Callable[[], object], *, limit_s: float = 20.0) -> tuple[str, object]:
    """Run ``fn`` under a wall-clock limit: ("ok", value) | ("error", NifoError) | ("traceback", exc) | ("hang", None)."""
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, limit_s)
    try:
        return "ok", fn()
    except Hang:
        return "hang", None
    except NifoError as err:
        return "error", err
    except Exception as err:  # noqa: BLE001 - the point: anything else is a traceback
        return "traceback", err
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def names_file_and_fix(err: BaseException, path: Path | str) -> bool:
    """The one-line message names the file (path or name) and says what to do."""
    text = str(err)
    p = Path(path)
    return "\n" not in text and (str(p) in text or p.name in text) and ". Fix: " in text


def same_record(a: Record, b: Record) -> bool:
    if a.fs_hz != b.fs_hz or a.n != b.n or a.t0_ns != b.t0_ns or a.has_tire_patch != b.has_tire_patch:
        return False
    pairs = [(a.spindle_accel, b.spindle_accel), (a.body_accel, b.body_accel)]
    if a.has_tire_patch:
        pairs.append((a.tire_patch_disp, b.tire_patch_disp))
    return all(np.array_equal(x, y) for x, y in pairs)


def classify(tally: Tally, case: str, path: Path, outcome: str, value, check_ok: Callable[[object], str | None]):
    """Count one case; ``check_ok(value)`` returns None when a success is right, else what is wrong."""
    if outcome == "ok":
        wrong = check_ok(value)
        tally.add("wrong" if wrong else "ok", case, wrong or "")
    elif outcome == "error":
        tally.add("error" if names_file_and_fix(value, path) else "unnamed", case, str(value))
    elif outcome == "traceback":
        tally.add("traceback", case, f"{type(value).__name__}: {value}")
    else:
        tally.add("hang", case, "over the time limit")


# -----------------------------------------------------------------------------
# bags: the mutation fuzzer
# -----------------------------------------------------------------------------

def chunk_spans(blob: bytes) -> list[tuple[int, int]]:
    """(start, end) byte spans of the compressed payloads of the MCAP chunks in ``blob``."""
    spans, pos = [], 8
    while pos + 9 <= len(blob):
        op, length = struct.unpack_from("<BQ", blob, pos)
        body = pos + 9
        if op == 0x06:   # chunk: start, end, size (u64 x3), crc u32, compression string, records (u64-sized)
            clen = struct.unpack_from("<I", blob, body + 28)[0]
            rec_at = body + 32 + clen + 8
            spans.append((rec_at, body + length))
        if op == 0x0F or length > len(blob):
            break
        pos = body + length
    return spans


def bag_mutants(blob: bytes, rng: random.Random, n: int) -> list[tuple[str, bytes]]:
    """``n`` mutated copies of an MCAP file: bit flips (anywhere, or in a chunk payload), truncations,
    zeroed ranges, duplicated and deleted ranges."""
    spans = chunk_spans(blob) or [(8, len(blob))]
    out = []
    for _ in range(n):
        b = bytearray(blob)
        kind = rng.choice(["flip_any", "flip_chunk", "flip_chunk", "truncate", "zero", "dup", "delete", "flips"])
        if kind in ("flip_any", "flip_chunk"):
            lo, hi = (0, len(b)) if kind == "flip_any" else rng.choice(spans)
            i = rng.randrange(lo, hi)
            bit = rng.randrange(8)
            b[i] ^= 1 << bit
            desc = f"{kind} byte {i} bit {bit}"
        elif kind == "flips":
            idx = sorted(rng.randrange(len(b)) for _ in range(rng.randint(2, 16)))
            for i in idx:
                b[i] ^= 1 << rng.randrange(8)
            desc = f"flips at {idx[:4]}..."
        elif kind == "truncate":
            i = rng.randrange(len(b))
            del b[i:]
            desc = f"truncate at {i}"
        elif kind == "zero":
            i = rng.randrange(len(b))
            k = rng.randint(1, 64)
            b[i:i + k] = bytes(len(b[i:i + k]))
            desc = f"zero {k} bytes at {i}"
        elif kind == "dup":
            i = rng.randrange(len(b))
            k = rng.randint(1, 64)
            b[i:i] = b[i:i + k]
            desc = f"duplicate {k} bytes at {i}"
        else:
            i = rng.randrange(len(b))
            k = rng.randint(1, 64)
            del b[i:i + k]
            desc = f"delete {k} bytes at {i}"
        out.append((desc, bytes(b)))
    return out


def fuzz_bag(original: Record, workdir: Path, *, cases: int, seed: int, limit_s: float = 20.0,
             via_cli_every: int = 0) -> Tally:
    """Write ``original`` as a lone .mcap, mutate it ``cases`` times and read each mutant.

    A read that succeeds must give exactly the original record (the fields
    nifo does not use may change: frame ids, covariances); every
    ``via_cli_every``-th case also goes through ``nifo info`` in-process,
    whose output must then equal the original's.
    """
    from nifo.io.loader import load_record, save_record

    workdir.mkdir(parents=True, exist_ok=True)
    src = save_record(workdir / "orig.mcap", original)
    truth = load_record(src)
    assert same_record(truth, original) or truth.t0_ns != original.t0_ns
    blob = src.read_bytes()
    rng = random.Random(seed)
    tally = Tally()
    target = workdir / "mutant.mcap"
    info_ref = cli(["info", str(src)])[1].replace(str(src), "<path>")
    for k, (desc, data) in enumerate(bag_mutants(blob, rng, cases)):
        target.write_bytes(data)
        case = f"bag {desc}"
        outcome, value = guarded(lambda: load_record(target), limit_s=limit_s)
        classify(tally, case, target, outcome, value,
                 lambda rec: None if same_record(rec, truth) else "the record read differs from the original")
        if via_cli_every and k % via_cli_every == 0:
            outcome, value = guarded(lambda: cli(["info", str(target)]), limit_s=limit_s)
            if outcome == "ok":
                code, out, err = value
                if code == 0:
                    good = out.replace(str(target), "<path>") == info_ref
                    tally.add("ok" if good else "wrong", f"nifo info, {case}", "" if good else out[-300:])
                else:
                    lines = err.strip().splitlines()
                    named = len(lines) == 1 and str(target) in lines[0] and "Fix:" in lines[0]
                    tally.add("error" if named else "unnamed", f"nifo info, {case}", err[-300:])
            else:
                classify(tally, f"nifo info, {case}", target, outcome, value, lambda v: None)
    return tally


def fuzz_metadata(original: Record, work: Path, *, cases: int, seed: int) -> Tally:
    """Mutate a bag directory's metadata.yaml (bit flips, wrong message counts, truncation); a read that
    succeeds must give the original record."""
    from nifo.io.loader import load_record, save_record

    work.mkdir(parents=True, exist_ok=True)
    bag = save_record(work / "bag", original)
    truth = load_record(bag)
    meta = (bag / "metadata.yaml").read_bytes()
    rng = random.Random(seed)
    tally = Tally()
    for _ in range(cases):
        b = bytearray(meta)
        kind = rng.choice(["flip", "count", "truncate"])
        if kind == "flip":
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
        elif kind == "count":
            text = b.decode()
            k = rng.choice([0, 1, truth.n - 1, truth.n + 1, 10**6, -5])
            text = text.replace(f"message_count: {truth.n}", f"message_count: {k}", rng.randint(1, 3))
            b = bytearray(text.encode())
        else:
            del b[rng.randrange(len(b)):]
        (bag / "metadata.yaml").write_bytes(bytes(b))
        outcome, value = guarded(lambda: load_record(bag), limit_s=20)
        classify(tally, f"metadata.yaml {kind}", bag, outcome, value,
                 lambda rec: None if same_record(rec, truth) else "the record read differs from the original")
    (bag / "metadata.yaml").write_bytes(meta)
    return tally


def cli(argv: list[str]) -> tuple[int, str, str]:
    """``nifo ARGV`` in this process: (exit code, stdout, stderr); non-nifo exceptions propagate."""
    from nifo.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return int(code), out.getvalue(), err.getvalue()
