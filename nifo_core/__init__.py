"""nifo_core: the pure library behind nifo.

Arrays and frozen configs in, frozen results out. No ROS, Rerun, file formats
or logging set-up in here (a test enforces it). Modules, one concern each:

- ``errors``      the error hierarchy (``NifoError`` and friends, with exit codes)
- ``record``      ``Record``: two accelerations (and optionally the tire patch) on one time base
- ``timebase``    checks that turn raw stamps into a uniform sample rate
- ``vehicle``     the linear quarter car and its analytical transfer functions (the truth)
- ``simulate``    the nonlinear quarter-car simulator
- ``integrate``   band-limited integration of accelerations (one FIR, batch and streaming)
- ``describing``  the describing-function library (forms of docs/method.md §2)
- ``spectral``    the one spectral engine (cross-spectral matrix, batch and streaming)
- ``nifo``        output-only and input-measured NIFO (paper Eq. 5, 8-10)
- ``model``       the identified model and its predictions
- ``restoring``   restoring-force data, slicing and automatic characterization
"""

import os as _os
import sys as _sys

__version__ = "0.1.0"

# One BLAS thread per process: nifo's linear algebra is small (a few hundred rows), where OpenBLAS's threads only
# add overhead — 14× slower rational fits on a busy two-core machine (benchmarks/bench_blas_threads.py prints the
# ratio). Set before numpy and scipy load their OpenBLAS (cheap: nothing heavy is imported here, so a Ctrl-C at
# start-up still lands where the command catches it); a numpy loaded before nifo_core is limited now.
# NIFO_BLAS_THREADS overrides; the fleet scales over processes instead.
_BLAS_THREADS = _os.environ.get("NIFO_BLAS_THREADS", "1")
_os.environ.setdefault("OPENBLAS_NUM_THREADS", _BLAS_THREADS)
if "numpy" in _sys.modules:
    from threadpoolctl import threadpool_limits as _threadpool_limits

    _threadpool_limits(int(_BLAS_THREADS), user_api="blas")
