"""Output staging: all old or all new, leftovers of killed runs cleaned, the user's files never replaced."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from nifo.io import atomic
from nifo.io.atomic import INCOMPLETE, MARKER, check_output, clean_leftovers, staged_dir, staged_file, staged_run
from nifo.io.ownership import write_marker
from nifo_core.errors import OutputError


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_staged_run_restores_the_old_output_on_error_and_replaces_it_on_success(tmp_path, monkeypatch):
    monkeypatch.setattr(atomic, "_state", {"committed": [], "restored": []})   # as in a fresh nifo process
    out = tmp_path / "res"
    (out / "identify").mkdir(parents=True)
    (out / "identify" / "identify.json").write_text("old")
    write_marker(out)    # what an earlier nifo run left: its marker lists what it wrote
    with pytest.raises(KeyboardInterrupt):
        with staged_run(out) as d:
            assert d == out and (out / INCOMPLETE).is_file() and not (out / "identify").exists()
            (out / "characterize").mkdir()
            raise KeyboardInterrupt
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "identify"]
    assert (out / "identify" / "identify.json").read_text() == "old"
    assert "earlier results in" in atomic.interrupt_note()
    with staged_run(out) as d:
        (d / "report.html").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "report.html"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]


def test_leftovers_of_a_dead_process_are_removed_by_the_next_writer(tmp_path):
    pid = _dead_pid()
    stale = [tmp_path / f".res.partial-{pid}-abc", tmp_path / f".res.old-{pid}"]
    for s in stale:
        s.mkdir()
    live = tmp_path / f".res.partial-{os.getpid()}-mine"
    live.mkdir()
    other = tmp_path / f".other.partial-{pid}-x"
    other.mkdir()
    with staged_dir(tmp_path / "res") as d:
        (d / "a.json").write_text("{}")
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted(["res", live.name, other.name])
    assert clean_leftovers(tmp_path / "other") == [other]


def test_a_directory_of_the_users_files_or_a_regular_file_is_never_replaced(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    (data / "run1.mcap").write_bytes(b"\x89MCAP0\r\n")
    for cm in (staged_dir, staged_run):
        with pytest.raises(OutputError, match=r"holds files nifo did not write \(run1.mcap\).*Fix: give another --out"):
            with cm(data):
                pass
    assert (data / "run1.mcap").read_bytes() == b"\x89MCAP0\r\n"
    f = tmp_path / "notes.txt"
    f.write_text("keep")
    with pytest.raises(OutputError, match="is a regular file"):
        check_output(f)
    with pytest.raises(OutputError, match=r"notes.txt is a regular file, not a directory"):
        check_output(f / "sub" / "out")
    with pytest.raises(OutputError, match="is a directory; a file was to be written"):
        with staged_file(data):
            pass


def test_a_full_disk_is_one_output_error_and_the_old_file_stays(tmp_path):
    import errno

    f = tmp_path / "r.json"
    f.write_text('{"nifo_truth": 1, "old": true}')   # a file nifo wrote (its own key): it may be replaced
    with pytest.raises(OutputError, match=r"r.json: cannot write the output \(the disk is full\)\. Fix: free"):
        with staged_file(f) as tmp:
            tmp.write_text("half")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert f.read_text() == '{"nifo_truth": 1, "old": true}' and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]
