"""The bag mutation fuzzer at a fixed seed: 0 tracebacks, 0 hangs, 0 wrong results with exit 0.

Bit flips (anywhere and inside chunk payloads), truncations, zeroed,
duplicated and deleted byte ranges of a bag nifo wrote; every read either
gives exactly the original record or one line naming the file and the fix
(a damaged chunk: "corrupt chunk at byte offset N"). Every 10th case also
goes through ``nifo info``. The release run (more cases, more seeds) is
``tools/fuzz_release.py``.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from nifo.io.loader import load_record, save_record
from nifo_core.errors import CorruptDataError
from nifo_core.signal.record import Record

from fuzz_engine import chunk_spans, fuzz_bag, fuzz_metadata

SEED = 14
CASES = 300


def _record(n: int = 4000) -> Record:
    rng = np.random.default_rng(SEED)
    return Record(600.0, rng.standard_normal(n), 0.1 * rng.standard_normal(n), 1e-3 * rng.standard_normal(n),
                  t0_ns=1_700_000_000_000_000_000, source="fuzz")


def test_bag_mutation_fuzzer_finds_no_traceback_hang_or_wrong_result(tmp_path):
    tally = fuzz_bag(_record(), tmp_path, cases=CASES, seed=SEED, via_cli_every=10)
    print(tally.line())
    assert tally.counts["cases"] >= CASES
    assert tally.bad == 0, tally.line() + "\n" + "\n".join(f"{c}: {d}" for c, d in tally.failures)


def test_metadata_yaml_mutations_never_change_the_record_silently(tmp_path):
    """Flipped topic names, wrong message counts, cut files: the original record or one clear line."""
    tally = fuzz_metadata(_record(3000), tmp_path, cases=120, seed=SEED)
    print(tally.line())
    assert tally.bad == 0, tally.line() + "\n" + "\n".join(f"{c}: {d}" for c, d in tally.failures)


def test_every_single_bit_flip_in_a_chunk_payload_is_a_corrupt_chunk_error(tmp_path):
    """The issue's case: a flipped bit inside a chunk changed samples silently (13 of 33 flips)."""
    path = save_record(tmp_path / "b.mcap", _record(2000))
    blob = path.read_bytes()
    (lo, hi), = chunk_spans(blob)[:1]
    rng = np.random.default_rng(1)
    for i in rng.integers(lo, hi, 33).tolist():
        bad = bytearray(blob)
        bad[i] ^= 1 << int(rng.integers(8))
        path.write_bytes(bytes(bad))
        with pytest.raises(CorruptDataError, match=rf"{path}: corrupt chunk at byte offset \d+: .*Fix: "):
            load_record(path)


def test_the_chunk_crc_is_checked_on_read(tmp_path):
    """A chunk whose records are intact but whose recorded CRC differs: the CRC check (not zstd) says so."""
    path = save_record(tmp_path / "b.mcap", _record(2000))
    blob = bytearray(path.read_bytes())
    (lo, _), = chunk_spans(bytes(blob))[:1]
    # before the records: their u64 length, "zstd" and its u32 length, and before those the CRC u32
    crc_at = lo - 8 - len(b"zstd") - 4 - 4
    assert blob[crc_at + 4:crc_at + 8] == struct.pack("<I", 4) and struct.unpack_from("<I", blob, crc_at)[0]
    blob[crc_at] ^= 0x01
    path.write_bytes(bytes(blob))
    with pytest.raises(CorruptDataError, match=rf"{path}: corrupt chunk at byte offset \d+: CRC-32 [0-9a-f]{{8}} does "
                                               r"not match the recorded [0-9a-f]{8}"):
        load_record(path)


def test_chunks_and_summary_carry_crcs(tmp_path):
    path = save_record(tmp_path / "b.mcap", _record(2000))
    blob = path.read_bytes()
    (lo, _), = chunk_spans(blob)[:1]
    assert struct.unpack_from("<I", blob, lo - 8 - 4 - 4 - 4)[0] != 0
    assert struct.unpack_from("<I", blob, len(blob) - 8 - 4)[0] != 0   # footer summary_crc
    assert zlib.crc32(b"") == 0


# -----------------------------------------------------------------------------
# issue 26: the bundled sample's CRCs, receive times beyond 2^63 ns, bags from writers without CRCs
# -----------------------------------------------------------------------------

BAGS = Path(__file__).resolve().parents[1] / "bags"


def _zero_crcs(path: Path) -> None:
    """Make ``path`` look like a bag from a writer without CRCs: every chunk's and the summary's CRC set to 0."""
    from nifo.io.bag._mcap import _summary

    with path.open("r+b") as f:
        for ci in _summary(f).chunk_indexes:
            f.seek(ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8)
            f.write(bytes(4))
        f.seek(path.stat().st_size - 8 - 4)
        f.write(bytes(4))


def test_every_bag_in_bags_has_chunk_crcs():
    from nifo.io.bag import chunk_crc_status

    mcaps = sorted(BAGS.rglob("*.mcap"))
    assert len(mcaps) >= 3
    for m in mcaps:
        status = chunk_crc_status(m)
        assert status is not None and status["chunks"] > 0 and status["without_crc"] == 0, (m, status)
        blob = m.read_bytes()
        assert struct.unpack_from("<I", blob, len(blob) - 8 - 4)[0] != 0, f"{m}: no summary CRC"
    for bag in sorted(p for p in (BAGS / "sample").iterdir() if p.is_dir()):
        meta = load_record(bag).meta
        assert meta["chunk_crc"]["without_crc"] == 0 and "integrity_note" not in meta


def test_100_single_bit_flips_in_the_bundled_sample_chunks_are_all_refused(tmp_path):
    """Issue 26: 5 of 12 flips in the sample's chunks changed samples silently (no CRC). Now 0 of 100."""
    import random
    import shutil

    rng = random.Random(SEED)
    bags = sorted(p for p in (BAGS / "sample").iterdir() if p.is_dir())
    copies = {b: shutil.copytree(b, tmp_path / b.name) for b in bags}
    refused, silent, other = 0, [], []
    for k in range(100):
        bag = copies[bags[k % len(bags)]]
        mcap = next(bag.glob("*.mcap"))
        blob = mcap.read_bytes()
        lo, hi = rng.choice(chunk_spans(blob))
        i, bit = rng.randrange(lo, hi), rng.randrange(8)
        with mcap.open("r+b") as f:
            f.seek(i)
            f.write(bytes([blob[i] ^ (1 << bit)]))
        try:
            load_record(bag)
            silent.append((bag.name, i, bit))
        except CorruptDataError as err:
            text = str(err)
            if (text.startswith(f"{mcap}: corrupt chunk at byte offset") and "Fix: " in text
                    and "\n" not in text and err.exit_code == 14):
                refused += 1
            else:
                other.append((bag.name, i, bit, text))
        except Exception as err:  # noqa: BLE001 - counted and reported
            other.append((bag.name, i, bit, f"{type(err).__name__}: {err}"))
        finally:
            with mcap.open("r+b") as f:
                f.seek(i)
                f.write(bytes([blob[i]]))
    print(f"bundled sample: {refused}/100 single-bit flips in chunk payloads refused (exit 14), "
          f"{len(silent)} silent changes")
    assert refused == 100 and not silent and not other, (silent, other)


def test_receive_times_beyond_2_63_ns_with_zero_header_stamps_are_refused_or_read_exactly(tmp_path):
    """Issue 26: receive times above 2^63 ns wrapped to 1677 with exit 0. Now: exit 6, or (below 2^63) exact."""
    import random

    from fuzz_engine import Tally, classify, cli, guarded
    from nifo.io.bag import IMU, TopicData, write_channels
    from nifo.io.loader import iter_record_chunks
    from nifo_core.errors import TimestampError

    rng = random.Random(SEED)
    n, period = 400, 10_000_000                     # 4 s at 100 Hz
    tally = Tally()
    for k in range(16):
        base = 2**63 + rng.randint(-8 * 10**9, 4 * 10**9) if k else 2**63 + 10**9   # some below, some across
        log = np.uint64(base) + np.arange(n, dtype=np.uint64) * np.uint64(period)
        vals = np.sin(np.arange(n) / 5.0)
        zero = np.zeros(n, np.int64)
        path = write_channels(tmp_path / f"b{k}.mcap", [TopicData("/nifo/spindle/imu", IMU, "spindle", zero, vals, log),
                                                       TopicData("/nifo/body/imu", IMU, "body", zero, 2 * vals, log)])
        fits = base + (n - 1) * period < 2**63

        def right(rec) -> str | None:
            if not fits:
                return f"receive times up to {base + (n - 1) * period} ns were read (t0={rec.t0_ns})"
            return None if rec.t0_ns == base and rec.fs_hz == 100.0 else f"t0={rec.t0_ns} fs={rec.fs_hz}"

        for how, fn in (("load", lambda: load_record(path)),
                        ("chunks", lambda: next(iter(iter_record_chunks(path, chunk_samples=128))))):
            outcome, value = guarded(fn, limit_s=20)
            classify(tally, f"{how} base={base}", path, outcome, value, right)
            if outcome == "error":
                assert isinstance(value, TimestampError) and value.exit_code == 6, value
        code, _, err = cli(["info", str(path)])
        assert (code == 0) == fits and (fits or ("2^63" in err and len(err.strip().splitlines()) == 1)), err
    print(tally.line())
    assert tally.bad == 0 and tally.counts["error"] and tally.counts["ok"], tally.failures


def test_a_bag_without_chunk_crcs_is_said_once_and_its_mutants_never_crash(tmp_path):
    """A bag from a writer without CRCs: info's integrity line and the record's provenance say so (once); the
    mutation fuzzer finds no traceback or hang; a changed sample read from such a bag carries the note."""
    import random

    from fuzz_engine import Tally, bag_mutants, classify, cli, guarded, same_record
    from nifo.io.loader import iter_record_chunks

    path = save_record(tmp_path / "other.mcap", _record(2000))
    _zero_crcs(path)
    rec = load_record(path)
    assert rec.meta["chunk_crc"]["without_crc"] == rec.meta["chunk_crc"]["chunks"] > 0
    assert "carry no CRC-32" in rec.meta["integrity_note"] and "cannot be detected" in rec.meta["integrity_note"]
    assert next(iter(iter_record_chunks(path, chunk_samples=500))).meta["integrity_note"] == rec.meta["integrity_note"]
    code, out, _ = cli(["info", str(path)])
    assert code == 0 and out.count("carry no CRC-32") == 1 and "integrity" in out
    fresh = save_record(tmp_path / "nifo.mcap", _record(2000))
    assert "CRC-32 of every chunk checked" in cli(["info", str(fresh)])[1]
    blob = path.read_bytes()
    tally, announced = Tally(), 0
    target = tmp_path / "mutant.mcap"
    for desc, data in bag_mutants(blob, random.Random(SEED), 120):
        target.write_bytes(data)
        outcome, value = guarded(lambda: load_record(target), limit_s=20)
        if outcome == "ok" and not same_record(value, rec):
            announced += "integrity_note" in value.meta
        classify(tally, f"no-CRC bag {desc}", target, outcome, value,
                 lambda r: None if same_record(r, rec) or "integrity_note" in r.meta
                 else "a changed record without the no-CRC note")
    print(tally.line(), f"; {announced} changed records read, each carrying the no-CRC note")
    assert tally.bad == 0, tally.failures
