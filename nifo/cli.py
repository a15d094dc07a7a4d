"""The ``nifo`` command: argument parsing, output conventions, error reporting and exit codes.

Sub-commands live in :mod:`nifo.commands` (one module each); ``run(args)``
returns a summary dict (its ``exit_code`` key, when present, the exit code). Global options, before or after the
command: ``--json`` prints one JSON document on stdout summarising the result
(the human text goes to stderr), ``--quiet`` keeps only warnings and errors,
``--verbose`` shows progress for short work too and a traceback with errors.
Errors derived from :class:`nifo_core.errors.NifoError` print one line and
exit with the error's code; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import contextvars
import importlib
import io
import json
import math
import os
import sys
import traceback

from nifo.commands import SUMMARIES
from nifo_core import __version__
from nifo_core.errors import EXIT_CODES, USAGE_EXIT_CODE, NifoError
from nifo.interrupt import by_interrupt, term_as_interrupt

__all__ = ["main", "build_parser", "add_common_arguments", "COMMANDS"]

#: order shown in ``nifo --help``: the summaries' (:data:`nifo.commands.SUMMARIES`)
COMMANDS = tuple(SUMMARIES)


def _load(name: str):
    try:
        return importlib.import_module(f"nifo.commands.{name}")
    except ModuleNotFoundError as err:
        if err.name == f"nifo.commands.{name}":
            return None  # not built yet
        raise


def add_common_arguments(p: argparse.ArgumentParser, *, top: bool = False) -> None:
    """``--json``, ``--quiet``, ``--verbose``: on the top parser with defaults, on each command's parser
    without (so ``nifo --json identify ...`` and ``nifo identify ... --json`` both work)."""
    g = p.add_argument_group("output")
    kw = {} if top else {"default": argparse.SUPPRESS}
    g.add_argument("--json", action="store_true", help="print one JSON document summarising the result on stdout "
                   "(human-readable text goes to stderr)", **kw)
    v = g.add_mutually_exclusive_group()
    v.add_argument("-q", "--quiet", action="store_true", help="no progress and no summary text; warnings and "
                   "errors only", **kw)
    v.add_argument("-v", "--verbose", action="store_true", help="progress for short work too, debug log, "
                   "tracebacks with errors", **kw)


def exit_code_help() -> str:
    """The exit-code table of ``nifo --help``."""
    rows = [(0, "success", "")]
    rows.append((USAGE_EXIT_CODE, "usage", "The command line does not parse (argparse)"))
    rows += [(code, name, what) for name, (code, what) in EXIT_CODES.items()]
    return "\n".join(f"  {code:>3}  {name:<24} {what}" for code, name, what in sorted(rows)) + \
        "\n  130  interrupted              Ctrl-C; nothing was written"


def _present(name: str) -> bool:
    """Whether the command's module is part of this build (found, not imported)."""
    import importlib.util

    return importlib.util.find_spec(f"nifo.commands.{name}") is not None


def build_parser(only: str | None = None, *, summary: bool = False) -> argparse.ArgumentParser:
    """The full parser; with ``only``, import just that command's module (fast start-up); with ``summary``, the
    commands by name and line only (:data:`nifo.commands.SUMMARIES`), none imported: what ``nifo --help``,
    ``nifo --version`` and a mistyped command need (measured: ``nifo --help`` 1.97 -> 0.09 s)."""
    p = argparse.ArgumentParser(
        prog="nifo",
        description="Identify nonlinear suspension models from spindle and body accelerations "
                    "(restoring force + output-only NIFO).",
        epilog=f"Exit codes:\n{exit_code_help()}\n\nRun 'nifo COMMAND --help' for a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"nifo {__version__}")
    add_common_arguments(p, top=True)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for name in COMMANDS:
        if only is not None and name != only:
            continue
        if summary:
            if _present(name):
                sub.add_parser(name, help=SUMMARIES[name])
            continue
        mod = _load(name)
        if mod is None:
            continue
        sp = sub.add_parser(name, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(sp)
        add_common_arguments(sp)
        sp.set_defaults(_run=mod.run, _output=getattr(mod, "OUTPUT", None))
    return p


def _jsonable(x):
    """Paths, numpy scalars and tuples as JSON values; a NaN or infinite number as null (as in the files written)."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, os.PathLike):
        return os.fspath(x)
    if hasattr(x, "item") and callable(x.item):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _error_doc(err: BaseException, code: int) -> dict:
    if isinstance(err, NifoError):
        return {"type": type(err).__name__, "exit_code": code, "message": err.message, "source": err.source,
                "channel": err.channel, "hint": err.hint, "text": str(err)}
    return {"type": type(err).__name__, "exit_code": code, "message": str(err)}


def _abandon_helpers(*, again: bool = False) -> None:
    """An interrupted or failed (``again``) command's figure helpers ended with it
    (:func:`nifo.plots.writer.abandon_helpers`), if any ran."""
    writer = sys.modules.get("nifo.plots.writer")
    if writer is not None:
        writer.abandon_helpers(again=again)


def _run_explained(args):
    """The command; an error of its names the data it is about and where the setting it concerns came from
    (:func:`nifo.settings.explain`), when the command got as far as choosing its settings. Inside it, a file read
    once is not read again (:func:`nifo.io.memo.reuse_reads`): measured on the loop benchmark (``nifo loop`` on
    4 × 300 s bags), each bag was decoded twice, in chunks by the settings' probe and then whole."""
    from nifo.io.memo import reuse_reads

    settings = sys.modules.get("nifo.settings")
    if settings is not None:      # settings chosen before this command (a caller's own, in this process) are not its
        settings.forget_step()
    try:
        with reuse_reads():
            return args._run(args)
    except NifoError as err:
        settings = sys.modules.get("nifo.settings")
        if settings is None:
            raise
        raise settings.explain(err) from None


@contextlib.contextmanager
def _warnings_as_lines(command: str):
    """A warning no step turned into its own text reaches the user as one line only when it is nifo's (a warning
    class of nifo's raised from nifo's code); a library's (numpy's "All-NaN slice", a divide by zero) is kept for
    ``--verbose`` (the debug log), not printed beside the command's output (issue 56)."""
    import logging
    import warnings

    own = (os.path.dirname(os.path.abspath(__file__)),
           os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "nifo_core"))

    def show(message, category, filename, lineno, file=None, line=None):
        text = str(message).replace("\n", " ")
        if issubclass(category, UserWarning) and os.path.abspath(filename).startswith(own):
            print(f"nifo {command}: warning: {text}", file=sys.stderr)
        else:
            logging.getLogger("nifo").debug("%s: %s (%s:%s)", category.__name__, text, filename, lineno)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    if first == "fleet" and not any(a in ("-h", "--help") or a.startswith("--scheduler") for a in argv):
        from nifo.fleet.cluster import start_worker_server

        # before anything else is imported: the embedded cluster's workers are forked from a server that imports
        # and warms in its own process while this one parses, reads the manifest and starts the scheduler
        # (measured: 0.8 s of this process's start-up saved; docs/fleet.md, "Start-up and scaling")
        start_worker_server()
    # the top-level help (also asked before a command: ``nifo -h run``) and a mistyped command need every name
    before = argv[:argv.index(first)] if first is not None else argv
    top = first not in COMMANDS or any(a in ("-h", "--help", "--version") for a in before)
    parser = build_parser(summary=True) if top else build_parser(first)
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 0
    from nifo.io.lock import output_lock
    from nifo.io.ownership import set_invocation
    from nifo.progress import configure

    configure(quiet=args.quiet, verbose=args.verbose)
    set_invocation(argv)   # recorded in the .nifo-output marker of every folder written
    # --json: stdout carries the JSON document only (the commands' text goes to stderr); --quiet: no text
    target = io.StringIO() if args.quiet else (sys.stderr if args.json else None)
    summary, err, code = None, None, 0
    # one writer per output: the output is locked for the whole command, so a second command on it is refused at
    # once (nifo.io.lock) rather than after its work
    output = getattr(args, args._output, None) if getattr(args, "_output", None) else None
    try:
        with term_as_interrupt(), output_lock(output), _warnings_as_lines(args.command), \
                contextlib.redirect_stdout(target) if target is not None else contextlib.nullcontext():
            # in a context of its own: what the command's steps record about themselves (the settings they chose,
            # for the errors) ends with it
            result = contextvars.copy_context().run(_run_explained, args)
        if isinstance(result, dict):
            summary = result
            code = int(result.get("exit_code", 0))
        else:
            code = int(result or 0)
    except NifoError as e:
        err, code = e, e.exit_code
        print(f"nifo {args.command}: error: {e}", file=sys.stderr)
        # every figure of the command was cancelled or waited for on the way out (figure_batch, deferred_figures):
        # its helpers, if any started, are ended at once instead of at exit, once they have finished their start-up
        # (measured: ``nifo run`` of a missing file, 2.7 → 1.5 s and 2.4 → 1.5 CPU-s)
        _abandon_helpers(again=True)
        if args.verbose:
            traceback.print_exc()
    except KeyboardInterrupt as e:
        from nifo.io.atomic import interrupt_note

        _abandon_helpers()
        err, code = e, 130
        print(f"nifo {args.command}: {interrupt_note()}", file=sys.stderr)
    except Exception as e:
        # a Ctrl-C/SIGTERM inside a library's clean-up can surface as another error raised while handling
        # it (matplotlib's savefig: AttributeError in restore_bbox): still an interruption, not a bug
        if not by_interrupt(e):
            raise
        from nifo.io.atomic import interrupt_note

        _abandon_helpers()
        err, code = KeyboardInterrupt(), 130
        print(f"nifo {args.command}: {interrupt_note()}", file=sys.stderr)
    if args.json:
        doc = {"command": args.command, "ok": code == 0, "exit_code": code,
               **{k: v for k, v in (summary or {}).items() if k != "exit_code"}}
        if err is not None:
            doc["error"] = _error_doc(err, code)
        print(json.dumps(_jsonable(doc), ensure_ascii=False, allow_nan=False, default=str))
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
