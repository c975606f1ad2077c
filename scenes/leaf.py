"""A growing leaf for POV-Ray: a flat, leaf-shaped, textured surface that grows uniformly
in its own plane, moves towards the cameras and is lit by a spotlight circling it, with
its ground truth from the scene's own geometry.

The leaf lies in the local ``(u, v)`` plane: its base at ``v = -L/2``, its tip at
``v = +L/2``, half-width ``W/2 * sin(pi s^0.75)^0.8`` at ``s = (v + L/2) / L``.  At frame
offset ``t`` it is scaled by ``1 + growth t / 2`` about its base (so that its area grows
at the relative rate ``growth`` at ``t = 0``), turned by ``tilt_x_deg`` about the camera X
axis and ``tilt_y_deg`` about Y, and its base is carried to ``(0, base_y, center_z +
U_Z t)``.  The texture (POV-Ray's ``bozo``, high contrast) is declared inside the object
before these transforms, so it grows with the leaf: material points keep their texture.
A growth gradient from base to tip (as dicot leaves show) would need a non-affine
deformation of the surface, which POV-Ray's object transforms cannot express; it is not
modelled.

Frames: model (camera) frame right-handed, X right, Y down, Z forward, as everywhere in
gridflow; POV-Ray's left-handed Y-up frame is reached by flipping Y (as in
:mod:`scenes.cube`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

import numpy as np

from gridflow.errors import ParameterError

from .cube import POV_FLIP, pov_vec

__all__ = ["LeafScene", "LeafRecording", "leaf_truth", "leaf_outline", "LEAF_TRUTH_NAMES"]

_SDL_VERSION = "leaf-sdl-1"


def leaf_outline(s: np.ndarray) -> np.ndarray:
    """Half-width of the leaf (in units of its full width) at ``s`` in [0, 1] from base
    to tip: widest a third of the way up, pointed at the tip."""
    return 0.5 * np.sin(np.pi * np.clip(s, 0.0, 1.0) ** 0.75) ** 0.8


@dataclass(frozen=True)
class LeafScene:
    """Every parameter of the leaf scene (lengths in mm, angles in degrees, rates per
    frame).

    Defaults: the leaf is 150 mm long and 80 mm wide at 420 mm, seen by a 5 x 5 grid
    0.4 mm apart with f = 650 px (as the cube: 0.59-0.74 px of disparity between
    neighbouring cameras); it grows at 2e-3 per frame (about 6 % per hour at a frame every
    two minutes, a fast leaf) and approaches the cameras at 1 mm per frame.
    """

    width: int = 256
    height: int = 256
    grid: tuple[int, int] = (5, 5)
    spacing: tuple[float, float] = (0.4, 0.4)
    frames: int = 9
    focal_length: float | None = None
    leaf_length: float = 150.0
    leaf_width: float = 80.0
    center_z: float = 420.0            # depth of the leaf's centre at the reference frame
    tilt_x_deg: float = 25.0           # about the camera X axis (slope along Y)
    tilt_y_deg: float = -20.0          # about the camera Y axis (slope along X)
    growth: float = 2e-3               # relative area rate per frame
    U_Z: float = -1.0                  # per frame
    texture_scale: float = 6.0
    ambient: float = 0.3
    diffuse: float = 0.6
    spot_power: float = 0.8
    spot_radius_deg: float = 8.0
    spot_falloff_deg: float = 18.0
    spot_distance: float = 300.0
    spot_height: float = -60.0
    spot_start_deg: float = 40.0
    spot_end_deg: float = -40.0

    name = "leaf"                      # the render folder's prefix

    def __post_init__(self):
        if self.width < 8 or self.height < 8:
            raise ParameterError("image must be at least 8 x 8")
        if any(int(g) != g or g < 1 or g % 2 == 0 for g in self.grid):
            raise ParameterError(f"grid {self.grid} must be odd positive sizes")
        if self.frames < 1:
            raise ParameterError("frames must be >= 1")
        if not (self.leaf_length > 0 and self.leaf_width > 0):
            raise ParameterError("the leaf's length and width must be positive")

    @property
    def f(self) -> float:
        return float(self.focal_length or 650.0 * self.width / 256.0)

    @property
    def ref_frame(self) -> int:
        return (self.frames - 1) // 2

    def rotation(self) -> np.ndarray:
        """Model-frame rotation of the leaf's local frame: about X, then about Y."""
        ax, ay = np.deg2rad(self.tilt_x_deg), np.deg2rad(self.tilt_y_deg)
        Rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
        Ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
        return Ry @ Rx

    def center(self, t: float) -> np.ndarray:
        """The leaf's centre (model frame) at frame offset ``t`` if it did not grow."""
        return np.array([0.0, 0.0, self.center_z + self.U_Z * t])

    def base(self, t: float) -> np.ndarray:
        """The leaf's base point, the fixed point of its growth, at frame offset ``t``."""
        return self.center(t) + self.rotation() @ np.array([0.0, -self.leaf_length / 2, 0.0])

    def scale(self, t: float) -> float:
        """The leaf's linear size at frame offset ``t`` relative to the reference frame:
        ``1 + growth t / 2``."""
        return 1.0 + 0.5 * self.growth * t

    def growth_rate(self, t: float) -> float:
        """Relative area rate at frame offset ``t``, ``2 s'(t) / s(t)`` (``growth`` at the
        reference frame)."""
        return self.growth / self.scale(t)

    def transform(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)``: local leaf coordinates ``p`` (base-centred at ``(0, -L/2, 0)``) to
        the model frame, ``X = A p + b`` at frame offset ``t``."""
        s = self.scale(t)
        R = self.rotation()
        pb = np.array([0.0, -self.leaf_length / 2, 0.0])
        A = s * R
        b = self.base(t) - A @ pb
        return A, b

    def light(self, k: int) -> np.ndarray:
        frac = 0.0 if self.frames == 1 else k / (self.frames - 1)
        az = np.deg2rad(self.spot_start_deg + frac * (self.spot_end_deg - self.spot_start_deg))
        c = self.center(k - self.ref_frame)
        return c + np.array([self.spot_distance * np.sin(az), self.spot_height,
                             -self.spot_distance * np.cos(az)])

    def camera(self, i: int, j: int) -> np.ndarray:
        Sy, Sx = self.grid
        return np.array([(j - (Sx - 1) / 2) * self.spacing[0],
                         (i - (Sy - 1) / 2) * self.spacing[1], 0.0])

    def as_dict(self) -> dict:
        return asdict(self)

    def key(self) -> str:
        blob = json.dumps(self.as_dict(), sort_keys=True) + _SDL_VERSION
        return hashlib.sha1(blob.encode()).hexdigest()[:12]

    def sdl(self, k: int, i: int, j: int) -> str:
        """POV-Ray scene text for frame ``k``, camera ``(i, j)``."""
        import vapory as vp

        t = k - self.ref_frame
        A, b = self.transform(t)
        M = POV_FLIP @ A @ POV_FLIP
        m = [*M.T.ravel().tolist(), *pov_vec(b)]
        s = np.linspace(0.0, 1.0, 61)
        half = leaf_outline(s) * self.leaf_width
        v = -self.leaf_length / 2 + s * self.leaf_length
        pts = [(float(h), float(y)) for h, y in zip(half, v)]
        pts += [(-h, y) for h, y in reversed(pts[1:-1])]
        pts.append(pts[0])                               # POV-Ray closes with the first
        # local (u, v, 0) in the model frame is (u, -v, 0) in POV-Ray's (Y up): the matrix
        # below includes the flip, so the polygon is given in model coordinates
        poly = "polygon { %d, %s\n texture { pigment { bozo color_map { [0 rgb 0.05] " \
               "[1 rgb 0.95] } scale %g } finish { ambient %g diffuse %g } }\n" \
               " matrix <%s> }" % (
                   len(pts), ", ".join(f"<{u:.9g}, {-y:.9g}>" for u, y in pts),
                   self.texture_scale, self.ambient, self.diffuse,
                   ", ".join(f"{x:.12g}" for x in m))
        cam = self.camera(i, j)
        camera = vp.Camera("perspective", "location", pov_vec(cam),
                           "right", [self.width, 0, 0], "up", [0, self.height, 0],
                           "direction", pov_vec([0.0, 0.0, self.f]))
        c = pov_vec(self.center(t))
        light = vp.LightSource(pov_vec(self.light(k)), "rgb", self.spot_power,
                               "spotlight", "point_at", c, "radius", self.spot_radius_deg,
                               "falloff", self.spot_falloff_deg)
        sdl = vp.Scene(camera, objects=[vp.Background("rgb", 0), light],
                       global_settings=["assumed_gamma 1.0", "ambient_light rgb 1"])
        return "#version 3.7;\n" + str(sdl) + "\n" + poly + "\n"

    def truth(self) -> dict:
        return leaf_truth(self)


def leaf_truth(scene: LeafScene, margin: float = 12.0,
               frame: int | None = None) -> dict[str, np.ndarray]:
    """Ground truth at the reference camera and ``frame`` (default the reference frame),
    from the scene's geometry.

    Returns
    -------
    dict of str to ndarray, each shape (H, W)
        ``Z, Zx, Zy, Ux, Uy, Uz`` (the velocity of the leaf point each pixel sees),
        ``growth``, ``rotation``, ``Zx_t``, ``Zy_t`` (NaN off the leaf), ``leaf`` (bool),
        ``interior`` (leaf pixels at least ``margin`` px from its edge), ``spot_angle``
        (degrees from the spotlight's axis at ``frame``).
    """
    from scipy.ndimage import distance_transform_edt

    k = scene.ref_frame if frame is None else int(frame)
    t = float(k - scene.ref_frame)

    H, W = scene.height, scene.width
    x = np.arange(W) - (W - 1) / 2
    y = np.arange(H) - (H - 1) / 2
    X, Y = np.meshgrid(x, y)
    A, b = scene.transform(t)
    n = scene.rotation() @ np.array([0.0, 0.0, 1.0])
    r = np.stack([X / scene.f, Y / scene.f, np.ones_like(X)], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = (b @ n) / (r @ n)                       # ray through the origin hits n.X = n.b
    P = r * Z[..., None]
    local = (P - b) @ np.linalg.inv(A).T           # (u, v, 0) on the leaf
    s = (local[..., 1] + scene.leaf_length / 2) / scene.leaf_length
    leaf = (s >= 0) & (s <= 1) & (np.abs(local[..., 0]) <= leaf_outline(s) * scene.leaf_width)
    leaf &= Z > 0
    # velocity: the base moves with (0, 0, U_Z); the rest grows away from it at s'/s,
    # half the area rate
    g = scene.growth_rate(t)
    V = np.array([0.0, 0.0, scene.U_Z]) + 0.5 * g * (P - scene.base(t))
    nan = lambda a: np.where(leaf, a, np.nan)  # noqa: E731
    const = lambda v: nan(np.full((H, W), float(v)))  # noqa: E731
    Zx, Zy = -n[0] / n[2], -n[1] / n[2]
    L = scene.light(k)
    axis = scene.center(t) - L
    d = P - L
    cos = (d @ axis) / (np.linalg.norm(d, axis=-1) * np.linalg.norm(axis))
    return {"Z": nan(Z), "Zx": const(Zx), "Zy": const(Zy),
            "Ux": nan(V[..., 0]), "Uy": nan(V[..., 1]), "Uz": nan(V[..., 2]),
            "growth": const(g), "rotation": const(0.0), "Zx_t": const(0.0),
            "Zy_t": const(0.0), "leaf": leaf,
            "interior": leaf & (distance_transform_edt(leaf) >= margin),
            "spot_angle": nan(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))}


@dataclass(frozen=True)
class LeafRecording(LeafScene):
    """The leaf as a long recording: it grows at a rate that follows a day/night rhythm,
    under a spotlight that swings across it with the same rhythm, with truth per frame.

    Time runs from frame 0 (``ref_frame`` is 0: frame ``k`` is time ``t = k``).  The
    relative area rate is ``g(t) = growth (1 + rhythm sin(2 pi t / period))`` and the
    leaf's linear size, about its base, ``s(t) = exp(1/2 integral_0^t g)`` (as the
    synthetic plane of :mod:`gridflow.generators.recording`).  The spotlight's azimuth is
    ``spot_swing_deg sin(2 pi t / period)`` about the leaf's centre, so each pixel's
    brightness changes smoothly with the day.  ``U_Z`` is 0 by default: a leaf held in
    place, as a growth experiment holds it (a constant approach over hundreds of frames
    would leave the cameras' depth of field).

    Rendering (:func:`scenes.render.render_cube`) writes the images of every frame into a
    camera-grid folder without truth (a recording's folder carries none);
    :meth:`truth_at` gives each frame's.
    """

    frames: int = 60
    U_Z: float = 0.0
    rhythm: float = 0.8
    period: float = 40.0
    spot_swing_deg: float = 25.0
    frame_interval: float = 120.0
    margin: float = 16.0               # px: the truth's growth is given this far inside

    name = "leafrec"

    def __post_init__(self):
        super().__post_init__()
        if not 0 <= self.rhythm < 1:
            raise ParameterError(f"rhythm {self.rhythm} must be in [0, 1): the leaf "
                                 "never shrinks")
        if not self.period > 0:
            raise ParameterError(f"period {self.period} must be positive (frames)")

    @property
    def ref_frame(self) -> int:
        return 0

    def growth_rate(self, t) -> float:
        return float(self.growth * (1.0 + self.rhythm * np.sin(2 * np.pi * t / self.period)))

    def scale(self, t: float) -> float:
        w = 2 * np.pi / self.period
        integral = self.growth * (t + self.rhythm * (1.0 - np.cos(w * t)) / w)
        return float(np.exp(0.5 * integral))

    def light(self, k: int) -> np.ndarray:
        az = np.deg2rad(self.spot_swing_deg * np.sin(2 * np.pi * k / self.period))
        c = self.center(float(k))
        return c + np.array([self.spot_distance * np.sin(az), self.spot_height,
                             -self.spot_distance * np.cos(az)])

    def truth(self) -> dict:
        return {}

    def truth_at(self, k: int) -> dict[str, np.ndarray]:
        """Truth of frame ``k`` at the centre camera, each shape (H, W): ``Z``, ``Ux``,
        ``Uy``, ``Uz`` on the leaf and ``growth`` on its interior (``margin`` px inside
        its edge, where the estimator's window lies on the leaf), NaN elsewhere."""
        t = leaf_truth(self, margin=self.margin, frame=k)
        out = {n: t[n] for n in ("Z", "Ux", "Uy", "Uz")}
        out["growth"] = np.where(t["interior"], t["growth"], np.nan)
        return out


LEAF_TRUTH_NAMES = ("Z", "Ux", "Uy", "Uz", "growth")
