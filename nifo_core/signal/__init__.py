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

Layer: it imports the bottom (it imports only :mod:`nifo_core.errors`) (``.importlinter``). The names below are its
front door; the modules' private (``_``) names stay inside the package.
"""

from .record import Record, CHANNELS, acceleration_from_displacement, concatenate
from .timebase import sample_rate_from_stamps, check_common_rate
from .integrate import (IntegrationBand, Integrated, default_band, lowest_edge_hz, integrator_taps,
                        integrator_length, integrate, StreamingIntegrator, integrator_response, lowest_resolvable_hz,
                        band_for_records, MAX_TAPS)
from .spectral import (Window, Detrend, SpectralSettings, CrossSpectra, CrossSpectralAccumulator, cross_spectra,
                       auto_spectrum, cross_spectrum, block_ffts)
from .frf import (h1, h2, coherence, mimo_h1, multiple_coherence, partial_coherence, condition_number, MimoFit,
                  mimo_fit, white_noise_floor, bound_factor)
from .uncertainty import CoefficientBounds, coefficient_bounds, effective_samples
from .excitation import Excitation, analyse_excitation, combine_excitations, detect_period
from .noise import NoiseEstimate, estimate_noise

__all__ = ["Record", "CHANNELS", "acceleration_from_displacement", "concatenate", "sample_rate_from_stamps",
           "check_common_rate", "IntegrationBand", "Integrated", "default_band", "lowest_edge_hz", "integrator_taps",
           "integrator_length", "integrate", "StreamingIntegrator", "integrator_response", "lowest_resolvable_hz",
           "band_for_records", "MAX_TAPS", "Window", "Detrend", "SpectralSettings", "CrossSpectra",
           "CrossSpectralAccumulator", "cross_spectra", "auto_spectrum", "cross_spectrum", "block_ffts", "h1", "h2",
           "coherence", "mimo_h1", "multiple_coherence", "partial_coherence", "condition_number", "MimoFit",
           "mimo_fit", "white_noise_floor", "bound_factor", "CoefficientBounds", "coefficient_bounds",
           "effective_samples", "Excitation", "analyse_excitation", "combine_excitations", "detect_period",
           "NoiseEstimate", "estimate_noise"]
