"""nifo_core: the pure library behind nifo.

Arrays and frozen configs in, frozen results out. No ROS, Rerun, file formats
or logging set-up in here (a test enforces it). Modules, one concern each:

- ``errors``      the error hierarchy (``NifoError`` and friends, with exit codes)
- ``record``      ``Record``: two accelerations (and optionally the tire patch) on one time base
- ``timebase``    checks that turn raw stamps into a uniform sample rate
- ``vehicle``     the linear quarter car and its analytical transfer functions (the truth)
- ``simulate``    the nonlinear quarter-car simulator
- ``integrate``   band-limited integration of accelerations (one FIR, batch and streaming)
- ``describing``  the describing-function library (forms of METHOD.md §2)
- ``spectral``    the one spectral engine (cross-spectral matrix, batch and streaming)
- ``nifo``        output-only and input-measured NIFO (paper Eq. 5, 8-10)
- ``model``       the identified model and its predictions
- ``restoring``   restoring-force data, slicing and automatic characterization
"""

__version__ = "0.1.0"
