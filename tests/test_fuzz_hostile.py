"""Issue 56's hostile classes at fixed seeds (``tests/hostile_engine.py``; ``tools/fuzz_release.py --hostile`` runs
more of each): two commands at once on one folder, a killed run's folder and the user's files, forged or edited
markers, records of one name, a force model without a force, clipping, nothing excited, offsets from 1e-3 to 1e6, and
the issue's messages. The acceptance: 0 tracebacks, 0 wrong with exit 0, 0 errors not naming their file, 0 files lost.

Before this issue the same classes (``tools/fuzz_release.py --hostile --tree`` on the commit before it) gave the counts
in docs/CONTRACTS.md ("Hostile classes").
"""

from __future__ import annotations

import random
import warnings

import numpy as np
import pytest

import hostile_engine as h
from conftest import REPO
from fuzz_engine import Tally, cli
from nifo_core.signal.clipping import ClippingWarning, clipping


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    return h.make_inputs(tmp_path_factory.mktemp("hostile"))


@pytest.mark.parametrize("name", list(h.CLASSES))
def test_hostile_class_has_no_traceback_no_wrong_exit_0_no_unnamed_error_no_file_lost(inputs, name):
    fn, ci, _ = h.CLASSES[name]
    if ci == 0:
        pytest.skip("release only (tools/fuzz_release.py --hostile): tests/test_output_lock.py runs it once")
    tally = Tally()
    fn(h.Nifo(REPO, inprocess=True), inputs, tally, random.Random(56), ci)
    print(f"{name}: {tally.line()}")
    assert tally.counts["cases"] >= ci and tally.bad == 0, tally.failures


def test_clipping_counts_flat_runs_at_the_extremes_the_same_whole_or_in_chunks():
    rng = np.random.default_rng(1)
    x = rng.standard_normal(50_000)
    assert clipping(x).fraction == 0                                   # a continuous signal touches its extreme once
    # a slow sine from a coarse converter (12 bits, 2500 samples a period): every peak sits ~17 samples at its value,
    # entered by one step of the converter; a rail is entered by a jump
    q = np.round(np.sin(np.linspace(0, 40 * np.pi, 50_000)) * 2 ** 11) / 2 ** 11
    assert clipping(q).fraction == 0 and clipping(np.clip(q, -0.9, 0.9)).fraction > 0.05
    smooth = np.convolve(x, np.ones(20), "same")
    smooth /= smooth.std()                   # a band-limited signal, as a sensor's: clipped, it stays at the rail
    c = np.clip(smooth, -2, 2)
    whole = clipping(c)
    beyond = np.mean(np.abs(smooth) >= 2)    # excursions of one or two samples beyond the rail are not runs
    assert 0.5 * beyond < whole.fraction <= beyond and (whole.high, whole.low) == (2, -2)
    parts = [clipping(c[i:i + 7000]) for i in range(0, c.size, 7000)]
    merged = parts[0]
    for p in parts[1:]:
        merged = merged.merge(p)
    assert abs(merged.fraction - whole.fraction) < 5e-4 and (merged.high, merged.low) == (2, -2)


def test_a_little_clipping_is_one_warning_line_even_with_quiet_and_a_librarys_warning_none(inputs, tmp_path):
    from dataclasses import replace

    from nifo.io.loader import load_record, save_record

    base = load_record(inputs.rec)
    s = base.spindle_accel
    p = save_record(tmp_path / "little.csv", replace(base, spindle_accel=np.clip(s, -3.5 * s.std(), 3.5 * s.std())))
    code, _, err = cli(["identify", str(p), "--model", str(inputs.model), "--out", str(tmp_path / "i"), "--no-plots",
                        "-q"])
    lines = err.strip().splitlines()
    assert code == 0 and len(lines) == 1 and lines[0].startswith("nifo identify: warning: ") and p.name in lines[0]
    assert "flat at the channel's extremes" in lines[0] and issubclass(ClippingWarning, UserWarning)

    import nifo.cli as nifo_cli

    with warnings.catch_warnings(record=True):
        with nifo_cli._warnings_as_lines("x"):
            import io
            import contextlib

            buf = io.StringIO()
            with contextlib.redirect_stderr(buf):
                np.nanmedian(np.array([np.nan]))            # numpy's RuntimeWarning: All-NaN slice
                warnings.warn("something nifo says", UserWarning)   # not from nifo's code: kept for --verbose
    assert buf.getvalue() == ""


def test_a_band_nifo_chose_is_never_reported_as_the_users_flag():
    from nifo.settings import _Origins, in_context
    from nifo_core.errors import ConfigError

    err = ConfigError("analysis band 0.0156-0.078 Hz holds no frequency line", hint="widen it")
    chosen = in_context(err, _Origins({}), source="slow.csv")
    assert str(chosen).startswith("slow.csv: analysis band 0.0156-0.078 Hz holds no frequency line (the analysis "
                                  "band was chosen from the data, not given). Fix: give --analysis-band LO HI")
    flag = ConfigError("--analysis-band 47.75 4.39 must satisfy 0 <= LO < HI", channel="--analysis-band")
    from_file = in_context(flag, _Origins({"analysis_band_hz": "model file"}), source="m.yaml")
    assert str(from_file) == ("m.yaml: analysis band 47.75 4.39 must satisfy 0 <= LO < HI (the analysis band was given "
                              "in the model file). Fix: correct it in the model file's settings, or give --analysis-band "
                              "LO HI")
    given = in_context(flag, _Origins({"analysis_band_hz": "command line"}), source="rec.csv")
    assert "--analysis-band 47.75 4.39" in str(given)


def test_a_command_does_not_take_the_settings_chosen_before_it_in_this_process(inputs, tmp_path):
    """A caller's own steps in this process (a notebook, a test) chose an analysis band from the data: a command run
    after them names a bad band in its model.json as the model file's, not as a band chosen from the data with a
    "give --freq-range" fix (the suite saw it once, after other tests in the same worker)."""
    import json

    from nifo import settings
    from nifo.settings import _Origins

    ident = tmp_path / "ident"
    assert cli(["identify", str(inputs.rec), "--model", str(inputs.model), "--out", str(ident), "--no-plots",
                "-q"])[0] == 0
    doc = json.loads((ident / "model.json").read_text())
    doc["analysis_band_hz"] = [47.75, 4.39]
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "model.json").write_text(json.dumps(doc))
    token = settings._step.set((_Origins({}), ["earlier.csv"]))      # the band "chosen from the data" before
    try:
        code, _, err = cli(["predict", str(inputs.rec), "--model", str(tmp_path / "bad" / "model.json"),
                            "--no-plots", "--out", str(tmp_path / "out")])
    finally:
        settings._step.reset(token)
    assert code == 9 and "model.json" in err and "--analysis-band" not in err and "earlier.csv" not in err, err
