"""The derivative signals of the data rows (Sec. 3, step 1), in numpy.

Every axis of the volume is filtered with a separable prefilter / derivative pair
(:mod:`estimator.filters`).  The camera and time axes come first, at the reference
camera: one weighted sum over the grid's camera taps per frame (:func:`camera_sums`),
then the temporal taps of each frame of the window as one matrix product
(:func:`temporal_taps`).  Then x and y: the base signals ``x, y, sx, sy, t, I`` of
:data:`estimator.models.ROWS` are each one separable 5-tap correlation of those
(:func:`spatial_jobs`, :func:`separable`).

:class:`SignalPlan` holds everything about the filtering that does not depend on the
data (the taps, the frames a band needs, the camera weights), so that an implementation
(:mod:`estimator.backends`) only has to supply the two loops over the data: the camera
sums and the separable filtering.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .filters import FilterPair

__all__ = ["SignalPlan", "signal_plan", "camera_sums", "temporal_taps", "spatial_jobs",
           "separable", "ZOOM_SIGNALS", "FramedVolume", "FrameStack"]

# The zoom-blur correction's base signals (estimator.models.ZOOM_ROW_SIGNALS): the
# prefilter's first moment along the axis of a row's monomial, applied to the row's
# signal.  Along the derivative's own axis that is ``(o p) * ∂I``, given by the pair's
# ``moment_derivative`` kernel; across it ``o p`` itself.  (kernel along x, along y), with
# "p", "d" the pair, "o" its moment and "m" its moment derivative.
ZOOM_SIGNALS = {"zxx": ("m", "p"), "zxy": ("d", "o"), "zyx": ("o", "d"),
                "zyy": ("p", "m"), "zIx": ("o", "p"), "zIy": ("p", "o")}


def _taps(kernel: np.ndarray, centre: int):
    r = kernel.size // 2
    return [(centre + o, float(w)) for o, w in zip(range(-r, r + 1), kernel) if w != 0.0]


@dataclass(frozen=True)
class SignalPlan:
    """How the signals of one volume are filtered (independent of the data).

    Attributes
    ----------
    needed : ndarray of int, shape (F_in,)
        The frames read: those of the temporal window and their temporal filter taps.
    iy0, ix0 : int
        First camera row and column the camera filters read.
    weights : ndarray, shape (C, ny, nx)
        Camera-tap weights (the intensity scale folded in) of the camera signals
        ``combos``: ``"pp"`` (prefiltered along both camera axes), ``"dp"`` (derivative
        along sx), ``"pd"`` (derivative along sy; 2-D grids only).
    combos : tuple of str
    taps : dict of str to ndarray, each shape (F, F_in)
        Temporal taps of the frames of the window over the frames read: ``"p"``
        (prefilter, or the frames as they are without a time axis) and ``"d"``
        (derivative; absent without a time axis).
    spatial : FilterPair
        The x/y pair.
    extra : tuple of str
        The zoom-blur signals (keys of :data:`ZOOM_SIGNALS`) made besides the base ones.
    """

    needed: np.ndarray
    iy0: int
    ix0: int
    weights: np.ndarray
    combos: tuple[str, ...]
    taps: dict
    spatial: FilterPair
    extra: tuple[str, ...] = ()


@dataclass(frozen=True)
class FramedVolume:
    """A volume given frame by frame, for windows of a recording that share frames.

    The estimator takes it wherever it takes a volume.  It reads a frame only through
    ``memo``, for what depends on that frame alone: its camera sums (the first step of
    :func:`camera_sums`, per frame), its largest magnitude (with the finiteness check)
    and the reference view.  A caller that keeps these per frame across the steps of a
    series (``gridflow estimate --every 1``: each frame is in up to 17 windows) lets a
    step sum only its new frames over the views, and no step holds the window itself;
    one that also keeps ``derive``'s values (each frame's filtered signals) lets a step
    filter only its new frames along t, x and y (on the numba backend, a step in one
    band, with no mask).  The maps are those of the same frames given as one array, bit for bit (the
    camera weights' scale is a power of two, applied to the kept sums or, with kept
    signals, to their products, :func:`estimator.driver._unit_scale`; where a float64
    frame's magnitudes leave 2^-400 .. 2^400 the sums are taken again under the scaled
    weights, :data:`estimator.driver._EXACT_RANGE`, and signals are kept only within
    2^-200 .. 2^200, :data:`estimator.driver._KEPT_RANGE`).

    Attributes
    ----------
    shape : tuple of int
        ``(T, Sy, Sx, H, W)``, as the volume it stands for.
    dtype : numpy.dtype
        float32 or float64: the frames' type.
    memo : callable
        ``memo(t, key, fn)``: ``fn(frame)`` for frame ``t`` of the window (``frame`` of
        shape (Sy, Sx, H, W), of ``dtype``); a caller may return a value it kept for
        the same frame and ``key`` instead of calling ``fn`` again.
    derive : callable, optional
        ``derive(t, span, key, fn)``: ``fn()``, a value computed from frames ``span``
        of the window (through ``memo``), such as frame ``t``'s filtered signals from
        the camera sums of the frames its temporal taps reach; a caller may return a
        value it kept for ``t`` and ``key`` while the frames of ``span`` are those it
        was computed from.  With it the estimator keeps each frame's signals (not only
        its sums) for the steps that share the frame, and filters only a step's new
        frames; None (the default) filters the window's signals every step.
    """

    shape: tuple
    dtype: np.dtype
    memo: Callable
    derive: Callable | None = None

    @property
    def ndim(self) -> int:
        return len(self.shape)


@dataclass(frozen=True)
class FrameStack:
    """One base signal of a window given frame by frame, for the tensor's products: the
    frames' own arrays, kept across the steps of a recording that share them, instead
    of one (F, h, W) array assembled per step.

    Attributes
    ----------
    frames : tuple of ndarray, each shape (h, W), float64, C-contiguous
        The signal of each frame of the window, under the unscaled camera weights.
    scale : float
        The window's intensity scale (a power of two, :func:`estimator.driver.
        _unit_scale`): the signal is ``scale`` times ``frames``.  The products take it as
        ``scale^2`` in their frame weights, which gives the same bits as scaled signals
        (a power of two commutes with every rounding while no value leaves the normal
        range).
    """

    frames: tuple
    scale: float

    @property
    def shape(self) -> tuple:
        return (len(self.frames),) + tuple(self.frames[0].shape)


def signal_plan(shape, frames: np.ndarray, cam_x: FilterPair, cam_y: FilterPair | None,
                time: FilterPair | None, spatial: FilterPair, scale: float = 1.0,
                extra: tuple[str, ...] = ()) -> SignalPlan:
    """The filtering of a volume of ``shape`` at its centre camera.

    Parameters
    ----------
    shape : tuple (T, Sy, Sx, H, W)
    frames : ndarray of int, shape (F,)
        Frames of the temporal window; each needs ``time.radius`` frames either side.
    cam_x, cam_y : FilterPair
        Filters across the camera axes, applied at the centre camera.  ``cam_y`` is None
        for a 1-D grid (``Sy = 1``).
    time : FilterPair or None
        None for a light field of one frame (no time axis).
    spatial : FilterPair
    scale : float
        Factor applied to the intensities (folded into the camera weights).
    extra : tuple of str
        Zoom-blur signals to make (keys of :data:`ZOOM_SIGNALS`).
    """
    unknown = [e for e in extra if e not in ZOOM_SIGNALS]
    if unknown:
        raise ValueError(f"unknown zoom-blur signals {unknown}; expected keys of ZOOM_SIGNALS")
    T, Sy, Sx, H, W = shape
    jc, ic = (Sx - 1) // 2, (Sy - 1) // 2
    ys = [(ic, 1.0)] if cam_y is None else _taps(cam_y.prefilter, ic)
    yd = [] if cam_y is None else _taps(cam_y.derivative, ic)
    xs, xd = _taps(cam_x.prefilter, jc), _taps(cam_x.derivative, jc)
    tr_ = 0 if time is None else time.radius
    needed = sorted({int(k) + o for k in frames for o in range(-tr_, tr_ + 1)})
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

    def along_t(kernel: np.ndarray) -> np.ndarray:
        # the temporal taps of every frame as one (F, len(needed)) matrix
        m = np.zeros((len(frames), len(needed)))
        for f, k in enumerate(frames):
            for kk, w in _taps(kernel, int(k)):
                m[f, needed.index(kk)] += w
        return m

    one = np.ones(1)                          # no time axis: the frames as they are
    taps = {"p": along_t(one if time is None else time.prefilter)}
    if time is not None:
        taps["d"] = along_t(time.derivative)
    return SignalPlan(np.asarray(needed, dtype=np.int64), iy[0], ix[0],
                      np.ascontiguousarray(np.stack(list(combos.values()))),
                      tuple(combos), taps, spatial, tuple(extra))


def camera_sums(volume: np.ndarray, plan: SignalPlan, rows: slice) -> np.ndarray:
    """``out[c, j] = sum_(i, l) weights[c, i, l] * volume[needed[j], iy0 + i, ix0 + l, rows]``.

    Parameters
    ----------
    volume : ndarray, shape (T, Sy, Sx, H, W)
    plan : SignalPlan
    rows : slice
        Image rows (a band); only views of the volume are read.

    Returns
    -------
    ndarray, shape (C, F_in, h, W), float64
    """
    weights, needed = plan.weights, plan.needed
    ny, nx = weights.shape[1:]
    ysl, xsl = slice(plan.iy0, plan.iy0 + ny), slice(plan.ix0, plan.ix0 + nx)
    first = volume[needed[0], ysl, xsl, rows]
    out = np.empty((weights.shape[0], len(needed)) + first.shape[2:])
    for j, k in enumerate(needed):
        block = volume[k, ysl, xsl, rows]              # view (ny, nx, h, W)
        for c in range(weights.shape[0]):
            out[c, j] = np.einsum("ij,ijhw->hw", weights[c], block, dtype=np.float64,
                                  optimize=False)
    return out


def temporal_taps(sums: np.ndarray, plan: SignalPlan) -> dict[str, np.ndarray]:
    """The camera sums filtered along time: the camera/time signals.

    Parameters
    ----------
    sums : ndarray, shape (C, F_in, h, W)
        From :func:`camera_sums` (or an implementation with the same result).
    plan : SignalPlan

    Returns
    -------
    dict of str to ndarray, each shape (F, h, W), float64
        ``"p"``: prefiltered along sx, sy, t; ``"sx"``, ``"sy"``, ``"t"``: derivative
        along that axis, prefiltered along the others (``"sy"`` absent for 1-D grids,
        ``"t"`` without a time axis).
    """
    cams = dict(zip(plan.combos, sums))
    out = {"p": _taps_sum(plan.taps["p"], cams["pp"]),
           "sx": _taps_sum(plan.taps["p"], cams["dp"])}
    if "d" in plan.taps:
        out["t"] = _taps_sum(plan.taps["d"], cams["pp"])
    if "pd" in cams:
        out["sy"] = _taps_sum(plan.taps["p"], cams["pd"])
    return out


def _taps_sum(taps: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """``out[f] = sum_j taps[f, j] frames[j]``, the terms added one at a time in the
    order of ``j``.

    Not ``np.tensordot``: BLAS orders (and fuses) the sums by the machine's CPU and its
    thread count, so the signals, and every estimate after them, would differ in the
    last bits from one machine to another (a result that cannot be reproduced to the
    byte).  Elementwise products and sums are IEEE-exact whatever the SIMD width.
    """
    out = np.zeros((taps.shape[0],) + frames.shape[1:])
    tmp = np.empty(frames.shape[1:])
    for f in range(taps.shape[0]):
        for j in np.flatnonzero(taps[f]):
            np.multiply(frames[j], taps[f, j], out=tmp)
            out[f] += tmp
    return out


def spatial_jobs(ct: dict[str, np.ndarray], spatial: FilterPair,
                 extra: tuple[str, ...] = ()) -> dict[str, tuple]:
    """The x/y filtering that gives each base signal of the data rows.

    Parameters
    ----------
    ct : dict of str to ndarray, each shape (F, h, W)
        From :func:`temporal_taps`.
    spatial : FilterPair
    extra : tuple of str
        Zoom-blur signals (keys of :data:`ZOOM_SIGNALS`) to add, filtered from the same
        prefiltered camera/time signal as ``"x", "y", "I"``.

    Returns
    -------
    dict of str to (ndarray (F, h, W), kx, ky)
        ``"x", "y", "I", "sx"`` and, where ``ct`` has them, ``"t", "sy"``, then
        ``extra``: the source and the correlation kernels along x and y.  Filtered (:func:`separable`), rows within
        ``spatial.radius`` of a band's edges are not valid.
    """
    p, d = spatial.prefilter, spatial.derivative
    base = ct["p"]
    jobs = {"x": (base, d, p), "y": (base, p, d), "I": (base, p, p),
            "sx": (ct["sx"], p, p)}
    if "t" in ct:
        jobs["t"] = (ct["t"], p, p)
    if "sy" in ct:
        jobs["sy"] = (ct["sy"], p, p)
    kernels = {"p": p, "d": d, "o": spatial.moment, "m": spatial.moment_derivative}
    for name in extra:
        kx, ky = ZOOM_SIGNALS[name]
        jobs[name] = (base, kernels[kx], kernels[ky])
    return jobs


def separable(a: np.ndarray, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
    """``a`` (F, h, W) correlated with ``kx`` along x, then with ``ky`` along y, edge
    values repeated (``scipy.ndimage.correlate1d(..., mode="nearest")`` twice)."""
    return _correlate_nearest(_correlate_nearest(np.asarray(a, dtype=np.float64), kx, -1),
                              ky, -2)


def _correlate_nearest(a: np.ndarray, k: np.ndarray, axis: int) -> np.ndarray:
    """``out[i] = sum_j k[j] a[i + j - r]`` along ``axis`` with edge values repeated
    beyond the ends; a short filter as a sum of shifted slices, so the estimator's signal
    path does not need scipy."""
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
