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

HARNESS = """<!DOCTYPE html><html><head><meta charset="utf-8"><link rel="icon" href="data:,">
<style>body { margin: 0; }</style></head><body>
<iframe id="f" src="report.html" style="width:WIDTHpx;height:HEIGHTpx;border:0;display:block"></iframe>
<pre id="result">pending</pre>
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
  const vw = d.documentElement.clientWidth;
  const wide = Array.from(d.body.querySelectorAll("*")).filter(e => e.getBoundingClientRect().right > vw + 0.5)
      .map(e => e.tagName + "." + e.className + ": " + e.textContent.slice(0, 60));
  const head = Array.from(d.querySelectorAll("figure.headline-fig img")).map(i => {
      const r = i.getBoundingClientRect(); return {alt: i.alt, top: r.top, bottom: r.bottom, width: r.width}; });
  const blocks = Array.from(d.querySelectorAll("table, .facts li, figure")).map(e => e.textContent.trim());
  document.getElementById("result").textContent = JSON.stringify(
      {imgs, ext, errors, prov, title: d.title, h2: Array.from(d.querySelectorAll("h2")).map(h => h.textContent),
       scroll: d.documentElement.scrollWidth, vw, wide, head, blocks, text: d.body.innerText});
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


def _render(chromium: str, report: Path, tmp_path: Path, width: int = 1200,
            height: int = 900) -> tuple[dict, subprocess.CompletedProcess]:
    """What the harness saw of ``report`` in Chromium in a ``width`` × ``height`` px frame, and Chromium's process
    (its log on stderr)."""
    page = tmp_path / "report.html"
    shutil.copy(report, page)
    (tmp_path / "harness.html").write_text(HARNESS.replace("WIDTH", str(width)).replace("HEIGHT", str(height)))
    proc = _chromium(chromium, tmp_path, "--allow-file-access-from-files", "--virtual-time-budget=10000",
                     f"--window-size={width + 40},{height + 200}", "--enable-logging=stderr", "--v=0",
                     "--dump-dom", (tmp_path / "harness.html").as_uri())
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
    _chromium(chromium, tmp_path, "--window-size=1400,900", f"--screenshot={shot}", report.as_uri())
    assert shot.is_file() and shot.stat().st_size > 20_000
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the docs' screenshot is of the bundled sample (tools/report_screenshot.sh); tests never write the tree


def repeated(blocks: list[str]) -> list[str]:
    """The tables, facts and figures (their whole text) that appear more than once: each fact is printed once."""
    seen, twice = set(), []
    for b in blocks:
        if b in seen and b not in twice:
            twice.append(b)
        seen.add(b)
    return twice


@pytest.mark.parametrize("which", ["sample_report", "f16_report"])
@pytest.mark.parametrize("width", [800, 1400])
def test_report_fits_the_page_and_prints_each_table_once(chromium, which, width, request, tmp_path):
    seen, _ = _render(chromium, request.getfixturevalue(which), tmp_path, width=width)
    assert seen["vw"] == width
    assert seen["scroll"] <= width and not seen["wide"], seen["wide"][:5]     # no horizontal scroll
    assert not repeated(seen["blocks"]), [b[:120] for b in repeated(seen["blocks"])]
    assert len(set(seen["h2"])) == len(seen["h2"]), seen["h2"]


def test_the_check_for_repeated_tables_finds_a_table_printed_twice(chromium, sample_report, tmp_path):
    html = sample_report.read_text()
    noise = html.index('<section id="noise">')
    table = html[html.index("<table>", noise):html.index("</table>", noise) + len("</table>")]
    doubled = tmp_path / "doubled.html"
    doubled.write_text(html.replace(table, table + table, 1))
    (tmp_path / "r").mkdir()
    seen, _ = _render(chromium, doubled, tmp_path / "r")
    assert [b for b in repeated(seen["blocks"]) if "% of its RMS" in b or "%" in b]


@pytest.mark.parametrize("which", ["sample_report", "f16_report"])
def test_the_first_screen_shows_the_force_law_and_the_prediction_against_linear(chromium, which, request,
                                                                               tmp_path):
    seen, _ = _render(chromium, request.getfixturevalue(which), tmp_path, width=1400, height=900)
    head = {h["alt"]: h for h in seen["head"]}
    assert set(head) == {"headline force law", "headline prediction"}, head
    for h in head.values():                                  # whole, on the first 1400 × 900 px screen
        assert 0 <= h["top"] and h["bottom"] <= 900 and h["width"] > 900, h
    first = seen["text"].split("Contents")[0]
    for key in ("does:", "How well it predicts:", "What the loop changed:"):
        assert key in first, first[:600]
    loop_line = first.split("What the loop changed:")[1]       # the loop's held-out error in the band and over all
    assert "held-out prediction NMSE" in loop_line and "over all frequencies" in loop_line, loop_line[:400]


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
        words = seen["text"].rsplit("Settings and data provenance", 1)[0].lower()   # all shown before provenance
        for car in ("sprung mass", "spindle", "strut", "body"):
            assert not re.search(rf"\b{car}\b", words), (car, words[max(0, words.find(car) - 200):][:400])
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
