"""A Ctrl-C that lands inside a library surfaces as that library's error: still an interruption (nifo.interrupt)."""

from __future__ import annotations

import pytest

from nifo.interrupt import by_interrupt

pytestmark = pytest.mark.usefixtures("sigint_deliverable")   # (conftest.py)


def test_an_interrupt_inside_class_creation_counts_as_an_interrupt():
    # the shape measured in tests/test_kill.py: SIGINT while scipy.stats created a dataclass during an import;
    # Python 3.11 raises RuntimeError("Error calling __set_name__ ...") from the KeyboardInterrupt
    class Field:
        def __set_name__(self, owner, name):
            raise KeyboardInterrupt

    with pytest.raises(BaseException) as info:
        type("Method", (), {"rng": Field()})
    assert by_interrupt(info.value)


def test_an_error_raised_while_handling_an_interrupt_counts_and_others_do_not():
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise AttributeError("restore_bbox")   # matplotlib's savefig, interrupted
    except AttributeError as e:
        assert by_interrupt(e)
    assert not by_interrupt(ValueError("a bug"))
    assert not by_interrupt(None)


def test_an_interrupt_that_a_c_extension_drops_while_nifo_starts_still_ends_with_the_one_line(tmp_path):
    # the shape measured in CI (tests/test_kill.py, SIGINT 0.1 s into nifo identify): numpy's C extension, cut
    # while importing datetime, raised ImportError("PyCapsule_Import could not import module ...") and kept no
    # trace of the KeyboardInterrupt. A stand-in numpy does the same, deterministically: the signal arrives, the
    # interrupt is swallowed, an unrelated ImportError is raised.
    import os
    import subprocess
    import sys

    fake = tmp_path / "numpy"
    fake.mkdir()
    (fake / "__init__.py").write_text(
        "import os, signal, time\n"
        "try:\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(5)\n"
        "except KeyboardInterrupt:\n"
        "    pass\n"
        "raise ImportError('PyCapsule_Import could not import module \"datetime\"')\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.getcwd()])}
    p = subprocess.run([sys.executable, "-m", "nifo", "identify", "--help"], env=env, capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 130, p.stderr
    assert p.stderr.strip() == "nifo: interrupted while starting; nothing was written"


def test_an_error_without_an_interrupt_stays_a_bug_even_at_start_up(tmp_path):
    import os
    import subprocess
    import sys

    fake = tmp_path / "numpy"
    fake.mkdir()
    (fake / "__init__.py").write_text("raise ImportError('a broken numpy')\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.getcwd()])}
    p = subprocess.run([sys.executable, "-m", "nifo", "identify", "--help"], env=env, capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 1 and "ImportError: a broken numpy" in p.stderr


#: ``python -m nifo ARGS`` with a Ctrl-C that lands inside a finalizer when module ``argv[1]`` is first imported:
#: the shape measured in tests/test_kill.py (SIGINT 0.1 s into ``nifo run``: "Exception ignored in: <function
#: _get_module_lock.<locals>.cb>", the KeyboardInterrupt swallowed, the run finished with exit 0)
_CUT_IN_A_FINALIZER = """
import os, runpy, signal, sys

cut_at = sys.argv.pop(1)

class Cut:
    def __del__(self):   # the signal arrives while a finalizer runs: its KeyboardInterrupt is raised in there
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(10 ** 7):
            pass

class Finder:
    def find_spec(self, name, path=None, target=None):
        if name == cut_at:
            sys.meta_path.remove(self)
            Cut()   # dropped at once: its finalizer runs here, inside the import
        return None

sys.meta_path.insert(0, Finder())
sys.argv[0] = "nifo"
runpy.run_module("nifo", run_name="__main__", alter_sys=True)
"""


@pytest.mark.parametrize("cut_at", [
    "nifo.interrupt",           # nifo's guarded first imports (nifo.__main__)
    "nifo.pipeline.identify",   # the command's imports, once entry() has set its own hook
])
def test_a_ctrl_c_swallowed_by_a_finalizer_still_interrupts_the_command(tmp_path, cut_at):
    import os
    import subprocess
    import sys

    from nifo.commands.run import sample_data

    data = sample_data()[0]   # a bundled bag (the command is cut before it reads it; without the cut it would)
    model = tmp_path / "model.yaml"
    model.write_text("nifo_model: 1\nnonlinearities:\n  - {kind: velocity_deadzone, params: {knee: 0.03}}\n")
    out = tmp_path / "ident"
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    p = subprocess.run([sys.executable, "-c", _CUT_IN_A_FINALIZER, cut_at, "identify", str(data), "--model",
                        str(model), "--out", str(out), "--quiet"], env=env, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 130, (p.returncode, p.stderr)
    assert p.stderr.strip() == "nifo: interrupted while starting; nothing was written", p.stderr
    assert not out.exists()
