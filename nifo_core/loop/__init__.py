"""Closing the loop: residual → the effect the model lacks → add it → error before and after (docs/method.md §5).

Modules:

- :mod:`nifo_core.loop.closing`  ``close_loop``
- :mod:`nifo_core.loop.residual`  the residuals and the evidence for each candidate
- :mod:`nifo_core.loop.gates`  when a candidate is added: held-out prediction, one term of a kind
- :mod:`nifo_core.loop.refine`  the output-error refinement of the loop's final model
- :mod:`nifo_core.loop.results`  ``LoopResult`` and its parts
- :mod:`nifo_core.loop.detection`  what the data could not reveal: detection limits, confounded pairs

Layer: it imports everything else: :mod:`nifo_core.characterize`, :mod:`nifo_core.predict`,
:mod:`nifo_core.settings` (``.importlinter``). The names below are its front door; the modules' private (``_``)
names stay inside the package.
"""

from .closing import (LoopSettings, Errors, Trial, Evidence, Round, LoopRefinement, LoopResult, close_loop,
                      RESIDUAL_BANDS_HZ, NOTHING_MISSING)
from .detection import (DetectionLimit, Confounding, Undetermined, detection_limits, confounded_pairs,
                        undetermined_terms)

__all__ = ["LoopSettings", "Errors", "Trial", "Evidence", "Round", "LoopRefinement", "LoopResult", "close_loop",
           "RESIDUAL_BANDS_HZ", "NOTHING_MISSING", "DetectionLimit", "Confounding", "Undetermined",
           "detection_limits", "confounded_pairs", "undetermined_terms"]
