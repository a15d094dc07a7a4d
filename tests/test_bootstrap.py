"""``./test.sh`` does its own set-up: headless Chromium is installed when missing (as root) or named, and nifo's own
modules are compiled to bytecode.

The logic (``nifo_need_chromium`` in tools/bootstrap.sh) runs in a real bash with a PATH of stand-ins:
an ``id`` that says root or not, an ``apt-get`` that logs its arguments (and, for ``install``, puts a
``chromium`` on that PATH), so the machine's own Chromium is neither hidden nor removed.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BASH = shutil.which("bash") or "/bin/bash"


def _fake_bin(tmp: Path, *, uid: int, apt_ok: bool = True) -> Path:
    bin_ = tmp / "bin"
    bin_.mkdir()
    (bin_ / "id").write_text(f"#!{BASH}\necho {uid}\n")
    install = f'printf "#!{BASH}\\necho chromium\\n" > "{bin_}/chromium"; chmod +x "{bin_}/chromium"' if apt_ok \
        else "exit 100"
    (bin_ / "apt-get").write_text(f'#!{BASH}\necho "$*" >> "{tmp}/apt.log"\n'
                                  f'case "$*" in *install*) {install};; esac\n')
    (bin_ / "chmod").symlink_to(shutil.which("chmod"))
    for f in bin_.iterdir():
        if not f.is_symlink():
            f.chmod(0o755)
    return bin_


def _need_chromium(bin_: Path) -> subprocess.CompletedProcess:
    env = {"PATH": str(bin_), "HOME": os.environ.get("HOME", "/tmp")}
    return subprocess.run([BASH, "-c", f'source "{REPO}/tools/bootstrap.sh" && nifo_need_chromium'],
                          env=env, capture_output=True, text=True, timeout=30)


def test_missing_chromium_as_root_is_installed_with_apt_after_an_update(tmp_path):
    proc = _need_chromium(_fake_bin(tmp_path, uid=0))
    assert proc.returncode == 0, proc.stderr
    calls = (tmp_path / "apt.log").read_text().splitlines()
    assert calls[0].startswith("update")
    assert calls[1].startswith("install") and "-y" in calls[1] and calls[1].endswith("chromium")


def test_missing_chromium_without_root_fails_with_the_one_command_to_run(tmp_path):
    proc = _need_chromium(_fake_bin(tmp_path, uid=1000))
    assert proc.returncode != 0
    assert "sudo apt-get update && sudo apt-get install -y chromium" in proc.stderr
    assert not (tmp_path / "apt.log").exists()


def test_a_failed_install_says_so(tmp_path):
    proc = _need_chromium(_fake_bin(tmp_path, uid=0, apt_ok=False))
    assert proc.returncode != 0 and "could not install chromium" in proc.stderr


def test_present_chromium_needs_nothing(tmp_path):
    bin_ = _fake_bin(tmp_path, uid=1000)
    (bin_ / "chromium").write_text(f"#!{BASH}\n")
    (bin_ / "chromium").chmod(0o755)
    assert _need_chromium(bin_).returncode == 0
    assert not (tmp_path / "apt.log").exists()


def test_ci_only_calls_the_test_command():
    lines = [ln for ln in (REPO / ".ci" / "run").read_text().splitlines() if ln and not ln.startswith("#")]
    assert lines[-1].startswith("exec ./test.sh") and not any("apt-get" in ln for ln in lines)
    assert "nifo_need_chromium" in (REPO / "test.sh").read_text()


def test_set_up_compiles_nifos_own_modules_to_bytecode(tmp_path):
    """``nifo_compile_bytecode`` (run by every ``./nifo.sh`` and ``./test.sh``): where PYTHONDONTWRITEBYTECODE is set,
    nothing else writes nifo's bytecode and every process would compile its modules again. Written here under a
    cache prefix of the test's own (PYTHONPYCACHEPREFIX), so the checkout is not touched."""
    env = {"PATH": os.environ.get("PATH", ""), "HOME": os.environ.get("HOME", "/tmp"),
           "PYTHONPYCACHEPREFIX": str(tmp_path / "pyc"), "PYTHONDONTWRITEBYTECODE": "1"}
    proc = subprocess.run([BASH, "-c", f'source "{REPO}/tools/bootstrap.sh" && nifo_compile_bytecode "{REPO}" '
                                       f'"{sys.executable}"'], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    root = tmp_path / "pyc" / REPO.relative_to("/")
    written = {p.relative_to(root).parts[0] for p in root.rglob("*.pyc")}
    assert {"nifo", "nifo_core", "nifo_nodes", "launch_scripts", "ros2_ws"} <= written, written
    for module in ("nifo_core/loop/closing.py", "nifo/pipeline/job.py", "nifo_nodes/identifier.py"):
        src = REPO / module
        cached = tmp_path / "pyc" / src.parent.relative_to("/") / f"{src.stem}.{sys.implementation.cache_tag}.pyc"
        assert cached.is_file(), cached
