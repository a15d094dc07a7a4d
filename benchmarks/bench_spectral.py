"""Benchmark of the one spectral engine (nifo_core.signal.spectral), measured in one run.

Compares, for the paper's settings (Table 2: block 6144, 52 % overlap,
flattop, fs 600 Hz) on 4 channels of 180 000 samples:

- ``cross_spectra``: the full 4×4 cross-spectral matrix (our engine);
- ``scipy.signal.csd`` over all 16 channel pairs (what a naive caller does;
  target: ours ≥ 4× faster);
- the bare batched rfft of the same windowed blocks, nothing else (the floor;
  target: ours within 2.5× of it).

Run: ``.venv/bin/python benchmarks/bench_spectral.py [--channels 4] [--samples 180000] [--repeat 7]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.fft
from numpy.lib.stride_tricks import sliding_window_view
from scipy import signal

from nifo_core.signal.spectral import SpectralSettings, cross_spectra


def _best_of(fn, repeat: int) -> float:
    fn()  # warm-up (caches, plans)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channels", type=int, default=4)
    ap.add_argument("--samples", type=int, default=180_000)
    ap.add_argument("--fs", type=float, default=600.0)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args(argv)

    s = SpectralSettings()  # paper Table 2
    x = np.random.default_rng(0).standard_normal((args.channels, args.samples))
    win = s.window_array()

    def ours():
        return cross_spectra(x, args.fs, s)

    def scipy_pairs():
        return [signal.csd(x[a], x[b], fs=args.fs, window=s.window, nperseg=s.block, noverlap=s.noverlap,
                           detrend=s.detrend if s.detrend != "none" else False)
                for a in range(args.channels) for b in range(args.channels)]

    def bare_fft():
        nb = s.n_blocks(x.shape[1])
        blocks = sliding_window_view(x, s.block, axis=-1)[:, ::s.step][:, :nb]
        return scipy.fft.rfft(blocks * win, axis=-1)

    # same answer first
    g = ours().G
    ref = scipy_pairs()
    err = max(np.max(np.abs(g[:, a, b] - ref[a * args.channels + b][1])) / np.max(np.abs(g[:, a, a]))
              for a in range(args.channels) for b in range(args.channels))

    t_ours = _best_of(ours, args.repeat)
    t_scipy = _best_of(scipy_pairs, max(2, args.repeat // 2))
    t_fft = _best_of(bare_fft, args.repeat)
    nb = s.n_blocks(args.samples)
    print(f"{args.channels} channels x {args.samples} samples, block {s.block}, overlap {s.overlap:.0%} "
          f"({nb} blocks), {s.window}, fs {args.fs:g} Hz; max relative difference to scipy.csd {err:.1e}")
    print(f"  cross_spectra (full {args.channels}x{args.channels} matrix): {t_ours * 1e3:8.1f} ms")
    print(f"  scipy.signal.csd, all {args.channels ** 2} pairs:        {t_scipy * 1e3:8.1f} ms   "
          f"-> ours is {t_scipy / t_ours:.1f}x faster (target >= 4x)")
    print(f"  bare batched rfft of the blocks:        {t_fft * 1e3:8.1f} ms   "
          f"-> ours takes {t_ours / t_fft:.2f}x the bare FFT (target <= 2.5x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
