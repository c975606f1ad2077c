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

__all__ = ["LeafScene", "LeafRecording", "UnevenLeafRecording", "leaf_truth",
           "uneven_leaf_truth", "leaf_outline", "LEAF_TRUTH_NAMES"]

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
        return self._scene_sdl(k, i, j, poly)

    def _scene_sdl(self, k: int, i: int, j: int, leaf: str) -> str:
        """The scene of frame ``k`` seen by camera ``(i, j)`` (camera, spotlight on the
        leaf's centre, black background) with the ``leaf`` object's text."""
        import vapory as vp

        t = k - self.ref_frame
        camera = vp.Camera("perspective", "location", pov_vec(self.camera(i, j)),
                           "right", [self.width, 0, 0], "up", [0, self.height, 0],
                           "direction", pov_vec([0.0, 0.0, self.f]))
        light = vp.LightSource(pov_vec(self.light(k)), "rgb", self.spot_power,
                               "spotlight", "point_at", pov_vec(self.center(t)),
                               "radius", self.spot_radius_deg,
                               "falloff", self.spot_falloff_deg)
        sdl = vp.Scene(camera, objects=[vp.Background("rgb", 0), light],
                       global_settings=["assumed_gamma 1.0", "ambient_light rgb 1"])
        return "#version 3.7;\n" + str(sdl) + "\n" + leaf + "\n"

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


# --- a leaf that grows unevenly: fast at its base, slow at its tip (issue 36) -------------

# Gauss-Legendre nodes on [0, 1]: the along-leaf velocity is an integral of a smooth
# (exponential of linear) integrand, exact to rounding with 16 nodes
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W


def _expm1_ratio(x):
    """``expm1(x) / x``, 1 at 0."""
    x = np.asarray(x, float)
    small = np.abs(x) < 1e-12
    return np.where(small, 1.0 + 0.5 * x, np.expm1(x) / np.where(small, 1.0, x))


def _log1p_ratio(q):
    """``log1p(q) / q``, 1 at 0."""
    q = np.asarray(q, float)
    small = np.abs(q) < 1e-12
    return np.where(small, 1.0 - 0.5 * q, np.log1p(q) / np.where(small, 1.0, q))


@dataclass(frozen=True)
class UnevenLeafRecording(LeafRecording):
    """The leaf recording growing unevenly, as dicot leaves do: its relative area rate
    falls linearly along the leaf from ``growth`` at the base to ``tip_growth`` at the tip
    (per frame, times the day/night rhythm), with truth per frame from the geometry.

    The leaf is a ``mesh2`` whose vertices are material points, moved exactly; its
    texture is uv-mapped on the material coordinates, so it moves with them.  In the
    leaf's plane, a material point ``(U, W)`` (``W`` its distance from the base along the
    axis, ``U`` across, at ``t = 0``) is at

        ``x_u = U exp(c g(W))``,  ``x_w = integral_0^W exp(c g(w)) dw``,

    with ``g(W) = growth + (tip_growth - growth) W / L`` the material rate and
    ``c = theta(t) / 2``, ``theta`` the rhythm's integral (:meth:`growth_time`).  The
    local area ratio is ``exp(2 c g(W))``, so each material element grows at exactly
    ``g(W) theta'(t)``, whatever the frame; its width and length grow alike, and the
    across-leaf motion shears slightly (a rotation ``-x_u theta' g'/(4 dx_w/dW)`` about
    the normal, at most 1e-4 per frame at the defaults).  ``x_w`` has a closed form and
    inverse (:meth:`deform`, :meth:`undeform`); the velocity along the axis is the
    integral's time derivative, by 16-point Gauss-Legendre quadrature.
    """

    tip_growth: float = 2e-4          # the material rate at the tip, per frame

    name = "leafuneven"

    def __post_init__(self):
        super().__post_init__()
        if not (self.growth > 0 and self.tip_growth > 0):
            raise ParameterError(f"growth {self.growth} and tip_growth {self.tip_growth} "
                                 "must be positive (per frame)")

    # the rhythm's integral and its derivative
    def growth_time(self, t):
        w = 2 * np.pi / self.period
        return t + self.rhythm * (1.0 - np.cos(w * t)) / w

    def growth_pace(self, t):
        return 1.0 + self.rhythm * np.sin(2 * np.pi * t / self.period)

    def growth_rate(self, t) -> float:
        """The rate at the base, ``growth theta'(t)`` (the tip's is ``tip_growth
        theta'(t)``)."""
        return float(self.growth * self.growth_pace(t))

    def material_rate(self, W):
        """``g(W)``: the relative area rate per unit growth time at the material distance
        ``W`` (mm) from the base."""
        return self.growth + (self.tip_growth - self.growth) * np.asarray(W) / self.leaf_length

    def deform(self, U, W, t):
        """Material ``(U, W)`` to the leaf plane's ``(x_u, x_w)`` at frame ``t`` (mm)."""
        c = 0.5 * self.growth_time(t)
        k = (self.tip_growth - self.growth) / self.leaf_length
        W = np.asarray(W, float)
        x_w = np.exp(c * self.growth) * W * _expm1_ratio(c * k * W)
        return np.asarray(U, float) * np.exp(c * self.material_rate(W)), x_w

    def undeform(self, x_u, x_w, t):
        """The inverse of :meth:`deform`: plane ``(x_u, x_w)`` to material ``(U, W)``."""
        c = 0.5 * self.growth_time(t)
        k = (self.tip_growth - self.growth) / self.leaf_length
        D = np.asarray(x_w, float) * np.exp(-c * self.growth)
        W = D * _log1p_ratio(c * k * D)
        return np.asarray(x_u, float) * np.exp(-c * self.material_rate(W)), W

    def plane_velocity(self, x_u, x_w, t):
        """The velocity ``(v_u, v_w)`` in the leaf's plane (mm per frame) of the material
        point at ``(x_u, x_w)`` at frame ``t``, and the material ``W`` there."""
        c = 0.5 * self.growth_time(t)
        half_pace = 0.5 * self.growth_pace(t)
        _, W = self.undeform(x_u, x_w, t)
        v_u = np.asarray(x_u, float) * half_pace * self.material_rate(W)
        w = np.multiply.outer(W, _GL_X)                      # (..., 16) nodes on [0, W]
        g = self.material_rate(w)
        v_w = half_pace * W * ((g * np.exp(c * g)) @ _GL_W)
        return v_u, v_w, W

    def point(self, x_u, x_w, t):
        """Model-frame position of the plane point ``(x_u, x_w)`` at frame ``t``,
        shape (..., 3)."""
        R = self.rotation()
        return self.base(t) + np.multiply.outer(x_u, R[:, 0]) + np.multiply.outer(x_w, R[:, 1])

    def sdl(self, k: int, i: int, j: int) -> str:
        """POV-Ray scene text for frame ``k``, camera ``(i, j)``: the leaf as a ``mesh2``
        of material points at their frame-``k`` positions, uv-mapped texture."""
        t = float(k - self.ref_frame)
        ns, nc = 240, 24                       # along (0.6 mm) and across the leaf
        s = np.linspace(0.0, 1.0, ns + 1)
        c = np.linspace(-1.0, 1.0, nc + 1)
        W = np.repeat(s * self.leaf_length, nc + 1)
        U = (np.outer(leaf_outline(s) * self.leaf_width, c)).ravel()
        x_u, x_w = self.deform(U, W, t)
        P = self.point(x_u, x_w, t) @ POV_FLIP
        faces = []
        for a in range(ns):
            for b in range(nc):
                p = a * (nc + 1) + b
                q = p + nc + 1
                if a > 0:                      # the base's vertices coincide: no triangle
                    faces.append((p, p + 1, q + 1))
                if a < ns - 1:                 # nor at the tip
                    faces.append((p, q + 1, q))
        vec = lambda rows: ", ".join("<" + ", ".join(f"{x:.9g}" for x in r) + ">"  # noqa: E731
                                     for r in rows)
        mesh = ("mesh2 {\n vertex_vectors { %d, %s }\n uv_vectors { %d, %s }\n"
                " face_indices { %d, %s }\n"
                " texture { uv_mapping pigment { bozo color_map { [0 rgb 0.05] "
                "[1 rgb 0.95] } scale %g } finish { ambient %g diffuse %g } }\n}" % (
                    len(P), vec(P), len(U), vec(np.stack([U, W], axis=1)),
                    len(faces), vec(faces), self.texture_scale, self.ambient, self.diffuse))
        return self._scene_sdl(k, i, j, mesh)

    def truth_at(self, k: int) -> dict[str, np.ndarray]:
        """Truth of frame ``k`` at the centre camera, each shape (H, W): ``Z``, ``Ux``,
        ``Uy``, ``Uz`` on the leaf and ``growth`` on its interior (``margin`` px inside
        its edge), NaN elsewhere (:func:`uneven_leaf_truth` has more)."""
        t = uneven_leaf_truth(self, margin=self.margin, frame=k)
        out = {n: t[n] for n in ("Z", "Ux", "Uy", "Uz")}
        out["growth"] = np.where(t["interior"], t["growth"], np.nan)
        return out


def uneven_leaf_truth(scene: UnevenLeafRecording, margin: float = 16.0,
                      frame: int = 0) -> dict[str, np.ndarray]:
    """Ground truth of the unevenly growing leaf at the centre camera and ``frame``.

    Returns
    -------
    dict of str to ndarray, each shape (H, W)
        ``Z, Zx, Zy, Ux, Uy, Uz, growth, rotation, Zx_t, Zy_t`` (NaN off the leaf),
        ``W`` (the material distance from the base, mm), ``leaf`` (bool), ``interior``
        (leaf pixels at least ``margin`` px from its edge).
    """
    from scipy.ndimage import distance_transform_edt

    t = float(frame - scene.ref_frame)
    H, Wd = scene.height, scene.width
    x = np.arange(Wd) - (Wd - 1) / 2
    y = np.arange(H) - (H - 1) / 2
    X, Y = np.meshgrid(x, y)
    R = scene.rotation()
    n = R[:, 2]
    b = scene.base(t)
    r = np.stack([X / scene.f, Y / scene.f, np.ones_like(X)], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = (b @ n) / (r @ n)
    P = r * Z[..., None]
    local = (P - b) @ R                         # (x_u, x_w, 0) in the leaf's plane
    x_u, x_w = local[..., 0], local[..., 1]
    U, Wm = scene.undeform(x_u, x_w, t)
    s = Wm / scene.leaf_length
    with np.errstate(invalid="ignore"):
        leaf = (s >= 0) & (s <= 1) & (np.abs(U) <= leaf_outline(s) * scene.leaf_width)
    leaf &= Z > 0
    v_u, v_w, _ = scene.plane_velocity(x_u, x_w, t)
    V = np.array([0.0, 0.0, scene.U_Z]) + v_u[..., None] * R[:, 0] + v_w[..., None] * R[:, 1]
    pace = scene.growth_pace(t)
    c = 0.5 * scene.growth_time(t)
    k = (scene.tip_growth - scene.growth) / scene.leaf_length
    growth = scene.material_rate(Wm) * pace
    # the shear of the across-leaf motion: d v_u / d x_w = x_u pace k / (2 dx_w/dW)
    rotation = -0.25 * x_u * pace * k / np.exp(c * scene.material_rate(Wm))
    nan = lambda a: np.where(leaf, a, np.nan)  # noqa: E731
    const = lambda v: nan(np.full((H, Wd), float(v)))  # noqa: E731
    return {"Z": nan(Z), "Zx": const(-n[0] / n[2]), "Zy": const(-n[1] / n[2]),
            "Ux": nan(V[..., 0]), "Uy": nan(V[..., 1]), "Uz": nan(V[..., 2]),
            "growth": nan(growth), "rotation": nan(rotation), "Zx_t": const(0.0),
            "Zy_t": const(0.0), "W": nan(Wm), "leaf": leaf,
            "interior": leaf & (distance_transform_edt(leaf) >= margin)}
