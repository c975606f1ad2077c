"""Pooling the affine model's depth motion and tilt rates over the leaf (beyond the paper).

Per pixel, the affine model tells growth from depth motion and tilt by the change of the
disparity in time (``v_t, z_x,t, z_y,t``), a tiny signal: its noise, carried through the
9 x 9 solve, dominates the growth map's.  The image flow and its gradient (the other six
observations) are well determined per pixel.  On a plane that moves and turns as a
whole the rates are simple functions of the pixel (``docs/model.md``, *Pooled depth
rates*): ``z_x = Z_x / c`` and ``z_y = Z_y / c`` are constant, ``v_t`` is affine in
``x, y``, ``z_x,t`` and ``z_y,t`` are constant, whatever the growth pattern in the plane.
A local linear fit of each rate over a bell-shaped support much wider than the estimator's
window keeps that exactly and averages the noise over the support; the per-pixel 9 x 9
solve then takes the pooled rates with the pixel's own flow and flow gradient.

Only pixels whose window sees texture everywhere (:func:`textured_windows`: not reaching
over a leaf's edge onto a blank background) enter the fits, each weighted by the inverse
of its ``v_t``'s first-order variance. Where a rate departs from its fit by more than
``k`` times the residuals' local spread (a fold, an edge, a second leaf), the pixel
keeps its own rates (the per-pixel solution) and the fit is redone without it; the map
``pooled`` says which.

Numerics only (scipy.ndimage's box filters); everything a pixel's pooled rates read lies
within :func:`pool_reach` pixels (``estimator.band_halo`` adds what ``growth_sd`` reads),
so a row band with that many more rows either side gives the whole image's result.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import ndimage

__all__ = ["POOLED_RATES", "pool_reach", "local_linear_fit", "pool_rates",
           "textured_windows", "texture_reach", "local_spread", "fit_variance",
           "local_mean", "support_radius", "bell", "bell_radius", "bell_square_sum"]

# the per-pixel quantities pooled: the projected slopes and the rates of the disparity
# and of the projected slopes at a fixed pixel
POOLED_RATES = ("zx", "zy", "v_t", "zx_t", "zy_t")

# The support is three passes of a box filter (a quadratic B-spline, bell-shaped like a
# Gaussian of the same variance): each pass costs the same whatever its width (scipy's
# running sum), where a sampled Gaussian of sigma 96 px would take 577 taps, and its
# reach is exact and finite (1.5 (w - 1) <= 3 sigma).  The local linear fit below is
# exact on affine fields for any kernel.
_PASSES = 3


# a pixel whose rate lies further than this many local standard deviations of the
# residual from the fit keeps its own rates: at 4 sd a Gaussian residual crosses it at
# 6e-5 of the pixels (times the five rates), so under noise alone nearly every pixel is
# pooled
OUTLIER_SD = 4.0


def _box_width(sigma: float) -> int:
    """The odd box width whose three passes have variance closest to ``sigma^2``: a box
    of ``w`` taps has variance ``(w^2 - 1) / 12``."""
    w = math.sqrt(12.0 * sigma * sigma / _PASSES + 1.0)
    return max(1, 2 * int(round((w - 1) / 2)) + 1)


# Above this many pixels of standard deviation per pixel of block, the support's sums
# are taken over blocks of f x f pixels (exact sums of every product a fit needs),
# smoothed on the grid of blocks and the results interpolated linearly back to the pixels
# (:class:`_Support`): at the default sigma_s = 96 px, 8-px blocks, 64 times fewer
# samples to smooth.  The bell is then the block's box and three boxes on the block grid
# (its variance within a few per cent of sigma^2), and a fit stays exact on affine fields
# (the block sums are exact, linear interpolation is exact on affine fields).
_SIGMA_PER_BLOCK = 12.0


def _block(sigma: float) -> int:
    """The block size, px, for a support of standard deviation ``sigma``."""
    return max(1, int(sigma // _SIGMA_PER_BLOCK))


def _radius(sigma: float) -> int:
    f = _block(sigma)
    if f == 1:
        return bell_radius(sigma)
    # the coarse boxes' reach in blocks, the block itself and the interpolation's next node
    return f * (_PASSES * (_box_width(sigma / f) - 1) // 2 + 2)


def bell_radius(sigma: float) -> int:
    """The reach, px, of :func:`bell` (three boxes at full resolution)."""
    return _PASSES * (_box_width(sigma) - 1) // 2


def bell(a: np.ndarray, sigma: float) -> np.ndarray:
    """``a`` (shape (H, W)) smoothed by the bell of standard deviation ``sigma`` (three box
    filters per axis, zeros outside the image), at full resolution."""
    return _smooth(a, sigma)


def bell_square_sum(sigma: float) -> float:
    """``sum K^2`` of the 2-D bell of :func:`bell` (``1 / (4 pi sigma^2)`` for a
    Gaussian): a white noise's variance falls by this factor under it."""
    return _bell_square_sum(float(sigma))


@lru_cache(maxsize=8)
def _bell_square_sum(sigma: float) -> float:
    # computed once per sigma (a few hundred exactly rounded sums: 2 ms a step); sigma a
    # Python float, so that a float32 and a float64 of equal value (whose box widths can
    # differ) do not share an entry
    w = _box_width(sigma)
    # the box's repeated convolution in Python floats, each sum exactly rounded (numpy's
    # convolve goes through BLAS, whose sums round by the machine's CPU)
    k = [1.0]
    for _ in range(_PASSES):
        k = [math.fsum(k[j] for j in range(max(0, i - w + 1), min(i, len(k) - 1) + 1)) / w
             for i in range(len(k) + w - 1)]
    return math.fsum(v * v for v in k) ** 2


class _Support:
    """The support of standard deviation ``sigma`` on an image of ``shape``, on its grid of
    blocks (``f`` px; 1: the pixels themselves).  ``origin`` ``(row, col)``: a pixel where
    blocks start, in the image's rows and columns, so that a row band (its origin moved
    with it) has the whole image's blocks."""

    def __init__(self, shape, sigma: float, origin=(0, 0), block: int | None = None):
        H, W = shape
        f = _block(sigma) if block is None else int(block)
        self.f, self.sigma, self.shape = f, float(sigma), (H, W)
        x, y = _coordinates(shape)
        self.px, self.py = x, y
        if f == 1:
            self.x, self.y = x, y
            return
        # zeros before the first block boundary (rows = origin mod f) and after the last
        self.pad = []
        for n, o in ((H, origin[0]), (W, origin[1])):
            before = (f - int(o) % f) % f
            after = (-(n + before)) % f
            self.pad.append((before, after))
        (t, b), (le, r) = self.pad
        ny, nx = (H + t + b) // f, (W + le + r) // f
        # the blocks' centres in the pixels' coordinates (those of _coordinates)
        self.y = (np.arange(ny) * f - t + (f - 1) / 2.0 - (H - 1) / 2.0)[:, None]
        self.x = (np.arange(nx) * f - le + (f - 1) / 2.0 - (W - 1) / 2.0)[None, :]
        self._rows = self._linear(H, t, ny)
        self._cols = self._linear(W, le, nx)

    def _linear(self, n, before, nodes):
        """Per pixel along one axis: the lower node and the weight of the upper, linear
        interpolation between the nodes' centres (extrapolation past the outer ones)."""
        u = (np.arange(n) + before - (self.f - 1) / 2.0) / self.f
        i0 = np.clip(np.floor(u).astype(int), 0, max(nodes - 2, 0))
        return i0, u - i0

    def sums(self, a: np.ndarray) -> np.ndarray:
        """``sum K a`` about each node (each pixel where ``f`` is 1): ``a`` of shape
        (H, W), or (K, H, W) for K maps at once (the same values as one by one)."""
        if self.f == 1:
            return _smooth(a, self.sigma)
        f = self.f
        # the blocks' means: the bell over the pixels still sums to 1 (as at f = 1), which
        # fit_variance's squared kernel relies on
        return _smooth(self._block_sums(a) / (f * f), self.sigma / f)

    def _block_sums(self, a: np.ndarray) -> np.ndarray:
        """Each block's sum of ``a`` (shape (..., H, W)), shape (..., ny, nx): the rows of
        a block added in turn (row ``k`` of every block is one strided slice), then its
        columns alike.  Whole rows of 512 samples at a time: at 512^2 and 8-px blocks
        0.13 ms against 0.55 ms for numpy's mean over the blocks' two axes of a padded
        copy (measured), and every sum in a fixed order (elementwise adds only)."""
        f = self.f
        (t, _), (le, _) = self.pad
        ny, nx = self.y.shape[0], self.x.shape[1]
        lead = a.shape[:-2]
        rows = np.zeros(lead + (ny, a.shape[-1]))
        for first in range(f):
            # the rows first, first + f, ...: one row of each block from block b0 on (row
            # i is in block (i + t) // f; zeros pad the first block)
            part = a[..., first::f, :]
            b0 = (first + t) // f
            rows[..., b0:b0 + part.shape[-2], :] += part
        out = np.zeros(lead + (ny, nx))
        for first in range(f):
            part = rows[..., first::f]
            b0 = (first + le) // f
            out[..., b0:b0 + part.shape[-1]] += part
        return out

    def to_pixels(self, a: np.ndarray) -> np.ndarray:
        """A field at the nodes, linearly interpolated to the pixels, shape (H, W)."""
        if self.f == 1:
            return a
        (i0, t), (j0, s) = self._rows, self._cols
        if a.shape[0] > 1:
            a = a[i0] * (1 - t)[:, None] + a[i0 + 1] * t[:, None]
        else:
            a = np.repeat(a, len(i0), axis=0)
        if a.shape[1] > 1:
            return a[:, j0] * (1 - s) + a[:, j0 + 1] * s
        return np.repeat(a, len(j0), axis=1)


def pool_reach(sigma: float) -> int:
    """Pixels either side whose per-pixel rates a pixel's pooled rates read, for a support
    of standard deviation ``sigma`` and radius ``R`` (about 3 ``sigma``): ``3 R`` (the
    first fit reads ``R``, a pixel's outlier test its residuals' spread over ``R`` more,
    the second fit the outlier tests within ``R``).  0 when ``sigma`` is 0 (no
    pooling)."""
    return 0 if sigma == 0 else 3 * _radius(sigma)


def support_radius(sigma: float) -> int:
    """The support's radius ``R`` in pixels (0 when ``sigma`` is 0)."""
    return 0 if sigma == 0 else _radius(sigma)


def texture_reach(radius: int) -> int:
    """Pixels either side that :func:`textured_windows` reads for a window radius."""
    return radius + 4


def _smooth(a: np.ndarray, sigma: float) -> np.ndarray:
    """``a`` (shape (..., H, W)) under three boxes along each of its last two axes."""
    # zeros outside the image: together with the weights' own smoothing this is the
    # normalized convolution (Knutsson & Westin) of the samples inside
    w = _box_width(sigma)
    # the passes along the rows on a transposed copy, each line's running sum contiguous
    # (the same sums in the same order): at 512^2 a pass down the columns took 2.3 ms,
    # along the rows 0.6 ms (measured)
    a = np.ascontiguousarray(np.swapaxes(a, -1, -2))
    for _ in range(_PASSES):
        a = ndimage.uniform_filter1d(a, w, axis=-1, mode="constant", cval=0.0)
    a = np.ascontiguousarray(np.swapaxes(a, -1, -2))
    for _ in range(_PASSES):
        a = ndimage.uniform_filter1d(a, w, axis=-1, mode="constant", cval=0.0)
    return a


# a window "sees texture everywhere" when its least textured pixel has at least this
# fraction of the window's mean gradient energy: a window reaching over a leaf's edge
# onto a dark, blank background fails it (there the energy is 0); the sinusoids pass it
# (their energy, smoothed over 1 px, never falls to 1/100 of its mean)
_BLANK = 0.01


def textured_windows(image: np.ndarray, radius: int, mask: np.ndarray | None = None
                     ) -> np.ndarray:
    """Pixels whose window (``2 radius + 1`` px square) holds no blank part: the least
    gradient energy in it (smoothed over 1 px) is at least 1/100 of its mean.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        The reference camera's image at the reference frame.
    radius : int
        The estimator's window radius, px.
    mask : ndarray of bool, shape (H, W), optional
        The pixels a window uses (the object's): only these are looked at.

    Returns
    -------
    ndarray of bool, shape (H, W)
        Reads pixels up to ``radius + 4`` away.
    """
    gy, gx = np.gradient(np.asarray(image, dtype=float))
    energy = ndimage.gaussian_filter(gx * gx + gy * gy, 1.0, mode="nearest", truncate=3.0)
    size = 2 * radius + 1
    if mask is None:
        low = ndimage.minimum_filter(energy, size=size, mode="nearest")
        mean = ndimage.uniform_filter(energy, size=size, mode="nearest")
        return low > _BLANK * mean
    m = np.asarray(mask, dtype=bool)
    low = ndimage.minimum_filter(np.where(m, energy, np.inf), size=size, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (ndimage.uniform_filter(np.where(m, energy, 0.0), size=size, mode="nearest")
                / ndimage.uniform_filter(m.astype(float), size=size, mode="nearest"))
    return m & (low > _BLANK * mean)


def _coordinates(shape):
    # coordinates relative to the image centre keep the moments' magnitudes near
    # sigma^2, whatever the image size
    H, W = shape
    return ((np.arange(W, dtype=float) - (W - 1) / 2.0)[None, :],
            (np.arange(H, dtype=float) - (H - 1) / 2.0)[:, None])


def _moments(w, sup: _Support, smooth):
    """The normal matrix's entries about each node p: ``sum K w (x_q - x_p)^i (y_q -
    y_p)^j`` for ``i + j <= 2`` (``smooth`` applies K; pixels ``q``, nodes ``p``)."""
    x, y = sup.px, sup.py
    m = {k: smooth(w * f) for k, f in
         (("1", 1.0), ("x", x), ("y", y), ("xx", x * x), ("xy", x * y), ("yy", y * y))}
    s0 = m["1"]
    x, y = sup.x, sup.y
    return (s0, m["x"] - x * s0, m["y"] - y * s0,
            m["xx"] - 2 * x * m["x"] + x * x * s0,
            m["xy"] - x * m["y"] - y * m["x"] + x * y * s0,
            m["yy"] - 2 * y * m["y"] + y * y * s0)


def _first_inverse_row(w, sup: _Support):
    """The cofactors ``c0, c1, c2`` of the first row of the normal matrix ``A = [[s0, sx,
    sy], [sx, sxx, sxy], [sy, sxy, syy]]`` and ``1 / det A`` (NaN where no plane is
    determined), at the support's nodes: the fit's constant term needs only ``A^-1``'s
    first row."""
    sigma = sup.sigma
    s0, sx, sy, sxx, sxy, syy = _moments(w, sup, sup.sums)
    c0 = sxx * syy - sxy * sxy
    c1 = sxy * sy - sx * syy
    c2 = sx * sxy - sxx * sy
    det = s0 * c0 + sx * c1 + sy * c2
    # a plane needs samples within reach, not in one line: s0 above the running sums'
    # roundoff, and A far from singular
    ok = (s0 > 1e-9 * s0.max()) & (det > 1e-9 * (s0 * s0 * s0) * sigma ** 4)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(ok, 1.0 / det, np.nan)
    return c0, c1, c2, r


def fit_variance(weights: np.ndarray, sigma: float, correlation_area,
                 origin=(0, 0)) -> np.ndarray:
    """The variance of :func:`local_linear_fit`'s value per unit variance of the samples'
    noise, for noise correlated over ``correlation_area`` pixels (its autocorrelation's
    integral; 1 for white noise).

    The fit's value is ``sum_q l_q v_q`` with the equivalent weights ``l_q = K_q w_q
    (A^-1 u_q)_0``, ``u_q = (1, x_q - x_p, y_q - y_p)``; for noise whose correlation is
    short against the support, its variance is ``correlation_area sum_q l_q^2 =
    correlation_area a^T B a`` with ``a = A^-1 e_0`` and ``B = sum K^2 w^2 u u^T``.  The
    kernel's square is taken as the same bell at ``sigma / sqrt(2)`` over ``4 pi
    sigma^2`` (exact for a Gaussian).

    Parameters
    ----------
    weights : ndarray, shape (H, W)
    sigma : float
    correlation_area : float or ndarray, shape (H, W)
        Pixels.
    origin : (int, int)
        Where the support's blocks start (:class:`_Support`).

    Returns
    -------
    ndarray, shape (H, W)
    """
    w = np.asarray(weights, dtype=float)
    sup = _Support(w.shape, sigma, origin)
    c0, c1, c2, r = _first_inverse_row(w, sup)
    k2 = 1.0 / (4.0 * np.pi * sigma * sigma)
    half = _Support(w.shape, sigma / np.sqrt(2), origin, block=sup.f)
    b00, b01, b02, b11, b12, b22 = _moments(w * w, sup, lambda a: k2 * half.sums(a))
    quad = (c0 * c0 * b00 + c1 * c1 * b11 + c2 * c2 * b22
            + 2 * (c0 * c1 * b01 + c0 * c2 * b02 + c1 * c2 * b12))
    return correlation_area * sup.to_pixels(quad * r * r)


def local_linear_fit(values: np.ndarray, weights: np.ndarray, sigma: float,
                     origin=(0, 0)) -> np.ndarray:
    """Weighted local linear regression of each map on the pixel coordinates.

    At each pixel ``p`` the fit minimises ``sum_q K(q - p) w_q (v_q - a - b (x_q - x_p) -
    c (y_q - y_p))^2`` with ``K`` a bell of standard deviation ``sigma`` (three box
    filters, radius about 3 ``sigma``) and returns ``a``: exact for values affine in
    ``x, y``, and a weighted average elsewhere.  Where the weights do not determine a
    plane (fewer than three weighted pixels in line), NaN.

    Parameters
    ----------
    values : ndarray, shape (K, H, W)
        Maps to fit; read only where ``weights > 0``.
    weights : ndarray, shape (H, W)
        Non-negative sample weights (0 drops a pixel).
    sigma : float
        Pixels.
    origin : (int, int)
        Where the support's blocks start (:class:`_Support`): a pixel's row and column,
        the same for a row band as for the whole image (the principal point).

    Returns
    -------
    ndarray, shape (K, H, W)
    """
    w = np.asarray(weights, dtype=float)
    sup = _Support(w.shape, sigma, origin)
    c0, c1, c2, r = _first_inverse_row(w, sup)
    out = np.empty(np.shape(values), dtype=float)
    x, y = sup.px, sup.py
    for k, v in enumerate(values):
        wv = w * np.where(w > 0, v, 0.0)
        b0 = sup.sums(wv)
        bx = sup.sums(wv * x) - sup.x * b0
        by = sup.sums(wv * y) - sup.y * b0
        out[k] = sup.to_pixels((c0 * b0 + c1 * bx + c2 * by) * r)
    return out


def pool_rates(rates: np.ndarray, valid: np.ndarray, sigma: float,
               k: float = OUTLIER_SD, weights: np.ndarray | None = None, origin=(0, 0)
               ) -> tuple[np.ndarray, np.ndarray]:
    """The rates pooled over a bell-shaped support, the outliers keeping their own.

    A first local linear fit over the valid pixels; the residuals' local spread (their
    root mean square over the same support); a pixel with any rate further than ``k``
    spreads from its fit is an outlier; a second fit without the outliers gives every
    other pixel its pooled rates.

    Parameters
    ----------
    rates : ndarray, shape (K, H, W)
        Per-pixel rates (:data:`POOLED_RATES`).
    valid : ndarray of bool, shape (H, W)
        Pixels with a per-pixel estimate.
    sigma : float
        The support's standard deviation, pixels.
    k : float
        Outlier threshold in local standard deviations.
    weights : ndarray, shape (H, W), optional
        Sample weights of the fits (default 1 on the valid pixels).
    origin : (int, int)
        Where the support's blocks start (:func:`local_linear_fit`).

    Returns
    -------
    rates : ndarray, shape (K, H, W)
        Pooled at pooled pixels, the pixel's own at outliers, NaN outside ``valid``.
    pooled : ndarray of bool, shape (H, W)
        Where the pooled rates were used.
    spread : ndarray, shape (K, H, W)
        The per-pixel rates' local standard deviation about the first fit (the local
        root mean square of its residuals): their noise where the rates are affine.
    """
    valid = valid & np.isfinite(rates).all(0)
    base = np.ones(valid.shape) if weights is None else np.asarray(weights, dtype=float)
    w = np.where(valid, base, 0.0)
    fit = local_linear_fit(rates, w, sigma, origin)
    sup = _Support(valid.shape, sigma, origin)
    with np.errstate(invalid="ignore", divide="ignore"):
        res = np.where(valid, rates - fit, 0.0)
        total = sup.sums(w)
        spread = np.stack([sup.to_pixels(np.sqrt(sup.sums(w * r * r) / total))
                           for r in res])
        outlier = (np.abs(res) > k * spread).any(0)
    keep = valid & ~outlier
    if outlier.any():
        fit = local_linear_fit(rates, np.where(keep, w, 0.0), sigma, origin)
    pooled = keep & np.isfinite(fit).all(0)
    out = np.where(pooled, fit, np.where(valid, rates, np.nan))
    return out, pooled, spread


def local_mean(values: np.ndarray, weights: np.ndarray, sigma: float,
               origin=(0, 0)) -> np.ndarray:
    """The weighted local mean of ``values`` (already multiplied by ``weights``, shape
    (H, W)) over the support: ``sum K v / sum K w``."""
    sup = _Support(np.shape(weights), sigma, origin)
    with np.errstate(invalid="ignore", divide="ignore"):
        return sup.to_pixels(sup.sums(values) / sup.sums(weights))


def local_spread(values: np.ndarray, weights: np.ndarray, sigma: float,
                 origin=(0, 0)) -> np.ndarray:
    """The local standard deviation of each map about its local linear fit
    (:func:`local_linear_fit`): the weighted root mean square of the residuals over the
    same support.  Shapes as :func:`local_linear_fit`."""
    fit = local_linear_fit(values, weights, sigma, origin)
    w = np.asarray(weights, dtype=float)
    sup = _Support(w.shape, sigma, origin)
    with np.errstate(invalid="ignore", divide="ignore"):
        res = np.where(w > 0, values - fit, 0.0)
        total = sup.sums(w)
        return np.stack([sup.to_pixels(np.sqrt(sup.sums(w * r * r) / total)) for r in res])
