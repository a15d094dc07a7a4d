"""Math text parsed once per process for all renderers (nifo.plots.mathtext_cache): the same files, fewer parses.

Each way renders in a process of its own: a long-lived matplotlib process can lay out a figure a little
differently after others (measured: tick labels 2.7 px apart between two passes over the same figures in one
process, with matplotlib's own cache alone), so a comparison in one process would test that, not the cache.
"""

from __future__ import annotations

import json
import subprocess
import sys

from conftest import REPO

_RENDER = r"""
import json, sys
from pathlib import Path
from matplotlib import _mathtext
from nifo.plots import mathtext_cache, pyplot, save_figure

plt = pyplot()                       # installs the shared cache
if sys.argv[2] == "own":
    mathtext_cache.uninstall()
parses = [0]
real = _mathtext.Parser.parse
def counted(self, *args, **kwargs):
    parses[0] += 1
    return real(self, *args, **kwargs)
_mathtext.Parser.parse = counted
out = Path(sys.argv[1])
for k in range(2):                   # two figures with the same kinds of labels, as a step writes them
    fig, (a, b) = plt.subplots(1, 2, figsize=(7, 3))
    f = [1 + 0.5 * i for i in range(200)]
    a.loglog(f, [1e-3 * x ** -2 for x in f])
    a.set_xlabel("frequency [Hz]"); a.set_ylabel(r"$|T_{21}|$ [-]")
    b.plot(f, [1e4 * (x + k) for x in f]); b.ticklabel_format(useMathText=True, scilimits=(0, 0))
    b.set_title(r"$\mu_1/K_2$ [N/m per kg]")
    save_figure(fig, out / f"fig{k}.png")
print(json.dumps({"parses": parses[0], "installed": sys.argv[2] != "own"}))
"""


def _render(out, way: str) -> dict:
    out.mkdir()
    p = subprocess.run([sys.executable, "-c", _RENDER, str(out), way], cwd=out, capture_output=True, text=True,
                       env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin", "MPLBACKEND": "Agg"}, timeout=300)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_the_installed_matplotlib_is_the_one_the_cache_was_measured_on():
    """If matplotlib changes its parser's cached method, install() leaves matplotlib alone and says so: this
    test then fails, so that the lost speed is noticed rather than silently gone."""
    from nifo.plots import mathtext_cache, pyplot

    pyplot()
    assert mathtext_cache.install() is True


def test_shared_parses_write_the_same_bytes_with_fewer_parses(tmp_path):
    own = _render(tmp_path / "own", "own")
    shared = _render(tmp_path / "shared", "shared")
    for name in ("fig0.png", "fig0.svg", "fig1.png", "fig1.svg"):
        assert (tmp_path / "own" / name).read_bytes() == (tmp_path / "shared" / name).read_bytes(), name
    # matplotlib's own cache parses each label again for every renderer (layout pass, drawing, the SVG's text)
    print(f"\nmath-text parses: matplotlib's cache {own['parses']}, shared {shared['parses']}")
    assert shared["parses"] < 0.6 * own["parses"], (own, shared)
