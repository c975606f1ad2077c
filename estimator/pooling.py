"""Pooling the affine model's depth motion and tilt rates over the leaf (beyond the paper).

Per pixel, the affine model tells growth from depth motion and tilt by the change of the
disparity in time (``v_t, z_x,t, z_y,t``), a tiny signal: its noise, carried through the
9 x 9 solve, dominates the growth map's.  The image flow and its gradient (the other six
observations) are well determined per pixel.  On a plane that moves and turns as a
whole the rates are simple functions of the pixel (``docs/model.md``, *Pooled depth
rates*): ``z_x = Z_x / c`` and ``z_y = Z_y / c`` are constant, ``v_t`` is affine in
``x, y``, ``z_x,t`` and ``z_y,t`` are constant, whatever the growth pattern in the plane.
A local linear fit of each rate over a Gaussian support much wider than the estimator's
window keeps that exactly and averages the noise over the support; the per-pixel 9 x 9
solve then takes the pooled rates with the pixel's own flow and flow gradient.

Where a rate departs from its fit by more than ``k`` times the residuals' local spread
(a fold, an edge, a second leaf), the pixel keeps its own rates (the per-pixel solution)
and the fit is redone without it; the map ``pooled`` says which.

Numerics only (scipy.ndimage's Gaussian filter); everything a pixel's result reads lies
within :func:`pool_reach` pixels, so a row band with that many more rows either side
gives the whole image's result.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

__all__ = ["POOLED_RATES", "pool_reach", "local_linear_fit", "pool_rates"]

# the per-pixel quantities pooled: the projected slopes and the rates of the disparity
# and of the projected slopes at a fixed pixel
POOLED_RATES = ("zx", "zy", "v_t", "zx_t", "zy_t")

# the Gaussian is cut at this many standard deviations (scipy's default 4 would widen
# the reach by a third for weights below 3e-4 of the peak)
_TRUNCATE = 3.0

# a pixel whose rate lies further than this many local standard deviations of the
# residual from the fit keeps its own rates: at 4 sd a Gaussian residual crosses it at
# 6e-5 of the pixels (times the five rates), so under noise alone nearly every pixel is
# pooled
OUTLIER_SD = 4.0


def _radius(sigma: float) -> int:
    return int(math.ceil(_TRUNCATE * sigma))


def pool_reach(sigma: float) -> int:
    """Pixels either side whose per-pixel rates a pixel's pooled rates read: two passes
    (the fit that finds the outliers, then the fit without them) of a Gaussian of
    standard deviation ``sigma`` cut at 3 ``sigma``.  0 when ``sigma`` is 0 (no pooling).
    """
    return 0 if sigma == 0 else 2 * _radius(sigma)


def _smooth(a: np.ndarray, sigma: float) -> np.ndarray:
    # zeros outside the image: together with the weights' own smoothing this is the
    # normalized convolution (Knutsson & Westin) of the samples inside
    return ndimage.gaussian_filter(a, sigma, mode="constant", cval=0.0, truncate=_TRUNCATE)


def local_linear_fit(values: np.ndarray, weights: np.ndarray, sigma: float) -> np.ndarray:
    """Weighted local linear regression of each map on the pixel coordinates.

    At each pixel ``p`` the fit minimises ``sum_q K(q - p) w_q (v_q - a - b (x_q - x_p) -
    c (y_q - y_p))^2`` with ``K`` a Gaussian of standard deviation ``sigma`` (cut at 3
    ``sigma``) and returns ``a``: exact for values affine in ``x, y``, and a weighted
    average elsewhere.  Where the weights do not determine a plane (fewer than three
    weighted pixels in line), NaN.

    Parameters
    ----------
    values : ndarray, shape (K, H, W)
        Maps to fit; read only where ``weights > 0``.
    weights : ndarray, shape (H, W)
        Non-negative sample weights (0 drops a pixel).
    sigma : float
        Pixels.

    Returns
    -------
    ndarray, shape (K, H, W)
    """
    H, W = weights.shape
    # coordinates relative to the image centre keep the moments' magnitudes near
    # sigma^2, whatever the image size
    y = (np.arange(H, dtype=float) - (H - 1) / 2.0)[:, None]
    x = (np.arange(W, dtype=float) - (W - 1) / 2.0)[None, :]
    w = np.asarray(weights, dtype=float)
    m = {k: _smooth(w * f, sigma) for k, f in
         (("1", 1.0), ("x", x), ("y", y), ("xx", x * x), ("xy", x * y), ("yy", y * y))}
    # the moments about each pixel p: sum K w (x_q - x_p)^i (y_q - y_p)^j
    s0 = m["1"]
    sx = m["x"] - x * s0
    sy = m["y"] - y * s0
    sxx = m["xx"] - 2 * x * m["x"] + x * x * s0
    sxy = m["xy"] - x * m["y"] - y * m["x"] + x * y * s0
    syy = m["yy"] - 2 * y * m["y"] + y * y * s0
    A = np.stack([np.stack([s0, sx, sy], -1), np.stack([sx, sxx, sxy], -1),
                  np.stack([sy, sxy, syy], -1)], -2)            # (H, W, 3, 3)
    ok = np.linalg.det(A) > 1e-9 * np.maximum(s0, 1e-300) ** 3 * sigma ** 4
    A[~ok] = np.eye(3)
    out = np.empty(np.shape(values), dtype=float)
    for k, v in enumerate(values):
        wv = w * np.where(w > 0, v, 0.0)
        b0 = _smooth(wv, sigma)
        bx = _smooth(wv * x, sigma) - x * b0
        by = _smooth(wv * y, sigma) - y * b0
        coef = np.linalg.solve(A, np.stack([b0, bx, by], -1)[..., None])[..., 0, 0]
        out[k] = np.where(ok, coef, np.nan)
    return out


def pool_rates(rates: np.ndarray, valid: np.ndarray, sigma: float,
               k: float = OUTLIER_SD) -> tuple[np.ndarray, np.ndarray]:
    """The rates pooled over a Gaussian support, the outliers keeping their own.

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

    Returns
    -------
    rates : ndarray, shape (K, H, W)
        Pooled at pooled pixels, the pixel's own at outliers, NaN outside ``valid``.
    pooled : ndarray of bool, shape (H, W)
        Where the pooled rates were used.
    """
    valid = valid & np.isfinite(rates).all(0)
    w = valid.astype(float)
    fit = local_linear_fit(rates, w, sigma)
    with np.errstate(invalid="ignore", divide="ignore"):
        res = np.where(valid, rates - fit, 0.0)
        spread = np.sqrt(np.stack([_smooth(w * r * r, sigma) for r in res])
                         / _smooth(w, sigma))
        outlier = (np.abs(res) > k * spread).any(0)
    keep = valid & ~outlier
    fit = local_linear_fit(rates, keep.astype(float), sigma)
    pooled = keep & np.isfinite(fit).all(0)
    out = np.where(pooled, fit, np.where(valid, rates, np.nan))
    return out, pooled
