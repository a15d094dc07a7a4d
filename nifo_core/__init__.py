"""nifo_core: the pure library behind nifo.

Arrays and frozen configs in, frozen results out. No ROS, Rerun, file formats
or logging set-up in here (``.importlinter`` and a test enforce it). Grouped by
concern into subpackages, each a layer that imports only the ones below it
(``.importlinter``), each ``__init__`` the front door saying what it offers:

- ``loop``          closing the loop: residual → missing effect → refit (docs/method.md §5)
- ``characterize``  restoring force and automatic characterization (docs/method.md §2, §5)
- ``predict``       the identified model, its linear part, its prediction in time, refinement (§4)
- ``nifo``          output-only and input-measured NIFO, batch and streaming (paper Eq. 5, 8-10; §3)
- ``simulate``      the simulated quarter car and road: the truth tests check against (§1, §6)
- ``settings``      the one settings object: given > model file > chosen from the data (§8)
- ``kinds``         the nonlinearity kinds: the describing functions and the registry of their facts
- ``signal``        records, time bases, integration, the one spectral engine, FRFs, excitation
- ``fleet``         fleet statistics (standard errors, intervals, outliers)
- ``errors``        the error hierarchy (``NifoError`` and friends, with exit codes)
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
