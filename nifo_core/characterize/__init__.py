"""Restoring force and automatic characterization: which describing function explains it (docs/method.md §2, §5).

Modules:

- :mod:`nifo_core.characterize.restoring`  restoring-force data from two accelerations, and its slices
- :mod:`nifo_core.characterize.automatic`  ``characterize``: the ranking, the greedy model search, the suggested model
- :mod:`nifo_core.characterize.data`  the regression data and grid search
- :mod:`nifo_core.characterize.score`  a candidate's score and significance
- :mod:`nifo_core.characterize.static`  where the static position lies (bump stops measured from it)
- :mod:`nifo_core.characterize.result`  ``Characterization`` and its parts

Layer: it imports :mod:`nifo_core.signal` and :mod:`nifo_core.kinds` (``.importlinter``). The names below are its
front door; the modules' private (``_``) names stay inside the package.

The front door is lazy (``lazy_loader``, as :mod:`nifo_core.signal`'s): a name's module is imported when the name
is first used, so importing one module of the package does not import the others.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs={
    "restoring": ["RestoringForce", "restoring_force", "bandpass", "bandpass_settle_samples", "suggest_band",
                  "BandSuggestion", "FrequencyTrack", "track_frequency", "instantaneous_frequency", "Slice",
                  "frequency_slices", "amplitude_slices", "local_amplitude"],
    "automatic": ["Thresholds", "Candidate", "FittedModel", "Characterization", "RecordSummary", "characterize",
                  "characterize_restoring", "rank_beyond", "grid_search", "DEFAULT_KINDS",
                  "candidate_grid"],
    "data": ["RegressionData", "GridSearch", "refine_grid"],
    "score": ["score_candidate", "lstsq"],
    "static": ["mean_shift", "static_bump_stops", "equation_fit", "balance_offsets"],
})
