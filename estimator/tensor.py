"""Derivative signals and the structure tensor J (Sec. 3, steps 1-2).

``J = sum_Omega w d d^T`` over a neighbourhood that is Gaussian in x and y (the paper's
65-tap, sigma = 16 window) and uniform over the frames of the temporal window, at the
reference camera.  Rows with ``Δx, Δy`` are not formed per neighbourhood: the sum
``sum_Δ w(Δ) Δ^k g(c + Δ)`` is a correlation of ``g`` with the kernel ``w(Δ) Δ^k``.

Two implementations give the same J:

* :func:`structure_tensor` groups the 120 entries by the product of base signals they
  share, sums frames before the (linear) spatial smoothing, and reuses the x-pass across
  the y-moments.
* :func:`structure_tensor_reference` is the straightforward one: frames summed, then every
  entry its own separable correlation.  It is kept for checking and as the baseline of
  ``bench/``.
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np

from .filters import FilterPair
from .models import ROWS

__all__ = ["camera_time_signals", "spatial_signals", "gaussian_moment_kernels",
           "structure_tensor", "structure_tensor_reference"]


def _taps(kernel: np.ndarray, centre: int):
    r = kernel.size // 2
    return [(centre + o, float(w)) for o, w in zip(range(-r, r + 1), kernel) if w != 0.0]


def _camera_sums_numpy(volume, needed, iy0, ix0, rows, weights):
    """``out[c, j] = sum_(i, l) weights[c, i, l] * volume[needed[j], iy0 + i, ix0 + l, rows]``.

    Shapes: weights (C, ny, nx); returns (C, len(needed), h, W), float64."""
    ny, nx = weights.shape[1:]
    ysl, xsl = slice(iy0, iy0 + ny), slice(ix0, ix0 + nx)
    first = volume[needed[0], ysl, xsl, rows]
    out = np.empty((weights.shape[0], len(needed)) + first.shape[2:])
    for j, k in enumerate(needed):
        block = volume[k, ysl, xsl, rows]              # view (ny, nx, h, W)
        for c in range(weights.shape[0]):
            out[c, j] = np.einsum("ij,ijhw->hw", weights[c], block, dtype=np.float64,
                                  optimize=False)
    return out


def camera_time_signals(volume: np.ndarray, frames: np.ndarray, cam_x: FilterPair,
                        cam_y: FilterPair | None, time: FilterPair,
                        rows: slice = slice(None), scale: float = 1.0,
                        camera_sums=None) -> dict[str, np.ndarray]:
    """Filter the camera and time axes at the reference camera.

    Parameters
    ----------
    volume : ndarray, shape (T, Sy, Sx, H, W)
    frames : ndarray of int, shape (F,)
        Frames of the temporal window; each needs ``time.radius`` frames either side.
    cam_x, cam_y : FilterPair
        Filters across the camera axes, applied at the centre camera.  ``cam_y`` is None
        for a 1-D grid (``Sy = 1``).
    time : FilterPair or None
        None for a light field of one frame (no time axis).
    rows : slice
        Image rows to process (a band); only views of the volume are taken, so memory
        grows with the band, not the volume.
    scale : float
        Factor applied to the intensities (folded into the camera weights).
    camera_sums : callable, optional
        ``camera_sums(volume, needed, iy0, ix0, rows, weights)``: the weighted sums over
        the camera taps (see ``_camera_sums_numpy``, the default); the fast path passes a
        parallel kernel with the same result.

    Returns
    -------
    dict of str to ndarray, each shape (F, h, W), float64
        ``"p"``: prefiltered along sx, sy, t; ``"sx"``, ``"sy"``, ``"t"``: derivative
        along that axis, prefiltered along the others (``"sy"`` absent for 1-D grids).
    """
    T, Sy, Sx, H, W = volume.shape
    jc, ic = (Sx - 1) // 2, (Sy - 1) // 2
    ys = [(ic, 1.0)] if cam_y is None else _taps(cam_y.prefilter, ic)
    yd = [] if cam_y is None else _taps(cam_y.derivative, ic)
    xs, xd = _taps(cam_x.prefilter, jc), _taps(cam_x.derivative, jc)
    tr_ = 0 if time is None else time.radius
    needed = sorted({int(k) + o for k in frames for o in range(-tr_, tr_ + 1)})
    # Camera axes first, per frame: one weighted sum over the grid's (sy, sx) taps, so
    # every array below is (h, W) or (F, h, W) and only views of the volume are read.
    iy = sorted({i for i, _ in ys} | {i for i, _ in yd})
    ix = sorted({j for j, _ in xs} | {j for j, _ in xd})

    def weights(ytaps, xtaps):
        w = np.zeros((len(iy), len(ix)))
        for i, wy in ytaps:
            for j, wx in xtaps:
                w[iy.index(i), ix.index(j)] = wy * wx
        return w

    combos = {"pp": scale * weights(ys, xs), "dp": scale * weights(ys, xd)}
    if cam_y is not None:
        combos["pd"] = scale * weights(yd, xs)
    sums = (camera_sums or _camera_sums_numpy)(
        volume, np.asarray(needed, dtype=np.int64), iy[0], ix[0], rows,
        np.ascontiguousarray(np.stack(list(combos.values()))))
    cams = {key: sums[c] for c, key in enumerate(combos)}

    def along_t(src: np.ndarray, kernel: np.ndarray) -> np.ndarray:
        # the temporal taps of every frame as one (F, len(needed)) matrix: one BLAS
        # product over the band instead of F weighted sums of images
        taps = np.zeros((len(frames), len(needed)))
        for f, k in enumerate(frames):
            for kk, w in _taps(kernel, int(k)):
                taps[f, needed.index(kk)] += w
        return np.tensordot(taps, src, axes=1)

    one = np.ones(1)                          # no time axis: the frames as they are
    out = {"p": along_t(cams["pp"], one if time is None else time.prefilter),
           "sx": along_t(cams["dp"], one if time is None else time.prefilter)}
    if time is not None:
        out["t"] = along_t(cams["pp"], time.derivative)
    if cam_y is not None:
        out["sy"] = along_t(cams["pd"], one if time is None else time.prefilter)
    return out


def spatial_signals(ct: dict[str, np.ndarray], spatial: FilterPair,
                    separable=None) -> dict[str, np.ndarray]:
    """Filter x and y, giving the base signals of the data rows.

    Parameters
    ----------
    ct : dict of str to ndarray, each shape (F, h, W)
        Output of :func:`camera_time_signals` (possibly a band of rows).
    spatial : FilterPair
    separable : callable, optional
        ``separable(a, kx, ky)``: ``a`` (F, h, W) correlated with ``kx`` along x and ``ky``
        along y, edges repeated; default numpy on a thread pool, the fast path passes a
        parallel kernel with the same result.

    Returns
    -------
    dict of str to ndarray, each shape (F, h, W), float64
        ``"x", "y", "sx", "sy", "t", "I"`` (``"sy"`` only if present in ``ct``).  Rows
        within ``spatial.radius`` of the band's edges are not valid.
    """
    from concurrent.futures import ThreadPoolExecutor

    p, d = spatial.prefilter, spatial.derivative

    def sep(job):
        a, kx, ky = job
        return _correlate_nearest(_correlate_nearest(np.asarray(a, dtype=np.float64), kx, -1),
                                  ky, -2)

    base = ct["p"]
    jobs = {"x": (base, d, p), "y": (base, p, d), "I": (base, p, p),
            "sx": (ct["sx"], p, p)}
    if "t" in ct:
        jobs["t"] = (ct["t"], p, p)
    if "sy" in ct:
        jobs["sy"] = (ct["sy"], p, p)
    if separable is not None:
        return {k: separable(a, kx, ky) for k, (a, kx, ky) in jobs.items()}
    # numpy releases the GIL in its loops: the six signals are filtered on all cores
    with ThreadPoolExecutor() as ex:
        return dict(zip(jobs, ex.map(sep, jobs.values())))


def _correlate_nearest(a: np.ndarray, k: np.ndarray, axis: int) -> np.ndarray:
    """``out[i] = sum_j k[j] a[i + j - r]`` along ``axis`` with edge values repeated
    beyond the ends (``scipy.ndimage.correlate1d(..., mode="nearest")``); a short filter
    as a sum of shifted slices, so the estimator's signal path does not need scipy."""
    a = np.moveaxis(a, axis, -1)
    r = k.size // 2
    n = a.shape[-1]
    pad = np.concatenate([np.repeat(a[..., :1], r, axis=-1), a,
                          np.repeat(a[..., -1:], r, axis=-1)], axis=-1)
    out = k[0] * pad[..., 0:n]
    for j in range(1, k.size):
        if k[j] != 0.0:
            out += k[j] * pad[..., j:j + n]
    return np.moveaxis(out, -1, axis)


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
    w = np.exp(-0.5 * (delta / sigma) ** 2)
    w /= w.sum()
    return np.stack([w, w * delta, w * delta ** 2])


def _entry_keys(rows: tuple[str, ...]):
    """For each upper-triangle entry: (a, b, signal pair, t-power, x-power, y-power)."""
    keys = []
    for a, b in combinations_with_replacement(range(len(rows)), 2):
        sa, ta, ma = ROWS[rows[a]]
        sb, tb, mb = ROWS[rows[b]]
        mono = ma + mb
        keys.append((a, b, tuple(sorted((sa, sb))), ta + tb, mono.count("x"), mono.count("y")))
    return keys


def _entry_groups(rows: tuple[str, ...]) -> dict[tuple, list]:
    """Upper-triangle entries grouped by the (signal pair, t-power) product they share."""
    groups: dict[tuple, list] = {}
    for key in _entry_keys(rows):
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
    for (pair, tpow), entries in _entry_groups(rows).items():
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
    for a, b, pair, tpow, px, py in _entry_keys(rows):
        coef = tvals.astype(float) ** tpow / F
        prod = np.einsum("f,fhw,fhw->hw", coef, signals[pair[0]], signals[pair[1]])
        J[..., a, b] = _smooth(prod, kernels[px], kernels[py], halo)
        J[..., b, a] = J[..., a, b]
    return J
