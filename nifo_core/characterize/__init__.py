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
"""

from .restoring import (RestoringForce, restoring_force, bandpass, bandpass_settle_samples, suggest_band,
                        BandSuggestion, FrequencyTrack, track_frequency, instantaneous_frequency, Slice,
                        frequency_slices, amplitude_slices, local_amplitude)
from .automatic import (Thresholds, Candidate, FittedModel, Characterization, RecordSummary, characterize,
                        characterize_restoring, rank_beyond, DEFAULT_KINDS, POSITIVE_KINDS, candidate_grid)
from .data import RegressionData, GridSearch, refine_grid
from .score import score_candidate, lstsq
from .static import mean_shift, static_bump_stops

__all__ = ["RestoringForce", "restoring_force", "bandpass", "bandpass_settle_samples", "suggest_band",
           "BandSuggestion", "FrequencyTrack", "track_frequency", "instantaneous_frequency", "Slice",
           "frequency_slices", "amplitude_slices", "local_amplitude", "Thresholds", "Candidate", "FittedModel",
           "Characterization", "RecordSummary", "characterize", "characterize_restoring", "rank_beyond",
           "DEFAULT_KINDS", "POSITIVE_KINDS", "candidate_grid", "RegressionData", "GridSearch", "refine_grid",
           "score_candidate", "lstsq", "mean_shift", "static_bump_stops"]
