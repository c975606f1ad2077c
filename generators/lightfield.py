"""Static light fields with exact disparity: textured planes, two-layer scenes, a
smooth wall in front of a slanted textured plane and a periodic pattern behind a box.

Each view is sampled from an analytic texture at the position its ray meets the surface
(no interpolation, no noise), in the HCI convention: a centre-view pixel of disparity
``d`` (px per camera step) appears in view ``(r, c)`` at ``(x - d (c - cc), y - d (r -
cc))``, ``cc`` the centre index.  The tests and ``bench/lightfield_study.py`` use them.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plane_views", "layered_views", "crossing_views", "smooth_wall_views",
           "periodic_views"]


def _texture(rng, mean: float, amp: float, freq: float, terms: int = 6):
    """A smooth random texture: ``mean + amp * sum of terms sinusoids`` of random
    direction and phase, wave numbers ~ N(0, freq) rad/px per axis."""
    k = rng.normal(size=(terms, 2)) * freq
    ph = rng.uniform(0, 2 * np.pi, terms)
    return lambda X, Y: mean + amp * sum(np.sin(k[i, 0] * X + k[i, 1] * Y + ph[i])
                                         for i in range(terms))


def _sensor(views: np.ndarray, rng, noise: float, bits: int | None) -> np.ndarray:
    """``views`` as a camera records them: Gaussian noise of ``noise`` (intensities
    0..1) added from ``rng``, then quantised to ``bits`` bits (None or 0: not at all)."""
    if noise > 0:
        views = views + rng.normal(0.0, noise, views.shape)
    if bits:
        q = 2 ** bits - 1
        views = np.round(np.clip(views, 0.0, 1.0) * q) / q
    return views


def _slanted_plane(xc, d0: float, slope: float, dc: int):
    """The point ``u`` (px from the image centre, along x) of the plane of disparity
    ``d0 + slope * u`` that pixel column ``xc`` of the view ``dc`` camera steps off the
    centre sees, and its disparity: the point appears in that view at ``u - d(u) dc``, so
    ``xc = u - (d0 + slope u) dc`` solved for ``u``."""
    u = (xc + d0 * dc) / (1 - slope * dc)
    return u, d0 + slope * u


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
    views = np.empty((n, n, size, size))
    for r in range(n):
        for c in range(n):
            dc, dr = c - cc, r - cc
            u, d = _slanted_plane(xc, d0, slope, dc)
            views[r, c] = tex(u, y + d * dr)
    return views, d0 + slope * xc


def layered_views(n: int = 9, size: int = 96, d_fg: float = 0.5, d_bg: float = -1.5,
                  band=(40, 52), seed: int = 0, bands=None, inside=None):
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
    inside : callable, optional
        ``inside(x, y)`` (arrays of the foreground's own coordinates, those of the
        centre view) true where the foreground is: any shape instead of the bands.
    seed : int
        Texture seed.

    Returns
    -------
    views : ndarray, shape (n, n, size, size)
    disparity : ndarray, shape (size, size)
    """
    bands = [band] if bands is None else bands

    def in_band(yy, xx):
        if inside is not None:
            return inside(xx, yy)
        return np.logical_or.reduce([(yy >= b0) & (yy < b1) for b0, b1 in bands])

    rng = np.random.default_rng(seed)
    fg, bg = _texture(rng, 0.7, 0.06, 0.5), _texture(rng, 0.3, 0.03, 0.5)
    cc = n // 2
    y, x = np.mgrid[0:size, 0:size].astype(float)
    views = np.empty((n, n, size, size))
    for r in range(n):
        for c in range(n):
            dc, dr = c - cc, r - cc
            yf, xf = y + d_fg * dr, x + d_fg * dc
            views[r, c] = np.where(in_band(yf, xf), fg(xf, yf),
                                   bg(x + d_bg * dc, y + d_bg * dr))
    return views, np.where(in_band(y, x), d_fg, d_bg)


def crossing_views(n: int = 9, size: int = 192, bar: int = 8, gap: int = 4,
                   d_fg: float = 0.5, d_bg: float = -1.5, seed: int = 5):
    """Thin foreground bars in both directions (:func:`layered_views` with a shape):
    bars of ``bar`` px with gaps of ``gap`` px, running along x in the image's left half
    and along y in its right half (the region from 4 px right of the middle), rows 20 to
    ``size - 20``; the same exact occlusion.

    Returns
    -------
    views : ndarray, shape (n, n, size, size)
    disparity : ndarray, shape (size, size)
    """
    period = bar + gap

    def inside(x, y):
        rows = (y >= 20) & (y < size - 20)
        along_x = (x < size / 2) & ((y - 20) % period < bar)
        along_y = (x >= size / 2 + 4) & ((x - 20) % period < bar)
        return rows & (along_x | along_y)

    return layered_views(n=n, size=size, d_fg=d_fg, d_bg=d_bg, seed=seed, inside=inside)


def smooth_wall_views(n: int = 9, size: int = 256, d_range=(-3.0, 2.4), d_wall: float = 1.0,
                      wall=(0.15, 0.95, 0.2, 0.95), shading: float = 0.0,
                      wavelength: float = 120.0, noise: float = 0.0, bits: int | None = 8,
                      seed: int = 0, bar=None):
    """A smooth wall and a textured plane slanted in x through it, as on HCI scenes with
    large texture-poor regions: a fronto-parallel rectangle of disparity ``d_wall`` shaded
    by at most ``shading`` (a product of sinusoids of ``wavelength`` px; 0: uniform), and
    a plane whose disparity runs linearly from ``d_range[0]`` (left edge) to
    ``d_range[1]`` (right edge); each ray sees the nearer of the two (the larger
    disparity): the wall occludes the plane where the plane lies behind it, and the plane
    cuts through the wall where it comes nearer.  Exact occlusion; optional Gaussian
    sensor noise, then quantisation to ``bits`` bits, as an 8-bit camera's images.
    Optionally a thin fronto-parallel bar in front (``bar``), textured as the plane with
    its contrast scaled, the nearest of the three where its ray meets it.

    Parameters
    ----------
    n, size : int
        Views per side (odd) and image side (px).
    d_range : (float, float)
        The plane's disparity at the left and the right edge (px per camera step).
    d_wall : float
        The wall's disparity.
    wall : (float, float, float, float)
        The wall's rows and columns in the centre view, ``(y0, y1, x0, x1)`` as fractions
        of the image side.
    shading, wavelength : float
        The wall's intensity variation (0.6 +- shading) and its wavelength (px).
    noise : float
        Standard deviation of Gaussian noise added to every view (intensities 0..1).
    bits : int or None
        Quantise to this many bits (None: not at all).
    seed : int
        Texture and noise seed.
    bar : (int, int, int, int, float, float), optional
        ``(x0, x1, y0, y1, d_bar, contrast)``: the bar's columns ``[x0, x1)`` and rows
        ``[y0, y1)`` in the centre view (px), its disparity and its texture's contrast
        relative to the plane's (``0.45 + contrast (texture - 0.45)``).

    Returns
    -------
    views : ndarray, shape (n, n, size, size)
    disparity : ndarray, shape (size, size)
    """
    rng = np.random.default_rng(seed)
    tex = _texture(rng, 0.45, 0.08, 0.35)
    cc = n // 2
    y, x = np.mgrid[0:size, 0:size].astype(float)
    xc = x - (size - 1) / 2
    slope = (d_range[1] - d_range[0]) / (size - 1)
    d0 = (d_range[1] + d_range[0]) / 2
    y0, y1, x0, x1 = (int(f * size) for f in wall)
    views = np.empty((n, n, size, size))
    for r in range(n):
        for c in range(n):
            dc, dr = c - cc, r - cc
            u, d_plane = _slanted_plane(xc, d0, slope, dc)
            plane = tex(u, y + d_plane * dr)
            xf, yf = x + d_wall * dc, y + d_wall * dr
            # the wall where its ray meets it first (the larger disparity is the nearer)
            on_wall = ((yf >= y0) & (yf < y1) & (xf >= x0) & (xf < x1)
                       & (d_wall >= d_plane))
            shade = 0.6 + shading * (np.sin(2 * np.pi * xf / wavelength)
                                     * np.cos(2 * np.pi * yf / wavelength))
            views[r, c] = np.where(on_wall, shade, plane)
            if bar is not None:
                bx0, bx1, by0, by1, d_bar, contrast = bar
                xb, yb = x + d_bar * dc, y + d_bar * dr
                on_bar = ((yb >= by0) & (yb < by1) & (xb >= bx0) & (xb < bx1)
                          & (d_bar >= np.where(on_wall, d_wall, d_plane)))
                views[r, c] = np.where(on_bar, 0.45 + contrast * (tex(xb, yb) - 0.45),
                                       views[r, c])
    views = _sensor(views, rng, noise, bits)
    d_plane = d0 + slope * xc
    on_wall = (y >= y0) & (y < y1) & (x >= x0) & (x < x1) & (d_wall >= d_plane)
    truth = np.where(on_wall, d_wall, d_plane)
    if bar is not None:
        bx0, bx1, by0, by1, d_bar, _ = bar
        on_bar = (y >= by0) & (y < by1) & (x >= bx0) & (x < bx1) & (d_bar >= truth)
        truth = np.where(on_bar, d_bar, truth)
    return views, truth


def periodic_views(n: int = 9, size: int = 192, period: float = 4.0, d_bg: float = -1.5,
                   d_box: float = 2.5, box=(0.3, 0.7), contrast: float = 0.1,
                   shading: float = 0.04, wavelength: float = 60.0, noise: float = 0.0,
                   bits: int | None = 8, seed: int = 0):
    """A fine periodic pattern behind a textured box: where a shear a whole number of
    periods per camera step away fits the pattern as well as the right one (aliasing).

    The background is a fronto-parallel plane of disparity ``d_bg`` with a grid of
    ``0.35 + contrast * (sin(2 pi x / period) + sin(2 pi y / period)) / 2`` (within
    ``contrast`` of 0.35) over a faint smooth
    shading (``shading``: a product of sinusoids of ``wavelength`` px, what a low-pass
    keeps of the scene).  Shifting each view ``(r, c)`` by ``Δ (c - cc), Δ (r - cc)`` with
    ``Δ`` a multiple of ``period`` maps the grid onto itself, so at ``d_bg + Δ`` only the
    shading tells the shears apart.  In front, a square box (rows and columns ``box``,
    fractions of the image side) of disparity ``d_box`` with a random texture brings
    ``d_bg + period`` (the default: 2.5 px per view) into the scene's range.  Exact
    occlusion; optional Gaussian sensor noise, then quantisation to ``bits`` bits.

    Parameters
    ----------
    n, size : int
        Views per side (odd) and image side (px).
    period : float
        The grid's period, px.
    d_bg, d_box : float
        Disparity of the background and of the box (px per camera step).
    box : (float, float)
        First and last fraction of the image side the box covers, in x and y.
    contrast, shading, wavelength : float
        The grid's amplitude (its intensity lies within ``contrast`` of 0.35), the
        shading's amplitude and its wavelength (px).
    noise : float
        Standard deviation of Gaussian noise added to every view (intensities 0..1).
    bits : int or None
        Quantise to this many bits (None: not at all).
    seed : int
        Texture and noise seed.

    Returns
    -------
    views : ndarray, shape (n, n, size, size)
    disparity : ndarray, shape (size, size)
    """
    rng = np.random.default_rng(seed)
    tex = _texture(rng, 0.6, 0.06, 0.4)
    cc = n // 2
    y, x = np.mgrid[0:size, 0:size].astype(float)
    b0, b1 = (int(f * size) for f in box)
    views = np.empty((n, n, size, size))
    for r in range(n):
        for c in range(n):
            dc, dr = c - cc, r - cc
            xb, yb = x + d_bg * dc, y + d_bg * dr
            grid = 0.35 + contrast * 0.5 * (np.sin(2 * np.pi * xb / period)
                                             + np.sin(2 * np.pi * yb / period))
            shade = shading * (np.sin(2 * np.pi * xb / wavelength)
                               * np.cos(2 * np.pi * yb / wavelength))
            xf, yf = x + d_box * dc, y + d_box * dr
            # the box where its ray meets it first (the larger disparity is the nearer)
            on_box = (yf >= b0) & (yf < b1) & (xf >= b0) & (xf < b1) & (d_box >= d_bg)
            views[r, c] = np.where(on_box, tex(xf, yf), grid + shade)
    views = _sensor(views, rng, noise, bits)
    on_box = (y >= b0) & (y < b1) & (x >= b0) & (x < b1) & (d_box >= d_bg)
    return views, np.where(on_box, d_box, d_bg)
