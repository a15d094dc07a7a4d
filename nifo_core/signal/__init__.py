"""Signals and their spectra: what every other part of the core stands on.

Modules:

- :mod:`nifo_core.signal.record`  ``Record``: the two accelerations (a force, a tire patch) on one time base
- :mod:`nifo_core.signal.timebase`  raw stamps turned into a uniform sample rate
- :mod:`nifo_core.signal.integrate`  band-limited integration of accelerations (one FIR, batch and streaming)
- :mod:`nifo_core.signal.spectral`  the one spectral engine: the cross-spectral matrix, batch and streaming
- :mod:`nifo_core.signal.frf`  H1, coherences and multiple-input fits derived from it
- :mod:`nifo_core.signal.uncertainty`  random errors and confidence bounds of spectral estimates
- :mod:`nifo_core.signal.noise`  each sensor's noise, estimated from the data
- :mod:`nifo_core.signal.bias_correction`  a fit's bias removed by simulating it with that noise (errors in variables)
- :mod:`nifo_core.signal.excitation`  what the data say about their excitation: period, transient, excited band (docs/method.md §8)
- :mod:`nifo_core.signal.band`  a band of frequencies as a zero-phase filter (where a model holds)

Layer: it imports the bottom (it imports only :mod:`nifo_core.errors`) (``.importlinter``). The names below are its
front door; the modules' private (``_``) names stay inside the package.

The front door is lazy (scientific-python's ``lazy_loader``, SPEC 1): a name's module is imported when the name is
first used. Importing :mod:`nifo_core.signal.record` alone (``nifo info``, every file reader) then costs no
scipy.signal, numba or the integrator's FIR design: measured, ``nifo info`` on a 20 s bag 1.3-1.7 s → 0.37-0.41 s
(three runs each, alternating, from an empty directory; ``benchmarks/compare_versions.py`` says why), its imports
1.2 s → 0.3 s (``python -X importtime -m nifo info BAG``). ``EAGER_IMPORT=1`` imports everything at once.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs={
    "record": ["Record", "CHANNELS", "acceleration_from_displacement", "concatenate"],
    "timebase": ["sample_rate_from_stamps", "check_common_rate"],
    "integrate": ["IntegrationBand", "Integrated", "default_band", "lowest_edge_hz", "integrator_taps",
                  "integrator_length", "integrate", "StreamingIntegrator", "integrator_response",
                  "lowest_resolvable_hz", "band_for_records", "MAX_TAPS"],
    "spectral": ["Window", "Detrend", "SpectralSettings", "CrossSpectra", "CrossSpectralAccumulator", "cross_spectra",
                 "auto_spectrum", "cross_spectrum", "block_ffts"],
    "frf": ["h1", "h2", "coherence", "mimo_h1", "multiple_coherence", "partial_coherence", "condition_number",
            "MimoFit", "mimo_fit", "white_noise_floor", "bound_factor"],
    "uncertainty": ["CoefficientBounds", "coefficient_bounds", "effective_samples"],
    "excitation": ["Excitation", "analyse_excitation", "combine_excitations", "detect_period"],
    "noise": ["NoiseEstimate", "estimate_noise"],
    "band": ["band_taper", "band_limit", "edge_width_hz", "fraction_outside", "prediction_taper", "PREDICTION_EDGE"],
})
