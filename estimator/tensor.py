"""The structure tensor J (Sec. 3, step 2) and the containers the solvers read it from.

``J = sum_Omega w d d^T`` over a neighbourhood that is Gaussian in x and y (the paper's
65-tap, sigma = 16 window) and uniform over the frames of the temporal window, at the
reference camera.  Rows with ``Δx, Δy`` are not formed per neighbourhood: the sum
``sum_Δ w(Δ) Δ^k g(c + Δ)`` is a correlation of ``g`` with the kernel ``w(Δ) Δ^k``
(:func:`gaussian_moment_kernels`).  An entry of J is therefore a product of two base
signals (times a power of t), smoothed with one of those kernels in x and one in y:
:func:`entry_keys` lists them, :func:`entry_groups` groups the entries that share a
product.

Three implementations give the same J (to roundoff):

* :func:`structure_tensor_reference` is the straightforward one: frames summed, then every
  entry its own separable correlation.  It is kept for checking and as the baseline of
  ``bench/``.
* :func:`structure_tensor` groups the entries by the product of base signals they share,
  sums frames before the (linear) spatial smoothing, and reuses the x-pass across the
  y-moments.
* :func:`estimator.spectral.structure_tensor_fft` smooths each product in the frequency
  domain and returns a packed tensor.

The solvers read J from a :class:`DenseTensor` (full matrices per pixel) or a
:class:`PackedTensor` (one plane per distinct entry); both give any model's sub-block.
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np

from .models import ROWS, ZOOM_ROW_SIGNALS, ZOOM_ROWS
from .portable import gaussian_taps

# every row's (base signal, t-power, monomial): the model rows and the zoom-blur rows
_ROW_SIGNALS = {**ROWS, **ZOOM_ROW_SIGNALS}

__all__ = ["gaussian_moment_kernels", "entry_keys", "entry_groups", "structure_tensor",
           "zoom_terms",
           "structure_tensor_reference", "DenseTensor", "PackedTensor", "zoom_corrected",
           "scaled"]


def gaussian_moment_kernels(sigma: float, window: int) -> np.ndarray:
    """Kernels ``w(Δ) Δ^k`` for ``k = 0, 1, 2``.

    Parameters
    ----------
    sigma : float
        Standard deviation of the Gaussian in pixels.
    window : int
        Odd number of taps.

    Returns
    -------
    ndarray, shape (3, window)
        Row ``k`` is ``w(Δ) Δ^k`` with ``Δ = -R..R`` and ``sum w = 1``.
    """
    R = window // 2
    delta = np.arange(-R, R + 1, dtype=float)
    # the same bits on every machine (numpy's SIMD exp rounds by the CPU)
    w = gaussian_taps(sigma, R)
    return np.stack([w, w * delta, w * delta ** 2])


def entry_keys(rows: tuple[str, ...]):
    """For each upper-triangle entry: (a, b, signal pair, t-power, x-power, y-power)."""
    keys = []
    for a, b in combinations_with_replacement(range(len(rows)), 2):
        sa, ta, ma = _ROW_SIGNALS[rows[a]]
        sb, tb, mb = _ROW_SIGNALS[rows[b]]
        mono = ma + mb
        keys.append((a, b, tuple(sorted((sa, sb))), ta + tb, mono.count("x"), mono.count("y")))
    return keys


def entry_groups(rows: tuple[str, ...]) -> dict[tuple, list]:
    """Upper-triangle entries grouped by the (signal pair, t-power) product they share."""
    groups: dict[tuple, list] = {}
    for key in entry_keys(rows):
        groups.setdefault((key[2], key[3]), []).append(key)
    return groups


def _smooth(img: np.ndarray, kx: np.ndarray, ky: np.ndarray, halo: int) -> np.ndarray:
    from scipy.ndimage import correlate1d

    out = correlate1d(img, kx, axis=-1, mode="constant")
    out = correlate1d(out, ky, axis=-2, mode="constant")
    return out[halo:img.shape[0] - halo] if halo else out


def structure_tensor(signals: dict[str, np.ndarray], tvals: np.ndarray, rows: tuple[str, ...],
                     kernels: np.ndarray, halo: int) -> np.ndarray:
    """Structure tensor for every pixel of a band, grouped computation.

    Parameters
    ----------
    signals : dict of str to ndarray, each shape (F, h, W)
        Base signals from :func:`spatial_signals`.
    tvals : ndarray, shape (F,)
        Frame offsets ``t`` of the frames (relative to the reference frame).
    rows : tuple of str
        Data rows (see :mod:`estimator.models`).
    kernels : ndarray, shape (3, window)
        From :func:`gaussian_moment_kernels`.
    halo : int
        Rows dropped at the top and bottom of the band (the window's reach).

    Returns
    -------
    ndarray, shape (h - 2 halo, W, n, n), float64
    """
    from scipy.ndimage import correlate1d

    n = len(rows)
    F, h, W = next(iter(signals.values())).shape
    wt = np.full(F, 1.0 / F)
    J = np.empty((h - 2 * halo, W, n, n))
    for (pair, tpow), entries in entry_groups(rows).items():
        coef = wt * tvals.astype(float) ** tpow
        prod = np.einsum("f,fhw,fhw->hw", coef, signals[pair[0]], signals[pair[1]])
        xpass: dict[int, np.ndarray] = {}
        done: dict[tuple[int, int], np.ndarray] = {}
        for a, b, _, _, px, py in entries:
            if (px, py) not in done:
                if px not in xpass:
                    xpass[px] = correlate1d(prod, kernels[px], axis=-1, mode="constant")
                sm = correlate1d(xpass[px], kernels[py], axis=-2, mode="constant")
                done[(px, py)] = sm[halo:h - halo] if halo else sm
            J[..., a, b] = done[(px, py)]
            J[..., b, a] = done[(px, py)]
    return J


def structure_tensor_reference(signals: dict[str, np.ndarray], tvals: np.ndarray,
                               rows: tuple[str, ...], kernels: np.ndarray,
                               halo: int) -> np.ndarray:
    """Straightforward structure tensor: each entry smoothed on its own.

    The frames of the temporal window are summed first (the smoothing is linear and the
    temporal weights uniform), then every one of the ``n (n + 1) / 2`` entries gets its own
    separable correlation; no product or pass is shared between entries.  Same parameters
    and result as :func:`structure_tensor`.
    """
    n = len(rows)
    F, h, W = next(iter(signals.values())).shape
    J = np.empty((h - 2 * halo, W, n, n))
    for a, b, pair, tpow, px, py in entry_keys(rows):
        coef = tvals.astype(float) ** tpow / F
        prod = np.einsum("f,fhw,fhw->hw", coef, signals[pair[0]], signals[pair[1]])
        J[..., a, b] = _smooth(prod, kernels[px], kernels[py], halo)
        J[..., b, a] = J[..., a, b]
    return J


class DenseTensor:
    """J as full matrices, one per pixel.

    Parameters
    ----------
    J : ndarray, shape (N, n, n)
    rows : tuple of str
        The data rows of J's rows and columns.
    """

    def __init__(self, J: np.ndarray, rows: tuple[str, ...]):
        self.J, self.rows = J, tuple(rows)

    def block(self, rows: tuple[str, ...]) -> np.ndarray:
        """The sub-block of ``rows`` (a model's J), shape (N, len(rows), len(rows))."""
        sub = np.array([self.rows.index(r) for r in rows])
        return self.J[:, sub[:, None], sub[None, :]]


class PackedTensor:
    """J packed: one contiguous plane per distinct entry (as the FFT tensor makes it).

    Parameters
    ----------
    planes : ndarray, shape (E, N)
    index : ndarray of int, shape (n, n)
        Entry (a, b) of J is ``planes[index[a, b]]``.
    rows : tuple of str
    """

    def __init__(self, planes: np.ndarray, index: np.ndarray, rows: tuple[str, ...]):
        self.planes, self.index, self.rows = planes, index, tuple(rows)

    def sub_index(self, rows: tuple[str, ...]) -> np.ndarray:
        """The index of the sub-block of ``rows``, shape (len(rows), len(rows))."""
        sub = np.array([self.rows.index(r) for r in rows])
        return self.index[np.ix_(sub, sub)]

    def block(self, rows: tuple[str, ...]) -> np.ndarray:
        """The sub-block of ``rows`` as full matrices, shape (N, len(rows), len(rows))."""
        return np.ascontiguousarray(np.moveaxis(self.planes[self.sub_index(rows)], -1, 0))


def zoom_terms(ext: tuple[str, ...], rows: tuple[str, ...]):
    """``(rows, terms)``: each row of ``rows`` as the sum of rows of ``ext``
    (:func:`estimator.models.zoom_rows` ``(rows)``): itself and, where it has one, its
    correction row (``ZOOM_ROWS``); ``terms[a]`` their indices in ``ext``."""
    terms = [[ext.index(r)] + ([ext.index(ZOOM_ROWS[r])] if r in ZOOM_ROWS else [])
             for r in rows]
    return tuple(rows), terms


def zoom_corrected(J, rows: tuple[str, ...]):
    """J of ``rows`` with the zoom-blur correction, from J_ext over
    :func:`estimator.models.zoom_rows` ``(rows)``.

    A corrected row is the row plus its correction row (``ZOOM_ROWS``), so entry ``(a, b)``
    of the corrected J is ``J_ext[a, b] + J_ext[a, b'] + J_ext[a', b] + J_ext[a', b']``
    (``a'`` the correction of ``a``, terms without one left out): ``T J_ext T^T``.

    Parameters
    ----------
    J : DenseTensor or PackedTensor
        Over ``zoom_rows(rows)``.
    rows : tuple of str

    Returns
    -------
    DenseTensor or PackedTensor
        Of the same kind, over ``rows``.
    """
    ext = J.rows
    n = len(rows)
    terms = zoom_terms(ext, rows)[1]
    if isinstance(J, DenseTensor):
        T = np.zeros((n, len(ext)))
        for a, t in enumerate(terms):
            T[a, t] = 1.0
        return DenseTensor(np.matmul(np.matmul(T, J.J), T.T), rows)
    index = np.empty((n, n), dtype=np.int64)
    planes = np.empty((n * (n + 1) // 2, J.planes.shape[1]))
    e = 0
    for a, b in combinations_with_replacement(range(n), 2):
        out = planes[e]
        np.copyto(out, J.planes[J.index[terms[a][0], terms[b][0]]])
        for i in terms[a]:
            for j in terms[b]:
                if (i, j) != (terms[a][0], terms[b][0]):
                    out += J.planes[J.index[i, j]]
        index[a, b] = index[b, a] = e
        e += 1
    return PackedTensor(planes, index, rows)


def scaled(J, factor: np.ndarray):
    """J with each pixel's matrix times ``factor`` (shape (N,)), of the same kind: the
    normalisation of a masked window's sums to weighted means (``estimate_models``'s
    ``mask``)."""
    if isinstance(J, DenseTensor):
        return DenseTensor(J.J * factor[:, None, None], J.rows)
    return PackedTensor(J.planes * factor[None, :], J.index, J.rows)
