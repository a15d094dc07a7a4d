"""The streaming integrator per push size: the direct sum against overlap-add FFT, measured in one run.

:class:`nifo_core.signal.integrate.StreamingIntegrator` convolves a push of up to ``DIRECT_MAX`` samples directly
(``np.convolve``) and a longer one by overlap-add FFT (``scipy.signal.oaconvolve``). For each band (so the choice is
not tuned to one length of taps) and each push size, this streams 60 s of a random acceleration both ways (the
second with ``DIRECT_MAX = 0``: FFT for every push) and prints the CPU time per push of each, their ratio, and the
largest difference of the two velocity streams from the batch :func:`~nifo_core.signal.integrate.integrate`,
relative to its largest sample. Timing: best of ``--repeat`` rounds, the two ways in turn within each round
(``time.thread_time``: this thread's CPU, not what other jobs took).

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_integrator.py [--repeat 3]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from nifo_core.signal.integrate import IntegrationBand, StreamingIntegrator, integrate

#: (fs [Hz], band): the paper's 600 Hz with the default band and with the sample's data-chosen band, and 400 Hz
CASES = ((600.0, IntegrationBand(2.0, 200.0)), (600.0, IntegrationBand(0.84, 138.0)),
         (400.0, IntegrationBand(1.0, 100.0)))
PUSHES = (1, 8, 60, 128, 256, 512, 2048)


def _stream(a: np.ndarray, fs: float, band: IntegrationBand, m: int, direct_max: int) -> tuple[float, np.ndarray]:
    """CPU seconds per push of ``m`` samples, and the velocity stream (flushed, delay removed)."""
    si = StreamingIntegrator(fs, band)
    si.DIRECT_MAX = direct_max
    si.push(np.zeros(1))      # taps designed (cached) and the path warm before the clock starts
    si = StreamingIntegrator(fs, band)
    si.DIRECT_MAX = direct_max
    parts = []
    t = time.thread_time()
    for i in range(0, a.size, m):
        parts.append(si.push(a[i:i + m])[0])
    took = time.thread_time() - t
    parts.append(si.flush()[0])
    return took / -(-a.size // m), np.concatenate(parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    print(f"{'fs':>5} {'band [Hz]':>12} {'taps':>6} {'push':>5} {'direct [µs]':>12} {'FFT [µs]':>10} "
          f"{'FFT/direct':>10} {'err direct':>10} {'err FFT':>9}  used")
    for fs, band in CASES:
        a = np.random.default_rng(1).standard_normal(int(args.seconds * fs))
        ref = integrate(a, fs, band=band).velocity
        taps = StreamingIntegrator(fs, band).delay_samples * 2 + 1
        for m in PUSHES:
            best_d = best_f = np.inf
            for _ in range(args.repeat):
                td, vd = _stream(a, fs, band, m, StreamingIntegrator.DIRECT_MAX)
                tf, vf = _stream(a, fs, band, m, 0)
                best_d, best_f = min(best_d, td), min(best_f, tf)
            scale = float(np.max(np.abs(ref)))
            ed, ef = (float(np.max(np.abs(v - ref))) / scale for v in (vd, vf))
            used = "direct" if m <= StreamingIntegrator.DIRECT_MAX else "FFT"
            print(f"{fs:5.0f} {band.f_lo_hz:5.2f}-{band.f_hi_hz:<6g} {taps:6d} {m:5d} {best_d * 1e6:12.1f} "
                  f"{best_f * 1e6:10.1f} {best_f / best_d:10.2f} {ed:10.1e} {ef:9.1e}  {used}")


if __name__ == "__main__":
    main()
