"""Output-only and input-measured NIFO (paper Eq. 5, 8-10; docs/method.md §3).

Modules:

- :mod:`nifo_core.nifo.identify`  ``identify_nifo``, ``identify_two_step``: NIFO on records
- :mod:`nifo_core.nifo.stream`  ``StreamingNifo``: the accumulators, fed chunk by chunk, merged exactly
- :mod:`nifo_core.nifo.estimate`  ``nifo_from_spectra``: the estimates from the cross-spectral matrix
- :mod:`nifo_core.nifo.result`  ``NifoResult``: T21, the coefficient functions, their bounds, its conditioning
  and usability
- :mod:`nifo_core.nifo.engine`  ``IdentifySetup``, ``accumulate_record``: how every shell (CLI, fleet, node,
  viewer) feeds records into the accumulators — one set-up decision, one constructor, one push
- :mod:`nifo_core.nifo.summary`  ``summarize``: the numbers and warnings every shell reports

Layer: it imports :mod:`nifo_core.signal` and :mod:`nifo_core.kinds` (``.importlinter``). The names below are its
front door; the modules' private (``_``) names stay inside the package.

The front door is lazy (``lazy_loader``, as :mod:`nifo_core.signal`'s): a name's module is imported when the name
is first used, so importing one module of the package does not import the others.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs={
    "identify": ["IllConditionedWarning", "InputMeasured", "StaticFit", "NifoResult", "FixedTerms", "StreamingNifo",
                 "identify_nifo", "identify_two_step", "nifo_from_spectra", "static_fits",
                 "DEFAULT_ANALYSIS_BAND_HZ", "DEFAULT_COND_LIMIT"],
    "result": ["ILL_FRACTION", "OnIll", "Conditioning"],
    "engine": ["RecordProbe", "IdentifySetup", "accumulate_record"],
    "summary": ["summarize"],
})
