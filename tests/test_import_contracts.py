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
