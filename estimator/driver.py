"""The public driver: from a camera-grid volume to per-pixel depth, slopes, motion and
brightness change.

:func:`estimate_models` checks the input and the settings and turns them into a
:class:`Plan` (filters per axis, the temporal window, the camera geometry); then, band by
band of image rows, a backend (:mod:`estimator.backends`, chosen once from the method)
filters the signals, forms the structure tensor and solves each model's null space, and
:func:`estimator.disentangle.disentangle` turns the parameter vectors into world units.
``docs/architecture.md`` follows one call through the modules.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .backends import TensorPlan, backend_class, select_backend
from .disentangle import disentangle, solve_affine
from .filters import FilterPair, get_filter_pair
from .masks import MIN_OBJECT_WEIGHT, object_window
from .models import (BRIGHTNESS_MODELS, MODELS, MOTION_MODELS, ZOOM_ROW_SIGNALS, Model,
                     covering_rows, get_model, one_frame_problem, zoom_rows)
from .pooling import (bell, bell_radius, bell_square_sum, fit_variance, local_linear_fit,
                      local_mean, local_spread, pool_rates, pool_reach, support_radius,
                      texture_reach, textured_windows)
from .result import Estimate
from .settings import EstimatorSettings, InputError
from .signals import FramedVolume, FrameStack, SignalPlan, signal_plan
from .tensor import gaussian_moment_kernels, scaled, zoom_corrected, zoom_terms

__all__ = ["Estimate", "EstimatorSettings", "InputError", "estimate", "estimate_models",
           "window_halo", "band_halo", "temporal_reach", "band_rows", "BAND_BYTES",
           "estimate_memory", "kept_frame_bytes"]

# Pixels per call of the disentangling (whole rows): 8192 doubles are 64 KB, below
# glibc's threshold for giving each array fresh pages of its own.
_DISENTANGLE_PIXELS = 8192


@dataclass(frozen=True)
class Plan:
    """A volume and settings checked and turned into what the estimate does.

    Attributes
    ----------
    volume : ndarray, shape (T, Sy, Sx, H, W), or FramedVolume
    scale : float
        Power of two bringing max|V| near 1 (:func:`_unit_scale`), folded into the
        camera weights.
    focal_length : float
        Pixels.
    spacing : (float, float)
        ``(ds_x, ds_y)``; ``ds_y = 0`` on a 1-D grid.
    cx, cy : float
        Principal point, pixels.
    spatial, cam_x, cam_y, time : FilterPair
        The filter pair per axis (``cam_y`` None on a 1-D grid, ``time`` None for a
        light field of one frame).
    k_ref, R_t : int
        Reference frame and the temporal window's radius.
    halo : int
        Border pixels without a full window and filters.
    grid_dims : {1, 2}
    static : bool
        A light field of one frame.
    """

    volume: np.ndarray
    scale: float
    focal_length: float
    spacing: tuple[float, float]
    cx: float
    cy: float
    spatial: FilterPair
    cam_x: FilterPair
    cam_y: FilterPair | None
    time: FilterPair | None
    k_ref: int
    R_t: int
    halo: int
    grid_dims: int
    static: bool

    @property
    def frames(self) -> np.ndarray:
        """The frames of the temporal window."""
        return np.arange(self.k_ref - self.R_t, self.k_ref + self.R_t + 1)

    def signal_plan(self, extra: tuple[str, ...] = (), scale: float | None = None
                    ) -> SignalPlan:
        """The signals' plan, the camera weights times ``scale`` (default
        :attr:`scale`)."""
        return signal_plan(self.volume.shape, self.frames, self.cam_x, self.cam_y, self.time,
                           self.spatial, scale=self.scale if scale is None else scale,
                           extra=extra)


def _check_volume(volume, backend) -> tuple[np.ndarray, float]:
    """``(volume, max |V|)`` of a valid volume, or an InputError naming the problem."""
    if isinstance(volume, FramedVolume):
        # its largest magnitude comes with its frames' sums (estimate_models)
        _check_framed(volume)
        return volume, float("nan")
    if not isinstance(volume, np.ndarray):
        raise InputError(f"volume must be a numpy array, got {type(volume).__name__}")
    if volume.ndim != 5:
        raise InputError(
            f"volume must have shape (T, Sy, Sx, H, W) (5 axes); got shape {volume.shape}")
    if volume.dtype not in (np.float32, np.float64):
        raise InputError(
            f"volume must be float32 or float64, got {volume.dtype}; convert integer "
            "images with volume.astype(np.float64) (intensities must be linear)")
    if volume.size:
        scanned = backend.scan(volume)          # one parallel pass, no temporaries
        if scanned is not None and scanned[0] == 0:
            return volume, scanned[1]
    # frame by frame: a whole-volume boolean mask would cost a quarter of the volume
    # (also the path that finds the first bad value for the message)
    count, first, amax = 0, None, 0.0
    for k in range(volume.shape[0]):
        bad = ~np.isfinite(volume[k])
        nbad = int(np.count_nonzero(bad))
        if nbad:
            count += nbad
            if first is None:
                first = (k,) + tuple(int(i) for i in np.argwhere(bad)[0])
        elif volume[k].size:
            amax = max(amax, float(np.max(np.abs(volume[k]))))
    if count:
        raise InputError(f"volume has {count} non-finite values (NaN or inf); "
                         f"first at index (t, sy, sx, y, x) = {first}")
    if volume.size == 0:
        raise InputError(f"volume is empty (shape {volume.shape})")
    return volume, amax


def _check_framed(volume: FramedVolume) -> None:
    """The shape and type of a :class:`FramedVolume` (its frames are checked as they are
    read: :func:`_framed_frames`), or an InputError as :func:`_check_volume` gives."""
    if len(volume.shape) != 5:
        raise InputError(f"volume must have shape (T, Sy, Sx, H, W) (5 axes); got shape "
                         f"{volume.shape}")
    if np.dtype(volume.dtype) not in (np.float32, np.float64):
        raise InputError(f"volume must be float32 or float64, got {volume.dtype}")
    if 0 in volume.shape:
        raise InputError(f"volume is empty (shape {volume.shape})")


def _framed_frames(volume: FramedVolume, splan: SignalPlan, backend) -> list[dict]:
    """What the estimate needs of each frame of a :class:`FramedVolume`, read once per
    frame (``volume.memo``: a caller may keep it for the next step): ``amax`` (max |V|,
    the frame checked finite as :func:`_check_volume` checks an array), ``amin`` (the
    smallest |V| but 0 of a float64 frame, else None), ``sums`` (its camera sums over the
    whole image under the weights of ``splan``, unscaled but for extreme magnitudes
    (:data:`_EXACT_RANGE`), shape (C, H, W), float64, as ``backend.camera_sums`` gives
    them for the frame alone) and ``view`` (the centre view, (H, W)).  One per frame of
    the volume."""
    key, per_frame = _frame_values(volume, splan, backend)
    return [volume.memo(k, key, per_frame(k)) for k in range(volume.shape[0])]


def _frame_values(volume: FramedVolume, splan: SignalPlan, backend):
    """``(key, per_frame)``: the memo key of :func:`_framed_frames`' values and
    ``per_frame(k)``, the function of frame ``k`` that makes them."""
    one = SignalPlan(np.zeros(1, dtype=np.int64), splan.iy0, splan.ix0, splan.weights,
                     splan.combos, splan.taps, splan.spatial, splan.extra)
    Sy, Sx = volume.shape[1:3]
    key = _frame_key(splan, backend)

    def per_frame(k):
        def fn(frame):
            # the backend's one-pass scan where it has one (as _check_volume), else numpy
            scanned = backend.scan(frame[None])
            if scanned is None or scanned[0]:
                bad = ~np.isfinite(frame)
                if bad.any():
                    first = (k,) + tuple(int(i) for i in np.argwhere(bad)[0])
                    raise InputError(f"volume has {int(np.count_nonzero(bad))} non-finite "
                                     f"values (NaN or inf) in frame {k}; first at index "
                                     f"(t, sy, sx, y, x) = {first}")
            amax = float(np.max(np.abs(frame))) if scanned is None else float(scanned[1])
            # the smallest magnitude but 0 (float64 only: every float32 sample is far
            # from float64's subnormals, :data:`_EXACT_RANGE`)
            mag = np.abs(frame) if frame.dtype == np.float64 else None
            nz = mag[mag > 0] if mag is not None else None
            return {"amax": amax,
                    "amin": float(nz.min()) if nz is not None and nz.size else None,
                    "sums": backend.camera_sums(frame[None], one, slice(None))[:, 0],
                    "view": frame[Sy // 2, Sx // 2].copy()}
        return fn
    return key, per_frame


def _frame_key(splan: SignalPlan, backend) -> tuple:
    """What a frame's kept values of :func:`_framed_frames` depend on beside the frame."""
    return ("frame", backend.name, splan.iy0, splan.ix0, splan.weights.shape,
            splan.weights.tobytes())


# Where every sample's magnitude (but 0) lies within 2^-200 .. 2^200, the signals under the
# unscaled weights, their products and the products' frame weights times the scale's
# square (a power of two) stay normal floats: the products of signals kept frame by frame
# (:func:`_kept_signals`) are then those of the scaled window's signals, bit for bit.
_KEPT_RANGE = (2.0 ** -200, 2.0 ** 200)


def _kept_signals(volume: FramedVolume, splan: SignalPlan, out_frames: np.ndarray,
                  scale: float, backend) -> dict[str, FrameStack]:
    """The signals of a :class:`FramedVolume`'s window, frame by frame: for each frame
    of the temporal window (``out_frames``, window indices), its base signals from the
    camera sums of the frames its temporal taps reach under the unscaled weights
    (``splan``, :func:`_framed_frames`' values, read through ``volume.memo`` when they
    are filtered), through ``volume.derive`` so that a caller keeps them for the next
    steps, which then filter only their new frames.  The signals are those of
    ``backend.from_sums`` on the window's sums as one array (each frame's temporal taps
    add the same terms in the same order, and the x/y filtering is per frame), up to
    the scale, which the products take (:class:`FrameStack`).

    Returns
    -------
    dict of str to FrameStack
        Each of F frames of shape (H, W).
    """
    taps = splan.taps
    frame_key, per_frame_sums = _frame_values(volume, splan, backend)
    base = (frame_key, str(np.dtype(volume.dtype)), splan.extra,
            tuple(k.tobytes() for k in (splan.spatial.prefilter, splan.spatial.derivative,
                                        splan.spatial.moment,
                                        splan.spatial.moment_derivative)))
    per_frame = []
    for i, t in enumerate(int(f) for f in out_frames):
        cols = np.flatnonzero(np.any([taps[k][i] != 0.0 for k in taps], axis=0))
        src = splan.needed[cols]
        one = SignalPlan(src, splan.iy0, splan.ix0, splan.weights, splan.combos,
                         {k: np.ascontiguousarray(v[i:i + 1, cols]) for k, v in taps.items()},
                         splan.spatial, splan.extra)
        key = ("signals", base, tuple(int(k) - t for k in src),
               tuple((k, v.tobytes()) for k, v in sorted(one.taps.items())))

        def fn(src=src, one=one):
            # the sums as kept now (a frame rewritten since the step read it is read
            # again: derive keeps the signals under the frames' state before this)
            sums = np.stack([volume.memo(int(k), frame_key, per_frame_sums(int(k)))["sums"]
                             for k in src], axis=1)
            return {name: a[0] for name, a in backend.from_sums(sums, one).items()}

        per_frame.append(volume.derive(t, tuple(int(k) for k in src), key, fn))
    return {name: FrameStack(tuple(f[name] for f in per_frame), scale)
            for name in per_frame[0]}


# Where every sample's magnitude (but 0) lies within 2^-400 .. 2^400, the camera sums under
# the unscaled weights (taps of magnitude 2^-30 or more, sums of at most a few hundred
# terms) and every product and partial sum stay normal floats before and after the scale
# (2^-400 .. 2^400 too): multiplying by a power of two is then exact in either order.
# Outside it (float64 data near the ends of its range) the sums are taken under the
# scaled weights, as the window's are.
_EXACT_RANGE = (2.0 ** -400, 2.0 ** 400)


def _framed_sums(frames: list[dict], needed: np.ndarray, scale: float,
                 rows: slice) -> np.ndarray:
    """The camera sums of a band of a :class:`FramedVolume` (``frames`` from
    :func:`_framed_frames`), as ``backend.camera_sums`` gives those of the same frames
    as one array, bit for bit: the frames' unscaled sums times ``scale``, a power of two
    (exact: every product and sum scales with it; ``scale`` is 1 where the sums were
    taken under the scaled weights, :data:`_EXACT_RANGE`).

    Returns
    -------
    ndarray, shape (C, len(needed), h, W), float64
    """
    sums = np.stack([frames[int(k)]["sums"][:, rows] for k in needed], axis=1)
    if scale != 1.0:
        sums *= scale
    return sums


def window_halo(s: EstimatorSettings) -> int:
    """The maps' border of NaN: the window's radius plus the spatial derivative filter's
    (the pixels without a whole window).  An image needs more than twice this many
    pixels per side."""
    return s.window // 2 + get_filter_pair(s.filters).radius


def band_halo(s: EstimatorSettings) -> int:
    """Rows either side of a row band that its estimate reads: :func:`window_halo`, plus,
    under affine motion, the reach of the pooled rates
    (:func:`estimator.pooling.pool_reach`).  A band estimated with this many rows either
    side (where the image has them) gives the whole image's maps there."""
    sigma = s.pooling_sigma
    if sigma == 0:
        return window_halo(s)
    # in per-pixel results: the pooled rates read pool_reach (3 R); growth_sd reads 2 R
    # of pooled results beyond (the growth map's local spread; its correlation-area term:
    # a fit, a bell of 2 sigma, a local mean); each per-pixel result
    # reads its window of the volume, the texture test a window and 4 px
    R = support_radius(sigma)
    reach = pool_reach(sigma) + 2 * R + bell_radius(2.0 * s.sigma)
    return max(window_halo(s), texture_reach(s.window // 2)) + reach


#: Bytes a band's signals, tensor and work arrays may take (:func:`band_rows`): at 512^2
#: px a volume of 9 frames (and a recording's step of 17) is one band under every model.
BAND_BYTES = 3 * 2 ** 29


def _band_model(packed: bool, W: int, n_ext: int, n_out: int, n_signals: int, frames: int,
                halo: int) -> tuple[int, int]:
    """``(bytes per output row, bytes per band)`` of a band (:func:`band_rows`)."""
    if packed:
        planes = n_out * (n_out + 1) // 2
        spectrum = 16 * (W // 2 + 1)
        # the signals, four complex half-spectra and up to three real products (a pair
        # of signals under each power of t, estimator.spectral)
        every_row = n_signals * frames * 8 * W + 4 * spectrum + 3 * 8 * W
        return every_row + planes * (8 * W + spectrum), 2 * halo * every_row
    # J and, as large, the zoom-blur correction's product T J (T^T)
    return 2 * W * n_ext * n_ext * 8, 0


def band_rows(backend, W: int, n_ext: int, n_out: int, n_signals: int, frames: int,
              halo: int, budget: int = BAND_BYTES) -> int:
    """Output rows per band: at most as many as keep a band's arrays within ``budget``
    bytes, so that memory does not grow with the image, and no fewer than 16.

    A dense backend holds J as ``n_ext x n_ext`` matrices per pixel, twice (the zoom-blur
    correction's ``T J T^T`` is made from it).  An FFT backend holds, over the band and
    its ``halo`` rows either side, the ``n_signals`` base signals of the window's
    ``frames``, four complex half-spectra (a product's and its y-passes') and up to
    three real products (one pair of signals under each power of t), and over
    the band's own rows the packed tensor (one plane per distinct entry of the ``n_out``
    rows, at most ``n_out (n_out + 1) / 2``) and as many half-spectra while it sums them
    (``tests/test_estimator_properties.py`` measures a band's peak against this).
    Fewer, taller bands transform fewer halo rows: at 512^2 the affine model's 4 bands
    of the former 512 MB rule took 2.6 s, one band 2.0 s (``bench/README.md``).

    Parameters
    ----------
    backend : Backend
        :func:`estimator.backends.select_backend`'s; ``packed`` tells the kinds apart.
    W : int
        Image width, px.
    n_ext, n_out : int
        Rows of J before and after the zoom-blur correction's sums.
    n_signals, frames : int
        Base signals (with the correction's) and frames of the temporal window.
    halo : int
        Rows either side of a band that its signals need.
    budget : int
        Bytes.

    Returns
    -------
    int
    """
    per_row, fixed = _band_model(getattr(backend, "packed", False), W, n_ext, n_out,
                                 n_signals, frames, halo)
    return max(16, int((budget - fixed) // per_row))


def _equal_bands(most: int, H: int, halo: int) -> tuple[int, int]:
    """Rows per band when bands of at most ``most`` rows cover the ``H - 2 halo`` inner
    rows in equal heights (a last band of a few rows would cost its halo's transforms
    for little), and the inner rows."""
    inner = max(1, H - 2 * halo)
    return -(-inner // -(-inner // most)), inner


# Bytes per image pixel that an estimate holds besides its bands (its maps, the affine
# model's pooling inputs, the solver's per-pixel results and the signals' intermediates),
# and the factor on the band model, of estimate_memory: an upper envelope of the peaks
# measured (VmHWM over the call less the RSS before it, float32 sinusoid volumes of 5 x 5
# views, the full model, numba backend): 512^2 x 9 frames translation 585 MiB (modelled
# 951), 512^2 x 17 affine 1054 MiB (1674), 256^2 x 9 affine 269 MiB (320), 512 x 200 x
# 17 affine 427 MiB (560), 1024^2 x 9 translation 1811 MiB (2319).
_MAP_BYTES = 600
_BAND_MARGIN = 1.25


def _rows_and_signals(shape, s: EstimatorSettings, models) -> tuple[tuple, tuple, int]:
    """The data rows of ``models`` on a volume of ``shape``, with the zoom-blur
    correction's rows where ``s`` asks for them, and the number of base signals."""
    T, Sy = shape[:2]
    rows = covering_rows([get_model(m, 2 if Sy > 1 else 1, T == 1, s.motion)
                          for m in models])
    ext = zoom_rows(rows) if s.zoom_correction else rows
    return rows, ext, 6 + len({ZOOM_ROW_SIGNALS[r][0] for r in ext[len(rows):]})


def estimate_memory(shape, settings: EstimatorSettings | None = None,
                    models=("full",), method: str = "fast", *,
                    kept_signals: bool = False) -> int:
    """Bytes :func:`estimate_models` holds beyond its volume for a volume of ``shape``
    ``(T, Sy, Sx, H, W)``: its bands (:func:`band_rows`'s model, at most
    :data:`BAND_BYTES` a band, with a margin) and its whole-image maps (an envelope of
    measured peaks; see the constants above).  For planning memory (the pipeline's
    tasks), not a bound that holds on every machine.

    Parameters
    ----------
    shape : tuple of int
    settings : EstimatorSettings, optional
    models : tuple of str
    method : str
        As ``estimate_models``'s.
    kept_signals : bool
        A :class:`FramedVolume` whose caller keeps each frame's signals
        (:func:`kept_frame_bytes` counts them; no mask): where the estimate keeps them
        (:func:`_keeps_signals`) they are not its own.

    Returns
    -------
    int
    """
    s = settings or EstimatorSettings()
    T, Sy, Sx, H, W = shape
    rows, ext, n_signals = _rows_and_signals(shape, s, models)
    if kept_signals and _keeps_signals(shape, s, models, method):
        n_signals = 0
    halo = window_halo(s)
    packed = method == "fast"
    per_row, fixed = _band_model(packed, W, len(ext), len(rows), n_signals, T, halo)
    band, inner = _equal_bands(max(16, int((BAND_BYTES - fixed) // per_row)), H, halo)
    return int(_BAND_MARGIN * (fixed + min(band, inner) * per_row) + _MAP_BYTES * H * W)


def _keeps_signals(shape, s: EstimatorSettings, models, method: str,
                   masked: bool = False) -> bool:
    """Whether :func:`estimate_models` keeps the signals of a :class:`FramedVolume` of
    ``shape`` frame by frame (``derive``): on a backend that takes them, with no mask,
    the window in one band (as :func:`estimate_models` cuts it, for a window of ``T``
    frames centred on its reference frame, as the pipeline's steps are; the magnitudes'
    range, :data:`_KEPT_RANGE`, is the data's and not known here)."""
    if masked or not getattr(backend_class(method, shape), "frame_stacks", False):
        return False
    T, Sy, Sx, H, W = shape
    rows, ext, n_signals = _rows_and_signals(shape, s, models)
    halo = window_halo(s)
    if s.band_rows is not None:
        return s.band_rows >= H - 2 * halo
    out_frames = max(1, T - 2 * get_filter_pair(s.filters).radius)
    most = band_rows(backend_class(method, shape), W, len(ext), len(rows), n_signals,
                     out_frames, halo, BAND_BYTES)
    band, inner = _equal_bands(most, H, halo)
    return band >= inner


def kept_frame_bytes(shape, settings: EstimatorSettings | None = None,
                     models=("full",), method: str = "fast", itemsize: int = 8, *,
                     masked: bool = False) -> int:
    """Bytes a caller keeps per frame of a :class:`FramedVolume` where it keeps what the
    estimator asks it to keep (``memo`` and ``derive``): the frame's camera sums
    (float64), its centre view and, where the estimate keeps them
    (:func:`_keeps_signals`), its base signals (float64).  For planning memory.

    Parameters
    ----------
    shape : tuple of int
        ``(T, Sy, Sx, H, W)`` of a step's window.
    settings : EstimatorSettings, optional
    models : tuple of str
    method : str
        As ``estimate_models``'s.
    itemsize : int
        Bytes a sample of the frames as read (the centre view is kept as read).
    masked : bool
        The estimate has a mask (its signals are then not kept).

    Returns
    -------
    int
    """
    s = settings or EstimatorSettings()
    T, Sy, Sx, H, W = shape
    n_signals = _rows_and_signals(shape, s, models)[2]
    sums = 3 if Sy > 1 else 2                    # pp, dp and pd (2-D grids): SignalPlan
    kept = n_signals if _keeps_signals(shape, s, models, method, masked) else 0
    return H * W * (8 * (sums + kept) + itemsize)


def temporal_reach(s: EstimatorSettings) -> int:
    """Frames either side of the reference frame that an estimate reads where the volume
    has them: the temporal radius of Omega (``s.temporal_radius``, default the motion
    model's: 2 under translation, 6 under affine motion) plus the
    temporal derivative filter's radius.  A window of ``2 * reach + 1`` frames around a
    frame gives the same estimate there as the whole sequence; with fewer frames the
    driver narrows the window or falls back to the 3-tap filters (:func:`_time_window`).
    """
    radius = (MOTION_MODELS[s.motion].temporal_radius if s.temporal_radius is None
              else int(s.temporal_radius))
    return radius + get_filter_pair(s.filters).radius


def _unit_scale(amax: float) -> float:
    """Power of two bringing max|V| near 1.  Estimates do not depend on the volume's scale
    (J scales by c^2); rescaling keeps the products in J clear of overflow (|V| ~ 1e200)
    and underflow (|V| ~ 1e-300).  A power of two is exact in binary floating point.

    For subnormal volumes (max|V| < 2^-1022) the factor itself, up to 2^1074, is not a
    float64; it is capped at 2^1023, which still lifts max|V| above 2^-51 — far from
    underflow in J's products of order max|V|^2 after the rescale."""
    if amax == 0.0 or not np.isfinite(amax):
        return 1.0
    exponent = int(min(1023, -round(math.log2(amax))))
    return float(np.ldexp(1.0, exponent))


def _axis_pair(name: str, samples: int, axis: str) -> FilterPair:
    pair = get_filter_pair(name)
    if samples >= pair.taps:
        return pair
    small = get_filter_pair("matched3")
    if samples >= small.taps:
        return small
    raise InputError(f"too few {axis}: {samples}; the derivative filters need at least 3")


def _time_window(s: EstimatorSettings, T: int, k_ref: int, models) -> tuple[FilterPair, int]:
    """The temporal filter pair and the temporal radius of Ω that fit the frames."""
    reach = min(k_ref, T - 1 - k_ref)
    # rows with a factor t (brightness change, affine motion) need t to vary over Omega
    needs_t = (any(BRIGHTNESS_MODELS[m].needs_time for m in models)
               or MOTION_MODELS[s.motion].needs_time)
    time = None
    for cand in (get_filter_pair(s.filters), get_filter_pair("matched3")):
        room = reach - cand.radius
        if room >= (1 if needs_t else 0):
            time = cand
            break
    if time is None:
        need = "at least 5 frames (3 in the temporal window)" if needs_t else "at least 3 frames"
        raise InputError(f"too few frames around the reference frame: T = {T}, k_ref = "
                         f"{k_ref}; models {models} with motion {s.motion!r} need {need}")
    R_t = (min(MOTION_MODELS[s.motion].temporal_radius, reach - time.radius)
           if s.temporal_radius is None else int(s.temporal_radius))
    if R_t < 0 or R_t > reach - time.radius or (needs_t and R_t < 1):
        raise InputError(f"temporal_radius {R_t} does not fit: frames {k_ref} +- {R_t} need "
                         f"{time.radius} more frames either side, T = {T}")
    return time, R_t


def _plan(volume, focal_length, camera_spacing, principal_point, s: EstimatorSettings,
          models: tuple[str, ...], backend) -> Plan:
    """Check the volume, geometry and settings against each other (InputError naming the
    problem) and choose the filters and the temporal window."""
    volume, amax = _check_volume(volume, backend)
    T, Sy, Sx, H, W = volume.shape
    for m in models:
        if m not in MODELS:
            raise InputError(f"unknown model {m!r}; expected one of {MODELS}")
    if Sx % 2 == 0 or Sy % 2 == 0:
        raise InputError(f"camera grid {Sy}x{Sx} (Sy x Sx) has an even size: the "
                         "reference camera must be the centre of an odd grid")
    if Sx < 3:
        raise InputError(f"too few cameras along x: Sx = {Sx}; need at least 3 "
                         "(a 1-D grid is horizontal: Sy = 1, Sx >= 3)")
    f = float(focal_length)
    if not np.isfinite(f) or f <= 0:
        raise InputError(f"focal_length must be a positive number of pixels, got {focal_length}")
    sp = np.asarray(camera_spacing, dtype=float).ravel()
    if sp.size != 2 or not np.all(np.isfinite(sp)) or sp[0] <= 0 or (Sy > 1 and sp[1] <= 0):
        raise InputError(f"camera_spacing must be [ds_x, ds_y] > 0, got {camera_spacing}")
    if principal_point is None:
        cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
    else:
        try:
            pp = np.asarray(principal_point, dtype=float).ravel()
        except (TypeError, ValueError):
            pp = np.array([np.nan])
        if pp.size != 2 or not np.all(np.isfinite(pp)):
            raise InputError(f"principal_point must be two finite numbers (cx, cy) in "
                             f"pixels, got {principal_point!r}")
        cx, cy = float(pp[0]), float(pp[1])
    spatial = get_filter_pair(s.filters)
    cam_x = _axis_pair(s.filters, Sx, "cameras along x")
    cam_y = _axis_pair(s.filters, Sy, "cameras along y") if Sy > 1 else None
    k_ref = (T - 1) // 2 if s.ref_frame is None else int(s.ref_frame)
    if not 0 <= k_ref < T:
        raise InputError(f"ref_frame {k_ref} outside the {T} frames")
    static = T == 1
    if static:
        # a static light field: depth and slopes from the camera axes alone
        problem = one_frame_problem([BRIGHTNESS_MODELS[m] for m in models],
                                    MOTION_MODELS[s.motion])
        if problem:
            raise InputError(problem)
        if s.temporal_radius not in (None, 0):
            raise InputError(f"temporal_radius {s.temporal_radius}: a light field of one "
                             "frame has no time axis")
        time, k_ref, R_t = None, 0, 0
    else:
        time, R_t = _time_window(s, T, k_ref, models)
    halo = window_halo(s)
    if H <= 2 * halo or W <= 2 * halo:
        raise InputError(f"image {H}x{W} too small for a {s.window}-tap window and "
                         f"{spatial.taps}-tap filters: need more than {2 * halo} pixels "
                         "per side")
    return Plan(volume=volume, scale=_unit_scale(amax), focal_length=f,
                spacing=(sp[0], sp[1] if Sy > 1 else 0.0), cx=cx, cy=cy, spatial=spatial,
                cam_x=cam_x, cam_y=cam_y, time=time, k_ref=k_ref, R_t=R_t, halo=halo,
                grid_dims=2 if Sy > 1 else 1, static=static)


def _effective_samples(w: np.ndarray, spatial: FilterPair, frames: int,
                       time: FilterPair | None) -> float:
    """The number of independent samples a window's noise averages over, for the error
    estimates: ``1 / Var(sum of the weighted samples)`` per unit sample variance.

    The samples are prefiltered (the 5-tap pairs in x and y, and in time), so their noise
    is correlated over the prefilter's reach: the variance of a weighted sum is
    ``sum_ij w_i w_j R(i - j)`` with ``R`` the prefilter's normalised autocorrelation, per
    axis (Gaussian weights ``w`` in x and y, ``frames`` uniform weights in time)."""
    def variance(weights, pair):
        # in Python floats with exactly rounded sums: numpy's correlate, convolve and dot
        # go through BLAS, whose sums round by the machine's CPU
        p = [float(v) for v in pair.prefilter]
        w = [float(v) for v in weights]
        pp = math.fsum(v * v for v in p)
        R = [math.fsum(p[i] * p[i + d] for i in range(len(p) - d)) / pp
             for d in range(len(p))]
        return math.fsum(w[i] * w[j] * R[abs(i - j)] for i in range(len(w))
                         for j in range(len(w)) if abs(i - j) < len(p))

    vx = variance(w, spatial)
    vt = variance(np.full(frames, 1.0 / frames), time) if time is not None else 1.0
    return 1.0 / (vx * vx * vt)


def estimate(volume: np.ndarray, focal_length: float, camera_spacing, *, model: str = "full",
             principal_point=None, mask=None, **settings) -> Estimate:
    """Estimate depth, slopes, 3-D motion and brightness change at the reference camera.

    Parameters
    ----------
    volume : ndarray, shape (T, Sy, Sx, H, W), float32 or float64
        ``V[t, sy, sx, y, x]``: frames, camera rows (growing with camera Y), camera
        columns (growing with camera X), image rows (down), image columns (right).
        Intensities linear in radiance.  ``Sy = 1`` is a horizontal 1-D grid.  Or a
        :class:`estimator.signals.FramedVolume` standing for one: the same maps, bit for
        bit, from frames read one at a time (a recording's steps that share frames).
    focal_length : float
        Focal length in pixels.
    camera_spacing : (float, float)
        ``(ds_x, ds_y)`` in world units (``ds_y`` ignored for a 1-D grid).
    model : {"bcc", "hf", "full"}
        The brightness model (:data:`estimator.models.MODELS`): brightness constancy,
        Haussecker-Fleet (spatially constant change), or the paper's full model
        (spatially varying change).  The motion model is the setting ``motion``.
    principal_point : (float, float), optional
        ``(cx, cy)`` in pixels; default the image centre.
    mask : ndarray of bool, shape (H, W), optional
        The object's pixels (a leaf) in the reference camera's image at the reference
        frame: each window then uses only the object's samples (normalized convolution:
        :func:`object_window`), so pixels near its edge are measured from the object
        alone, and the maps are NaN off it.  Default: every pixel.
    **settings
        See :class:`EstimatorSettings`.

    Returns
    -------
    Estimate
        Maps of shape (H, W) in world units per frame; NaN where invalid.

    Raises
    ------
    InputError
        Wrong shape or dtype, NaN/inf, even or too small camera grids, too few frames,
        an image smaller than the window, or bad settings.
    """
    return estimate_models(volume, focal_length, camera_spacing, models=(model,),
                           principal_point=principal_point, mask=mask, **settings)[model]


def estimate_models(volume: np.ndarray, focal_length: float, camera_spacing, *,
                    models=MODELS, principal_point=None, mask=None,
                    **settings) -> dict[str, Estimate]:
    """Run several models on one volume, sharing the structure tensor.

    The tensor of the largest model contains the smaller ones as sub-blocks, so it is
    computed once.  Parameters as :func:`estimate`; returns ``{model: Estimate}``.
    """
    s = EstimatorSettings(**settings)
    models = tuple(models)
    framed = isinstance(volume, FramedVolume)
    shape = tuple(volume.shape) if framed else np.shape(volume)
    backend = select_backend(s.method, shape)
    plan = _plan(volume, focal_length, camera_spacing, principal_point, s, models, backend)
    shape_hw = tuple(shape[-2:])
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != shape_hw or not (mask.dtype == bool or np.isin(mask, (0, 1)).all()):
            raise InputError(f"mask must be an image of 0/1 or booleans of the volume's "
                             f"shape {shape_hw}, got {mask.dtype} of shape {mask.shape}")
        mask = mask.astype(bool)
    mdl: dict[str, Model] = {m: get_model(m, plan.grid_dims, plan.static, s.motion)
                             for m in models}
    rows = covering_rows(mdl.values())
    # the zoom-blur correction: each corrected row is the sum of the row and its
    # correction row; the FFT backends sum their entries' spectra (tplan.combine), the
    # others return J over both (J_ext), summed after (tensor.zoom_corrected)
    ext = zoom_rows(rows) if s.zoom_correction else rows
    extra = tuple(dict.fromkeys(ZOOM_ROW_SIGNALS[r][0] for r in ext[len(rows):]))
    vol = plan.volume
    T, Sy, Sx, H, W = vol.shape
    halo = plan.halo
    n = len(ext)
    if framed:
        # a volume given frame by frame: each frame's sums (under the unscaled weights),
        # largest magnitude and centre view, read once; the scale from the magnitudes
        unit = plan.signal_plan(extra, scale=1.0)
        frames = _framed_frames(vol, unit, backend)
        amax = max(f["amax"] for f in frames)
        plan = replace(plan, scale=_unit_scale(amax))
        lo, hi = _EXACT_RANGE
        factor = plan.scale
        if amax > hi or any(f["amin"] is not None and f["amin"] < lo for f in frames):
            frames, factor = _framed_frames(vol, plan.signal_plan(extra), backend), 1.0
    splan = plan.signal_plan(extra)
    band = s.band_rows
    if band is None:
        # as many bands as the budget asks, of equal height
        band, _ = _equal_bands(band_rows(backend, W, n, len(rows), 6 + len(extra),
                                         len(plan.frames), halo, BAND_BYTES), H, halo)
    tplan = TensorPlan(tvals=plan.frames - plan.k_ref, rows=ext,
                       kernels=gaussian_moment_kernels(s.sigma, s.window),
                       radius=s.window // 2, spatial_radius=plan.spatial.radius,
                       cols=slice(halo, W - halo),
                       combine=zoom_terms(ext, rows) if ext != rows else None)

    interior = np.zeros((H, W), dtype=bool)
    interior[halo:H - halo, halo:W - halo] = True
    # with a mask: the samples the windows use, each window's weight on them (at least
    # MIN_OBJECT_WEIGHT where estimated)
    used_samples = window_weight = None
    if mask is not None:
        used_samples, window_weight, estimated = object_window(mask, tplan.kernels[0],
                                                               plan.spatial.radius)
        interior &= estimated
        window_weight = np.maximum(window_weight, MIN_OBJECT_WEIGHT)

    def nan_border(names):
        # the interior is written band by band below; only the border needs its NaN.  One
        # block for all of a model's maps: numpy asks for huge pages from 4 MB on, so
        # writing them costs a few page faults instead of one per 4 KB of every map
        a = np.empty((len(names), H, W))
        a[:, :halo] = a[:, H - halo:] = a[:, :, :halo] = a[:, :, W - halo:] = np.nan
        return dict(zip(names, a))

    out = {m: nan_border(mdl[m].outputs + ("model_error",)) for m in models}
    # the affine model's per-pixel observations and plane, for pooling its rates after
    # the last band (estimator.pooling): nine observations, then v, z_x, z_y
    sigma_pool = s.pooling_sigma
    pool = {m: np.full((13, H, W), np.nan) for m in models
            if mdl[m].motion.pools_rates and sigma_pool > 0}
    # disentangling runs over a few rows at a time: its many (N,) temporaries then stay
    # small enough for the allocator to reuse (and in cache) instead of each costing
    # fresh pages (measured at 512^2, full model: 0.041 s in one call, about 0.025 s so)
    cols = np.arange(halo, W - halo)
    step = max(1, _DISENTANGLE_PIXELS // cols.size)          # rows per call
    inv = 1.0 / plan.scale
    n_eff = _effective_samples(tplan.kernels[0], plan.spatial, len(plan.frames), plan.time)
    # a recording's step in one band: each frame's signals kept for the steps that share
    # the frame, where the caller keeps them (FramedVolume.derive) and the products of
    # signals kept unscaled give the same bits (_KEPT_RANGE)
    kept = (framed and vol.derive is not None and backend.frame_stacks and mask is None
            and factor == plan.scale and band >= H - 2 * halo
            and (amax == 0.0 or _KEPT_RANGE[0] <= amax <= _KEPT_RANGE[1])
            and all(f["amin"] is None or f["amin"] >= _KEPT_RANGE[0] for f in frames))
    for r0 in range(halo, H - halo, band):
        r1 = min(r0 + band, H - halo)
        band_rows_ = slice(r0 - halo, r1 + halo)
        if kept:
            signals = _kept_signals(vol, unit, plan.frames, factor, backend)
        elif framed:
            signals = backend.from_sums(_framed_sums(frames, splan.needed, factor,
                                                     band_rows_), splan)
        else:
            signals = backend.signals(vol, splan, band_rows_)
        if mask is not None:
            # normalized convolution: only the object's samples enter the window's sums
            m = used_samples[r0 - halo:r1 + halo]
            signals = {k: v * m for k, v in signals.items()}
        J = backend.tensor(signals, tplan)                # the band's interior pixels
        del signals
        if J.rows != rows:
            # a backend that does not sum the corrections itself (tplan.combine)
            J = zoom_corrected(J, rows)
        n_px = np.broadcast_to(n_eff, (r1 - r0) * cols.size)
        if mask is not None:
            # ... and the sums become means over them; the noise averages over the
            # fraction of the window on the object (docs/model.md, *Masks*)
            frac = window_weight[r0:r1, halo:W - halo].ravel()
            J = scaled(J, 1.0 / frac)
            n_px = n_eff * frac
        yy, xx = np.meshgrid(np.arange(r0, r1), cols, indexing="ij")
        x0 = (xx - plan.cx).ravel().astype(float)
        y0 = (yy - plan.cy).ravel().astype(float)
        starts = range(0, r1 - r0, step)
        for m in models:
            # the null space solved as the disentangling reaches its rows: only a few
            # rows' parameter vectors are held at once (under the affine model at 512^2
            # a whole band's are 134 MB; the same bits: estimator._solver.null_space_parts)
            parts = backend.null_space_parts(J, mdl[m], [min(a + step, r1 - r0) * cols.size
                                                         for a in starts])
            for a, ns in zip(starts, parts):
                b = min(a + step, r1 - r0)
                px = slice(a * cols.size, b * cols.size)
                P, g, err, valid = ns[:4]
                keep = {} if m in pool else None
                res = disentangle(P, g, mdl[m], x0[px], y0[px], plan.focal_length,
                                  plan.spacing, slant_correction=s.slant_correction,
                                  combine=s.combine, residual=err / n_px[px],
                                  pooling_inputs=keep, solver=backend.solve_affine)
                if keep:
                    pool[m][:, r0 + a:r0 + b, halo:W - halo] = np.concatenate(
                        [keep["obs"], keep["plane"], keep["var_vt"][None]]
                    ).reshape(13, b - a, cols.size)
                # an eigenvalue of J: undo the internal rescaling (J scales with its
                # square).  For |V| beyond ~1e154 the true value is not representable:
                # it becomes inf.
                with np.errstate(over="ignore", under="ignore"):
                    res["model_error"] = (np.where(valid, err, np.nan) * inv) * inv
                for name, val in res.items():
                    out[m][name][r0 + a:r0 + b, halo:W - halo] = val.reshape(b - a, cols.size)
        # the band's tensor and null spaces are done with: not held through the next
        # band's signals or the pooled rates (the affine model's tensor at 512^2: 313 MB)
        J = P = g = err = valid = ns = parts = res = None
    if pool:
        Sy, Sx = vol.shape[1:3]
        ref_view = frames[plan.k_ref]["view"] if framed else vol[plan.k_ref, Sy // 2, Sx // 2]
        textured = textured_windows(ref_view, s.window // 2,
                                    used_samples)
    for m, inputs in pool.items():
        out[m].update(_pooled(inputs, interior, textured, sigma_pool, plan, s.sigma,
                              backend.solve_affine))
        # a pixel that kept its own rates is the per-pixel solution: its growth_err
        alone = out[m]["pooled"] == 0.0
        out[m]["growth_sd"][alone] = out[m]["growth_err"][alone]
    for m in models:
        if "pooled" in out[m] and m not in pool:
            # not pooled (growth_support 0): every interior pixel solved alone, whose
            # first-order growth_err is its standard deviation
            out[m]["pooled"][interior] = 0.0
            out[m]["growth_sd"][interior] = out[m]["growth_err"][interior]
    if mask is not None:
        for m in models:
            for a in out[m].values():
                a[~interior] = np.nan
    # "masked" only where a mask was given: unmasked estimates record what they did
    used = dict(s.as_dict(), **({"masked": True} if mask is not None else {}),
                filters_xy=plan.spatial.name, filters_sx=plan.cam_x.name,
                filters_sy=plan.cam_y.name if plan.cam_y else None,
                filters_t=plan.time.name if plan.time else None,
                temporal_radius=plan.R_t, ref_frame=plan.k_ref, backend=backend.name,
                growth_support=sigma_pool if mdl[models[0]].motion.pools_rates else None)
    return {m: Estimate(out[m], m, interior, dict(used, model=m), motion=s.motion)
            for m in models}


def _growth_sd(growth, sens, own_rates, valid, fitted, weights, used, sigma,
               window_sigma, origin):
    """The pooled growth's standard deviation per pixel (``docs/model.md``, *Pooled depth
    rates*): the growth map's local scatter about its local linear fit (the noise the
    pixel's own flow and flow gradient bring, correlations included), plus what the
    pooled rates' error adds, common to the support and so invisible in that scatter:
    ``rho s^2`` with ``s`` the local spread of the growth's part that the pixel's own
    rates make, ``sum_j (dg/dr_j) r_j``, about its local fit, and ``rho`` the fit's
    variance per unit noise variance (:func:`estimator.pooling.fit_variance`) for that
    residual's correlation area, measured from the data (a bell of ``2 sigma_w`` leaves
    ``sum K^2 / area`` of a noise's variance).  NaN where the pixel kept its own rates
    (the caller gives it its ``growth_err``)."""
    H, W = growth.shape
    w = (fitted & used & np.isfinite(growth)).astype(float)
    local = local_spread(np.where(w > 0, growth, 0.0)[None], w, sigma, origin)[0]
    # the rates' noise as the growth sees it: the growth's part that the pixel's own
    # rates make (the three rates' errors are correlated, and partly cancel in it), its
    # residual about the local fit, and that residual's correlation area measured from
    # the data: a bell K of sigma_m leaves sum K^2 / A of a noise's variance
    part = np.zeros((H, W))
    part[valid] = np.sum(sens[:, 6:9] * own_rates.T, axis=1)
    wf = np.where(fitted & np.isfinite(part), 1.0, 0.0)
    part = np.where(wf > 0, part, 0.0)
    res = np.where(wf > 0, part - local_linear_fit(part[None], wf, sigma, origin)[0], 0.0)
    sm = 2.0 * window_sigma
    with np.errstate(invalid="ignore", divide="ignore"):
        # band_halo counts this bell's reach (bell_radius)
        smooth = bell(res, sm) / bell(wf, sm)
        smooth = np.where(wf > 0, smooth, 0.0)
        total = local_mean(wf * res * res, wf, sigma, origin)
        area = (local_mean(wf * smooth * smooth, wf, sigma, origin)
                / (total * bell_square_sum(sm)))
    common = fit_variance(weights, sigma, area, origin) * total
    sd = np.sqrt(local ** 2 + common)
    return np.where(used, sd, np.nan)


def _pooled(kept: np.ndarray, interior: np.ndarray, textured: np.ndarray, sigma: float,
            plan: Plan, window_sigma: float, solver=solve_affine) -> dict:
    """The affine model's motion with its depth motion and tilt rates pooled
    (:func:`estimator.pooling.pool_rates`) and each pixel's 9 x 9 system solved again
    with them (``docs/model.md``, *Pooled depth rates*).

    ``kept``: shape (13, H, W), the nine observations, ``v, z_x, z_y`` and the first-order
    variance of ``v_t`` per pixel; ``textured`` (H, W): the pixels whose window sees
    texture everywhere (:func:`estimator.pooling.textured_windows`), the only ones fitted.
    Returns the maps that replace the per-pixel solution's (``Ux, Uy, Uz, growth,
    rotation, Zx_t, Zy_t``) and ``pooled``: 1 where the pooled rates were used, 0 where
    the pixel kept its own, NaN outside the interior; ``growth_sd``
    (:func:`_growth_sd`).  ``Uz_err``, ``growth_err``, ``rotation_err`` stay those of the
    per-pixel solution.  ``solver`` solves the systems (:func:`solve_affine`, or the
    numba backend's kernel with its signature)."""
    obs, (v, zx, zy, var_vt) = kept[:9], kept[9:]
    valid = interior & np.isfinite(kept).all(0)
    # each pixel weighted by the inverse of its v_t's first-order variance: a pixel whose
    # window reaches off the leaf, or sees little texture, counts for little.  A variance
    # of 0 (a model error that rounds to 0 on exact data) gives no weight, but the pixel
    # is still solved with the pooled rates
    fit_me = valid & textured & (var_vt > 0)
    weights = np.where(fit_me, 1.0 / np.where(fit_me, var_vt, 1.0), 0.0)
    # the support's blocks start at the principal point's pixel: a row band (its
    # principal point moved with it) has the whole image's blocks
    origin = (int(np.floor(plan.cy)), int(np.floor(plan.cx)))
    rates, used, spread = pool_rates(np.stack([zx, zy, obs[6], obs[7], obs[8]]), valid,
                                     sigma, weights=weights, origin=origin)
    zx, zy = rates[0][valid], rates[1][valid]
    H, W = interior.shape
    yy, xx = np.nonzero(valid)
    x0 = xx - plan.cx
    y0 = yy - plan.cy
    f = plan.focal_length
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = -f / v[valid]
        # the plane's slopes from the pooled projected ones (as in disentangle)
        den = 1.0 + (zx * x0 + zy * y0) * Z / f
        Zx, Zy = zx * Z / den, zy * Z / den
    o = np.concatenate([obs[:6, valid], rates[2:, valid]])
    # in chunks of the disentangling's size: the solve's many temporaries stay small
    # enough for the allocator to reuse (as in estimate_models); one call when empty
    chunks = [slice(a, a + _DISENTANGLE_PIXELS)
              for a in range(0, Z.size, _DISENTANGLE_PIXELS)] or [slice(None)]
    parts = [solver(o[:, c], Z[c], Zx[c], Zy[c], x0[c], y0[c], f, sensitivity=True)
             for c in chunks]
    res = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    sens = res.pop("growth_sensitivity")
    out = {}
    for name, val in res.items():
        a = np.full((H, W), np.nan)
        a[valid] = val
        out[name] = a
    out["growth_sd"] = _growth_sd(out["growth"], sens, obs[6:9, valid], valid,
                                  weights > 0, weights, used, sigma, window_sigma, origin)
    flag = np.full((H, W), np.nan)       # NaN where the pixel has no estimate at all
    flag[valid] = 0.0
    flag[used] = 1.0
    out["pooled"] = flag
    return out
