"""Static light fields with exact disparity: textured planes and two-layer scenes.

Each view is sampled from an analytic texture at the position its ray meets the surface
(no interpolation, no noise), in the HCI convention: a centre-view pixel of disparity
``d`` (px per camera step) appears in view ``(r, c)`` at ``(x - d (c - cc), y - d (r -
cc))``, ``cc`` the centre index.  The tests and ``bench/lightfield_study.py`` use them.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plane_views", "layered_views"]


def _texture(rng, mean: float, amp: float, freq: float, terms: int = 6):
    """A smooth random texture: ``mean + amp * sum of terms sinusoids`` of random
    direction and phase, wave numbers ~ N(0, freq) rad/px per axis."""
    k = rng.normal(size=(terms, 2)) * freq
    ph = rng.uniform(0, 2 * np.pi, terms)
    return lambda X, Y: mean + amp * sum(np.sin(k[i, 0] * X + k[i, 1] * Y + ph[i])
                                         for i in range(terms))


def plane_views(n: int = 5, size: int = 96, d0: float = 0.4, slope: float = 0.0,
                seed: int = 0, freq: float = 0.35):
    """A textured fronto-parallel (or x-slanted) plane of disparity ``d0 + slope * x``.

    Parameters
    ----------
    n : int
        Views per side (odd).
    size : int
        Image side, px.
    d0, slope : float
        Disparity at the image centre (px per camera step) and its x gradient.
    seed, freq : int, float
        Texture: random seed and wave-number scale (rad/px).

    Returns
    -------
    views : ndarray, shape (n, n, size, size)
    disparity : ndarray, shape (size, size)
    """
    rng = np.random.default_rng(seed)
    k = rng.normal(size=(6, 2)) * freq
    ph = rng.uniform(0, 2 * np.pi, 6)

    def tex(X, Y):
        return 0.5 + 0.08 * sum(np.sin(k[i, 0] * X + k[i, 1] * Y + ph[i]) for i in range(6))

    cc = n // 2
    y, x = np.mgrid[0:size, 0:size].astype(float)
    xc = x - (size - 1) / 2
    # centre pixel x sees surface point u; in view c it appears at u - d(u) (c - cc)
    # with d = d0 + slope * u: solve x = u - (d0 + slope u) dc for u
    views = np.empty((n, n, size, size))
    for r in range(n):
        for c in range(n):
            dc, dr = c - cc, r - cc
            u = (xc + d0 * dc) / (1 - slope * dc)
            d = d0 + slope * u
            views[r, c] = tex(u, y + d * dr)
    return views, d0 + slope * xc


def layered_views(n: int = 9, size: int = 96, d_fg: float = 0.5, d_bg: float = -1.5,
                  band=(40, 52), seed: int = 0, bands=None):
    """Two fronto-parallel layers, as on the HCI *backgammon* scene: bright textured bands
    in front of a darker, weaker textured background, with exact occlusion.

    Parameters
    ----------
    n, size : int
        Views per side (odd) and image side (px).
    d_fg, d_bg : float
        Disparity of the bands and of the background (px per camera step).
    band : (int, int)
        Rows ``[y0, y1)`` of the centre view the band covers; or several, ``bands``.
    seed : int
        Texture seed.

    Returns
    -------
    views : ndarray, shape (n, n, size, size)
    disparity : ndarray, shape (size, size)
    """
    bands = [band] if bands is None else bands

    def in_band(yy):
        return np.logical_or.reduce([(yy >= b0) & (yy < b1) for b0, b1 in bands])

    rng = np.random.default_rng(seed)
    fg, bg = _texture(rng, 0.7, 0.06, 0.5), _texture(rng, 0.3, 0.03, 0.5)
    cc = n // 2
    y, x = np.mgrid[0:size, 0:size].astype(float)
    views = np.empty((n, n, size, size))
    for r in range(n):
        for c in range(n):
            dc, dr = c - cc, r - cc
            yf = y + d_fg * dr
            views[r, c] = np.where(in_band(yf), fg(x + d_fg * dc, yf),
                                   bg(x + d_bg * dc, y + d_bg * dr))
    return views, np.where(in_band(y), d_fg, d_bg)
