"""The block-product sums of the spectral engine, ``S[f, a, b] += Σ_k conj(X_a,k(f))·X_b,k(f)``, in numba.

Why hand-written (issue 29; measured on the shared 2-core machine under load,
paper Table 2 settings, 59 blocks × 3073 lines, CPU time best of 15-41
interleaved rounds, each relative to the bare batched rfft of the same blocks
in the same run; 4 channels, 8 in brackets):

- ``np.einsum('akf,bkf->fab', X.conj(), X, optimize=True)`` (the engine until
  issue 29): 0.76× (0.77×) the rfft on its own, which put the engine at 2.0-2.3×;
- one batched ``np.matmul`` of (F, C, K) by (F, K, C) (one small product per
  line), with the transposed copy it needs: 0.72× (0.82×);
- numpy over the upper triangle only, one ``multiply`` into a reused buffer and
  one ``sum`` per pair: 0.93× (1.01×);
- this kernel: 0.15-0.25× (0.32-0.45×), which puts the whole engine at
  1.15-1.4× the rfft for 4 channels, 1.1-1.6× for 2 and 1.4-1.65× for 8
  (``benchmarks/bench_spectral.py``).

It computes only the upper triangle a ≤ b and mirrors it (the matrix is
Hermitian), walks the lines in chunks that stay in cache so every block of
every channel is read from memory once, and takes two blocks per step. The
sum over blocks is therefore in a different order than einsum's: results agree
to rounding (~1e-15 relative), and the diagonal's imaginary part is exactly 0.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["accumulate_block_products"]

_CHUNK = 256  # lines per chunk: 2 × (C(C+1)/2) × 256 doubles of sums stay in L1/L2 for up to ~8 channels


def accumulate_block_products(spec: np.ndarray, total: np.ndarray) -> None:
    """Add ``Σ_k conj(spec[a, k, f])·spec[b, k, f]`` to ``total[f, a, b]`` in place.

    ``spec`` is complex128 of shape (n_ch, n_blocks, n_freq); ``total`` is a
    C-contiguous complex128 array of shape (n_freq, n_ch, n_ch) (the
    accumulator's own sums, which it may change).
    """
    n_ch, _, n_freq = spec.shape
    spec_f = np.ascontiguousarray(spec, dtype=np.complex128).view(np.float64)
    _accumulate(spec_f, total.view(np.float64).reshape(n_freq, n_ch, n_ch, 2))


@numba.njit(cache=True, nogil=True)
def _accumulate(spec_f, total_f):  # pragma: no cover - compiled; tested through the engine
    """spec_f: (C, K, 2F) float64 view of the complex spectra; total_f: (F, C, C, 2) float64 view of the sums."""
    n_ch, n_blocks, f2 = spec_f.shape
    n_freq = f2 // 2
    n_pairs = n_ch * (n_ch + 1) // 2
    re = np.empty((n_pairs, _CHUNK))
    im = np.empty((n_pairs, _CHUNK))
    for f0 in range(0, n_freq, _CHUNK):
        n = min(n_freq - f0, _CHUNK)
        lo, hi = 2 * f0, 2 * (f0 + n)
        re[:, :n] = 0.0
        im[:, :n] = 0.0
        for k in range(0, n_blocks - 1, 2):          # two blocks per pass over the sums
            p = 0
            for a in range(n_ch):
                xa = spec_f[a, k, lo:hi]
                ya = spec_f[a, k + 1, lo:hi]
                for b in range(a, n_ch):
                    xb = spec_f[b, k, lo:hi]
                    yb = spec_f[b, k + 1, lo:hi]
                    r = re[p]
                    i = im[p]
                    for j in range(n):
                        ar = xa[2 * j]
                        ai = xa[2 * j + 1]
                        br = xb[2 * j]
                        bi = xb[2 * j + 1]
                        cr = ya[2 * j]
                        ci = ya[2 * j + 1]
                        dr = yb[2 * j]
                        di = yb[2 * j + 1]
                        r[j] += (ar * br + ai * bi) + (cr * dr + ci * di)
                        i[j] += (ar * bi - ai * br) + (cr * di - ci * dr)
                    p += 1
        if n_blocks % 2:                               # the odd block out
            k = n_blocks - 1
            p = 0
            for a in range(n_ch):
                xa = spec_f[a, k, lo:hi]
                for b in range(a, n_ch):
                    xb = spec_f[b, k, lo:hi]
                    r = re[p]
                    i = im[p]
                    for j in range(n):
                        ar = xa[2 * j]
                        ai = xa[2 * j + 1]
                        br = xb[2 * j]
                        bi = xb[2 * j + 1]
                        r[j] += ar * br + ai * bi
                        i[j] += ar * bi - ai * br
                    p += 1
        p = 0
        for a in range(n_ch):                          # add the upper triangle and its mirror
            for b in range(a, n_ch):
                for j in range(n):
                    total_f[f0 + j, a, b, 0] += re[p, j]
                    total_f[f0 + j, a, b, 1] += im[p, j]
                    if b != a:
                        total_f[f0 + j, b, a, 0] += re[p, j]
                        total_f[f0 + j, b, a, 1] -= im[p, j]
                p += 1
