"""Hostile cases of issue 56, shared by ``tests/test_fuzz_hostile.py`` (a fixed, bounded slice in CI) and
``tools/fuzz_release.py --hostile`` (more of each, and against another checkout: ``--tree``).

The classes: two commands at once on one output folder; a run killed by SIGKILL, then the user's files saved into its
folder; forged or edited output markers; records of the same name; a force model given a record without a force;
clipped channels; records with nothing excited; constant offsets from 1e-3 to 1e6; and the messages the issue named.
Every case runs the real ``nifo`` command — in a process of its own (:class:`Nifo`, needed for two at once and for
kills, and to try another checkout) or, in CI, in this process (``inprocess``) — and ends in one outcome of
:class:`fuzz_engine.Tally`: ``ok`` (and right), ``error`` (one line naming the file and the fix), ``traceback``,
``wrong`` (exit 0 with a wrong result), ``unnamed``, or ``lost`` (a file nifo did not write, or one it wrote that was
changed since, is gone or changed).
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from fuzz_engine import Tally, cli, names_file_and_fix

__all__ = ["Nifo", "Inputs", "make_inputs", "CLASSES", "run_classes"]

#: the paper's damper knee (the preset the inputs are simulated with)
KNEE_MODEL = "nifo_model: 1\nnonlinearities:\n  - {kind: velocity_deadzone, params: {knee: 0.03}}\n"
#: a run as short as a run gets: the kills spread over what it does
RUN_FLAGS = ["--no-loop", "--no-refine", "--no-recording", "-q"]


@dataclass
class Nifo:
    """``nifo ARGS`` of a checkout (``tree``): in a process of its own, or in this one (``inprocess``: only the
    checkout this process imported)."""

    tree: Path
    inprocess: bool = False

    def env(self) -> dict:
        env = {**os.environ, "PYTHONPATH": str(self.tree), "PYTHONUNBUFFERED": "1", "NIFO_THREADS": "1"}
        env.pop("NIFO_FIGURE_WORKERS", None)
        return env

    def start(self, argv: list[str], cwd: Path) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "nifo", *argv], cwd=cwd, env=self.env(),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def __call__(self, argv: list[str], cwd: Path, *, timeout: float = 900) -> tuple[int, str, str]:
        if self.inprocess:
            here = os.getcwd()
            os.chdir(cwd)
            try:
                return cli(argv)
            except Exception as err:  # noqa: BLE001 - a traceback is an outcome here
                import traceback

                return 1, "", "Traceback (most recent call last):\n" + "".join(traceback.format_exception(err))
            finally:
                os.chdir(here)
        p = subprocess.run([sys.executable, "-m", "nifo", *argv], cwd=cwd, env=self.env(), capture_output=True,
                           text=True, timeout=timeout)
        return p.returncode, p.stdout, p.stderr


@dataclass
class Inputs:
    """What the cases start from: a 20 s record of the paper's damper knee, its model file, a force-driven single
    mass (spindle fixed), and a folder to work in."""

    root: Path
    rec: Path
    model: Path
    forced: Path
    forced_cols: str = "force=force,spindle_accel=fixed"


def make_inputs(root: Path) -> Inputs:
    from scipy.signal import lfilter

    from nifo.io.loader import save_record
    from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate

    root.mkdir(parents=True, exist_ok=True)
    sim = simulate(SimConfig(strut=preset("paper_deadzone"), duration_s=20.0, road=RandomRoad(2.5e-3)), rng=2)
    rec = save_record(root / "road.csv", replace(sim.record, tire_patch_disp=None))
    model = root / "knee.yaml"
    model.write_text(KNEE_MODEL)
    rng = np.random.default_rng(56)
    n, fs = 20000, 1000.0       # a 2 kg mass on a 20 Hz spring driven by a filtered random force
    f = lfilter([1.0], [1.0, -0.9], rng.standard_normal(n)) * 5.0
    w, m, zeta = 2 * np.pi * 20, 2.0, 0.05
    a, b = _mass_spring(w, zeta, fs)
    x = lfilter(b, a, f / m)
    acc = np.gradient(np.gradient(x, 1 / fs), 1 / fs)
    forced = root / "forced.csv"
    t = np.arange(n) / fs
    np.savetxt(forced, np.c_[t, acc, f], delimiter=",", header="time,body_accel,force", comments="", fmt="%.17g")
    return Inputs(root, rec, model, forced)


def _mass_spring(w: float, zeta: float, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """x/(F/m) = 1/(s² + 2ζωs + ω²) by the bilinear transform."""
    from scipy.signal import bilinear

    b, a = bilinear([1.0], [1.0, 2 * zeta * w, w * w], fs)
    return a, b


def _snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and not p.is_symlink()}


def _classify(tally: Tally, case: str, code: int, err: str, path: Path | str, *, ok: Callable[[], str | None],
              lost: str | None = None) -> None:
    """One outcome: lost files first, then a traceback, an error that must name ``path`` and say Fix:, or success
    checked by ``ok`` (None: right)."""
    if lost:
        tally.add("lost", case, lost)
    elif "Traceback" in err:
        tally.add("traceback", case, err[-400:])
    elif code != 0:
        line = [x for x in err.strip().splitlines() if "error:" in x]
        named = len(line) == 1 and names_file_and_fix(line[0].split("error: ", 1)[-1], path)
        tally.add("error" if named else "unnamed", case, err[-400:])
    else:
        wrong = ok()
        tally.add("wrong" if wrong else "ok", case, wrong or "")


# -----------------------------------------------------------------------------
# the output folder: two at once, a kill then the user's files, markers edited or forged
# -----------------------------------------------------------------------------

def _complete(out: Path) -> bool:
    """``out`` holds one finished result: a marker nifo can read, no INCOMPLETE, and nothing it does not list."""
    from nifo.io.ownership import read_marker, unowned

    doc = read_marker(out) if out.is_dir() else None
    return doc is not None and doc.get("complete", True) is not False and not (out / "INCOMPLETE").exists() \
        and not unowned(out)


def concurrent(nifo: Nifo, inp: Inputs, tally: Tally, rng: random.Random, trials: int, *, command: str) -> None:
    """Two commands on one --out at once (``command``: "characterize", cheap, or "run"), half the time over an
    earlier result: never neither result, never a traceback; a refusal names the folder."""
    argv = {"characterize": ["characterize", str(inp.rec), "--kinds", "coulomb", "--grid", "4", "-q"],
            "run": ["run", str(inp.rec), *RUN_FLAGS]}[command]
    for k in range(trials):
        work = inp.root / f"concurrent_{command}_{k}"
        work.mkdir()
        out = work / "SAME"
        had = rng.random() < 0.5
        if had:
            code, _, err = nifo([*argv, "--out", str(out)], work)
            if code != 0:
                tally.add("traceback" if "Traceback" in err else "unnamed", f"{command} setup", err[-300:])
                continue
        procs = [nifo.start([*argv, "--out", str(out)], work) for _ in range(2)]
        done = [(p.wait(900), *p.communicate()) for p in procs]
        case = f"two nifo {command} --out SAME at once ({'over a result' if had else 'new'}), trial {k}"
        errs = "".join(e for _, _, e in done)
        codes = [c for c, _, _ in done]
        if "Traceback" in errs:
            tally.add("traceback", case, errs[-400:])
        elif not _complete(out):
            tally.add("lost", case, f"exits {codes}; afterwards {out.name} is "
                      + ("missing" if not out.exists() else "incomplete or foreign") + f": {errs[-300:]}")
        elif all(c != 0 for c in codes) and not had:
            tally.add("wrong", case, f"exits {codes} yet a result is there")
        else:
            refused = [e for c, _, e in done if c != 0]
            named = all(names_file_and_fix(e.strip().split("error: ", 1)[-1], out) for e in refused)
            tally.add("ok" if named else "unnamed", case, "" if named else refused[0][-300:])


def killed_then_user_files(nifo: Nifo, inp: Inputs, tally: Tally, rng: random.Random, trials: int) -> None:
    """``nifo run`` killed (SIGKILL) at a random moment; the user saves a notebook into its folder and a script into
    a step's folder; the same command again must keep both (refuse naming them, or leave them)."""
    if nifo.inprocess:
        nifo = Nifo(nifo.tree)
    work = inp.root / "killed"
    work.mkdir()
    out = work / "R"
    t = time.monotonic()
    nifo(["run", str(inp.rec), *RUN_FLAGS, "--out", str(out)], work)
    t_full = time.monotonic() - t
    for k in range(trials):
        p = nifo.start(["run", str(inp.rec), *RUN_FLAGS, "--out", str(out)], work)
        delay = rng.uniform(1.0, t_full)
        try:
            p.wait(delay)
        except subprocess.TimeoutExpired:
            p.kill()
        p.communicate()
        mine = {}
        if out.is_dir():
            mine[out / "my_analysis.ipynb"] = b'{"cells": []}\n'
            subs = sorted(d for d in out.iterdir() if d.is_dir())
            if subs:
                mine[rng.choice(subs) / "my_plot.py"] = b"print('mine')\n"
        else:
            out.mkdir()
            mine[out / "my_analysis.ipynb"] = b'{"cells": []}\n'
        for f, data in mine.items():
            f.write_bytes(data)
        code, _, err = nifo(["run", str(inp.rec), *RUN_FLAGS, "--out", str(out)], work)
        gone = [str(f.relative_to(work)) for f, data in mine.items() if not f.is_file() or f.read_bytes() != data]
        case = f"run killed after {delay:.1f} s, then the user's files, then run again (trial {k})"
        _classify(tally, case, code, err, out, ok=lambda: None,
                  lost=f"{', '.join(gone)} gone after exit {code}" if gone else None)
        for f in mine:            # the user moves them out; the next run must then succeed
            f.unlink(missing_ok=True)
        code, _, err = nifo(["run", str(inp.rec), *RUN_FLAGS, "--out", str(out)], work)
        if code != 0:
            _classify(tally, f"{case}, files moved out", code, err, out, ok=lambda: None)


_MUTATIONS = ("edit a listed file", "add a user file", "list the user's file in the marker by hand",
              "flip a byte of the marker", "truncate the marker", "an older nifo's marker listing the user's file",
              "the marker of another result copied in", "an entry outside the folder", "delete the marker",
              "edit model.json by hand")


def markers(nifo: Nifo, inp: Inputs, tally: Tally, rng: random.Random, trials: int) -> None:
    """A result folder nifo wrote, then the user's change to it (or to its marker); the same command again must
    keep every file that is the user's: any file nifo did not write, and any it wrote that changed since."""
    work = inp.root / "markers"
    work.mkdir()
    ident = ["identify", str(inp.rec), "--model", str(inp.model), "--no-plots", "-q"]
    other = work / "other"
    nifo([*ident, "--out", str(other)], work)
    for k in range(trials):
        what = _MUTATIONS[k % len(_MUTATIONS)]
        out = work / f"res{k}"
        code, _, err = nifo([*ident, "--out", str(out)], work)
        if code != 0:
            tally.add("traceback" if "Traceback" in err else "unnamed", "markers setup", err[-300:])
            continue
        nifos = _snapshot(out)
        marker = out / ".nifo-output"
        user: dict[str, bytes] = {}
        if what in ("edit a listed file", "edit model.json by hand"):
            name = "model.json" if "model" in what else rng.choice([n for n in nifos if not n.startswith(".")])
            f = out / name
            f.write_bytes(f.read_bytes().replace(b"}", b', "edited": 1}', 1) if name.endswith(".json")
                          else f.read_bytes() + b"#")
            user[name] = f.read_bytes()
        else:
            (out / "notes.txt").write_text("mine\n")
            user["notes.txt"] = b"mine\n"
            raw = marker.read_bytes()
            if what == "list the user's file in the marker by hand":
                doc = json.loads(raw)
                doc["entries"].append("notes.txt")
                marker.write_text(json.dumps(doc))
            elif what == "flip a byte of the marker":
                b = bytearray(raw)
                i = rng.randrange(len(b))
                b[i] ^= 1 << rng.randrange(8)
                marker.write_bytes(bytes(b))
            elif what == "truncate the marker":
                marker.write_bytes(raw[:rng.randrange(len(raw))])
            elif what == "an older nifo's marker listing the user's file":
                marker.write_text(json.dumps({"nifo_output": 1, "nifo_version": "0.0.9",
                                              "entries": sorted([*nifos, "notes.txt"])}))
            elif what == "the marker of another result copied in":
                marker.write_bytes((other / ".nifo-output").read_bytes())
            elif what == "an entry outside the folder":
                doc = json.loads(raw)
                doc["entries"].append("../" + out.name + "/notes.txt")
                marker.write_text(json.dumps(doc))
            elif what == "delete the marker":
                marker.unlink()
        code, _, err = nifo([*ident, "--out", str(out)], work)
        gone = [n for n, data in user.items() if not (out / n).is_file() or (out / n).read_bytes() != data]
        _classify(tally, f"marker: {what} (trial {k})", code, err, out, ok=lambda: None,
                  lost=f"{', '.join(gone)} replaced after exit {code}" if gone else None)


# -----------------------------------------------------------------------------
# records and inputs
# -----------------------------------------------------------------------------

def _sim(root: Path, name: str, seed: int, *, scale: float = 1.0) -> Path:
    from nifo.io.loader import save_record
    from nifo_core.simulate.quarter_car import RandomRoad, SimConfig, preset, simulate

    sim = simulate(SimConfig(strut=preset("linear"), duration_s=20.0, road=RandomRoad(2e-3 * scale)), rng=seed)
    p = root / name
    p.parent.mkdir(parents=True, exist_ok=True)
    return save_record(p, replace(sim.record, tire_patch_disp=None))


def same_names(nifo: Nifo, inp: Inputs, tally: Tally, rng: random.Random, trials: int) -> None:
    """``nifo predict`` of records of one name from two folders, of names that normalise alike, of one file twice:
    every record's signals in a table of its own, every name different."""
    import pyarrow.parquet as pq

    from nifo.io.loader import load_record

    work = inp.root / "names"
    work.mkdir()
    ident = work / "ident"
    nifo(["identify", str(inp.rec), "--model", str(inp.model), "--out", str(ident), "--no-plots", "-q"], work)
    sets = [["day1/rec.csv", "day2/rec.csv"], ["rec 1.csv", "rec_1.csv"], ["a/r.csv", "b/r.csv", "r.csv"],
            ["x/Rec.csv", "x/rec.csv"], ["day1/rec.csv", "day1/rec.csv"]]
    for k in range(trials):
        names = sets[k % len(sets)]
        paths = [work / f"set{k}" / n for n in names]
        for i, p in enumerate(paths):
            if not p.exists():
                _sim(p.parent, p.name, seed=100 * k + i, scale=1 + 0.3 * i)
        out = work / f"pred{k}"
        code, _, err = nifo(["predict", *map(str, paths), "--model", str(ident), "--out", str(out), "-q"], work)

        def right() -> str | None:
            doc = json.loads((out / "predict.json").read_text())
            files = [f for r in doc["records"] for f in (*r["signals"], *r.get("figures", []))]
            if len(set(r["name"] for r in doc["records"])) != len(paths) or len(set(files)) != len(files):
                return f"names or files repeat: {[r['name'] for r in doc['records']]}"
            for r, p in zip(doc["records"], paths):
                got = pq.read_table(out / r["signals"][0]).column("body_accel_measured").to_numpy()
                if not np.array_equal(got, load_record(p).body_accel):
                    return f"{r['signals'][0]} does not hold {p.relative_to(work)}"
            return None

        _classify(tally, f"predict {' '.join(names)}", code, err, paths[0], ok=right)


def missing_force(nifo: Nifo, inp: Inputs, tally: Tally, rng: random.Random, trials: int) -> None:
    """A model identified with a measured force, given records without one: refused (exit 4, naming the channel)."""
    work = inp.root / "force"
    work.mkdir()
    fmodel = work / "fmodel"
    lin = work / "linear.yaml"
    lin.write_text("nifo_model: 1\nnonlinearities: []\n")
    code, _, err = nifo(["identify", str(inp.forced), "--columns", inp.forced_cols, "--model", str(lin), "--out",
                         str(fmodel), "--no-plots", "-q"], work)
    if code != 0:
        tally.add("traceback" if "Traceback" in err else "unnamed", "force model setup", err[-300:])
        return
    for k in range(trials):
        rec = [inp.rec, _sim(work, f"noforce{k}.csv", seed=300 + k)][k % 2]
        code, _, err = nifo(["predict", str(rec), "--model", str(fmodel), "--out", str(work / f"p{k}"), "-q"], work)
        case = f"force model, record without force {rec.name}"
        if code == 0:
            tally.add("wrong", case, "exit 0: the model driven by the spindle alone")
        elif "Traceback" not in err and (code != 4 or "force" not in err):
            tally.add("wrong", case, f"exit {code}, not 4 naming the force: {err[-200:]}")
        else:
            _classify(tally, case, code, err, rec, ok=lambda: None)


def clipped(nifo: Nifo, inp: Inputs, tally: Tally, rng: random.Random, trials: int) -> None:
    """Channels clipped at ±kσ: refused above the threshold (exit 16, naming the channel), a warning naming it
    below, nothing said of an unclipped record."""
    from nifo.io.loader import load_record, save_record
    from nifo_core.signal.clipping import REFUSE_FRACTION, clipping

    work = inp.root / "clip"
    work.mkdir()
    base = load_record(inp.rec)
    levels = [None, 2.0, 2.5, 3.0, 3.5, 4.0]
    for k in range(trials):
        level = levels[k % len(levels)]
        ch = ("spindle_accel", "body_accel")[(k // len(levels)) % 2]
        x = getattr(base, ch)
        xc = x if level is None else np.clip(x, -level * x.std(), level * x.std())
        frac = clipping(xc).fraction
        p = save_record(work / f"clip{k}.csv", replace(base, **{ch: xc}))
        code, _, err = nifo(["identify", str(p), "--model", str(inp.model), "--out", str(work / f"id{k}"),
                             "--no-plots"], work)
        case = f"{ch} clipped at {level}σ ({100 * frac:.3g} % flat)" if level else "not clipped"
        warned = "flat at the channel's extremes" in err and p.name in err
        if frac > REFUSE_FRACTION:
            if code == 0:
                tally.add("wrong", case, "exit 0 on a clipped record")
            else:
                _classify(tally, case, code, err, p, ok=lambda: None)
        else:
            _classify(tally, case, code, err, p,
                      ok=lambda: (None if warned == (frac > 0) else
                                  "no warning of the clipping" if frac > 0 else "a clipping warning on clean data"))


def nothing_excited(nifo: Nifo, inp: Inputs, tally: Tally, rng: random.Random, trials: int) -> None:
    """Records in which nothing can be identified: two independent noise channels, a dead channel, one channel read
    twice. ``identify`` and ``run`` must both refuse, naming the file."""
    from nifo.io.loader import save_record
    from nifo_core.signal.record import Record

    work = inp.root / "excite"
    work.mkdir()
    for k in range(trials):
        g = np.random.default_rng(500 + k)
        n = 24000
        kind = ("independent noise", "dead body channel", "one channel twice")[k % 3]
        u = g.standard_normal(n)
        y = {"independent noise": g.standard_normal(n), "dead body channel": np.zeros(n),
             "one channel twice": u}[kind]
        p = save_record(work / f"x{k}.csv", Record(600.0, u, y))
        for cmd in (["identify", str(p), "--model", str(inp.model), "--no-plots", "-q"], ["run", str(p), *RUN_FLAGS]):
            code, _, err = nifo([*cmd, "--out", str(work / f"{cmd[0]}{k}")], work)
            case = f"{kind}: nifo {cmd[0]}"
            if code == 0:
                tally.add("wrong", case, "exit 0 on a record with nothing to identify")
            else:
                _classify(tally, case, code, err, p, ok=lambda: None)


def _key_numbers(ident: Path) -> dict:
    doc = json.loads((ident / "model.json").read_text())
    return {"terms": [t.get("kind") for t in doc["terms"]], "c_over_m2": doc["c_over_m2"],
            "body": [doc["body"].get("k"), doc["body"].get("c")] if doc.get("body") else None}


def offsets(nifo: Nifo, inp: Inputs, tally: Tally, rng: random.Random, trials: int) -> None:
    """Constant offsets on the accelerations (1e-3 to 1e6 on both, gravity on the body): ``identify --refine``
    gives the numbers of the record without them (to 1e-6) and reports the offset."""
    from nifo.io.loader import load_record, save_record

    work = inp.root / "offsets"
    work.mkdir()
    base = load_record(inp.rec)
    argv = ["identify", "--model", str(inp.model), "--refine", "--no-plots", "-q"]
    code, _, err = nifo([*argv[:1], str(inp.rec), *argv[1:], "--out", str(work / "clean")], work)
    if code != 0:
        tally.add("traceback" if "Traceback" in err else "unnamed", "offsets setup", err[-300:])
        return
    ref = _key_numbers(work / "clean")
    cases = [(1e-3, 1e-3), (1.0, 1.0), (0.0, 9.81), (1e3, 1e3), (1e6, 1e6), (-1e6, 0.0)]
    for k in range(trials):
        o1, o2 = cases[k % len(cases)]
        p = save_record(work / f"off{k}.csv", replace(base, spindle_accel=base.spindle_accel + o1,
                                                       body_accel=base.body_accel + o2))
        out = work / f"id{k}"
        code, _, err = nifo([*argv[:1], str(p), *argv[1:], "--out", str(out)], work)

        def right() -> str | None:
            got = _key_numbers(out)
            if got["terms"] != ref["terms"]:
                return f"terms {got['terms']} (without the offset {ref['terms']})"
            a = np.array([*ref["c_over_m2"], *(ref["body"] or [])], float)
            b = np.array([*got["c_over_m2"], *(got["body"] or [])], float)
            if a.shape != b.shape or not np.allclose(a, b, rtol=1e-6, atol=0):
                return f"numbers {b.tolist()} (without the offset {a.tolist()})"
            said = json.loads((out / "identify.json").read_text()).get("settings", {}).get("inputs", {})
            told = next(iter(said.values()), {}).get("offsets_m_s2", {}) if said else {}
            mean = {"spindle_accel": float(np.mean(base.spindle_accel)) + o1,
                    "body_accel": float(np.mean(base.body_accel)) + o2}
            if not told or any(abs(told[c] - mean[c]) > 1e-9 * max(1.0, abs(mean[c])) for c in mean):
                return f"offset not reported ({told})"
            return None

        _classify(tally, f"offsets spindle {o1:g}, body {o2:g} m/s²", code, err, p, ok=right)


def messages(nifo: Nifo, inp: Inputs, tally: Tally, rng: random.Random, trials: int) -> None:
    """The issue's messages: each refusal names its file (data or model.json) and a setting by its true source; a
    record short of a block says its own length; no library warning reaches stderr."""
    from nifo.io.loader import load_record, save_record
    from nifo_core.signal.record import Record

    work = inp.root / "messages"
    work.mkdir()
    ident = work / "ident"
    nifo(["identify", str(inp.rec), "--model", str(inp.model), "--out", str(ident), "--no-plots", "-q"], work)
    base = load_record(inp.rec)
    doc = json.loads((ident / "model.json").read_text())

    def model_with(name: str, change) -> Path:
        d = json.loads(json.dumps(doc))
        change(d)
        (work / name).mkdir()
        (work / name / "model.json").write_text(json.dumps(d))
        return work / name / "model.json"

    def unstable(d):
        d["body"]["c"] = -abs(d["body"]["c"])
        d["linear_part"]["body"]["c"] = d["body"]["c"]

    def negative_mass(d):
        d["body"]["k"] = -abs(d["body"]["k"])
        d["linear_part"]["body"]["k"] = d["body"]["k"]

    step = np.zeros(base.n)
    step[base.n // 2:] = 1.0
    g = np.random.default_rng(7)
    cases = {
        "a 1 Hz record": (save_record(work / "slow.csv", replace(base, fs_hz=1.0)), "identify", None),
        "one channel twice": (save_record(work / "twice.csv", replace(base, body_accel=base.spindle_accel)), "run",
                              None),
        "unstable body in model.json": (work / "in.csv", "predict", model_with("unstable", unstable)),
        "negative stiffness in model.json": (work / "in.csv", "predict", model_with("negmass", negative_mass)),
        "reversed band in model.json": (work / "in.csv", "predict",
                                        model_with("reversed", lambda d: d.__setitem__("analysis_band_hz",
                                                                                      [47.75, 4.39]))),
        "a 10-sample record": (save_record(work / "ten.csv", base.slice(0, 10)), "predict", ident / "model.json"),
        "a step": (save_record(work / "step.csv", Record(600.0, step + 1e-3 * g.standard_normal(base.n),
                                                         np.convolve(step, np.exp(-np.arange(600) / 60) / 60)
                                                         [:base.n])), "run", None),
    }
    save_record(work / "in.csv", base)
    for k, (name, (data, cmd, model)) in enumerate(list(cases.items())[:trials]):
        argv = {"identify": ["identify", str(data), "--model", str(inp.model), "--no-plots"],
                "run": ["run", str(data), *RUN_FLAGS],
                "predict": ["predict", str(data), "--model", str(model), "--no-plots"]}[cmd]
        code, _, err = nifo([*argv, "--out", str(work / f"out{k}")], work)
        about = model if model is not None and "model.json" in name else data
        case = f"{name}: nifo {cmd}"
        library = [x for x in err.splitlines() if "Warning:" in x and ("numpy" in x or "site-packages" in x
                                                                     or "nifo_core" in x)]
        if library:
            tally.add("wrong", case, f"a library warning reached the user: {library[0][:200]}")
            continue
        bad = None
        if code != 0 and "--analysis-band" in err and not {"--analysis-band", "--freq-range"} & set(argv):
            bad = "names --analysis-band, which was not given"
        elif name == "a 10-sample record" and code != 0 and "10 samples" not in err:
            bad = f"does not say 10 samples: {err[-200:]}"
        if bad:
            tally.add("wrong", case, bad)
        else:
            _classify(tally, case, code, err, about, ok=lambda: None)


#: class name -> (function, cases in CI, cases in a release run)
CLASSES: dict[str, tuple[Callable, int, int]] = {
    "two at once (characterize)": (lambda *a: concurrent(*a, command="characterize"), 3, 20),
    "two at once (run)": (lambda *a: concurrent(*a, command="run"), 0, 4),
    "killed, then the user's files": (killed_then_user_files, 1, 10),
    "markers edited or forged": (markers, 10, 30),
    "records of one name": (same_names, 5, 10),
    "a force model without a force": (missing_force, 2, 4),
    "clipping": (clipped, 6, 12),
    "nothing excited": (nothing_excited, 3, 6),
    "offsets 1e-3 to 1e6": (offsets, 6, 12),
    "the issue's messages": (messages, 7, 7),
}


def run_classes(nifo: Nifo, root: Path, *, release: bool, seed: int = 56, only: list[str] | None = None,
                echo: Callable[[str], None] = print) -> dict[str, Tally]:
    """Every class (or ``only`` those) on one set of inputs; the tally of each."""
    inp = make_inputs(root / "inputs")
    out = {}
    for name, (fn, ci, rel) in CLASSES.items():
        if only and name not in only:
            continue
        tally = Tally()
        t = time.monotonic()
        fn(nifo, inp, tally, random.Random(seed), rel if release else ci)
        out[name] = tally
        echo(f"{name}: {tally.line()}, {tally.counts['lost']} lost ({time.monotonic() - t:.0f} s)")
        for case, what in tally.failures[:5]:
            echo(f"  FAIL {case}: {what[:300]}")
    return out
