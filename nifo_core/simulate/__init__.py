"""The simulated quarter car: the truth the tests and benchmarks check against (docs/method.md §1, §6).

Modules:

- :mod:`nifo_core.simulate.vehicle`  the linear quarter car and its analytical transfer functions
- :mod:`nifo_core.simulate.road`  road profiles (ISO 8608-like spectra) and chirps
- :mod:`nifo_core.simulate.quarter_car`  the nonlinear simulator: records with their truth
- :mod:`nifo_core.simulate.independent`  a second simulator written apart from the first (adaptive Dormand-Prince,
  its own forces, road and filters): what nifo is checked on does not rest on one discretisation

Layer: it imports :mod:`nifo_core.signal` and :mod:`nifo_core.kinds` (``.importlinter``). The names below are its
front door; the modules' private (``_``) names stay inside the package.

The front door is lazy (``lazy_loader``, as :mod:`nifo_core.signal`'s): a name's module is imported when the name
is first used, so importing one module of the package does not import the others.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs={
    "vehicle": ["QuarterCar"],
    "road": ["RandomRoad", "ChirpRoad", "Road", "road_signal", "road_from_dict"],
    "quarter_car": ["StrutForce", "SensorNoise", "SimConfig", "Simulation", "Truth", "simulate", "preset", "PRESETS"],
    "independent": ["Corner", "Element", "HarmonicRoad", "Sensors", "IndependentConfig", "IndependentRun",
                    "simulate_independent"],
})
