"""Static light fields with disparities beyond the derivative filters' range.

The camera-axis derivative filters see a point's displacement between neighbouring views
only while it is well below one wavelength of the texture: in practice disparities of
about +-1 px per view.  Beyond that this field shears (refocuses) the light field: view
``(r, c)`` shifted by ``s (c - cc)`` pixels in x and ``s (r - cc)`` in y brings points of
disparity ``s`` to disparity 0, so the estimator sees the residual ``d - s`` only.
:func:`estimate_refocused` does so for a set of integer shears (integer shifts move
pixels exactly, with no interpolation) and keeps, per pixel, the estimate of the shear
nearest to a coarse disparity.  The coarse disparity comes from the same estimator on
the light field low-passed in x and y (a Gaussian of ``coarse_sigma`` px): without fine
texture the views' shifts stay within the filters' range even at several pixels per
view, where the fine texture would alias (a shear far from the truth can then fit the
data as well as the right one, which a choice by model error alone falls for).
"""

from __future__ import annotations

import numpy as np

from .core import InputError, estimate

__all__ = ["shear", "estimate_refocused"]


def shear(views: np.ndarray, s: int) -> np.ndarray:
    """Views refocused to disparity ``s``: view (r, c) shifted by ``s (c - cc)`` px in x and
    ``s (r - cc)`` px in y, edges repeated.

    Parameters
    ----------
    views : ndarray, shape (n, n, H, W)
    s : int

    Returns
    -------
    ndarray, shape (n, n, H, W)
    """
    n = views.shape[0]
    cc = n // 2
    out = np.empty_like(views)
    H, W = views.shape[-2:]
    for r in range(n):
        for c in range(n):
            dy, dx = s * (r - cc), s * (c - cc)
            # out(y, x) = view(y - dy, x - dx)
            ys = np.clip(np.arange(H) - dy, 0, H - 1)
            xs = np.clip(np.arange(W) - dx, 0, W - 1)
            out[r, c] = views[r, c][np.ix_(ys, xs)]
    return out


def _lowpass(views: np.ndarray, sigma: float) -> np.ndarray:
    """Each view blurred in x and y by a Gaussian of ``sigma`` px (edges repeated)."""
    r = max(1, int(np.ceil(3 * sigma)))
    x = np.arange(-r, r + 1, dtype=float)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    g /= g.sum()
    H, W = views.shape[-2:]
    out = np.zeros_like(views)
    for o, w in zip(range(-r, r + 1), g):
        out += w * views[..., :, np.clip(np.arange(W) + o, 0, W - 1)]
    res = np.zeros_like(views)
    for o, w in zip(range(-r, r + 1), g):
        res += w * out[..., np.clip(np.arange(H) + o, 0, H - 1), :]
    return res


def estimate_refocused(views: np.ndarray, shifts=(-3, -2, -1, 0, 1, 2, 3), *,
                       sigma: float = 2.0, window: int = 9, filters: str = "matched5",
                       coarse_sigma: float = 2.0, fill: bool = False) -> dict:
    """Disparity of the centre view over a range of integer shears.

    Parameters
    ----------
    views : ndarray, shape (n, n, H, W)
        A static light field, n odd (e.g. the central 5 x 5 of an HCI scene); camera
        steps are the unit of disparity (HCI sign: a centre pixel with disparity d
        appears in view (r, c) at (x - d (c - cc), y - d (r - cc))).
    shifts : sequence of int
        The shears tried; they should cover the scene's disparity range.
    sigma, window, filters
        Estimator settings (:class:`estimator.EstimatorSettings`).
    coarse_sigma : float
        Low-pass of the coarse pass, px; its window is twice ``sigma``.
    fill : bool
        Give pixels without an admissible estimate the normalised convolution (Gaussian,
        ``2 sigma``) of their neighbours' estimates; ``filled`` marks them.

    Returns
    -------
    dict of str to ndarray, each shape (H, W)
        ``disparity``; ``coarse``: the coarse disparity; ``shear``: the shear used (the
        one nearest to the coarse disparity where its estimate is admissible, else the
        admissible one with the smallest model error); ``model_error``: its model error;
        ``confidence``: ``-log10`` of the model error relative to its median over the
        image (larger is better; threshold it to mask); ``valid``: an admissible estimate
        (finite, within half a pixel of its shear); ``filled``: see ``fill``.
    """
    v = np.asarray(views, dtype=np.float64)
    if v.ndim != 4 or v.shape[0] != v.shape[1] or v.shape[0] % 2 == 0:
        raise InputError(f"views must have shape (n, n, H, W) with n odd, got {v.shape}")
    shifts = [int(s) for s in shifts]
    if not shifts or len(set(shifts)) != len(shifts):
        raise InputError(f"shifts must be distinct integers, got {shifts}")
    H, W = v.shape[-2:]
    lo = np.array(sorted(shifts))
    win2 = 2 * (window // 2) * 2 + 1
    coarse = estimate(_lowpass(v, coarse_sigma)[None], float(W), (1.0, 1.0), model="bcc",
                      sigma=2 * sigma, window=win2, filters=filters)["disparity"]
    # the coarse window reaches further: near the border take the nearest coarse value
    bad = ~np.isfinite(coarse)
    if bad.any() and not bad.all():
        from scipy.ndimage import distance_transform_edt

        near = distance_transform_edt(bad, return_distances=False, return_indices=True)
        coarse = coarse[tuple(near)]
    # the shear nearest to the coarse disparity (the nearest end of the range beyond it)
    pick = np.where(np.isfinite(coarse),
                    lo[np.abs(np.nan_to_num(coarse)[..., None] - lo).argmin(-1)], np.nan)
    # every shear over the whole image: the estimate, its model error, admissible where
    # the residual stays within half a pixel of the shear
    D = np.full((lo.size, H, W), np.nan)
    E = np.full((lo.size, H, W), np.inf)
    for n_s, s in enumerate(lo):
        e = estimate(shear(v, int(s))[None], float(W), (1.0, 1.0), model="bcc", sigma=sigma,
                     window=window, filters=filters)
        # a shear moves up to |s| cc pixels of repeated edge into the outer views: keep
        # the pixels whose window stays clear of them
        m = abs(int(s)) * (v.shape[0] // 2)
        clear = np.zeros((H, W), dtype=bool)
        clear[m:H - m, m:W - m] = True
        clear &= (np.roll(np.roll(e.interior, m, 0), m, 1)
                  & np.roll(np.roll(e.interior, -m, 0), -m, 1))
        d = s + e["disparity"]
        ok = clear & np.isfinite(d) & np.isfinite(e["model_error"]) & (np.abs(d - s) <= 0.5)
        D[n_s] = np.where(ok, d, np.nan)
        E[n_s] = np.where(ok, e["model_error"], np.inf)
    # the shear nearest to the coarse disparity where it is admissible; elsewhere the
    # admissible neighbouring shear (one step either side) with the smaller model error;
    # shears further away are not considered: with fine texture an aliased shear can fit
    # as well as the right one
    idx_near = np.where(np.isfinite(pick), np.abs(np.nan_to_num(pick)[None] - lo[:, None, None])
                        .argmin(0), 0)
    rows, cols = np.indices((H, W))
    near_ok = np.isfinite(D[idx_near, rows, cols])
    far = np.abs(np.arange(lo.size)[:, None, None] - idx_near[None]) > 1
    idx_best = np.where(far, np.inf, E).argmin(0)
    idx = np.where(near_ok, idx_near, idx_best)
    disp = D[idx, rows, cols]
    err = np.where(np.isfinite(disp), E[idx, rows, cols], np.nan)
    valid = np.isfinite(disp)
    with np.errstate(divide="ignore", invalid="ignore"):
        med = np.nanmedian(err[valid]) if valid.any() else np.nan
        conf = np.where(valid, -np.log10(err / med), np.nan)
    filled = np.zeros((H, W), dtype=bool)
    if fill and valid.any():
        # normalised convolution of the valid estimates (Gaussian, 2 sigma) into the
        # pixels without one, inside the region the estimator covers
        from scipy.ndimage import gaussian_filter

        w = valid.astype(float)
        num = gaussian_filter(np.where(valid, disp, 0.0), 2 * sigma, mode="nearest")
        den = gaussian_filter(w, 2 * sigma, mode="nearest")
        inside = np.isfinite(D).any(0) | np.isfinite(coarse)
        filled = ~valid & inside & (den > 1e-3)
        disp = np.where(filled, num / np.where(den > 0, den, 1.0), disp)
    return {"disparity": disp, "coarse": coarse, "shear": lo[idx].astype(float),
            "model_error": err, "confidence": conf, "valid": valid, "filled": filled}
