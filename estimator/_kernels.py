"""Numba kernels of the fast path's data passes: the input scan, the camera sums, the
separable x/y filtering and the FFT tensor's products.

One parallel pass each, with the same results as their numpy counterparts to roundoff
(:func:`scan_volume`: the count of non-finite values with max |V|; :func:`camera_sums`
as :func:`estimator.signals.camera_sums`; :func:`spatial_filter` as
:func:`estimator.signals.separable`; :func:`weighted_product`: the products of
:func:`estimator.spectral.structure_tensor_fft`, written zero-padded to the FFT's size).
Only :class:`estimator.backends.NumbaBackend` calls them; whether numba's cache holds
them is :mod:`estimator.jit`'s business.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import carray, njit, prange, types
from numba.extending import intrinsic

__all__ = ["scan_volume", "camera_sums", "spatial_filter", "weighted_product",
           "Frames", "frames_of", "weighted_product_frames", "complex_multiply",
           "complex_multiply_2d"]


@njit(parallel=True, cache=True)
def _camera_sums_kernel(volume, needed, iy0, ix0, r0, r1, weights, out):
    C, ny, nx = weights.shape
    h = r1 - r0
    W = volume.shape[4]
    for job in prange(needed.size * h):
        j = job // h
        y = job - j * h
        k = needed[j]
        for c in range(C):
            for x in range(W):
                out[c, j, y, x] = 0.0
            for i in range(ny):
                for l in range(nx):
                    w = weights[c, i, l]
                    if w != 0.0:
                        src = volume[k, iy0 + i, ix0 + l, r0 + y]
                        for x in range(W):
                            out[c, j, y, x] += w * src[x]


def camera_sums(volume, needed, iy0, ix0, r0, r1, weights):
    """The camera sums of :func:`estimator.signals.camera_sums` (same result) for the
    image rows ``r0 .. r1 - 1``: each output row is one task, so the volume is read
    once, on all cores.

    Returns
    -------
    ndarray, shape (C, len(needed), r1 - r0, W), float64
    """
    out = np.empty((weights.shape[0], needed.size, r1 - r0, volume.shape[4]))
    _camera_sums_kernel(volume, needed, iy0, ix0, r0, r1, weights, out)
    return out


@njit(parallel=True, cache=True)
def _spatial_kernel(src, kx, ky, out):
    """Separable correlation of each image ``src[f]`` with ``ky`` along y and ``kx``
    along x, edge values repeated (as :func:`estimator.signals.separable`); one output
    row per task: the y-combination of the source rows, then the x-pass of that row."""
    F, h, W = src.shape
    ry, rx = ky.size // 2, kx.size // 2
    for job in prange(F * h):
        f = job // h
        y = job - f * h
        tmp = np.zeros(W)
        for j in range(ky.size):
            w = ky[j]
            if w != 0.0:
                yy = min(max(y + j - ry, 0), h - 1)
                for x in range(W):
                    tmp[x] += w * src[f, yy, x]
        # x-pass: the edge columns with clamped indices, the rest tap by tap over
        # contiguous runs (no index arithmetic in the inner loop, so it vectorises)
        row = out[f, y]
        for x in range(W):
            if x < rx or x >= W - rx:
                acc = 0.0
                for i in range(kx.size):
                    xx = min(max(x + i - rx, 0), W - 1)
                    acc += kx[i] * tmp[xx]
                row[x] = acc
            else:
                row[x] = 0.0
        for i in range(kx.size):
            w = kx[i]
            if w != 0.0:
                for x in range(rx, W - rx):
                    row[x] += w * tmp[x + i - rx]


def spatial_filter(a, kx, ky):
    """The separable filtering of :func:`estimator.signals.separable` (same result), in
    parallel over the output rows.

    Parameters
    ----------
    a : ndarray, shape (F, h, W)
    kx, ky : ndarray, shape (taps,)
        Correlation kernels along x and y.

    Returns
    -------
    ndarray, shape (F, h, W), float64
    """
    src = np.ascontiguousarray(a, dtype=np.float64)
    out = np.empty_like(src)
    _spatial_kernel(src, np.ascontiguousarray(kx, dtype=np.float64),
                    np.ascontiguousarray(ky, dtype=np.float64), out)
    return out


# output rows a task of the product kernel makes
_PRODUCT_BLOCK = 16


def weighted_product(coefs, a, b, shape, out=None):
    """The frame-weighted products of :func:`estimator.spectral.structure_tensor_fft`
    (its ``product``), in parallel over blocks of rows: several weightings of the same
    two signals in one pass over them (:func:`weighted_product_frames` of their frames).

    Parameters
    ----------
    coefs : ndarray, shape (K, F)
        One row of frame weights per product.
    a, b : ndarray, shape (F, h, W), float64, C-contiguous
    shape : (int, int)
        Size of each zero-padded result, at least (h, W).
    out : ndarray, shape (K,) + ``shape``, float64, C-contiguous, optional
        Where to write the results (the caller reuses one buffer for every product).

    Returns
    -------
    ndarray, shape (K,) + ``shape``
        ``out[k]`` is ``sum_f coefs[k, f] a[f] b[f]`` in the top-left corner, zero
        elsewhere.
    """
    coefs = np.ascontiguousarray(np.atleast_2d(coefs), dtype=np.float64)
    want = (coefs.shape[0],) + tuple(shape)
    if out is None:
        out = np.empty(want)
    if a.ndim != 3 or a.shape != b.shape or a.shape[0] != coefs.shape[1]:
        raise ValueError(f"weighted_product: a and b of one shape (F, h, W), F = "
                         f"{coefs.shape[1]} the frames of coefs; got {a.shape} and {b.shape}")
    # the kernel checks no bounds: a smaller or strided out would be written past
    if (out.shape != want or not out.flags.c_contiguous
            or any(n < m for n, m in zip(want[1:], a.shape[1:]))):
        raise ValueError(f"weighted_product: out must be C-contiguous of shape {want} "
                         f"(got {out.shape}) and hold a of shape {a.shape}")
    return weighted_product_frames(coefs, frames_of(a), frames_of(b), shape, out)


@intrinsic
def _float64_pointer(typingctx, address):
    """The integer ``address`` as a pointer to float64 (for :func:`numba.carray`)."""
    sig = types.CPointer(types.float64)(types.intp)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(signature.return_type))
    return sig, codegen


@njit(parallel=True, cache=True)
def _frames_product_kernel(coefs, a, b, h, W, out):
    """``out[k, y, x] = sum_f coefs[k, f] A_f[y, x] B_f[y, x]`` on the top-left (h, W) of
    each ``out[k]``, zeros elsewhere (the FFT's padding), with ``A_f``, ``B_f`` the
    C-contiguous float64 (h, W) arrays at the addresses ``a[f]``, ``b[f]``
    (:class:`Frames`).  Each output is summed over the frames in order, ``out += (c a)
    b``, whatever ``K``: the same bits as one product at a time, with both signals read
    once for all ``K``.  A task makes a block of 16 rows, frame after frame, so that the
    block's outputs stay in cache while the frames stream past (measured at 512^2, 13
    frames, K = 3, one thread: 4.8-5.3 ms a call against 6.0-7.1 ms with a row a
    task)."""
    K = coefs.shape[0]
    F = a.size
    R = out.shape[1]
    for blk in prange((R + _PRODUCT_BLOCK - 1) // _PRODUCT_BLOCK):
        y0 = blk * _PRODUCT_BLOCK
        y1 = min(y0 + _PRODUCT_BLOCK, R)
        for y in range(y0, y1):
            for k in range(K):
                for x in range(out.shape[2]):
                    out[k, y, x] = 0.0
        for f in range(F):
            fa = carray(_float64_pointer(a[f]), (h, W))
            fb = carray(_float64_pointer(b[f]), (h, W))
            for y in range(y0, min(y1, h)):
                for k in range(K):
                    c = coefs[k, f]
                    if c != 0.0:
                        for x in range(W):
                            out[k, y, x] += c * fa[y, x] * fb[y, x]


class Frames(NamedTuple):
    """A signal given frame by frame, as :func:`weighted_product_frames` takes it (made
    once for all the products of a signal by :func:`frames_of`)."""

    addresses: np.ndarray     # (F,) intp: where each frame's data starts
    shape: tuple              # (h, W) of every frame
    arrays: tuple             # the frames themselves, held while the addresses are used


def frames_of(arrays) -> Frames:
    """The :class:`Frames` of a sequence of F arrays of shape (h, W), each float64 and
    C-contiguous (a recording's frames kept across the steps that share them,
    :class:`estimator.signals.FrameStack`), or a ValueError: the kernel reads them
    through their addresses, unchecked."""
    arrays = tuple(arrays)
    hw = arrays[0].shape if arrays else None
    if not arrays or not all(p.ndim == 2 and p.shape == hw and p.dtype == np.float64
                             and p.flags.c_contiguous and p.flags.aligned for p in arrays):
        raise ValueError(f"frames_of: C-contiguous float64 frames of one shape (h, W) "
                         f"each, got {[(p.dtype.str, p.shape) for p in arrays]}")
    addresses = np.array([p.__array_interface__["data"][0] for p in arrays], dtype=np.intp)
    return Frames(addresses, hw, arrays)


def weighted_product_frames(coefs, a: Frames, b: Frames, shape, out=None):
    """:func:`weighted_product` of two signals given frame by frame (:func:`frames_of`),
    with the same result bit for bit as of the frames stacked into (F, h, W) arrays.
    Taking the frames where they are kept spares a step their copy into a window of its
    own (and its memory: 2 MB a frame and signal at 512^2).

    Parameters
    ----------
    coefs : ndarray, shape (K, F)
        One row of frame weights per product.
    a, b : Frames
        The two signals' F frames, each (h, W).
    shape : (int, int)
        Size of each zero-padded result, at least (h, W).
    out : ndarray, shape (K,) + ``shape``, float64, C-contiguous, optional

    Returns
    -------
    ndarray, shape (K,) + ``shape``
    """
    coefs = np.ascontiguousarray(np.atleast_2d(coefs), dtype=np.float64)
    F = coefs.shape[1]
    want = (coefs.shape[0],) + tuple(shape)
    if out is None:
        out = np.empty(want)
    hw = a.shape
    # the kernel checks no bounds: frames of another shape, or a smaller out, would be
    # read or written past
    if (a.addresses.size != F or b.addresses.size != F or b.shape != hw
            or out.shape != want or not out.flags.c_contiguous
            or any(n < m for n, m in zip(want[1:], hw))):
        raise ValueError(f"weighted_product_frames: two signals of {F} frames of one shape, "
                         f"within an out C-contiguous of shape {want} (got "
                         f"{a.addresses.size} and {b.addresses.size} frames of shapes {hw} "
                         f"and {b.shape}, out {out.shape})")
    _frames_product_kernel(coefs, a.addresses, b.addresses, hw[0], hw[1], out)
    return out


@njit(parallel=True, cache=True)
def _cmul_kernel(a, k, along_rows, out):
    # no fastmath: each part is two products and one sum, never fused into a
    # multiply-add, so the bits are those of estimator.spectral._cmul on any CPU
    for y in prange(a.shape[0]):
        for x in range(a.shape[1]):
            v = a[y, x]
            w = k[y] if along_rows else k[x]
            out[y, x] = complex(v.real * w.real - v.imag * w.imag,
                                v.imag * w.real + v.real * w.imag)


def complex_multiply(a, k, out):
    """``out = a * k`` for a complex (rows, cols) ``a`` and a kernel ``k`` of shape
    (rows, 1) or (1, cols), in parallel, rounded as :func:`estimator.spectral._cmul`
    (the same bits on every CPU: no fused multiply-adds)."""
    along_rows = k.shape[1] == 1 and k.shape[0] == a.shape[0]     # one factor per row
    _cmul_kernel(a, np.ascontiguousarray(k.ravel()), along_rows, out)
    return out


@njit(parallel=True, cache=True)
def _cmul2_kernel(a, ky, kx, m, add, out):
    # (a ky) kx, each complex product as _cmul_kernel's, times m, stored or added:
    # estimator.spectral._cmul2
    for y in prange(a.shape[0]):
        w = ky[y]
        for x in range(a.shape[1]):
            v = a[y, x]
            r1 = v.real * w.real - v.imag * w.imag
            i1 = v.imag * w.real + v.real * w.imag
            u = kx[x]
            re = (r1 * u.real - i1 * u.imag) * m
            im = (i1 * u.real + r1 * u.imag) * m
            if add:
                out[y, x] = complex(out[y, x].real + re, out[y, x].imag + im)
            else:
                out[y, x] = complex(re, im)


def complex_multiply_2d(a, ky, kx, m, out=None):
    """``m ((a * ky) * kx)`` for a complex (rows, cols) ``a``, ``ky`` (rows,) along its
    rows and ``kx`` (cols,) along its columns: into a new array where ``out`` is None,
    else added to ``out``; rounded as :func:`estimator.spectral._cmul2` (the same bits
    on every CPU: no fused multiply-adds)."""
    add = out is not None
    if out is None:
        out = np.empty(a.shape, dtype=complex)
    _cmul2_kernel(a, np.ascontiguousarray(ky), np.ascontiguousarray(kx), float(m), add,
                  out)
    return out


@njit(parallel=True, cache=True)
def _scan_kernel(flat, bad, amax):
    """Per image (row of ``flat``): the count of non-finite values and max |V|."""
    for i in prange(flat.shape[0]):
        nb = 0
        m = 0.0
        for v in flat[i]:
            # branch-free, so that it vectorises: NaN and inf fail a < inf
            a = abs(v)
            ok = a < np.inf
            nb += 0 if ok else 1
            m = max(m, a if ok else 0.0)
        bad[i] = nb
        amax[i] = m


def scan_volume(volume):
    """``(number of non-finite values, max |V| over the finite ones)`` of a C-contiguous
    volume, in one parallel pass; None when the array is not contiguous."""
    if not volume.flags.c_contiguous or volume.size == 0:
        return None
    flat = volume.reshape(-1, volume.shape[-1] * volume.shape[-2])
    bad = np.empty(flat.shape[0], dtype=np.int64)
    amax = np.empty(flat.shape[0])
    _scan_kernel(flat, bad, amax)
    return int(bad.sum()), float(amax.max())
