"""The structure tensor by FFT, packed (no numba: the small-volume path uses it too).

The entries are grouped by the product of base signals they share (as in
:func:`estimator.tensor.structure_tensor`); each product is transformed once
(``scipy.fft.rfft2``, multithreaded) and every Gaussian-moment kernel it needs (at most the
3x3 pairs of ``w Δ^0..2`` in x and y) is applied in the frequency domain.  With zero
padding of the window's reach this is the same linear correlation as the 65-tap FIR, up to
floating-point roundoff (tests: agreement with the entry-by-entry reference to 1e-8 of each
quantity's scale).  The result is *packed*: one contiguous (rows, W) plane per
upper-triangle entry, so writing it is not strided.
"""

from __future__ import annotations

import numpy as np

__all__ = ["packed_index", "structure_tensor_fft", "unpack"]


def packed_index(n: int) -> np.ndarray:
    """``idx[a, b]``: plane of entry (a, b) in a packed upper-triangle tensor."""
    idx = np.empty((n, n), dtype=np.int64)
    e = 0
    for a in range(n):
        for b in range(a, n):
            idx[a, b] = idx[b, a] = e
            e += 1
    return idx


def structure_tensor_fft(signals, tvals, rows, kernels, halo, cols=slice(None), workers=None,
                         backend: str = "scipy"):
    """Packed structure tensor of a band via FFT.

    Parameters and meaning as :func:`estimator.tensor.structure_tensor`, plus ``cols``:
    the columns to keep (the interior), so that no copy is needed afterwards, and
    ``backend``: ``"scipy"`` (multithreaded ``scipy.fft``) or ``"numpy"`` (``numpy.fft``,
    for small images: it spares the ~0.1 s import of scipy.fft and gives the same result
    to roundoff).

    Returns
    -------
    ndarray, shape (n (n + 1) / 2, h - 2 halo, ncols), float64
        Entry (a, b) is plane ``packed_index(n)[a, b]``.
    """
    from .tensor import _entry_groups

    n = len(rows)
    F, h, W = next(iter(signals.values())).shape
    R = kernels.shape[1] // 2
    wt = np.full(F, 1.0 / F)
    if backend == "scipy":
        import scipy.fft as sfft

        fast_len = sfft.next_fast_len
        kw = {"workers": workers or -1}
    else:
        sfft, fast_len, kw = np.fft, _next_smooth, {}
    shape = (fast_len(h + 2 * R, real=True), fast_len(W + 2 * R, real=True))
    # convolution kernels = flipped correlation kernels, zero-padded to the FFT size
    kx = np.zeros((3, shape[1]))
    ky = np.zeros((3, shape[0]))
    kx[:, :2 * R + 1] = kernels[:, ::-1]
    ky[:, :2 * R + 1] = kernels[:, ::-1]
    KX = sfft.rfft(kx, axis=1)
    KY = sfft.fft(ky, axis=1)
    idx = packed_index(n)
    out_rows = h - 2 * halo
    c0, c1, _ = cols.indices(W)
    Jp = np.empty((n * (n + 1) // 2, out_rows, c1 - c0))
    # output index i + R holds the correlation centred on input index i
    keep_rows = slice(R + halo, R + h - halo)
    keep_cols = slice(R + c0, R + c1)
    for (pair, tpow), entries in _entry_groups(rows).items():
        coef = wt * tvals.astype(float) ** tpow
        prod = np.einsum("f,fhw,fhw->hw", coef, signals[pair[0]], signals[pair[1]])
        FP = sfft.rfft2(prod, s=shape, **kw)
        # The kernel is separable, so the inverse is too: the y-inverse once per y-moment,
        # then the x-inverse (complex to real) per (x, y) moment pair, on the kept rows only.
        ypass = {}
        done = {}
        for a, b, _, _, px, py in entries:
            if (px, py) not in done:
                if py not in ypass:
                    ypass[py] = sfft.ifft(FP * KY[py][:, None], axis=0, **kw)[keep_rows]
                full = sfft.irfft(ypass[py] * KX[px][None, :], n=shape[1], axis=1, **kw)
                done[(px, py)] = full[:, keep_cols]
            Jp[idx[a, b]] = done[(px, py)]
    return Jp


def _next_smooth(n: int, real: bool = True) -> int:
    """Smallest 5-smooth integer >= n (numpy.fft is fast on those)."""
    m = n
    while True:
        k = m
        for f in (2, 3, 5):
            while k % f == 0:
                k //= f
        if k == 1:
            return m
        m += 1


def unpack(Jp: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Full matrices from packed planes.

    Parameters
    ----------
    Jp : ndarray, shape (E, N)
    idx : ndarray of int, shape (n, n)
        Plane of entry (a, b), e.g. a sub-block of :func:`packed_index`.

    Returns
    -------
    ndarray, shape (N, n, n)
    """
    return np.ascontiguousarray(np.moveaxis(Jp[idx], -1, 0))
