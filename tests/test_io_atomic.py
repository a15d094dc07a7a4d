"""Output staging: all old or all new, leftovers of killed runs cleaned, the user's files never replaced."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from nifo.io import atomic
from nifo.io.atomic import INCOMPLETE, MARKER, check_output, claim, clean_leftovers, staged_dir, staged_file, staged_run
from nifo.io.ownership import write_marker
from nifo_core.errors import OutputError

from conftest import REPO


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_staged_run_restores_the_old_output_on_error_and_replaces_it_on_success(tmp_path, monkeypatch):
    monkeypatch.setattr(atomic, "_state", {"committed": [], "restored": [], "kept": []})   # a fresh nifo process
    out = tmp_path / "res"
    (out / "identify").mkdir(parents=True)
    (out / "identify" / "identify.json").write_text("old")
    write_marker(out)    # what an earlier nifo run left: its marker lists what it wrote
    with pytest.raises(KeyboardInterrupt):
        with staged_run(out) as d:
            assert d == out and (out / INCOMPLETE).is_file() and not (out / "identify").exists()
            claim(out / "characterize")
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


# -----------------------------------------------------------------------------
# issue 26: a folder is nifo's to replace only when nifo wrote it
# -----------------------------------------------------------------------------

def _old_identify(d, *, extra: str | None = None):
    """A result folder as nifo identify wrote it before the marker: identify.json naming its figures."""
    d.mkdir(parents=True)
    (d / "identify.json").write_text('{"nifo_identify": 1, "nifo_version": "0.0.9", "figures": ["transmissibility.png"]}')
    (d / "model.json").write_text('{"nifo_identified_model": 1}')
    (d / "transmissibility.png").write_bytes(b"\x89PNG")
    (d / "transmissibility.svg").write_text("<svg/>")   # written beside every PNG (nifo.plots.save_figure)
    if extra:
        (d / extra).write_text("the user's")
    return d


def test_an_old_result_folder_is_recognised_exactly_and_one_extra_file_makes_it_the_users(tmp_path):
    old = _old_identify(tmp_path / "old")
    with staged_dir(old) as d:
        (d / "identify.json").write_text("{}")
    assert sorted(p.name for p in old.iterdir()) == [MARKER, "identify.json"]
    for extra in ("photo.png", "notes.txt", "model.yaml"):
        mine = _old_identify(tmp_path / f"mine_{extra}", extra=extra)
        with pytest.raises(OutputError, match=rf"holds files nifo did not write \({extra}\)"):
            check_output(mine)
        assert (mine / extra).read_text() == "the user's"
    fake = tmp_path / "fake"
    fake.mkdir()
    (fake / "identify.json").write_text('{"figures": ["a.png"]}')   # not nifo's document
    (fake / "a.png").write_bytes(b"png")
    with pytest.raises(OutputError, match="holds files nifo did not write"):
        check_output(fake)


def test_an_old_nifo_run_folder_is_replaced_whole_and_a_thesis_beside_it_is_not(tmp_path):
    def old_run(d):
        _old_identify(d / "identify")
        (d / "characterize").mkdir()
        (d / "characterize" / "characterize.json").write_text('{"nifo_characterize": 1, "figures": ["ranking.png"]}')
        (d / "characterize" / "suggested_model.yaml").write_text("nifo_model: 1\n")
        (d / "characterize" / "ranking.png").write_bytes(b"png")
        (d / "report").mkdir()
        (d / "report" / "report.html").write_text("<!DOCTYPE html>\n<html><head><title>nifo run: a, b</title>")
        return d

    res = old_run(tmp_path / "results")
    with staged_run(res) as d:
        (d / "report.html").write_text("new")
    assert sorted(p.name for p in res.iterdir()) == [MARKER, "report.html"]
    mine = old_run(tmp_path / "mine")
    (mine / "thesis.docx").write_bytes(b"PK")
    with pytest.raises(OutputError, match=r"holds files nifo did not write \(thesis\.docx\)"):
        check_output(mine)
    killed = tmp_path / "killed"   # an old run killed by SIGKILL: INCOMPLETE and what it had written
    killed.mkdir()
    (killed / INCOMPLETE).write_text("nifo run (process 123) is writing this directory, or was killed ...\n")
    _old_identify(killed / "identify")
    assert check_output(killed) == killed


def test_a_marked_folder_answers_for_its_entries_and_marked_sub_folders_for_theirs(tmp_path):
    out = tmp_path / "res"
    with staged_run(out) as d:
        with staged_dir(d / "identify") as i:
            claim(i / "identify.json")   # what every writer of a step does (write_json, the figures, ...)
            (i / "identify.json").write_text("{}")
        (d / "loop").mkdir()
        claim(d / "loop" / "loop.json")
        (d / "loop" / "loop.json").write_text("{}")
    marker = json.loads((out / MARKER).read_text())
    assert marker["entries"] == ["identify", "loop", "loop/loop.json"] and marker["complete"]
    assert json.loads((out / "identify" / MARKER).read_text())["entries"] == ["identify.json"]
    with staged_dir(out / "identify") as i:        # nifo identify --out res/identify: other files than before
        (i / "coefficients.png").write_bytes(b"png")
    assert check_output(out) == out                 # the sub-folder's own marker answers for it
    (out / "loop" / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match=r"holds files nifo did not write \(loop/notes\.txt\)"):
        check_output(out)
    (out / "loop" / "notes.txt").unlink()
    (out / "identify" / "link").symlink_to(tmp_path)
    with pytest.raises(OutputError, match=r"identify/link"):
        check_output(out)
    (out / "identify" / "link").unlink()
    (out / MARKER).write_text("not json")           # a marker nifo cannot read is no marker
    with pytest.raises(OutputError, match="holds files nifo did not write"):
        check_output(out)


def test_files_are_replaced_only_with_nifos_mark(tmp_path):
    from nifo.io.ownership import GENERATOR_META

    cases = {"r.html": ("<html><head>" + GENERATOR_META.format(version="0.1.0"), "<html><head><title>mine"),
             "t.json": ('{"nifo_truth": 1}', '{"truth": 1}'),
             "x.yaml": (None, "nifo_model: 1\n"), "x.csv": (None, "time,a\n"), "x.txt": (None, "notes")}
    for name, (ours, theirs) in cases.items():
        f = tmp_path / name
        if ours is not None:
            f.write_text(ours)
            with staged_file(f) as tmp:
                tmp.write_text("new")
            assert f.read_text() == "new"
        f.write_text(theirs)
        with pytest.raises(OutputError, match=r"nifo cannot tell it wrote this file \(.+\); it is left untouched"):
            check_output(f, kind="file")
        assert f.read_text() == theirs


# -----------------------------------------------------------------------------
# issue 56: the marker records what nifo wrote, with its content; a killed run's folder is nifo's only where it wrote
# -----------------------------------------------------------------------------

def test_a_file_nifo_wrote_and_the_user_edited_since_is_theirs_and_refused_by_name(tmp_path):
    out = tmp_path / "ident"
    with staged_dir(out) as d:
        (d / "model.json").write_text('{"nifo_identified_model": 1, "k": 1}')
        (d / "identify.json").write_text('{"nifo_identify": 1}')
    assert check_output(out) == out
    (out / "model.json").write_text('{"nifo_identified_model": 1, "k": 2}')     # edited by hand
    with pytest.raises(OutputError, match=r"ident: exists and holds files nifo wrote that were changed since "
                                          r"\(model\.json: yours now\); it is left untouched\. Fix: give another "
                                          r"--out, or move those files out of it"):
        with staged_dir(out):
            pass
    assert (out / "model.json").read_text() == '{"nifo_identified_model": 1, "k": 2}'


_KILLED_RUN = """
import os, signal, sys
from nifo.io.atomic import claim, staged_run
from nifo.io.results import write_json

with staged_run(sys.argv[1]) as d:
    write_json(d / "a.json", {"nifo_version": "new"}, atomic=False)
    (d / "step").mkdir()
    claim(d / "step" / "b.png")
    (d / "step" / "b.png").write_bytes(b"png")
    os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_killed_runs_folder_is_nifos_only_where_it_wrote_and_the_old_result_comes_back(tmp_path, monkeypatch):
    """The issue's case: nifo run killed (SIGKILL), the user saves a notebook into its folder and a script into a
    step's folder; the next run must not delete them (before: exit 0, both gone). It refuses naming them; once they
    are moved out, the killed run's previous result is put back and replaced (or restored if this run fails too)."""
    monkeypatch.setattr(atomic, "_state", {"committed": [], "restored": [], "kept": []})
    out = tmp_path / "R"
    with staged_run(out) as d:
        claim(d / "a.json")
        (d / "a.json").write_text('{"old": true}')
    p = subprocess.Popen([sys.executable, "-c", _KILLED_RUN, str(out)], env={**os.environ, "PYTHONPATH": str(REPO)},
                         stderr=subprocess.PIPE, text=True)
    assert p.wait(60) == -9, p.stderr.read()
    assert (out / INCOMPLETE).is_file() and (tmp_path / f".R.old-{p.pid}" / "a.json").read_text() == '{"old": true}'
    assert "The previous result is kept beside it" in (out / INCOMPLETE).read_text()
    (out / "my_analysis.ipynb").write_text("{}")
    (out / "step" / "my_plot.py").write_text("print(1)")
    with pytest.raises(OutputError, match=r"R: exists and a nifo run was cut short there and it holds files nifo did "
                                          r"not write \(my_analysis\.ipynb, step/my_plot\.py\); it is left untouched"):
        with staged_run(out):
            pass
    assert (out / "my_analysis.ipynb").read_text() == "{}" and (out / "step" / "my_plot.py").is_file()
    (out / "my_analysis.ipynb").unlink()
    (out / "step" / "my_plot.py").unlink()
    with pytest.raises(KeyboardInterrupt):      # the next run fails too: the result before the kill is back
        with staged_run(out) as d:
            raise KeyboardInterrupt
    assert (out / "a.json").read_text() == '{"old": true}' and not (out / INCOMPLETE).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["R"]


def test_a_forged_or_damaged_marker_makes_nothing_nifos(tmp_path):
    """A marker nifo cannot verify (its digest) answers for nothing, nor does an older nifo's (format 1: no content
    hashes), nor one listing a path outside its folder: the user's files in such a folder are never replaced."""
    out = tmp_path / "res"
    with staged_dir(out) as d:
        (d / "identify.json").write_text('{"nifo_identify": 1}')
    doc = json.loads((out / MARKER).read_text())
    (out / "notes.txt").write_text("mine")
    forged = {**doc, "entries": [*doc["entries"], "notes.txt"]}         # listed by hand, digest not updated
    forged_v1 = {"nifo_output": 1, "nifo_version": "0.0.9", "entries": ["identify.json", "notes.txt"]}
    outside = {**doc, "entries": ["../res/notes.txt", "identify.json"]}
    for marker in (forged, forged_v1, outside, {**doc, "digest": "0" * 32}):
        (out / MARKER).write_text(json.dumps(marker))
        with pytest.raises(OutputError, match=r"notes\.txt"):
            check_output(out)
        assert (out / "notes.txt").read_text() == "mine"


def test_a_run_folder_removed_by_someone_else_while_written_is_one_line_not_a_traceback(tmp_path):
    """Before issue 56 a run whose folder vanished under it ended in FileNotFoundError (INCOMPLETE) in staged_run."""
    import shutil

    out = tmp_path / "res"
    with pytest.raises(OutputError, match=r"res: the output folder was removed or replaced while nifo run wrote it"):
        with staged_run(out) as d:
            claim(d / "a.json")
            (d / "a.json").write_text("{}")
            shutil.rmtree(out)
    assert not out.exists()


def test_a_file_put_into_a_run_folder_while_it_is_written_survives_the_run_failing(tmp_path, monkeypatch):
    """The run's new folder goes when the run fails, but not a file the user saved into it meanwhile: the folder is
    kept beside (OUT.kept-PID) and the earlier result is back in place."""
    monkeypatch.setattr(atomic, "_state", {"committed": [], "restored": [], "kept": []})
    out = tmp_path / "R"
    with staged_run(out) as d:
        claim(d / "a.json")
        (d / "a.json").write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with staged_run(out) as d:
            claim(d / "b.json")
            (d / "b.json").write_text("new")
            (d / "notebook.ipynb").write_text("mine")      # the user, while the run goes on
            raise KeyboardInterrupt
    kept = tmp_path / f"R.kept-{os.getpid()}"
    assert (out / "a.json").read_text() == "old" and (kept / "notebook.ipynb").read_text() == "mine"
    assert "kept in" in atomic.interrupt_note() and str(kept) in atomic.interrupt_note()
