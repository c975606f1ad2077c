"""The textured cube of Sec. 4.2: scene description (POV-Ray SDL via vapory) and its
analytic ground truth.  Pure functions of :class:`CubeScene`; rendering (files, the
``povray`` process) lives in :mod:`gridflow.scenes.render`.

Frames.  gridflow's model frame is right-handed, X right, Y down, Z forward.  POV-Ray's is
left-handed, X right, Y up, Z forward: the same space with Y flipped, so a model point
``(X, Y, Z)`` is the POV-Ray point ``(X, -Y, Z)``, and a model transform ``p -> R p + c``
is the POV-Ray transform ``F R F``, ``F c`` with ``F = diag(1, -1, 1)``.  The ground truth
below is computed in the model frame from the very matrices written into the scene.

Geometry.  A cube of edge ``size`` turned by ``turn_deg`` about the vertical axis, a corner
towards the cameras: with ``turn_deg = -30`` the left face has ``Z_X = -cot 30 = -1.73``
(it recedes to the left) and the right face ``Z_X = tan 30 = 0.577``; ``Z_Y = 0``.  The
paper quotes the magnitudes 1.73 and 0.577.  It moves ``U_Z`` per frame (``-2``: 2 mm per
frame towards the cameras).  A spotlight circles the cube's centre from right to left over
the sequence; ambient light keeps the shadowed parts textured.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

import numpy as np

from gridflow.errors import ParameterError

__all__ = ["CubeScene", "scene_sdl", "cube_truth", "face_interior", "FACE_NAMES"]

FACE_NAMES = {1: "left", 2: "right"}


@dataclass(frozen=True)
class CubeScene:
    """Every parameter of the cube scene (lengths in mm, angles in degrees).

    Defaults: a 256 x 256 image with f = 650 px puts the 100 mm cube at 420 mm across most
    of the image; 1 px is 0.65 mm at that depth.  Camera spacing 0.4 mm gives a disparity
    of 0.59-0.74 px between neighbouring cameras and motion of 2 mm/frame an image motion
    of at most 0.68 px/frame on the cube (sub-pixel, as the estimator needs; both from
    :func:`cube_truth`, checked in ``tests/test_docs.py``).  The
    noise texture's features (``texture_scale`` 4 mm) are ~6 px wide: textured enough for
    the 65-tap window, smooth enough to render without anti-aliasing.
    """

    width: int = 256
    height: int = 256
    grid: tuple[int, int] = (5, 5)             # (Sy, Sx)
    spacing: tuple[float, float] = (0.4, 0.4)  # (ds_x, ds_y)
    frames: int = 9
    focal_length: float | None = None          # pixels; default 650 * width / 256
    size: float = 100.0
    center_z: float = 420.0                    # cube centre depth at the reference frame
    turn_deg: float = -30.0
    U_Z: float = -2.0                          # per frame, model frame
    texture_scale: float = 4.0
    ambient: float = 0.3
    diffuse: float = 0.6
    spot_power: float = 0.8
    spot_radius_deg: float = 10.0
    spot_falloff_deg: float = 22.0
    spot_distance: float = 300.0               # from the cube's centre
    spot_height: float = -60.0                 # model Y of the light (negative: above)
    spot_start_deg: float = 40.0               # azimuth at the first frame (right)
    spot_end_deg: float = -40.0                # ... and at the last (left)
    spotlight: bool = True                     # False: ambient + fixed light only
    static: bool = False                       # True: U_Z = 0 (for ground-truth checks)
    focus_distance: float | None = None        # mm: converging cameras (HCI-style)

    def __post_init__(self):
        if self.width < 8 or self.height < 8:
            raise ParameterError("image must be at least 8 x 8")
        if any(int(g) != g or g < 1 or g % 2 == 0 for g in self.grid):
            raise ParameterError(f"grid {self.grid} must be odd positive sizes")
        if self.frames < 1:
            raise ParameterError("frames must be >= 1")
        if not (np.isfinite(self.texture_scale) and self.texture_scale > 0):
            raise ParameterError(f"texture_scale must be a positive length in mm, got "
                                 f"{self.texture_scale}")

    @property
    def f(self) -> float:
        return float(self.focal_length or 650.0 * self.width / 256.0)

    @property
    def ref_frame(self) -> int:
        return (self.frames - 1) // 2

    @property
    def uz(self) -> float:
        return 0.0 if self.static else float(self.U_Z)

    def rotation(self) -> np.ndarray:
        """Model-frame rotation of the cube (about the vertical Y axis)."""
        a = np.deg2rad(self.turn_deg)
        return np.array([[np.cos(a), 0.0, np.sin(a)],
                         [0.0, 1.0, 0.0],
                         [-np.sin(a), 0.0, np.cos(a)]])

    def center(self, t: float) -> np.ndarray:
        """Cube centre (model frame) at time ``t`` frames from the reference frame."""
        return np.array([0.0, 0.0, self.center_z + self.uz * t])

    def light(self, k: int) -> np.ndarray:
        """Spotlight position (model frame) at frame ``k``: right to left."""
        frac = 0.0 if self.frames == 1 else k / (self.frames - 1)
        az = np.deg2rad(self.spot_start_deg + frac * (self.spot_end_deg - self.spot_start_deg))
        c = self.center(k - self.ref_frame)
        return c + np.array([self.spot_distance * np.sin(az), self.spot_height,
                             -self.spot_distance * np.cos(az)])

    def camera(self, i: int, j: int) -> np.ndarray:
        Sy, Sx = self.grid
        return np.array([(j - (Sx - 1) / 2) * self.spacing[0],
                         (i - (Sy - 1) / 2) * self.spacing[1], 0.0])

    def principal_shift(self, i: int, j: int) -> np.ndarray:
        """Shift (px, model x and y) of camera (i, j)'s principal point that makes the
        cameras converge at ``focus_distance``: points at that depth then have zero
        disparity, as in the HCI benchmark (zero without ``focus_distance``)."""
        if self.focus_distance is None:
            return np.zeros(2)
        return -self.f * self.camera(i, j)[:2] / self.focus_distance

    def disparity(self, Z: np.ndarray) -> np.ndarray:
        """HCI disparity (px per camera step along x) of depth ``Z`` (mm) at the
        reference camera: ``f ds_x (1/Z - 1/Z_focus)``."""
        inv_f = 0.0 if self.focus_distance is None else 1.0 / self.focus_distance
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.f * self.spacing[0] * (1.0 / np.asarray(Z, float) - inv_f)

    def as_dict(self) -> dict:
        d = asdict(self)
        if d["focus_distance"] is None:
            del d["focus_distance"]       # the scenes made before it keep their cache key
        return d

    def key(self) -> str:
        """Hash of everything that changes the images (the render cache key)."""
        blob = json.dumps(self.as_dict(), sort_keys=True) + _SDL_VERSION
        return hashlib.sha1(blob.encode()).hexdigest()[:12]

    name = "cube"                              # the render folder's prefix

    def sdl(self, k: int, i: int, j: int) -> str:
        """POV-Ray scene text of frame ``k``, camera ``(i, j)`` (:func:`scene_sdl`)."""
        return scene_sdl(self, k, i, j)

    def truth(self) -> dict:
        """The analytic ground truth (:func:`cube_truth`)."""
        return cube_truth(self)


_SDL_VERSION = "cube-sdl-1"
# POV-Ray's frame is left-handed with Y up: model (camera) vectors map to it by flipping Y
POV_FLIP = np.diag([1.0, -1.0, 1.0])


def pov_vec(v) -> list[float]:
    """A model-frame vector in POV-Ray's frame."""
    return [float(x) for x in (POV_FLIP @ np.asarray(v, float))]


def scene_sdl(scene: CubeScene, k: int, i: int, j: int) -> str:
    """POV-Ray scene text for frame ``k``, camera row ``i`` and column ``j``.

    The camera is a pinhole at the grid position looking along +Z with a focal length of
    ``scene.f`` pixels (``right`` = W, ``up`` = H, ``direction`` = f, all in pixels).
    """
    import vapory as vp

    t = k - scene.ref_frame
    R = POV_FLIP @ scene.rotation() @ POV_FLIP
    c = pov_vec(scene.center(t))
    h = scene.size / 2
    # POV-Ray applies `matrix` to row vectors: p' = p M + t, so M is R transposed.
    m = [*R.T.ravel().tolist(), *c]
    cube = vp.Box([-h, -h, -h], [h, h, h],
                  vp.Texture(vp.Pigment("bozo", "color_map", "{[0 rgb 0.05] [1 rgb 0.95]}",
                                        "scale", scene.texture_scale),
                             vp.Finish("ambient", scene.ambient, "diffuse", scene.diffuse)),
                  "matrix", "<%s>" % ", ".join(f"{v:.12g}" for v in m))
    cam = scene.camera(i, j)
    # a shifted principal point is an off-axis ray through the image centre: the ray of
    # image position (x, y) is (dx + x, dy + y, f) in the model frame
    dx, dy = scene.principal_shift(i, j)
    camera = vp.Camera("perspective", "location", pov_vec(cam),
                       "right", [scene.width, 0, 0], "up", [0, scene.height, 0],
                       "direction", pov_vec([dx, dy, scene.f]))
    objects = [cube, vp.Background("rgb", 0)]
    if scene.spotlight:
        objects.append(vp.LightSource(pov_vec(scene.light(k)), "rgb", scene.spot_power,
                                      "spotlight", "point_at", c,
                                      "radius", scene.spot_radius_deg,
                                      "falloff", scene.spot_falloff_deg))
    else:
        objects.append(vp.LightSource(pov_vec(scene.center(t) + [0, -100, -400]), "rgb",
                                      scene.spot_power * 0.5))
    sdl = vp.Scene(camera, objects=objects,
                   global_settings=["assumed_gamma 1.0", "ambient_light rgb 1"])
    return "#version 3.7;\n" + str(sdl)


def face_interior(face: np.ndarray, margin: float) -> np.ndarray:
    """Pixels of the visible faces at least ``margin`` pixels from another face or the
    background.

    Parameters
    ----------
    face : ndarray of int, shape (H, W)
        Face ids (:data:`FACE_NAMES`; 0 background).
    margin : float

    Returns
    -------
    ndarray of bool, shape (H, W)
    """
    from scipy.ndimage import distance_transform_edt

    inner = np.zeros(face.shape, dtype=bool)
    for fid in FACE_NAMES:
        m = face == fid
        if m.any():
            inner |= m & (distance_transform_edt(m) >= margin)
    return inner


def spot_angle(scene: CubeScene, Z: np.ndarray, k: int) -> np.ndarray:
    """Angle (degrees) between the spotlight's axis at frame ``k`` and the direction from
    the light to the surface point seen at each pixel of the reference camera.

    Inside ``spot_radius_deg`` the spot is at full strength, beyond ``spot_falloff_deg``
    it is off; in between lies its border, where the illumination varies across the
    surface.

    Parameters
    ----------
    scene : CubeScene
    Z : ndarray, shape (H, W)
        Depth of the surface at the reference frame (NaN off the cube).
    k : int
        Frame.

    Returns
    -------
    ndarray, shape (H, W)
        NaN off the cube.
    """
    H, W = Z.shape
    x = np.arange(W) - (W - 1) / 2
    y = np.arange(H) - (H - 1) / 2
    P = np.stack([x[None, :] * Z / scene.f, y[:, None] * Z / scene.f, Z], axis=-1)
    # the cube and the light move together: the geometry of frame k relative to the cube
    # is that of the reference frame shifted by the cube's motion
    shift = scene.center(k - scene.ref_frame) - scene.center(0.0)
    L = scene.light(k) - shift
    axis = scene.center(0.0) - L
    d = P - L
    cos = (d @ axis) / (np.linalg.norm(d, axis=-1) * np.linalg.norm(axis))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def cube_truth(scene: CubeScene, margin: float = 16.0) -> dict[str, np.ndarray]:
    """Ground truth at the reference camera and frame by ray casting the known cube.

    Parameters
    ----------
    scene : CubeScene
    margin : float
        Pixels a face-interior pixel keeps from any other face or the background.

    Returns
    -------
    dict of str to ndarray, each shape (H, W)
        ``Z, Zx, Zy, Ux, Uy, Uz`` (NaN off the cube), ``face`` (0 background, 1 left,
        2 right, 3 other faces), ``interior`` (bool).
    """
    H, W = scene.height, scene.width
    x = np.arange(W) - (W - 1) / 2
    y = np.arange(H) - (H - 1) / 2
    X, Y = np.meshgrid(x, y)
    d = np.stack([X / scene.f, Y / scene.f, np.ones_like(X)], axis=-1)   # ray directions
    R = scene.rotation()
    c = scene.center(0.0)
    o = -R.T @ c                                  # camera centre in cube coordinates
    dl = d @ R                                    # = (R^T d) for each pixel
    h = scene.size / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-h - o) / dl
        t2 = (h - o) / dl
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit = (tmax >= tmin) & (tmin > 0)
    axis = np.nanargmax(np.minimum(t1, t2), axis=-1)       # slab of the entry face
    sign = np.where(np.take_along_axis(dl, axis[..., None], -1)[..., 0] > 0, -1.0, 1.0)
    n_local = np.zeros(d.shape)
    np.put_along_axis(n_local, axis[..., None], sign[..., None], -1)
    n = n_local @ R.T                              # world normal of the entry face
    Z = np.where(hit, tmin, np.nan)                # direction has unit Z component
    with np.errstate(divide="ignore", invalid="ignore"):
        Zx = np.where(hit, -n[..., 0] / n[..., 2], np.nan)
        Zy = np.where(hit, -n[..., 1] / n[..., 2], np.nan)
    face = np.zeros((H, W), dtype=np.int64)
    face[hit] = 3
    face[hit & (np.abs(Zy) < 1e-9) & (Zx < 0)] = 1
    face[hit & (np.abs(Zy) < 1e-9) & (Zx > 0)] = 2
    interior = face_interior(face, margin)
    nan_off = lambda v: np.where(hit, v, np.nan)  # noqa: E731
    return {"Z": Z, "Zx": Zx, "Zy": Zy, "Ux": nan_off(0.0 * Z), "Uy": nan_off(0.0 * Z),
            "Uz": nan_off(np.full((H, W), scene.uz)), "face": face, "interior": interior}
