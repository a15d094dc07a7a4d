"""Progress for long work, on stderr: a bar on a terminal, a line every few seconds otherwise."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """``with Progress(total, "identify") as p: ... p.advance(k)``. ``total`` may be None (unknown)."""

    def __init__(self, total: float | None, desc: str, *, unit: str = "", stream=None,
                 min_interval_s: float | None = None, enabled: bool = True) -> None:
        self.total, self.desc, self.unit = total, desc, unit
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.min_interval_s = min_interval_s if min_interval_s is not None else (0.2 if self.tty else 5.0)
        self.enabled = enabled
        self.done = 0.0
        self._t0 = time.monotonic()
        self._last = -1e9

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, exc_type, *_):
        if exc_type is None:
            self._emit(final=True)
        elif self.tty and self.enabled:
            self.stream.write("\n")

    def advance(self, k: float = 1.0) -> None:
        self.done += k
        now = time.monotonic()
        if now - self._last >= self.min_interval_s:
            self._last = now
            self._emit()

    def _emit(self, final: bool = False) -> None:
        if not self.enabled:
            return
        el = time.monotonic() - self._t0
        if self.total:
            frac = min(self.done / self.total, 1.0)
            eta = (el / frac - el) if frac > 0 else float("nan")
            bar = "#" * int(frac * 24)
            msg = f"{self.desc}: [{bar:<24}] {100 * frac:5.1f}%  {el:5.1f}s elapsed"
            if not final and frac > 0:
                msg += f", ~{eta:.0f}s left"
        else:
            msg = f"{self.desc}: {self.done:g}{self.unit} {el:5.1f}s"
        if self.tty:
            self.stream.write("\r" + msg + ("\n" if final else ""))
        elif final or el > 1.0:
            self.stream.write(msg + "\n")
        self.stream.flush()
