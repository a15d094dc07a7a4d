"""Closing the loop: residual → the effect the model lacks → add it → error before and after (docs/method.md §5).

Modules:

- :mod:`nifo_core.loop.closing`  ``close_loop``, which runs the steps below
- :mod:`nifo_core.loop.state`  what every step works on: the records, the band (``loop_band``), the held-out split
- :mod:`nifo_core.loop.predictor`  the held-out prediction of a term set, and both its errors
- :mod:`nifo_core.loop.rounds`  the rounds: re-tune, trace, judge, add
- :mod:`nifo_core.loop.candidates`  what a round tries
- :mod:`nifo_core.loop.acceptance`  whether a candidate is added: every gate of one candidate, a round's judged
- :mod:`nifo_core.loop.best_set`  the best set of effects after the rounds
- :mod:`nifo_core.loop.final`  the final model: refinement, bias-corrected coefficients, the declared terms' fates
- :mod:`nifo_core.loop.residual`  the residuals and the evidence for each candidate
- :mod:`nifo_core.loop.gates`  when a candidate is added: held-out prediction, one term of a kind
- :mod:`nifo_core.loop.refine`  the output-error refinement of the loop's final model
- :mod:`nifo_core.loop.settings`  ``LoopSettings``
- :mod:`nifo_core.loop.round_results`  what each round tried and added: ``Errors``, ``Trial``, ``Round``
- :mod:`nifo_core.loop.results`  ``LoopResult``, its refinement and the declared terms' fates
- :mod:`nifo_core.loop.words`  the words of the loop's report
- :mod:`nifo_core.loop.detection`  what the data could not reveal: detection limits, confounded pairs

Layer: it imports everything else: :mod:`nifo_core.characterize`, :mod:`nifo_core.predict`,
:mod:`nifo_core.settings` (``.importlinter``). The names below are its front door; the modules' private (``_``)
names stay inside the package.

The front door is lazy (``lazy_loader``, as :mod:`nifo_core.signal`'s): a name's module is imported when the name
is first used, so importing one module of the package does not import the others.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs={
    "closing": ["close_loop"],
    "settings": ["LoopSettings", "RESIDUAL_BANDS_HZ"],
    "round_results": ["Errors", "Trial", "Evidence", "Round"],
    "results": ["LoopRefinement", "LoopResult"],
    "words": ["NOTHING_MISSING"],
    "detection": ["DetectionLimit", "Confounding", "Undetermined", "detection_limits", "confounded_pairs",
                  "undetermined_terms"],
})
