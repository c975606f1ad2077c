"""From the parameter vectors to world quantities (Sec. 3, steps 4-5).

Each motion model (:data:`estimator.models.MOTIONS`) has its own disentangling; the
brightness parameters are read the same way under every one.  The twice-estimated
quantities (``v, z_x, z_y, u_z``) are combined with inverse-variance weights from
:func:`estimator.nullspace.null_space`'s ``g`` (derivation there) or plainly averaged;
their correlation is ignored (the paper rotates coordinates to make it vanish; we do
not).

Beyond the paper: motion of a slanted surface
---------------------------------------------
The paper drops the products of ``z_x Δx`` with the motion terms.  To first order they are
not small: the flow of a slanted, laterally moving patch has ``∂(dx/dt)/∂Δx = u_z +
z_x p1 / v`` with ``p1 = u_x + x0 u_z`` (and likewise ``z_y p2 / v`` in y), so reading
``u_z`` straight from rows 3 and 6 is biased by ``U_X Z_X / U_Z`` (15 % for the slanted
test plane).  The TLS leaves the dt-column's rows 3-6 free, so the term is present in the
estimate and can be removed after the fact: ``u_z = P[3, t] - z_x P[1, t] / v`` (and
``P[6, t] - z_y P[2, t] / v``).  ``slant_correction=False`` gives the paper's reading.
"""

from __future__ import annotations

import numpy as np

from .models import Model

__all__ = ["disentangle"]


def _combine(x1, w1, x2, w2):
    with np.errstate(divide="ignore", invalid="ignore"):
        return (w1 * x1 + w2 * x2) / (w1 + w2)


def disentangle(P: np.ndarray, g: np.ndarray, model: Model, x0: np.ndarray, y0: np.ndarray,
                focal_length: float, spacing: tuple[float, float],
                slant_correction: bool = True,
                combine: str = "inverse_variance") -> dict[str, np.ndarray]:
    """Parameters in world units from the parameter vectors (Sec. 3, steps 4-5).

    Parameters
    ----------
    P : ndarray, shape (N, n, k)
        From :func:`estimator.nullspace.null_space`; derivatives are per pixel, per
        camera index and per frame.
    g : ndarray, shape (N, n)
    model : Model
    x0, y0 : ndarray, shape (N,)
        Pixel coordinates relative to the principal point.
    focal_length : float
        Pixels.
    spacing : (float, float)
        Camera spacing ``(ds_x, ds_y)`` in world units.
    slant_correction : bool
        Remove the slant-motion coupling from ``u_z`` (see module docstring).
    combine : {"inverse_variance", "mean"}
        Weights of the two estimates of ``v, z_x, z_y, u_z``: inverse variances (module
        docstring) or equal.

    Returns
    -------
    dict of str to ndarray, each shape (N,)
        ``Z, Zx, Zy, disparity``, the motion model's velocities and the brightness
        model's parameters (``model.outputs``), per frame.
    """
    def combine2(x1, w1, x2, w2):
        # the twice-estimated quantities: inverse-variance weights, or a plain average
        return _combine(x1, w1, x2, w2) if combine != "mean" else (x1 + x2) / 2.0

    v, zx, zy = _from_ds_columns(P, g, model, spacing, combine2)
    f = focal_length
    # disparity in pixels per camera step along x, the HCI benchmark's sign: a point moves
    # by v ds_x per step in gridflow's frame, by -d in the benchmark's
    disparity = -v * spacing[0]
    if model.static:
        with np.errstate(divide="ignore", invalid="ignore"):
            Z = -f / v
            den = 1.0 + (zx * x0 + zy * y0) * Z / f
            return {"Z": Z, "Zx": zx * Z / den, "Zy": zy * Z / den, "disparity": disparity}
    ct = P[..., -1]                                   # the dt column
    u = _MOTION[model.motion](ct, g, model, v, zx, zy, x0, y0, slant_correction, combine2)
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = -f / v
        # Eq. 16 inverted exactly for a plane: along a plane -f/Z is affine in x and y,
        # so z_x = Z_x / (Z (1 - (Z_x x0 + Z_y y0) / f)) with *both* slopes; solving for
        # Z_x, Z_y gives the common denominator below (the paper's per-axis form is exact
        # only when the other slope is 0).
        den = 1.0 + (zx * x0 + zy * y0) * Z / f
        Zx = zx * Z / den
        Zy = zy * Z / den
        out = {"Z": Z, "Zx": Zx, "Zy": Zy, "disparity": disparity}
        out.update(_world_motion(u, Z, f))
        out.update(_brightness(ct, model, Z, Zx, Zy, x0, y0, f))
    return out


def _from_ds_columns(P, g, model: Model, spacing, combine2):
    """Disparity ``v`` and the projected slopes ``z_x, z_y`` per world unit of ds, from the
    ds columns of P (each twice on a 2-D grid, combined)."""
    i = model.index
    dsx, dsy = spacing
    cx = P[..., 0]
    v = cx[:, i("Ix")] / dsx
    zx = cx[:, i("IxDx")] / dsx
    zy = cx[:, i("IxDy")] / dsx
    if model.grid_dims == 2:
        norm2 = np.einsum("nrc,nrc->nc", P, P)             # |p_c|^2
        cy = P[..., 1]
        wx = dsx ** 2 / norm2[:, 0]
        wy = dsy ** 2 / norm2[:, 1]
        v = combine2(v, wx / g[:, i("Ix")], cy[:, i("Iy")] / dsy, wy / g[:, i("Iy")])
        zx = combine2(zx, wx / g[:, i("IxDx")], cy[:, i("IyDx")] / dsy, wy / g[:, i("IyDx")])
        zy = combine2(zy, wx / g[:, i("IxDy")], cy[:, i("IyDy")] / dsy, wy / g[:, i("IyDy")])
    return v, zx, zy


def _translation(ct, g, model: Model, v, zx, zy, x0, y0, slant_correction, combine2):
    """The paper's motion model, from the dt column: the divergence ``u_z`` twice (rows 3
    and 6, combined), then the image translation ``u_x, u_y``."""
    i = model.index
    p1, p2 = ct[:, i("Ix")], ct[:, i("Iy")]
    uz_x, uz_y = ct[:, i("IxDx")], ct[:, i("IyDy")]
    if slant_correction:
        with np.errstate(divide="ignore", invalid="ignore"):
            uz_x = uz_x - zx * p1 / v
            uz_y = uz_y - zy * p2 / v
    uz = combine2(uz_x, 1.0 / g[:, i("IxDx")], uz_y, 1.0 / g[:, i("IyDy")])
    return {"ux": p1 - x0 * uz, "uy": p2 - y0 * uz, "uz": uz}


# motion model -> its disentangling of the dt column into image-based velocities
_MOTION = {"translation": _translation}


def _world_motion(u: dict, Z, f) -> dict:
    """Eq. 16 inverted: ``U_x = Z u_x / f``, ``U_y = Z u_y / f``, ``U_z = -Z u_z``."""
    return {"Ux": Z * u["ux"] / f, "Uy": Z * u["uy"] / f, "Uz": -Z * u["uz"]}


def _brightness(ct, model: Model, Z, Zx, Zy, x0, y0, f) -> dict:
    """The brightness parameters from the dt column (Eq. 20): ``a1 = -b1``, ``a2 = -b2``
    and, for the full model, their spatial variation."""
    i = model.index
    out = {}
    if "I" in model.rows:
        out["a1"] = -ct[:, i("I")]
        out["a2"] = -ct[:, i("tI")] / 2.0
    if "IDx" in model.rows:
        # Eq. 20 exactly: the brightness varies with the surface coordinates (X, Y),
        # whose pixel derivatives on the plane couple x and y; inverting
        # (b_x, b_y) = -(dX, dY)/d(x, y)^T (a_x, a_y) gives
        #   a_x = -((f - Z_x x0) b_x - Z_x y0 b_y) / Z,
        #   a_y = -((f - Z_y y0) b_y - Z_y x0 b_x) / Z.
        # (rows I t Δx, I t Δy carry 2 b2x, 2 b2y)
        for a, rx, ry, half in (("a1", "IDx", "IDy", 1.0), ("a2", "tIDx", "tIDy", 0.5)):
            bx = ct[:, i(rx)] * half
            by = ct[:, i(ry)] * half
            out[a + "x"] = -((f - Zx * x0) * bx - Zx * y0 * by) / Z
            out[a + "y"] = -((f - Zy * y0) * by - Zy * x0 * bx) / Z
    return out
