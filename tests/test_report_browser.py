"""The HTML report rendered in headless Chromium (Debian's ``chromium``; ``./test.sh`` installs it).

Rendered: the report of ``nifo run`` on the bundled sample (bags/sample, with its truth files) and on
the multisine levels 3, 5 and 7 of the F-16 ground vibration test (real data, MAT files read with --columns; Noël &
Schoukens 2017, nonlinearbenchmark.org). Every figure must load and every cell of the provenance
table must be filled.

A small harness page loads the report in an iframe and, once loaded, writes
what it sees (images decoded with their natural widths, errors raised on the
page) into its own DOM, which ``--dump-dom`` prints. Console messages come
from Chromium's own log (``--enable-logging=stderr --v=0``). The docs'
screenshot (docs/img/report.png) is made by tools/report_screenshot.sh.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from nifo.cli import main
from test_f16_loop import COLUMNS, f16_run_once
from test_run_cmd import pipeline, sample_run_once

REPO = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars"]

HARNESS = """<!DOCTYPE html><html><head><meta charset="utf-8"><link rel="icon" href="data:,"></head><body>
<pre id="result">pending</pre>
<iframe id="f" src="report.html" style="width:1200px;height:900px"></iframe>
<script>
const errors = [];
const frame = document.getElementById("f");
frame.addEventListener("load", () => {
  const w = frame.contentWindow, d = frame.contentDocument;
  w.addEventListener("error", e => errors.push(String(e.message)));
  const prov = Array.from(d.querySelectorAll("#provenance table")[0].querySelectorAll("tbody tr"))
      .map(tr => Array.from(tr.cells).map(td => ({text: td.textContent.trim(), cls: td.className})));
  const imgs = Array.from(d.images).map(i => ({alt: i.alt, complete: i.complete, width: i.naturalWidth,
                                              external: !i.src.startsWith("data:")}));
  const ext = Array.from(d.querySelectorAll("link[href],script[src]"))
      .map(e => e.getAttribute("href") || e.getAttribute("src")).filter(u => !u.startsWith("data:"));
  document.getElementById("result").textContent = JSON.stringify(
      {imgs, ext, errors, prov, title: d.title, h2: Array.from(d.querySelectorAll("h2")).map(h => h.textContent)});
});
</script></body></html>"""


@pytest.fixture(scope="module")
def chromium():
    if CHROMIUM is None:
        pytest.fail("chromium not found: install Debian's chromium (apt-get install chromium; .ci/run does)")
    return CHROMIUM


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    out, code, _ = pipeline(tmp_path_factory)
    assert code == 0
    return out / "report" / "report.html"


@pytest.fixture(scope="module")
def sample_report(tmp_path_factory) -> Path:
    """``nifo run`` on the bundled sample (three simulated road levels with their truth files)."""
    return sample_run_once(tmp_path_factory)[0] / "report" / "report.html"


#: the F-16 GVT's two sides of the nonlinear interface (data/README.md): wing row 1, payload row 2
F16_COLUMNS = COLUMNS[1]


@pytest.fixture(scope="module")
def f16_report(tmp_path_factory, shared_data) -> Path:
    """``nifo run`` on the F-16 multisine at levels 3, 5 and 7 (real data, read with --columns; the run
    test_f16_loop.py checks the predictions of)."""
    d = shared_data / "f16"
    if not all((d / f"F16Data_FullMSine_Level{k}.mat").is_file() for k in (3, 5, 7)):
        pytest.skip(f"F-16 files not found in {d}")
    return f16_run_once(tmp_path_factory, d) / "report" / "report.html"


def _chromium(chromium: str, tmp: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([chromium, *FLAGS, f"--user-data-dir={tmp / 'profile'}", *args],
                          capture_output=True, text=True, timeout=120)


def _render(chromium: str, report: Path, tmp_path: Path) -> tuple[dict, subprocess.CompletedProcess]:
    """What the harness saw of ``report`` in Chromium, and Chromium's process (its log on stderr)."""
    page = tmp_path / "report.html"
    shutil.copy(report, page)
    (tmp_path / "harness.html").write_text(HARNESS)
    proc = _chromium(chromium, tmp_path, "--allow-file-access-from-files", "--virtual-time-budget=10000",
                     "--enable-logging=stderr", "--v=0", "--dump-dom", (tmp_path / "harness.html").as_uri())
    m = re.search(r'<pre id="result">(.*?)</pre>', proc.stdout, re.S)
    assert m and m.group(1) != "pending", f"the harness did not run: {proc.stdout[-500:]} {proc.stderr[-2000:]}"
    seen = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&").replace("&lt;", "<")
                      .replace("&gt;", ">"))
    return seen, proc


def test_report_displays_every_figure_without_console_errors(chromium, report, tmp_path):
    seen, proc = _render(chromium, report, tmp_path)
    assert len(seen["imgs"]) >= 6, seen["imgs"]
    assert all(i["complete"] and i["width"] > 0 for i in seen["imgs"]), seen["imgs"]
    assert not any(i["external"] for i in seen["imgs"]) and not seen["ext"], "the report must be self-contained"
    assert not seen["errors"]
    assert any(h.startswith("Characterization") for h in seen["h2"])
    assert any(h.startswith("Identification") for h in seen["h2"])
    console = [ln for ln in proc.stderr.splitlines() if "CONSOLE" in ln or "Uncaught" in ln]
    assert not console, console


def test_report_screenshot_for_the_docs(chromium, report, tmp_path):
    shot = tmp_path / "report.png"
    _chromium(chromium, tmp_path, "--window-size=1200,1900", f"--screenshot={shot}", report.as_uri())
    assert shot.is_file() and shot.stat().st_size > 20_000
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the docs' screenshot is of the bundled sample (tools/report_screenshot.sh); tests never write the tree


def test_report_command_writes_one_self_contained_file(report, tmp_path, capsys):
    from nifo.cli import main

    out = tmp_path / "r.html"
    assert main(["report", str(report.parents[1] / "identify"), str(report.parents[1] / "characterize"),
                 "--out", str(out), "--no-levels"]) == 0
    text = out.read_text()
    assert text.count("data:image/png;base64,") >= 4
    assert not re.search(r'(src|href)="(?!data:|#)', text), "no external assets"
    assert list(tmp_path.iterdir()) == [out]


@pytest.mark.parametrize("which", ["sample_report", "f16_report"])
def test_report_of_sample_and_f16_loads_every_figure_and_fills_every_provenance_cell(chromium, which, request,
                                                                                    tmp_path):
    report = request.getfixturevalue(which)
    seen, proc = _render(chromium, report, tmp_path)
    assert len(seen["imgs"]) >= 5, seen["imgs"]
    assert all(i["complete"] and i["width"] > 0 for i in seen["imgs"]), seen["imgs"]
    assert not any(i["external"] for i in seen["imgs"]) and not seen["ext"] and not seen["errors"]
    # one row per data file: the sample's three levels, three F-16 levels
    assert len(seen["prov"]) == 3, seen["prov"]
    for row in seen["prov"]:
        assert len(row) == 6, row                            # path, format, fs, duration, size, channels
        for cell in row:
            assert cell["text"] not in ("", "–", "-") and "missing" not in cell["cls"], row
    fs = {row[2]["text"] for row in seen["prov"]}
    assert fs == ({"600"} if which == "sample_report" else {"400"}), fs
    html = report.read_text()
    if which == "f16_report":   # MAT keys in the channels column; no quarter-car words on an airframe
        assert "Acceleration[1]" in html and "F-16 wing-payload interface" in html
        assert "sprung mass" not in html and "spindle" not in html.split('id="provenance"')[0].lower()
    else:                       # the truth files beside the bundled sample are found and compared with
        pred = json.loads((report.parents[1] / "predict" / "predict.json").read_text())
        assert all(r["truth"]["model_nominal_t21_vs_true"]["median"] is not None for r in pred["records"])


def test_report_command_rereads_data_made_with_columns(f16_report, tmp_path, capsys):
    """``nifo report`` on F-16 results (MAT files read with --columns) re-reads them with the same column
    map (stored in the results): the levels figure is computed, the exit code is 0."""
    runs = f16_report.parents[1]
    doc = json.loads((runs / "identify" / "identify.json").read_text())
    assert doc["input"]["columns"] == F16_COLUMNS
    out = tmp_path / "f16.html"
    assert main(["report", str(runs / "characterize"), str(runs / "identify"), "--out", str(out)]) == 0
    text = out.read_text()
    assert 'alt="levels"' in text and "Acceleration[2]" in text


def test_report_of_an_identification_without_nonlinear_terms(tmp_path, capsys):
    from nifo.commands.run import sample_data

    model = tmp_path / "linear.yaml"
    model.write_text("nifo_model: 1\nnonlinearities: []\n")
    data = str(sample_data()[0])
    assert main(["-q", "identify", data, "--model", str(model), "--out", str(tmp_path / "i")]) == 0
    assert main(["-q", "report", str(tmp_path / "i"), "--out", str(tmp_path / "r.html")]) == 0
    assert "No nonlinear terms declared" in (tmp_path / "r.html").read_text()
