"""The simulated quarter car: the truth the tests and benchmarks check against (docs/method.md §1, §6).

Modules:

- :mod:`nifo_core.simulate.vehicle`  the linear quarter car and its analytical transfer functions
- :mod:`nifo_core.simulate.road`  road profiles (ISO 8608-like spectra) and chirps
- :mod:`nifo_core.simulate.quarter_car`  the nonlinear simulator: records with their truth

Layer: it imports :mod:`nifo_core.signal` and :mod:`nifo_core.kinds` (``.importlinter``). The names below are its
front door; the modules' private (``_``) names stay inside the package.
"""

from .vehicle import QuarterCar
from .road import RandomRoad, ChirpRoad, Road, road_signal, road_from_dict
from .quarter_car import StrutForce, SensorNoise, SimConfig, Simulation, Truth, simulate, preset, PRESETS

__all__ = ["QuarterCar", "RandomRoad", "ChirpRoad", "Road", "road_signal", "road_from_dict", "StrutForce",
           "SensorNoise", "SimConfig", "Simulation", "Truth", "simulate", "preset", "PRESETS"]
