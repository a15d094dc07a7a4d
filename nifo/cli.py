"""The ``nifo`` command: argument parsing, error reporting and exit codes.

Sub-commands live in :mod:`nifo.commands` (one module each). Errors derived
from :class:`nifo_core.errors.NifoError` print one line and exit with the
error's code; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from nifo_core import __version__
from nifo_core.errors import EXIT_CODES, NifoError

__all__ = ["main", "build_parser", "COMMANDS"]

#: order shown in ``nifo --help``
COMMANDS = ("run", "simulate", "info", "characterize", "identify", "predict", "loop",
            "replay", "view", "report", "fleet")


def _load(name: str):
    try:
        return importlib.import_module(f"nifo.commands.{name}")
    except ModuleNotFoundError as err:
        if err.name == f"nifo.commands.{name}":
            return None  # not built yet
        raise


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The full parser; with ``only``, import just that command's module (fast start-up)."""
    codes = "\n".join(f"  {code:>2}  {name}" for name, code in sorted(EXIT_CODES.items(), key=lambda kv: kv[1]))
    p = argparse.ArgumentParser(
        prog="nifo",
        description="Identify nonlinear suspension models from spindle and body accelerations "
                    "(restoring force + output-only NIFO).",
        epilog=f"Exit codes:\n   0  success\n{codes}\n\nRun 'nifo COMMAND --help' for a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"nifo {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for name in COMMANDS:
        if only is not None and name != only:
            continue
        mod = _load(name)
        if mod is None:
            continue
        sp = sub.add_parser(name, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(sp)
        sp.set_defaults(_run=mod.run)
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    first = argv[0] if argv else None
    parser = build_parser(first if first in COMMANDS else None)
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 0
    try:
        return int(args._run(args) or 0)
    except NifoError as err:
        print(f"nifo {args.command}: error: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print(f"nifo {args.command}: interrupted; nothing was written", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
