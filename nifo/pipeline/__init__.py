"""The pipeline's steps as plain functions with typed options: what the commands, ``nifo run``, the fleet's tasks and
the benchmarks share. A command (:mod:`nifo.commands`) only parses its arguments into the step's options and calls
it; nothing but the CLI imports a command (the import-linter contract in ``.importlinter``).

- :mod:`nifo.pipeline.options`       the typed options of every step (the command lines' names and defaults);
- :mod:`nifo.pipeline.characterize`  ``run_characterize``: restoring-force plots, ranking, the suggested model;
- :mod:`nifo.pipeline.identify`      ``run_identify``, and its parts: stream records into NIFO accumulators and
  merge them (``accumulate``), refuse when nothing usable is left (``NifoResult.check_usable``), the printed numbers and
  warnings (:func:`nifo_core.nifo.summary.summarize`);
- :mod:`nifo.pipeline.refine`        identify's output-error refinement and feedback-path fit, kept only when a
  held-out part is predicted no worse;
- :mod:`nifo.pipeline.loop`          ``run_loop``: the residual loop;
- :mod:`nifo.pipeline.predict`       ``run_predict``: a model applied to records;
- :mod:`nifo.pipeline.job`           ``run_job``: the whole job of ``nifo run``, step after step.

The steps print their human-readable summary as the commands always did (the CLI routes it to stderr with
``--json`` and drops it with ``--quiet``) and return the command's summary dict.

The front door is lazy (``lazy_loader``, as :mod:`nifo_core.signal`'s): a name's module is imported when the name
is first used, so importing one module of the package does not import the others.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs={
    "identify": ["CHUNK_SAMPLES", "accumulate"],
    "options": ["CharacterizeOptions", "IdentifyOptions", "Inputs", "LoopOptions", "PredictOptions", "RunOptions"],
})
