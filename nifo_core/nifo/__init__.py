"""Output-only and input-measured NIFO (paper Eq. 5, 8-10; docs/method.md §3).

Modules:

- :mod:`nifo_core.nifo.identify`  ``identify_nifo``, ``identify_two_step``: NIFO on records
- :mod:`nifo_core.nifo.stream`  ``StreamingNifo``: the accumulators, fed chunk by chunk, merged exactly
- :mod:`nifo_core.nifo.estimate`  ``nifo_from_spectra``: the estimates from the cross-spectral matrix
- :mod:`nifo_core.nifo.result`  ``NifoResult``: T21, the coefficient functions, their bounds

Layer: it imports :mod:`nifo_core.signal` and :mod:`nifo_core.kinds` (``.importlinter``). The names below are its
front door; the modules' private (``_``) names stay inside the package.
"""

from .identify import (IllConditionedWarning, InputMeasured, StaticFit, NifoResult, FixedTerms, StreamingNifo,
                       identify_nifo, identify_two_step, nifo_from_spectra, static_fits, DEFAULT_ANALYSIS_BAND_HZ,
                       DEFAULT_COND_LIMIT)
from .result import ILL_FRACTION, OnIll

__all__ = ["IllConditionedWarning", "InputMeasured", "StaticFit", "NifoResult", "FixedTerms", "StreamingNifo",
           "identify_nifo", "identify_two_step", "nifo_from_spectra", "static_fits", "DEFAULT_ANALYSIS_BAND_HZ",
           "DEFAULT_COND_LIMIT", "ILL_FRACTION", "OnIll"]
