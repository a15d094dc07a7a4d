"""The layering is a test: ``lint-imports`` keeps the contracts of ``.importlinter`` (nodes → shell → core, nothing
upward; a pure core; the commands imported by the CLI only; no import cycle)."""

import os
import subprocess
import sys

import pytest

from conftest import REPO

pytest.importorskip("importlinter", reason="pip install import-linter (the test extras)")


def test_lint_imports_keeps_every_contract():
    code = ("import sys; from importlinter.cli import lint_imports; "
            "sys.exit(lint_imports(config_filename='.importlinter', no_cache=True))")
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert "BROKEN" not in out.stdout and " kept, 0 broken." in out.stdout, out.stdout[-4000:]


def _private_names_across_packages() -> list[str]:
    """Every ``from X import _name`` whose module X lies outside the importing module's own package."""
    import ast

    found = []
    for top in ("nifo", "nifo_core", "nifo_nodes"):
        for path in sorted((REPO / top).rglob("*.py")):
            parts = list(path.relative_to(REPO).with_suffix("").parts)
            package = ".".join(parts[:-1])          # of a package's __init__ too: the package itself
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if not isinstance(node, ast.ImportFrom):
                    continue
                base = package.split(".")[: len(package.split(".")) - max(node.level - 1, 0)] if node.level else []
                source = ".".join(base + ([node.module] if node.module else [])) if node.level else node.module
                inside = source == package or source.startswith(package + ".")
                found += [f"{'.'.join(parts)}: from {source} import {a.name}" for a in node.names
                          if a.name.startswith("_") and not a.name.startswith("__") and not inside]
    return found


def test_private_names_stay_inside_their_package():
    """STYLE.md, subpackages with a front door: modules inside a package share private helpers freely, other
    packages use its public names only (the private *modules* are the import-linter contract ``private_modules``;
    this is the same rule for names). The one exception is the import-linter contract's own."""
    allowed = {"nifo.fleet.preload: from nifo_core.signal import _block_products"}   # numba cache warm-up
    assert set(_private_names_across_packages()) <= allowed


def test_the_analysis_defaults_are_written_once():
    """One value, one home (issue 57): the default analysis band and conditioning limit are written in
    nifo_core/defaults.py only; everything else imports them."""
    import re

    literal = re.compile(r"\(2(\.0)?, ?30(\.0)?\)|\[2\.0, ?30\.0\]|\b2(\.0)?-30(\.0)? Hz|=\s*1e4\b|\(1e4,|\b1e4\)")
    found = {str(p.relative_to(REPO)) for top in ("nifo", "nifo_core", "nifo_nodes")
             for p in sorted((REPO / top).rglob("*.py")) if p.name != "defaults.py"
             if any(literal.search(line) for line in p.read_text(encoding="utf-8").splitlines())}
    assert not found     # on a99f355: the loop's two copies (loop/closing.py, loop/results.py), the --help's "2-30 Hz"
