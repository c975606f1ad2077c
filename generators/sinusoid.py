"""The sinusoid experiment of Sec. 4.1, rendered by exact ray-plane intersection.

A textured plane ``Z = Z0 + U_Z t + Z_X Xm + Z_Y Ym`` translates with ``(U_X, U_Y, U_Z)``;
``(Xm, Ym)`` are the plane's own (material) coordinates, equal to world ``(X, Y)`` at
``t = 0`` with the origin on the reference camera's optical axis.  Beyond the paper, the
plane may also deform: its material points move with a translation plus a constant 3 x 3
velocity gradient ``G`` about the point ``X_c = (0, 0, Z0)`` the reference pixel sees,

    X(t) = X_c + U t + (I + G t) (M - X_c),      M = X_c + Xm e1 + Ym e2,

(``e1 = (1, 0, Z_X)``, ``e2 = (0, 1, Z_Y)``), so that the velocity field at ``t = 0`` is
``V(X) = U + G (X - X_c)`` and the plane stays a plane.  ``G`` is the sum of the
``G_XX .. G_ZZ`` parameters (``G_XY = dV_X / dY``), an isotropic growth in the plane
(``growth / 2`` times the projector onto it: the relative rate of change of area) and a
rotation about the plane's normal ``n = (-Z_X, -Z_Y, 1) / |.|`` at ``rotation`` rad per
unit time (right-handed in the camera frame).  An uneven growth ``growth_x`` adds a
displacement along the plane first: ``M`` is replaced by ``M + t growth_x Xm^2 / 2 e1``,
whose surface divergence is ``growth_x Xm`` (the growth of a leaf that grows faster at
its base than at its tip); the ray cast finds the mapped plane's coordinate
``Xm' = Xm + t growth_x Xm^2 / 2`` and inverts it in closed form.  Texture and
brightness change are functions of the material coordinates (Eq. 8, 11)::

    I = T(Xm, Ym) * exp((a1 + a1x Xm + a1y Ym) t + (a2 + a2x Xm + a2y Ym) t^2)

    T = offset + amplitude/2 * (sin(2 pi Xm / Lx) + sin(2 pi Ym / Ly))   (texture "sum")
    T = offset + amplitude * sin(2 pi Xm / Lx) * sin(2 pi Ym / Ly)       (texture "product")

Each pixel of each camera is rendered by intersecting its ray with the plane at that
time; nothing of the estimator's linearisation (Eq. 15-17) is used, so the estimator's
approximations are tested, not reproduced.

Conventions (``docs/model.md``): volume ``V[t, sy, sx, y, x]``, right-handed
camera frame with X right, Y down, Z forward; pixel coordinates relative to the principal
point (the image centre); cameras at ``s = ((j - (Sx-1)/2) ds_x, (i - (Sy-1)/2) ds_y, 0)``;
time ``t = (k - k_ref) * frame_interval`` with ``k_ref`` the centre frame.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from gridflow.errors import ParameterError
from gridflow.volume import GridVolume

__all__ = ["SinusoidParams", "SyntheticVolume", "make_sinusoid", "check_params", "BRIGHTNESS_PARAMS",
           "GRADIENT_PARAMS", "velocity_gradient"]

BRIGHTNESS_PARAMS = ("a1", "a1x", "a1y", "a2", "a2x", "a2y")
# the velocity gradient's entries, G_IJ = dV_I / dJ, row by row
GRADIENT_PARAMS = ("G_XX", "G_XY", "G_XZ", "G_YX", "G_YY", "G_YZ", "G_ZX", "G_ZY", "G_ZZ")
TEXTURES = ("sum", "product")

# exp() of float64 overflows at 709.8; refuse well before so that a sweep value that would
# produce inf/0 intensities is an error, not silent garbage.
_MAX_EXPONENT = 80.0


@dataclass(frozen=True)
class SinusoidParams:
    """Parameters of a sinusoid volume.

    Units: lengths in world units (think mm), time in frames unless ``frame_interval``
    says otherwise, ``f`` in pixels.  The defaults follow the paper where it speaks
    (``Z0 = 100``, ``U_Z = 0.1``, wavelengths 8 and 80 px, amplitude 1) and are
    justified in ``docs/reproduction.md`` where it is silent.

    Attributes
    ----------
    Z0 : float
        Depth of the plane on the reference optical axis at ``t = 0``.
    f : float
        Focal length in pixels.  The paper's ``f = 10`` is read as 10 mm with a 10 um
        pixel pitch, i.e. 1000 px (a literal 10 px lens would see a 160 deg field).
    U_X, U_Y, U_Z : float
        Velocity, world units per unit time.
    Z_X, Z_Y : float
        Surface slopes (normal ``(-Z_X, -Z_Y, 1)``).
    a1, a1x, a1y, a2, a2x, a2y : float
        Brightness change of Eq. 11, per unit time (``a2``: per unit time squared);
        ``a1x`` etc. additionally per world unit.
    wavelength_x, wavelength_y : float
        Texture wavelengths in pixels of the reference camera at depth ``Z0``.
    texture : {"sum", "product"}
        The sum of the two sinusoids (x- and y-structure everywhere) or their product.
    amplitude, offset : float
        Texture amplitude (peak deviation from the mean at ``t = 0``) and mean.  The
        default offset 0 is the literal reading of the paper's "amplitude 1" and "noise
        2.5 % of the amplitude"; with offset 1 BCC breaks down 5x earlier in ``a2``
        (docs/reproduction.md).
    noise : float
        Standard deviation of additive white Gaussian noise.
    seed : int
        Seed of the noise generator.
    height, width : int
        Image size in pixels.
    grid : tuple of int
        Camera grid ``(Sy, Sx)``; ``Sy = 1`` is a 1-D (horizontal) grid.
    spacing : tuple of float
        Camera spacing ``(ds_x, ds_y)`` in world units.
    frames : int
        Number of frames ``T``.
    frame_interval : float
        Time between frames.
    growth : float
        Isotropic growth in the plane: relative rate of change of surface area per unit
        time, ``d ln(area) / dt``.
    rotation : float
        Rotation about the plane's normal, rad per unit time.
    G_XX, G_XY, G_XZ, G_YX, G_YY, G_YZ, G_ZX, G_ZY, G_ZZ : float
        A velocity gradient ``dV_I / dJ`` per unit time, added to the two above
        (anisotropic growth, shear, rotation about any axis).
    growth_x : float
        Uneven growth: the growth's change per world unit along the material coordinate
        ``Xm`` (per unit time per world unit), so that the growth at a material point is
        ``growth + growth_x Xm`` (a leaf growing faster at its base than at its tip).  The
        material points move by ``t growth_x Xm^2 / 2`` along ``e1`` within the plane
        before ``I + G t`` acts (module docstring), so the plane stays a plane and the
        rendering stays exact.
    """

    Z0: float = 100.0
    f: float = 1000.0
    U_X: float = 0.0
    U_Y: float = 0.0
    U_Z: float = 0.1
    Z_X: float = 0.0
    Z_Y: float = 0.0
    a1: float = 0.0
    a1x: float = 0.0
    a1y: float = 0.0
    a2: float = 0.0
    a2x: float = 0.0
    a2y: float = 0.0
    wavelength_x: float = 8.0
    wavelength_y: float = 80.0
    texture: str = "sum"
    amplitude: float = 1.0
    offset: float = 0.0
    noise: float = 0.0
    seed: int = 0
    height: int = 192
    width: int = 192
    grid: tuple[int, int] = (5, 5)
    spacing: tuple[float, float] = (0.05, 0.05)
    frames: int = 9
    frame_interval: float = 1.0
    growth: float = 0.0
    rotation: float = 0.0
    G_XX: float = 0.0
    G_XY: float = 0.0
    G_XZ: float = 0.0
    G_YX: float = 0.0
    G_YY: float = 0.0
    G_YZ: float = 0.0
    G_ZX: float = 0.0
    G_ZY: float = 0.0
    G_ZZ: float = 0.0
    growth_x: float = 0.0

    def __post_init__(self) -> None:
        if self.texture not in TEXTURES:
            raise ParameterError(f"texture must be one of {TEXTURES}, got {self.texture!r}")
        for fl in fields(self):
            if fl.name == "texture":
                continue
            val = getattr(self, fl.name)
            vals = val if isinstance(val, tuple) else (val,)
            for v in vals:
                if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                    raise TypeError(f"{fl.name} must be numeric, got {val!r}")
                # a Python int is finite at any size (np.isfinite refuses one of 2**64)
                if not isinstance(v, (int, np.integer)) and not np.isfinite(v):
                    raise ParameterError(f"{fl.name} must be finite, got {val!r}")
        if len(self.grid) != 2 or len(self.spacing) != 2:
            raise ParameterError("grid is (Sy, Sx) and spacing is (ds_x, ds_y)")
        positive = {"Z0": self.Z0, "f": self.f, "wavelength_x": self.wavelength_x,
                    "wavelength_y": self.wavelength_y, "frame_interval": self.frame_interval}
        for name, v in positive.items():
            if v <= 0:
                raise ParameterError(f"{name} must be positive, got {v}")
        with np.errstate(over="ignore"):
            wavenumbers = texture_wavenumbers(self)
        for name, k in zip(("wavelength_x", "wavelength_y"), wavenumbers):
            if not np.isfinite(k):
                # a wavelength near the smallest float: 2 pi / (wavelength Z0 / f)
                # overflows, and the texture would be NaN
                raise ParameterError(f"{name} {getattr(self, name)!r} px is too small: "
                                     f"the texture's wavenumber 2 pi f / ({name} Z0) "
                                     "overflows")
        for name in ("noise", "amplitude"):
            if getattr(self, name) < 0:
                raise ParameterError(f"{name} must be non-negative")
        for name in ("height", "width", "frames", "seed"):
            v = getattr(self, name)
            if int(v) != v or v < 0:
                raise ParameterError(f"{name} must be a non-negative integer, got {v}")
        if self.height < 1 or self.width < 1 or self.frames < 1:
            raise ParameterError("height, width and frames must be at least 1")
        sy, sx = self.grid
        if int(sy) != sy or int(sx) != sx or sy < 1 or sx < 1:
            raise ParameterError(f"grid must be two positive integers, got {self.grid}")
        if self.spacing[0] <= 0 or (sy > 1 and self.spacing[1] <= 0):
            raise ParameterError(f"camera spacing must be positive, got {self.spacing}")

    @property
    def ref_frame(self) -> int:
        """Index ``k_ref`` of the reference (centre) frame."""
        return (self.frames - 1) // 2

    def replace(self, **changes) -> "SinusoidParams":
        """Return a copy with ``changes`` applied (validated)."""
        unknown = set(changes) - {fl.name for fl in fields(self)}
        if unknown:
            raise ParameterError(f"unknown sinusoid parameter(s): {sorted(unknown)}")
        d = asdict(self)
        d.update(changes)
        for key in ("grid", "spacing"):
            d[key] = tuple(d[key])
        return SinusoidParams(**d)

    def as_dict(self) -> dict:
        return asdict(self)

    @property
    def deforms(self) -> bool:
        """Whether the plane deforms or rotates (a velocity gradient is set)."""
        return any(getattr(self, n) != 0
                   for n in ("growth", "rotation", "growth_x") + GRADIENT_PARAMS)


def _normal(p: SinusoidParams) -> np.ndarray:
    n = np.array([-p.Z_X, -p.Z_Y, 1.0])
    return n / np.linalg.norm(n)


def velocity_gradient(p: SinusoidParams) -> np.ndarray:
    """The velocity gradient ``G`` (3 x 3, per unit time) of the parameters: ``G_XX ..
    G_ZZ`` plus ``growth / 2`` times the projector onto the plane plus ``rotation`` times
    the cross-product matrix of the normal."""
    n = _normal(p)
    tangent = np.eye(3) - np.outer(n, n)
    cross = np.array([[0.0, -n[2], n[1]], [n[2], 0.0, -n[0]], [-n[1], n[0], 0.0]])
    G = np.array([getattr(p, k) for k in GRADIENT_PARAMS], dtype=float).reshape(3, 3)
    return G + 0.5 * p.growth * tangent + p.rotation * cross


class SyntheticVolume(GridVolume):
    """A :class:`gridflow.volume.GridVolume` made by :func:`make_sinusoid`;
    ``meta["params"]`` holds the :class:`SinusoidParams` as a dict and ``params`` the
    object itself."""

    @property
    def params(self) -> SinusoidParams:
        return SinusoidParams(**{k: tuple(v) if isinstance(v, list) else v
                                 for k, v in self.meta["params"].items()})


def _pixel_grid(p: SinusoidParams) -> tuple[np.ndarray, np.ndarray]:
    x = np.arange(p.width, dtype=float) - (p.width - 1) / 2.0
    y = np.arange(p.height, dtype=float) - (p.height - 1) / 2.0
    return np.meshgrid(x, y)


def _intersect(p: SinusoidParams, x, y, sx, sy, t: float):
    """Exact ray-plane intersection; returns depth and material coordinates.  The camera
    offsets ``sx, sy`` are floats or arrays that broadcast with the pixels ``x, y``."""
    denom = 1.0 - (p.Z_X * x + p.Z_Y * y) / p.f
    num = p.Z0 + p.U_Z * t + p.Z_X * (sx - p.U_X * t) + p.Z_Y * (sy - p.U_Y * t)
    # a pixel whose ray is parallel to the plane (denom exactly 0) is refused before the
    # division, not turned into inf with a warning
    bad = np.any(denom <= 0)
    Z = num / np.where(denom > 0, denom, 1.0)
    if bad or np.any(Z <= 0):
        raise ParameterError(
            "the plane is seen edge-on or behind a camera for some pixel "
            f"(Z_X={p.Z_X}, Z_Y={p.Z_Y}, f={p.f}, image {p.height}x{p.width}); "
            "reduce the slopes or the image size")
    Xm = sx + x * Z / p.f - p.U_X * t
    Ym = sy + y * Z / p.f - p.U_Y * t
    return Z, Xm, Ym


def _intersect_deforming(p: SinusoidParams, G: np.ndarray, x, y, sx, sy, t: float):
    """Exact ray-plane intersection with the plane deformed by ``I + G t``: the material
    point ``M = X_c + Xm e1 + Ym e2`` is at ``X_c + U t + (I + G t)(M - X_c)``.  Along the
    ray ``s + Z r``, ``r = (x/f, y/f, 1)``: ``q = s + Z r - X_c - U t = Xm c1 + Ym c2``
    with ``c_i = (I + G t) e_i``, so ``q`` lies in the plane spanned by ``c1, c2`` (normal
    ``N = c1 x c2``), which gives ``Z``, then ``(Xm, Ym)`` from the 2 x 2 Gram system.
    With an uneven growth the coordinate found is ``Xm' = Xm + t b Xm^2 / 2`` (``b =
    growth_x``), inverted as ``Xm = 2 Xm' / (1 + sqrt(1 + 2 t b Xm'))`` (the root that is
    ``Xm'`` at ``t b = 0``, without the cancellation of the textbook form)."""
    Z, Xm, Ym = _intersect_mapped(p, np.eye(3) + G * t, x, y, sx, sy, t)
    if p.growth_x != 0 and t != 0:
        disc = 1.0 + 2.0 * t * p.growth_x * Xm
        if np.any(disc <= 0):
            raise ParameterError(
                f"growth_x={p.growth_x} folds the plane at t = {t:g} (material points "
                "would pass each other): use a smaller growth_x, fewer frames or a smaller "
                "image")
        Xm = 2.0 * Xm / (1.0 + np.sqrt(disc))
    return Z, Xm, Ym


def _intersect_mapped(p: SinusoidParams, A: np.ndarray, x, y, sx, sy, t: float):
    """:func:`_intersect_deforming` with the plane mapped by any 3 x 3 ``A`` at time ``t``
    (``I + G t`` there; a recording whose growth rate changes with time passes its own)."""
    c1 = A @ np.array([1.0, 0.0, p.Z_X])
    c2 = A @ np.array([0.0, 1.0, p.Z_Y])
    N = np.cross(c1, c2)
    # s - X_c - U t, shape (3,) or (3, ...) where the camera offsets are arrays
    b = np.stack(np.broadcast_arrays(sx - p.U_X * t, sy - p.U_Y * t, -p.Z0 - p.U_Z * t))
    rdotN = (x / p.f) * N[0] + (y / p.f) * N[1] + N[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = -(N @ b) / rdotN
    if np.any(rdotN <= 0) or not np.all(Z > 0):
        raise ParameterError(
            "the deforming plane is seen edge-on or behind a camera for some pixel at "
            f"t = {t:g} (Z_X={p.Z_X}, Z_Y={p.Z_Y}, growth={p.growth}, rotation={p.rotation}, "
            f"image {p.height}x{p.width}); reduce the slopes, the gradient or the frames")
    q = (b[0] + Z * x / p.f, b[1] + Z * y / p.f, b[2] + Z)
    d1 = c1[0] * q[0] + c1[1] * q[1] + c1[2] * q[2]
    d2 = c2[0] * q[0] + c2[1] * q[1] + c2[2] * q[2]
    g11, g12, g22 = c1 @ c1, c1 @ c2, c2 @ c2
    det = g11 * g22 - g12 * g12
    return Z, (g22 * d1 - g12 * d2) / det, (g11 * d2 - g12 * d1) / det


def texture_wavenumbers(p: SinusoidParams) -> tuple[float, float]:
    """The texture's angular wavenumbers per world unit in material coordinates: its
    wavelengths, given in pixels of the reference camera at depth ``Z0``."""
    return (2 * np.pi / (p.wavelength_x * p.Z0 / p.f),
            2 * np.pi / (p.wavelength_y * p.Z0 / p.f))


def texture(p: SinusoidParams, Xm, Ym, kx: float, ky: float):
    """The texture ``T(Xm, Ym)`` (module docstring) at material coordinates ``Xm, Ym``."""
    if p.texture == "sum":
        return p.offset + 0.5 * p.amplitude * (np.sin(kx * Xm) + np.sin(ky * Ym))
    return p.offset + p.amplitude * np.sin(kx * Xm) * np.sin(ky * Ym)


def make_sinusoid(params: SinusoidParams | None = None, *, dtype=np.float64,
                  **overrides) -> SyntheticVolume:
    """Render a sinusoid volume with ground truth.

    Parameters
    ----------
    params : SinusoidParams, optional
        Defaults to ``SinusoidParams()``; ``overrides`` replace single fields.
    dtype : {numpy.float64, numpy.float32}
        Type of the returned volume (rendering is always done in float64).

    Returns
    -------
    SyntheticVolume
        ``volume`` has shape ``(T, Sy, Sx, H, W)``.

    Raises
    ------
    ValueError
        If the plane is not visible in every pixel, or the brightness exponent
        ``|h|`` would exceed 80 anywhere (``exp`` would lose all precision).
    """
    p = (params or SinusoidParams()).replace(**overrides) if overrides else (params or SinusoidParams())
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise ParameterError(f"dtype must be float32 or float64, got {dtype}")
    check_params(p)
    x, y = _pixel_grid(p)
    Sy, Sx = p.grid
    dsx, dsy = p.spacing
    kx, ky = texture_wavenumbers(p)
    vol = np.empty((p.frames, Sy, Sx, p.height, p.width), dtype=dtype)
    rng = np.random.default_rng(p.seed)
    # a plane that only translates keeps the paper's closed form (bit for bit as before)
    G = velocity_gradient(p) if p.deforms else None
    for k in range(p.frames):
        t = (k - p.ref_frame) * p.frame_interval
        for i in range(Sy):
            sy = (i - (Sy - 1) / 2.0) * dsy
            for j in range(Sx):
                sx = (j - (Sx - 1) / 2.0) * dsx
                if G is None:
                    _, Xm, Ym = _intersect(p, x, y, sx, sy, t)
                else:
                    _, Xm, Ym = _intersect_deforming(p, G, x, y, sx, sy, t)
                h = ((p.a1 + p.a1x * Xm + p.a1y * Ym) * t
                     + (p.a2 + p.a2x * Xm + p.a2y * Ym) * t * t)
                img = texture(p, Xm, Ym, kx, ky) * np.exp(h)
                if p.noise > 0:
                    # image by image, in C order: reproducible from the seed alone, and
                    # no volume-sized float64 temporary (add_noise draws the same numbers)
                    img += p.noise * rng.standard_normal(img.shape)
                vol[k, i, j] = img
    return SyntheticVolume(volume=vol, focal_length=p.f, camera_spacing=(dsx, dsy),
                           principal_point=((p.width - 1) / 2.0, (p.height - 1) / 2.0),
                           truth=ground_truth(p), meta={"generator": "sinusoid", "params": p.as_dict()})


def add_noise(clean: SyntheticVolume, noise: float, seed: int) -> SyntheticVolume:
    """The volume ``make_sinusoid`` renders with ``noise`` and ``seed``, from its noise-free
    rendering: the same normal numbers, drawn image by image in the same order and added
    in float64, so the result is identical to the last bit.  Lets a sweep render each
    noise-free volume once for all its noise levels and seeds.

    Parameters
    ----------
    clean : SyntheticVolume
        From :func:`make_sinusoid` with ``noise = 0`` and the default float64; its volume
        has shape (T, Sy, Sx, H, W).  (A float32 rendering has lost the digits the noise
        is added to, so it could not give the same result.)
    noise : float
        Standard deviation of the added Gaussian noise (>= 0).
    seed : int

    Returns
    -------
    SyntheticVolume
        A new volume (``clean`` is not changed); ``clean`` itself if ``noise == 0``.
    """
    p = clean.params
    if p.noise != 0:
        raise ParameterError(f"add_noise needs a noise-free volume; this one has noise {p.noise}")
    if clean.volume.dtype != np.float64:
        raise ParameterError(f"add_noise needs a float64 rendering, got {clean.volume.dtype}")
    q = p.replace(noise=float(noise), seed=int(seed))
    check_params(q)
    if q.noise == 0:
        return clean
    rng = np.random.default_rng(q.seed)
    vol = np.empty_like(clean.volume)
    T, Sy, Sx = vol.shape[:3]
    for k in range(T):
        for i in range(Sy):
            for j in range(Sx):
                img = clean.volume[k, i, j].copy()
                img += q.noise * rng.standard_normal(img.shape)
                vol[k, i, j] = img
    return SyntheticVolume(volume=vol, focal_length=clean.focal_length,
                           camera_spacing=clean.camera_spacing,
                           principal_point=clean.principal_point, truth=clean.truth,
                           meta={**clean.meta, "params": q.as_dict()})


def ground_truth(p: SinusoidParams) -> dict[str, np.ndarray]:
    """Ground-truth maps at the reference camera and frame, per frame.

    Parameters
    ----------
    p : SinusoidParams

    Returns
    -------
    dict of str to ndarray, each shape (H, W)
        ``Z, Zx, Zy, Ux, Uy, Uz, growth, rotation, Zx_t, Zy_t, a1, a2, a1x, a1y, a2x,
        a2y``.  Motion and brightness parameters are converted to per-frame units with
        ``frame_interval``; ``Ux, Uy, Uz`` are the velocity of the surface point each
        pixel sees, and ``a1``, ``a2`` the local values ``a1 + a1x X + a1y Y`` there.
    """
    x, y = _pixel_grid(p)
    Z, Xm, Ym = _intersect(p, x, y, 0.0, 0.0, 0.0)
    dt = p.frame_interval
    const = lambda v: np.full(Z.shape, float(v))  # noqa: E731
    G = velocity_gradient(p)
    # the velocity of the material point each pixel sees, V = U + G (M - X_c)
    e1, e2 = np.array([1.0, 0.0, p.Z_X]), np.array([0.0, 1.0, p.Z_Y])
    U = np.array([p.U_X, p.U_Y, p.U_Z])
    b = p.growth_x
    V = [U[i] + (G[i] @ e1) * Xm + (G[i] @ e2) * Ym + 0.5 * b * Xm * Xm * e1[i]
         for i in range(3)]
    # growth: the surface divergence tr((I - n n^T) G); rotation: w . n with w the axial
    # vector of G's antisymmetric part
    n = _normal(p)
    growth = float(np.trace((np.eye(3) - np.outer(n, n)) @ G))
    w = 0.5 * np.array([G[2, 1] - G[1, 2], G[0, 2] - G[2, 0], G[1, 0] - G[0, 1]])
    # the uneven growth's field b Xm^2 / 2 e1 has the surface gradient L d = b Xm e1 (e1*.d)
    # (e1* the dual tangent): divergence b Xm, and a turn about n of
    # b Xm ((t2.e1)(e1*.t1) - (t1.e1)(e1*.t2)) / 2, zero unless the tangents are oblique
    m = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    e1_dual = np.linalg.inv(m)[0] @ np.stack([e1, e2])
    t1 = e1 / np.linalg.norm(e1)
    t2 = np.cross(n, t1)
    turn = 0.5 * ((t2 @ e1) * (e1_dual @ t1) - (t1 @ e1) * (e1_dual @ t2))
    # slopes' rates: the normal e1 x e2 = (-Z_X, -Z_Y, 1) moves by G e1 x e2 + e1 x G e2;
    # Z_X = -N_x / N_z, so dZ_X/dt = -dN_x - Z_X dN_z (N_z = 1)
    dN = np.cross(G @ e1, e2) + np.cross(e1, G @ e2)
    return {
        "Z": Z,
        "Zx": const(p.Z_X), "Zy": const(p.Z_Y),
        "Ux": V[0] * dt, "Uy": V[1] * dt, "Uz": V[2] * dt,
        "growth": (growth + b * Xm) * dt, "rotation": (float(w @ n) + b * turn * Xm) * dt,
        "Zx_t": const((-dN[0] - p.Z_X * dN[2]) * dt),
        "Zy_t": const((-dN[1] - p.Z_Y * dN[2]) * dt),
        "a1": (p.a1 + p.a1x * Xm + p.a1y * Ym) * dt,
        "a2": (p.a2 + p.a2x * Xm + p.a2y * Ym) * dt * dt,
        "a1x": const(p.a1x * dt), "a1y": const(p.a1y * dt),
        "a2x": const(p.a2x * dt * dt), "a2y": const(p.a2y * dt * dt),
    }


def check_params(p: SinusoidParams) -> None:
    """Raise the errors :func:`make_sinusoid` would raise, without rendering.

    The plane must be visible and ``|h|`` bounded everywhere.  ``h`` is linear in the
    material coordinates, which are monotone along image rows and columns, so its extremes
    lie on the image border: only border pixels are evaluated.

    Raises
    ------
    ValueError
    """
    x, y = _pixel_grid(p)
    border = np.zeros(x.shape, dtype=bool)
    border[[0, -1], :] = True
    border[:, [0, -1]] = True
    Sy, Sx = p.grid
    # every view's border pixels in one flat array per frame (views outer, pixels inner):
    # the intersections are elementwise in the pixel and the camera offset, so one call
    # a frame does what one call a view did (a sweep spec checks hundreds of points)
    n_border = int(border.sum())
    sx = np.repeat(np.tile((np.arange(Sx) - (Sx - 1) / 2.0) * p.spacing[0], Sy), n_border)
    sy = np.repeat(np.repeat((np.arange(Sy) - (Sy - 1) / 2.0) * p.spacing[1], Sx), n_border)
    xb, yb = np.tile(x[border], Sy * Sx), np.tile(y[border], Sy * Sx)
    G = velocity_gradient(p) if p.deforms else None
    for k in range(p.frames):
        t = (k - p.ref_frame) * p.frame_interval
        if G is not None:
            _, Xm, Ym = _intersect_deforming(p, G, xb, yb, sx, sy, t)
        else:
            _, Xm, Ym = _intersect(p, xb, yb, sx, sy, t)
        h = ((p.a1 + p.a1x * Xm + p.a1y * Ym) * t
             + (p.a2 + p.a2x * Xm + p.a2y * Ym) * t * t)
        if np.max(np.abs(h)) > _MAX_EXPONENT:
            raise ParameterError(
                f"brightness exponent |h| reaches {np.max(np.abs(h)):.3g} (> "
                f"{_MAX_EXPONENT}) at frame {k}: a1={p.a1}, a1x={p.a1x}, a1y={p.a1y}, "
                f"a2={p.a2}, a2x={p.a2x}, a2y={p.a2y} overflow exp(); use smaller "
                "values, fewer frames or a smaller image")
