"""Public driver: from a camera-grid volume to per-pixel depth, slopes, motion and
brightness change."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .filters import FILTER_NAMES, FilterPair, get_filter_pair
from .models import MODELS, get_model
from .solve import disentangle, null_space
from .tensor import (camera_time_signals, gaussian_moment_kernels, spatial_signals,
                     structure_tensor, structure_tensor_reference)

__all__ = ["Estimate", "EstimatorSettings", "InputError", "estimate", "estimate_models",
           "METHODS"]

METHODS = ("fast", "grouped", "reference")
COMBINE = ("inverse_variance", "mean")


class InputError(ValueError):
    """Input the estimator cannot work with; the message names the problem."""


@dataclass(frozen=True)
class EstimatorSettings:
    """Estimator options (all keyword arguments of :func:`estimate`).

    Attributes
    ----------
    sigma : float
        Standard deviation of the Gaussian neighbourhood in x and y, pixels (paper: 16).
    window : int
        Taps of that Gaussian (paper: 65).
    filters : str
        Derivative / prefilter pair for x and y, and for cameras and time where they
        have enough samples (see :mod:`estimator.filters`); ``"matched3"`` is used on an
        axis with fewer samples than the pair needs.
    temporal_radius : int or None
        The neighbourhood spans frames ``k_ref - R .. k_ref + R`` with uniform weights.
        Default: as many as the temporal filter allows, at most 2.
    ref_frame : int or None
        Reference frame ``k_ref``; default the centre frame ``(T - 1) // 2``.
    method : {"fast", "grouped", "reference"}
        Implementation; all give the same result to roundoff.  "fast" (default): FFT
        moment smoothing and a numba null-space solver (:mod:`estimator._fast`);
        "grouped": direct 65-tap smoothing of grouped products and LAPACK ``eigh``;
        "reference": the straightforward entry-by-entry tensor and ``eigh`` (the
        baseline of ``bench/``).
    slant_correction : bool
        Remove the slant-motion coupling from ``U_Z`` (see :mod:`estimator.solve`).
    combine : {"inverse_variance", "mean"}
        How the twice-estimated ``v, z_x, z_y, u_z`` are combined: weighted by their
        first-order error estimates (default), or plainly averaged.
    band_rows : int or None
        Output rows processed at a time (bounds memory); default from a 256 MB budget.
    """

    sigma: float = 16.0
    window: int = 65
    filters: str = "matched5"
    temporal_radius: int | None = None
    ref_frame: int | None = None
    method: str = "fast"
    slant_correction: bool = True
    band_rows: int | None = None
    combine: str = "inverse_variance"

    def __post_init__(self) -> None:
        """Refuse settings that are of the wrong type or out of range (InputError naming
        the setting); checks that need the volume are made by :func:`estimate`."""
        def integer(v) -> bool:
            return isinstance(v, (int, np.integer)) and not isinstance(v, bool)

        if isinstance(self.sigma, bool) or not isinstance(self.sigma, (int, float, np.number)) \
                or not (np.isfinite(self.sigma) and self.sigma > 0):
            raise InputError(f"sigma must be a positive number of pixels, got {self.sigma!r}")
        if not (integer(self.window) and self.window >= 3 and self.window % 2 == 1):
            raise InputError(f"window must be an odd number of taps >= 3, got {self.window!r}")
        if self.filters not in FILTER_NAMES:
            raise InputError(f"unknown filter pair {self.filters!r}; filters must be one of "
                             f"{FILTER_NAMES}")
        for name in ("temporal_radius", "ref_frame"):
            v = getattr(self, name)
            if v is not None and not (integer(v) and v >= 0):
                raise InputError(f"{name} must be a non-negative integer or None, got {v!r}")
        if self.method not in METHODS:
            raise InputError(f"method must be one of {METHODS}, got {self.method!r}")
        if not isinstance(self.slant_correction, (bool, np.bool_)):
            raise InputError(f"slant_correction must be true or false, got "
                             f"{self.slant_correction!r}")
        if self.combine not in COMBINE:
            raise InputError(f"combine must be one of {COMBINE}, got {self.combine!r}")
        if self.band_rows is not None and not (integer(self.band_rows) and self.band_rows >= 1):
            raise InputError(f"band_rows must be a positive integer or None, got "
                             f"{self.band_rows!r}")


@dataclass
class Estimate:
    """Result of :func:`estimate`.

    Attributes
    ----------
    maps : dict of str to ndarray, each shape (H, W)
        ``Z, Zx, Zy, Ux, Uy, Uz`` (world units, per frame), the model's brightness
        parameters (``a1, a2`` for hf; also ``a1x, a1y, a2x, a2y`` for full) and
        ``model_error``.  NaN on border pixels and where the estimate is degenerate.
    model : str
    interior : ndarray of bool, shape (H, W)
        Pixels free of border effects (the window and filters fit inside the image).
    settings : dict
        The settings used, including the filters chosen per axis.
    """

    maps: dict[str, np.ndarray]
    model: str
    interior: np.ndarray
    settings: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.maps[name]


# The fast path runs its numba kernels from this many image pixels on.  Below, loading
# them from numba's cache (about 0.5-0.8 s per process, measured) costs more than they
# save, so small volumes take the same FFT tensor with LAPACK's eigh instead (same
# answers within the fast path's tolerance; see bench/README.md).
NUMBA_MIN_PIXELS = 128 * 128
# Pixels per call of the disentangling (whole rows): 8192 doubles are 64 KB, below
# glibc's threshold for giving each array fresh pages of its own.
_DISENTANGLE_PIXELS = 8192


def _uses_numba(s, shape) -> bool:
    return (s.method == "fast" and len(shape) == 5
            and shape[-1] * shape[-2] >= NUMBA_MIN_PIXELS)


def _check_volume(volume, fast: bool = False) -> np.ndarray:
    if not isinstance(volume, np.ndarray):
        raise InputError(f"volume must be a numpy array, got {type(volume).__name__}")
    if volume.ndim != 5:
        raise InputError(
            f"volume must have shape (T, Sy, Sx, H, W) (5 axes); got shape {volume.shape}")
    if volume.dtype not in (np.float32, np.float64):
        raise InputError(
            f"volume must be float32 or float64, got {volume.dtype}; convert integer "
            "images with volume.astype(np.float64) (intensities must be linear)")
    if fast and volume.size:
        from ._fast import announce_compilation, scan_volume

        announce_compilation()                  # before the first kernel is compiled
        scanned = scan_volume(volume)           # one parallel pass, no temporaries
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


def _unit_scale(amax: float) -> float:
    """Power of two bringing max|V| near 1.  Estimates do not depend on the volume's scale
    (J scales by c^2); rescaling keeps the products in J clear of overflow (|V| ~ 1e200)
    and underflow (|V| ~ 1e-300).  A power of two is exact in binary floating point.

    For subnormal volumes (max|V| < 2^-1022) the factor itself, up to 2^1074, is not a
    float64; it is capped at 2^1023, which still lifts max|V| above 2^-51 — far from
    underflow in J's products of order max|V|^2 after the rescale."""
    if amax == 0.0 or not np.isfinite(amax):
        return 1.0
    exponent = int(min(1023, -np.round(np.log2(amax))))
    return float(np.ldexp(1.0, exponent))


def _axis_pair(name: str, samples: int, axis: str) -> FilterPair:
    pair = get_filter_pair(name)
    if samples >= pair.taps:
        return pair
    small = get_filter_pair("matched3")
    if samples >= small.taps:
        return small
    raise InputError(f"too few {axis}: {samples}; the derivative filters need at least 3")


def _time_window(s, T: int, k_ref: int, models) -> tuple:
    """The temporal filter pair and the temporal radius of Ω that fit the frames."""
    reach = min(k_ref, T - 1 - k_ref)
    needs_t = any(m != "bcc" for m in models)   # I t rows need t to vary over Omega
    time = None
    for cand in (get_filter_pair(s.filters), get_filter_pair("matched3")):
        room = reach - cand.radius
        if room >= (1 if needs_t else 0):
            time = cand
            break
    if time is None:
        need = "at least 5 frames (3 in the temporal window)" if needs_t else "at least 3 frames"
        raise InputError(f"too few frames around the reference frame: T = {T}, k_ref = "
                         f"{k_ref}; models {models} need {need}")
    R_t = min(2, reach - time.radius) if s.temporal_radius is None else int(s.temporal_radius)
    if R_t < 0 or R_t > reach - time.radius or (needs_t and R_t < 1):
        raise InputError(f"temporal_radius {R_t} does not fit: frames {k_ref} +- {R_t} need "
                         f"{time.radius} more frames either side, T = {T}")
    return time, R_t


def _prepare(volume, focal_length, camera_spacing, principal_point, s: EstimatorSettings,
             models: tuple[str, ...]):
    volume, amax = _check_volume(volume, fast=_uses_numba(s, np.shape(volume)))
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
        bad = [m for m in models if m != "bcc"]
        if bad:
            raise InputError(f"models {bad} need a time axis (brightness change over "
                             "frames); a light field of one frame takes model 'bcc'")
        if s.temporal_radius not in (None, 0):
            raise InputError(f"temporal_radius {s.temporal_radius}: a light field of one "
                             "frame has no time axis")
        time, k_ref, R_t = None, 0, 0
    else:
        time, R_t = _time_window(s, T, k_ref, models)
    R = s.window // 2
    halo = R + spatial.radius
    if H <= 2 * halo or W <= 2 * halo:
        raise InputError(f"image {H}x{W} too small for a {s.window}-tap window and "
                         f"{spatial.taps}-tap filters: need more than {2 * halo} pixels "
                         "per side")
    grid_dims = 2 if Sy > 1 else 1
    return dict(volume=volume, scale=_unit_scale(amax), f=f, spacing=(sp[0], sp[1] if Sy > 1 else 0.0), cx=cx, cy=cy,
                spatial=spatial, cam_x=cam_x, cam_y=cam_y, time=time, k_ref=k_ref, R_t=R_t,
                halo=halo, grid_dims=grid_dims, static=static)


def estimate(volume: np.ndarray, focal_length: float, camera_spacing, *, model: str = "full",
             principal_point=None, **settings) -> Estimate:
    """Estimate depth, slopes, 3-D motion and brightness change at the reference camera.

    Parameters
    ----------
    volume : ndarray, shape (T, Sy, Sx, H, W), float32 or float64
        ``V[t, sy, sx, y, x]``: frames, camera rows (growing with camera Y), camera
        columns (growing with camera X), image rows (down), image columns (right).
        Intensities linear in radiance.  ``Sy = 1`` is a horizontal 1-D grid.
    focal_length : float
        Focal length in pixels.
    camera_spacing : (float, float)
        ``(ds_x, ds_y)`` in world units (``ds_y`` ignored for a 1-D grid).
    model : {"bcc", "hf", "full"}
        Brightness constancy, Haussecker-Fleet (spatially constant change), or the
        paper's full model (spatially varying change).
    principal_point : (float, float), optional
        ``(cx, cy)`` in pixels; default the image centre.
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
                           principal_point=principal_point, **settings)[model]


def estimate_models(volume: np.ndarray, focal_length: float, camera_spacing, *,
                    models=MODELS, principal_point=None, **settings) -> dict[str, Estimate]:
    """Run several models on one volume, sharing the structure tensor.

    The tensor of the largest model contains the smaller ones as sub-blocks, so it is
    computed once.  Parameters as :func:`estimate`; returns ``{model: Estimate}``.
    """
    s = EstimatorSettings(**settings)
    models = tuple(models)
    c = _prepare(volume, focal_length, camera_spacing, principal_point, s, models)
    vol = c["volume"]
    T, Sy, Sx, H, W = vol.shape
    mdl = {m: get_model(m, c["grid_dims"], c["static"]) for m in models}
    union = get_model("full" if "full" in models else ("hf" if "hf" in models else "bcc"),
                      c["grid_dims"], c["static"])
    sub = {m: np.array([union.index(r) for r in mdl[m].rows]) for m in models}
    frames = np.arange(c["k_ref"] - c["R_t"], c["k_ref"] + c["R_t"] + 1)
    tvals = frames - c["k_ref"]
    kernels = gaussian_moment_kernels(s.sigma, s.window)
    halo = c["halo"]
    n = union.n
    # J of a band takes rows * W * n^2 * 8 bytes; bound it (and the FFT work arrays) to
    # ~512 MB, so memory does not grow with the image.
    band = s.band_rows or max(16, int(512e6 // (W * n * n * 8)))
    sums = separable = product = None
    numba_path = _uses_numba(s, vol.shape)
    if s.method == "fast":
        from .spectral import structure_tensor_fft, unpack

        tensor = structure_tensor_fft
        if numba_path:
            from ._fast import (announce_compilation, camera_sums, null_space_fast,
                                spatial_filter, weighted_product)

            announce_compilation()
            sums, separable, product = camera_sums, spatial_filter, weighted_product
    else:
        tensor = structure_tensor if s.method == "grouped" else structure_tensor_reference
        solver = null_space

    interior = np.zeros((H, W), dtype=bool)
    interior[halo:H - halo, halo:W - halo] = True
    def nan_border(names):
        # the interior is written band by band below; only the border needs its NaN.  One
        # block for all of a model's maps: numpy asks for huge pages from 4 MB on, so
        # writing them costs a few page faults instead of one per 4 KB of every map
        a = np.empty((len(names), H, W))
        a[:, :halo] = a[:, H - halo:] = a[:, :, :halo] = a[:, :, W - halo:] = np.nan
        return dict(zip(names, a))

    out = {m: nan_border(mdl[m].outputs + ("model_error",)) for m in models}
    # disentangling runs over a few rows at a time: its many (N,) temporaries then stay
    # small enough for the allocator to reuse (and in cache) instead of each costing
    # fresh pages (measured at 512^2, full model: 0.041 s in one call, about 0.025 s so)
    cols = np.arange(halo, W - halo)
    step = max(1, _DISENTANGLE_PIXELS // cols.size)          # rows per call
    for r0 in range(halo, H - halo, band):
        r1 = min(r0 + band, H - halo)
        rows_in = slice(r0 - halo, r1 + halo)
        ct = camera_time_signals(vol, frames, c["cam_x"], c["cam_y"], c["time"], rows_in,
                                 scale=c["scale"], camera_sums=sums)
        sig = spatial_signals(ct, c["spatial"], separable=separable)
        del ct
        # J covers rows r0 - spatial.radius .. r1 + spatial.radius; keep the band
        rs = c["spatial"].radius
        if s.method == "fast":
            Jp, pidx = tensor(sig, tvals, union.rows, kernels, s.window // 2 + rs,
                        cols=slice(halo, W - halo),
                        backend="scipy" if numba_path else "numpy", product=product)
            Jp = Jp.reshape(Jp.shape[0], -1)
        else:
            J = tensor(sig, tvals, union.rows, kernels, s.window // 2)
            Jf = J[rs:J.shape[0] - rs, cols].reshape(-1, n, n)
            del J
        del sig
        yy, xx = np.meshgrid(np.arange(r0, r1), cols, indexing="ij")
        x0 = (xx - c["cx"]).ravel().astype(float)
        y0 = (yy - c["cy"]).ravel().astype(float)
        for m in models:
            if numba_path:
                P, g, err, valid, _ = null_space_fast(Jp, mdl[m], pidx[np.ix_(sub[m], sub[m])])
            elif s.method == "fast":
                P, g, err, valid = null_space(unpack(Jp, pidx[np.ix_(sub[m], sub[m])]), mdl[m])
            else:
                P, g, err, valid = solver(Jf[:, sub[m][:, None], sub[m][None, :]], mdl[m])
            inv = 1.0 / c["scale"]
            for a in range(0, r1 - r0, step):
                b = min(a + step, r1 - r0)
                px = slice(a * cols.size, b * cols.size)
                res = disentangle(P[px], g[px], mdl[m], x0[px], y0[px], c["f"], c["spacing"],
                                  slant_correction=s.slant_correction, combine=s.combine)
                # an eigenvalue of J: undo the internal rescaling (J scales with its
                # square).  For |V| beyond ~1e154 the true value is not representable:
                # it becomes inf.
                with np.errstate(over="ignore", under="ignore"):
                    res["model_error"] = (np.where(valid[px], err[px], np.nan) * inv) * inv
                for name, val in res.items():
                    out[m][name][r0 + a:r0 + b, halo:W - halo] = val.reshape(b - a, cols.size)
    used = dict(s.__dict__, filters_xy=c["spatial"].name, filters_sx=c["cam_x"].name,
                filters_sy=c["cam_y"].name if c["cam_y"] else None,
                filters_t=c["time"].name if c["time"] else None,
                temporal_radius=c["R_t"], ref_frame=c["k_ref"])
    return {m: Estimate(out[m], m, interior, dict(used, model=m)) for m in models}
