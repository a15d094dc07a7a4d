"""Progress for long work and the log, on stderr, through rich.

One :class:`rich.console.Console` on stderr carries the progress bars and the
log records (:func:`configure` installs a :class:`rich.logging.RichHandler` on
it), so a log line printed during a bar appears above the bar instead of
breaking it. Nested :class:`Progress` blocks (``nifo run`` → ``identify``)
share one live display, one task line each. On a terminal the bars are live;
otherwise (CI logs, pipes) rich draws nothing live and prints the bars once
when the work ends, and a plain line is written every ``min_interval_s``
(default 10 s) meanwhile, so logs stay readable.

``nifo --quiet`` turns progress off, ``--verbose`` shows it even for short work.
"""

from __future__ import annotations

import logging
import time

from rich.console import Console
from rich.logging import RichHandler
from rich.progress import BarColumn, TaskProgressColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.progress import Progress as _RichProgress

__all__ = ["Progress", "configure", "console", "verbosity"]

_state = {"verbosity": 0, "console": None}
_live: dict = {"progress": None, "depth": 0}


def console() -> Console:
    """The stderr console shared by the progress bars and the log."""
    if _state["console"] is None:
        _state["console"] = Console(stderr=True)
    return _state["console"]


def verbosity() -> int:
    """-1 quiet, 0 normal, 1 verbose (``nifo --quiet`` / ``--verbose``)."""
    return _state["verbosity"]


def configure(*, quiet: bool = False, verbose: bool = False, stream=None) -> None:
    """Set the verbosity and route the ``nifo`` loggers through the shared console.

    ``quiet``: no progress, warnings and errors only; ``verbose``: progress for short work too and
    debug records. ``stream``: a file-like object instead of stderr (tests).
    """
    _state["verbosity"] = -1 if quiet else (1 if verbose else 0)
    _state["console"] = Console(file=stream, stderr=stream is None)
    log = logging.getLogger("nifo")
    for h in [h for h in log.handlers if getattr(h, "_nifo", False)]:
        log.removeHandler(h)
    handler = RichHandler(console=console(), show_time=False, show_path=verbose, markup=False,
                          rich_tracebacks=verbose)
    handler._nifo = True  # type: ignore[attr-defined]
    log.addHandler(handler)
    log.setLevel(logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO))
    log.propagate = False


class Progress:
    """``with Progress(total, "identify") as p: ... p.advance(k)``; ``total`` may be None (unknown).

    ``desc`` may be changed while running (``p.desc = "loop (round 2)"``). ``enabled=False``
    (e.g. work too short to be worth a bar) is overridden by ``--verbose``; ``--quiet`` wins over both.
    """

    def __init__(self, total: float | None, desc: str, *, unit: str = "", stream=None,
                 min_interval_s: float | None = None, enabled: bool = True) -> None:
        self.total, self.desc, self.unit = total, desc, unit
        self.enabled = verbosity() >= 0 and (enabled or verbosity() > 0)
        self.done = 0.0
        self._console = Console(file=stream) if stream is not None else console()
        self.min_interval_s = min_interval_s if min_interval_s is not None else 10.0
        self._task = None
        self._t0 = self._last = time.monotonic()

    # ------------------------------------------------------------------ context
    def __enter__(self) -> "Progress":
        if not self.enabled:
            return self
        if _live["progress"] is None:
            _live["progress"] = _RichProgress(
                TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(),
                TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
                console=self._console, transient=False)
            _live["progress"].start()
        _live["depth"] += 1
        self._task = _live["progress"].add_task(self.desc, total=self.total)
        return self

    def __exit__(self, exc_type, *_) -> None:
        if self._task is None:
            return
        prog = _live["progress"]
        prog.update(self._task, description=self.desc,
                    **({"completed": self.total} if exc_type is None and self.total else {}))
        _live["depth"] -= 1
        if _live["depth"] > 0 or exc_type is not None:  # a finished inner step leaves no line behind
            prog.remove_task(self._task)
        if _live["depth"] == 0:
            prog.stop()
            _live["progress"] = None

    # ------------------------------------------------------------------ updates
    def advance(self, k: float = 1.0) -> None:
        self.done += k
        if self._task is None:
            return
        _live["progress"].update(self._task, advance=k, description=self.desc)
        now = time.monotonic()
        if not self._console.is_terminal and now - self._last >= self.min_interval_s:
            self._last = now
            self._line()

    def _line(self) -> None:
        """The plain progress line written where no live bar can be drawn."""
        el = time.monotonic() - self._t0
        if self.total:
            frac = min(self.done / self.total, 1.0)
            msg = f"{self.desc}: {100 * frac:5.1f} %  {el:.1f} s elapsed"
            if frac > 0:
                msg += f", ~{el / frac - el:.0f} s left"
        else:
            msg = f"{self.desc}: {self.done:g}{self.unit}  {el:.1f} s"
        self._console.print(msg, markup=False, highlight=False, soft_wrap=True)
