"""The nonlinearity kinds: the registry of every per-kind fact, and their compiled forms.

Modules:

- :mod:`nifo_core.kinds.describing`  the describing-function library and the kind registry ``KINDS`` (docs/method.md §2)
- :mod:`nifo_core.kinds.strut_forces`  the kinds' forces one sample at a time in numba, for the simulator and the prediction engine

Layer: it imports the bottom, beside :mod:`nifo_core.signal` (``.importlinter``). The names below are its front
door; the modules' private (``_``) names stay inside the package.

The front door is lazy (``lazy_loader``, as :mod:`nifo_core.signal`'s): a name's module is imported when the name
is first used, so importing one module of the package does not import the others.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs={
    "describing": ["Kind", "GridSpec", "Term", "KINDS", "LIBRARY", "DEFAULT_KINDS", "ALIASES", "kind", "make_term",
                   "evaluate_terms", "play_operator", "path_slopes", "linear_twin", "CODES"],
    "strut_forces": ["PLAY", "kind_code", "strut_arrays", "g_one", "strut_force", "lipschitz", "slopes_within"],
})
