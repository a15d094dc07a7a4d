"""The HTML report rendered in headless Chromium (Debian's ``chromium``; ``.ci/run`` installs it).

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

from test_run_cmd import pipeline

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
  const imgs = Array.from(d.images).map(i => ({alt: i.alt, complete: i.complete, width: i.naturalWidth,
                                              external: !i.src.startsWith("data:")}));
  const ext = Array.from(d.querySelectorAll("link[href],script[src]"))
      .map(e => e.getAttribute("href") || e.getAttribute("src")).filter(u => !u.startsWith("data:"));
  document.getElementById("result").textContent = JSON.stringify(
      {imgs, ext, errors, title: d.title, h2: Array.from(d.querySelectorAll("h2")).map(h => h.textContent)});
});
</script></body></html>"""


@pytest.fixture(scope="module")
def chromium():
    if CHROMIUM is None:
        pytest.fail("chromium not found: install Debian's chromium (apt-get install chromium; .ci/run does)")
    return CHROMIUM


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    out, code, _ = pipeline(tmp_path_factory.getbasetemp() / "nifo_run")
    assert code == 0
    return out / "report" / "report.html"


def _chromium(chromium: str, tmp: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([chromium, *FLAGS, f"--user-data-dir={tmp / 'profile'}", *args],
                          capture_output=True, text=True, timeout=120)


def test_report_displays_every_figure_without_console_errors(chromium, report, tmp_path):
    page = tmp_path / "report.html"
    shutil.copy(report, page)
    (tmp_path / "harness.html").write_text(HARNESS)
    proc = _chromium(chromium, tmp_path, "--allow-file-access-from-files", "--virtual-time-budget=10000",
                     "--enable-logging=stderr", "--v=0", "--dump-dom", (tmp_path / "harness.html").as_uri())
    m = re.search(r'<pre id="result">(.*?)</pre>', proc.stdout, re.S)
    assert m and m.group(1) != "pending", f"the harness did not run: {proc.stdout[-500:]} {proc.stderr[-2000:]}"
    seen = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&").replace("&lt;", "<")
                      .replace("&gt;", ">"))
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
