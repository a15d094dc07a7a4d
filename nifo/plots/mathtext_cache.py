"""One cache of parsed math text for all of a process's renderers (issue 29: the figures' rendering).

Why: matplotlib keeps a parsed math string (a log axis's 10², an axis offset's ×10⁻³, a label's μ) in a cache
keyed by the ``MathTextParser`` instance as well, and every renderer has its own instance. The layout pass of
``savefig(bbox_inches="tight")``, the drawing pass after it and the SVG's text each get a fresh renderer, so
every file of a figure parses every label again with pyparsing (about 8 ms a string: 43 % of the rendering of
the coefficient figure, which has four log axes). Measured on the figures ``nifo run`` hands to its helpers,
rendered in one process both ways, alternating, best of 5 on an idle machine (``PYTHONPATH=. python
benchmarks/bench_figures.py --mathtext [--short]``): the bundled sample's 23 figures 15.38 → 13.60 CPU-s
(0.884); the 10 figures of ``nifo run --no-loop`` on a 20 s record (the kill test's) 5.68 → 5.17 CPU-s (0.911).
Every PNG and SVG the same bytes. A helper starts with an empty cache, so a short command gains less: ``nifo
run --no-loop`` on that record 11.68 → 11.46 CPU-s (0.981, ``benchmarks/compare_versions.py``, 5 runs).

How: matplotlib's cached method is replaced by one keyed on what a parse depends on, the output type (vector
or raster), the string, the dpi, the font properties, the antialiasing and the glyph-loading flags, not on the
instance; a parse runs matplotlib's own code, on the first parser seen of that output type (the instances of
one type differ in nothing else). Installed only where matplotlib's method has the signature it was measured
on; elsewhere matplotlib's own cache stays (:func:`install` says which).
"""

from __future__ import annotations

import functools
import inspect
import threading

__all__ = ["install", "uninstall", "cache_info", "ENTRIES"]

#: parsed strings kept (the sample's 23 figures parse 396 distinct keys)
ENTRIES = 4096
#: the parameters of ``MathTextParser._parse_cached`` this replaces (as in matplotlib 3.11.2, where it was measured)
_SIGNATURE = ("self", "s", "dpi", "prop", "antialiased", "load_glyph_flags")
_lock = threading.Lock()
_installed = False
_own = None          # matplotlib's method, while this one is installed
_shared = None       # the installed cache (functools.lru_cache)


def install() -> bool:
    """Share parsed math text between all renderers of this process (idempotent); False where matplotlib's
    parser is not the one measured (then nothing is changed)."""
    global _installed, _own, _shared
    with _lock:
        if _installed:
            return True
        from matplotlib import mathtext

        own = getattr(mathtext.MathTextParser, "_parse_cached", None)
        parse = getattr(own, "__wrapped__", None)
        try:
            if parse is None or tuple(inspect.signature(parse).parameters) != _SIGNATURE:
                return False
        except (TypeError, ValueError):
            return False
        first: dict[str, object] = {}

        @functools.lru_cache(ENTRIES)
        def shared(output_type, s, dpi, prop, antialiased, load_glyph_flags):
            return parse(first[output_type], s, dpi, prop, antialiased, load_glyph_flags)

        def _parse_cached(self, s, dpi, prop, antialiased, load_glyph_flags):
            first.setdefault(self._output_type, self)
            return shared(self._output_type, s, dpi, prop, antialiased, load_glyph_flags)

        _own, _shared = own, shared
        mathtext.MathTextParser._parse_cached = _parse_cached
        _installed = True
        return True


def uninstall() -> None:
    """matplotlib's own cache back (``benchmarks/bench_figures.py --mathtext`` compares the two)."""
    global _installed, _own, _shared
    with _lock:
        if _installed:
            from matplotlib import mathtext

            mathtext.MathTextParser._parse_cached = _own
            _installed, _own, _shared = False, None, None


def cache_info():
    """Hits and misses of the installed cache since it was installed (``functools`` cache info); None when not
    installed."""
    return _shared.cache_info() if _installed and _shared is not None else None
