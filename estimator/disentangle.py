"""From the parameter vectors to world quantities (Sec. 3, steps 4-5).

Each motion model (:data:`estimator.models.MOTION_MODELS`) has its own disentangling, a
function here registered for the model object with :func:`disentangles` (the models
module is below this one and cannot name the functions); the brightness parameters are
read the same way under every one.  The twice-estimated quantities (``v, z_x, z_y,
u_z``) are combined with inverse-variance weights from
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

from collections.abc import Callable

import numpy as np

from .models import AFFINE, TRANSLATION, Model, MotionModel

__all__ = ["disentangle", "disentangles", "solve_affine"]

# motion model -> its disentangling: world velocities (and, for affine motion, growth,
# rotation and the slopes' rates) from the parameter vectors and the plane.  Keyed by the
# object, not its name: a model made outside the registry of names gets its own entry.
_DISENTANGLING: dict[MotionModel, Callable] = {}


def disentangles(motion: MotionModel) -> Callable[[Callable], Callable]:
    """Register the decorated function as the disentangling of ``motion``.

    The function is called as ``fn(P, g, model, plane, x0, y0, f, spacing,
    slant_correction, combine2, residual, solver)`` (see :func:`_translation`; ``solver``
    solves the affine model's systems, :func:`solve_affine` or a kernel with its
    signature) and returns the maps of ``motion.outputs``.
    """
    def register(fn: Callable) -> Callable:
        _DISENTANGLING[motion] = fn
        return fn
    return register


def _combine(x1, w1, x2, w2):
    with np.errstate(divide="ignore", invalid="ignore"):
        return (w1 * x1 + w2 * x2) / (w1 + w2)


def disentangle(P: np.ndarray, g: np.ndarray, model: Model, x0: np.ndarray, y0: np.ndarray,
                focal_length: float, spacing: tuple[float, float],
                slant_correction: bool = True,
                combine: str = "inverse_variance",
                residual: np.ndarray | None = None,
                pooling_inputs: dict | None = None,
                solver: Callable | None = None) -> dict[str, np.ndarray]:
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
    residual : ndarray, shape (N,), optional
        The data's noise variance in units of J (motion models that give error
        estimates use it: the affine one).
    pooling_inputs : dict, optional
        Filled, for the affine model, with what pooling its rates needs
        (:mod:`estimator.pooling`): ``"obs"`` (the nine observations, shape (9, N)) and
        ``"plane"`` (``v, z_x, z_y``, shape (3, N)).
    solver : callable, optional
        Solves the affine model's per-pixel systems, with :func:`solve_affine`'s
        signature and results (the default); the numba backend passes its kernel
        (:mod:`estimator._affine`).

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
    plane = dict(v=v, zx=zx, zy=zy, Z=Z, Zx=Zx, Zy=Zy)
    try:
        motion = _DISENTANGLING[model.motion]
    except KeyError:
        raise LookupError(f"motion model {model.motion.name!r} has no disentangling: "
                          "register one with estimator.disentangle.disentangles") from None
    maps = motion(P, g, model, plane, x0, y0, f, spacing, slant_correction, combine2,
                  residual, solver or solve_affine)
    for key in [k for k in maps if k.startswith("_")]:
        extra = maps.pop(key)
        if pooling_inputs is not None:
            pooling_inputs[key[1:]] = extra
    out.update(maps)
    with np.errstate(divide="ignore", invalid="ignore"):
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


@disentangles(TRANSLATION)
def _translation(P, g, model: Model, plane, x0, y0, f, spacing, slant_correction, combine2,
                 residual=None, solver=None):
    """The paper's motion model, from the dt column: the divergence ``u_z`` twice (rows 3
    and 6, combined), then the image translation ``u_x, u_y``; in world units by Eq. 16
    inverted: ``U_x = Z u_x / f``, ``U_y = Z u_y / f``, ``U_z = -Z u_z``."""
    i = model.index
    ct = P[..., -1]
    v, zx, zy, Z = plane["v"], plane["zx"], plane["zy"], plane["Z"]
    p1, p2 = ct[:, i("Ix")], ct[:, i("Iy")]
    uz_x, uz_y = ct[:, i("IxDx")], ct[:, i("IyDy")]
    if slant_correction:
        with np.errstate(divide="ignore", invalid="ignore"):
            uz_x = uz_x - zx * p1 / v
            uz_y = uz_y - zy * p2 / v
    uz = combine2(uz_x, 1.0 / g[:, i("IxDx")], uz_y, 1.0 / g[:, i("IyDy")])
    ux, uy = p1 - x0 * uz, p2 - y0 * uz
    with np.errstate(divide="ignore", invalid="ignore"):
        return {"Ux": Z * ux / f, "Uy": Z * uy / f, "Uz": -Z * uz}


# The affine model's observations, in this order, and its unknowns: the velocity U of the
# surface point a pixel sees and the velocity's derivatives g1 = dV/dX, g2 = dV/dY along
# the surface (docs/model.md, *Affine motion*).
_AFFINE_OBS = ("w_x", "w_y", "W_xx", "W_xy", "W_yx", "W_yy", "v_t", "zx_t", "zy_t")


def affine_observations(theta, Z, Zx, Zy, x0, y0, f):
    """What a surface moving with ``theta = (U, g1, g2)`` shows at pixel ``(x0, y0)``.

    The surface is the plane ``Z = c + Z_x X + Z_y Y`` through the point ``X_c = Z (x0/f,
    y0/f, 1)`` the pixel sees; its points move with ``V = U + ΔX g1 + ΔY g2`` (``ΔX, ΔY``
    their offsets from ``X_c``).  Returns, per frame, the image flow ``w`` at the pixel,
    its gradient ``W = dw/d(x, y)``, and the rates of change at the fixed pixel of the
    disparity ``v = -f/Z`` and of the projected slopes ``z_x = dv/dx``, ``z_y = dv/dy``:
    the quantities the dt column and the ``t I_x``-rows of the ds columns hold.  Linear in
    ``theta``.

    Parameters
    ----------
    theta : ndarray, shape (9, N)
        ``U_X, U_Y, U_Z, g1 (3), g2 (3)`` per pixel.
    Z, Zx, Zy, x0, y0 : ndarray, shape (N,)
    f : float

    Returns
    -------
    ndarray, shape (9, N)
        In the order of ``_AFFINE_OBS``.
    """
    U, g1, g2 = theta[0:3], theta[3:6], theta[6:9]
    a, b = Zx, Zy
    c = Z * (1.0 - a * x0 / f - b * y0 / f)            # Z = c / (1 - a x/f - b y/f)
    Xc = np.stack([Z * x0 / f, Z * y0 / f, Z])
    wx = (f * U[0] - x0 * U[2]) / Z
    wy = (f * U[1] - y0 * U[2]) / Z
    Zdx, Zdy = a * Z * Z / (c * f), b * Z * Z / (c * f)   # dZ/dx, dZ/dy along the plane
    # the material offsets' derivatives along the image, then the velocity's
    dXdx, dXdy = (Zdx * x0 + Z) / f, Zdy * x0 / f
    dYdx, dYdy = Zdx * y0 / f, (Zdy * y0 + Z) / f
    Vdx = g1 * dXdx + g2 * dYdx
    Vdy = g1 * dXdy + g2 * dYdy
    Wxx = (f * Vdx[0] - U[2] - x0 * Vdx[2]) / Z - wx * Zdx / Z
    Wxy = (f * Vdy[0] - x0 * Vdy[2]) / Z - wx * Zdy / Z
    Wyx = (f * Vdx[1] - y0 * Vdx[2]) / Z - wy * Zdx / Z
    Wyy = (f * Vdy[1] - U[2] - y0 * Vdy[2]) / Z - wy * Zdy / Z
    # the plane's normal N = e1 x e2 = (-a, -b, 1) turns with the surface:
    # dN = g1 x e2 + e1 x g2; a = -N_x/N_z, b = -N_y/N_z, c = N . X_c / N_z
    e1 = np.stack([np.ones_like(a), np.zeros_like(a), a])
    e2 = np.stack([np.zeros_like(b), np.ones_like(b), b])
    dN = np.cross(g1, e2, axis=0) + np.cross(e1, g2, axis=0)
    N = np.stack([-a, -b, np.ones_like(a)])
    da = -dN[0] - a * dN[2]
    db = -dN[1] - b * dN[2]
    dc = (dN * Xc).sum(0) + (N * U).sum(0) - c * dN[2]
    v = -f / Z
    vt = (da * x0 + db * y0) / c - v * dc / c
    zxt = da / c - a * dc / (c * c)
    zyt = db / c - b * dc / (c * c)
    return np.stack([wx, wy, Wxx, Wxy, Wyx, Wyy, vt, zxt, zyt])


def _surface_frame(Zx, Zy):
    """The plane's tangents ``e1 = (1, 0, Z_x)``, ``e2 = (0, 1, Z_y)`` (each shape (3, N)),
    the inverse of their Gram matrix ``m`` (nested pairs of (N,) arrays; the dual vectors
    are ``e_i* = sum_j (m^-1)_ij e_j``) and a right-handed orthonormal ``(t1, t2, n)``."""
    N = Zx.size
    e1 = np.stack([np.ones(N), np.zeros(N), Zx])
    e2 = np.stack([np.zeros(N), np.ones(N), Zy])
    n = np.stack([-Zx, -Zy, np.ones(N)])
    n = n / np.sqrt((n * n).sum(0))
    m11, m12, m22 = (e1 * e1).sum(0), (e1 * e2).sum(0), (e2 * e2).sum(0)
    det = m11 * m22 - m12 * m12
    inv = ((m22 / det, -m12 / det), (-m12 / det, m11 / det))
    t1 = e1 / np.sqrt(m11)
    t2 = np.cross(n, t1, axis=0)
    return (e1, e2), inv, (t1, t2)


def _surface_rates(theta, Zx, Zy):
    """Growth, rotation about the normal and the slopes' rates of the motion ``theta =
    (U, g1, g2)`` (shape (9, N)) on the plane of slopes ``Zx, Zy`` (linear in theta)."""
    g1, g2 = theta[3:6], theta[6:9]
    e, inv, (t1, t2) = _surface_frame(Zx, Zy)
    e1, e2 = e
    # growth: tr of the surface gradient sum_i g_i (e_i* . d)
    gs = (g1, g2)
    growth = sum(inv[a][b] * (e[b] * gs[a]).sum(0) for a in range(2) for b in range(2))
    # rotation about n: (t2 . L t1 - t1 . L t2) / 2 for a right-handed (t1, t2, n), with
    # L d = sum_i g_i (e_i* . d) the surface gradient of V

    def L(d):
        dual = [sum(inv[a][b] * (e[b] * d).sum(0) for b in range(2)) for a in range(2)]
        return g1 * dual[0] + g2 * dual[1]

    rotation = 0.5 * ((t2 * L(t1)).sum(0) - (t1 * L(t2)).sum(0))
    dN = np.cross(g1, e2, axis=0) + np.cross(e1, g2, axis=0)
    return {"growth": growth, "rotation": rotation, "Zx_t": -dN[0] - Zx * dN[2],
            "Zy_t": -dN[1] - Zy * dN[2]}


def _rate_coefficients(Zx, Zy) -> dict:
    """The coefficients of growth, rotation and the slopes' rates in ``theta`` (each shape
    (N, 9); zero on ``U``): :func:`_surface_rates` is linear, ``growth = sum_i e_i* .
    g_i``, ``rotation = sum_i ((e_i* . t1) t2 - (e_i* . t2) t1) . g_i / 2``, ``Zx_t =
    g1z - Z_x g1x - Z_y g1y`` and ``Zy_t`` alike with ``g2``."""
    e, inv, (t1, t2) = _surface_frame(Zx, Zy)
    dual = [inv[a][0] * e[0] + inv[a][1] * e[1] for a in range(2)]
    zero = np.zeros((3, Zx.size))
    growth = np.concatenate([zero] + dual)
    rotation = np.concatenate(
        [zero] + [0.5 * ((d * t1).sum(0) * t2 - (d * t2).sum(0) * t1) for d in dual])
    # the slopes' rates: Zx_t = g1z - Zx g1x - Zy g1y, Zy_t = g2z - Zx g2x - Zy g2y
    slope = np.stack([-Zx, -Zy, np.ones_like(Zx)])
    zx_t = np.concatenate([zero, slope, zero])
    zy_t = np.concatenate([zero, zero, slope])
    return {"growth": growth.T, "rotation": rotation.T, "Zx_t": zx_t.T, "Zy_t": zy_t.T}


_AFFINE_DT_ROWS = ("Ix", "Iy", "IxDx", "IxDy", "IyDx", "IyDy")
_AFFINE_RATE_ROWS = (("v_t", "tIx", "tIy"), ("zx_t", "tIxDx", "tIyDx"),
                     ("zy_t", "tIxDy", "tIyDy"))


@disentangles(AFFINE)
def _affine(P, g, model: Model, plane, x0, y0, f, spacing, slant_correction, combine2,
            residual=None, solver=None):
    """Affine motion: the flow and its gradient from the dt column, the rates of the
    disparity and the projected slopes from the ``t I_x``-rows of the ds columns (each
    twice on a 2-D grid, combined), and the 9 x 9 linear system of
    :func:`affine_observations` solved per pixel for ``U, g1, g2``; then the growth (the
    surface divergence of V), the rotation about the normal and the slopes' rates.

    ``residual`` (shape (N,)): the data's noise variance ``s^2`` in units of J (the model
    error over the window's effective number of samples).  With it, first-order error
    estimates ``Uz_err``, ``growth_err``, ``rotation_err`` (standard deviations): the
    observations' variances ``s^2 |p_c|^2 g_r`` (:mod:`estimator.nullspace`), their
    correlations left out, carried through the solve."""
    i = model.index
    dsx, dsy = spacing
    ct, cx = P[..., -1], P[..., 0]
    Z, Zx, Zy = plane["Z"], plane["Zx"], plane["Zy"]
    norm2 = np.einsum("nrc,nrc->nc", P, P)            # |p_c|^2
    rates, var = {}, {}
    with np.errstate(divide="ignore", invalid="ignore"):
        for q, rx, ry in _AFFINE_RATE_ROWS:
            rates[q] = cx[:, i(rx)] / dsx
            var[q] = norm2[:, 0] * g[:, i(rx)] / dsx ** 2
            if model.grid_dims == 2:
                vy = norm2[:, 1] * g[:, i(ry)] / dsy ** 2
                rates[q] = combine2(rates[q], 1.0 / var[q], P[:, i(ry), 1] / dsy, 1.0 / vy)
                # the combination's own variance: 1 / (1/vx + 1/vy) for inverse-variance
                # weights, (vx + vy) / 4 for the mean; both are combine2 of the variances
                # with those weights, halved
                var[q] = combine2(var[q], 1.0 / var[q], vy, 1.0 / vy) / 2.0
    obs = np.stack([ct[:, i(r)] for r in _AFFINE_DT_ROWS]
                   + [rates[q] for q, _, _ in _AFFINE_RATE_ROWS])
    var_obs = None
    if residual is not None:
        var_obs = np.stack([norm2[:, -1] * g[:, i(r)] for r in _AFFINE_DT_ROWS]
                           + [var[q] for q, _, _ in _AFFINE_RATE_ROWS]).T * residual[:, None]
    out = (solver or solve_affine)(obs, Z, Zx, Zy, x0, y0, f, var_obs)
    # what pooling the rates over the leaf needs (estimator.pooling): the six flow
    # observations and the per-pixel projected slopes and rates, kept by the driver
    out["_obs"] = obs
    out["_plane"] = np.stack([plane["v"], plane["zx"], plane["zy"]])
    if var_obs is not None:
        out["_var_vt"] = var_obs[:, 6]
    return out


def solve_affine(obs: np.ndarray, Z: np.ndarray, Zx: np.ndarray, Zy: np.ndarray,
                 x0: np.ndarray, y0: np.ndarray, f: float,
                 var_obs: np.ndarray | None = None,
                 sensitivity: bool = False) -> dict[str, np.ndarray]:
    """Solve each pixel's 9 x 9 system ``M theta = o`` of :func:`affine_observations` for
    ``theta = (U, g1, g2)``; then the growth, the rotation about the normal and the
    slopes' rates.

    Parameters
    ----------
    obs : ndarray, shape (9, N)
        The observations in the order of ``_AFFINE_OBS``.
    Z, Zx, Zy, x0, y0 : ndarray, shape (N,)
        The plane each pixel sees and the pixel relative to the principal point.
    f : float
    var_obs : ndarray, shape (N, 9), optional
        The observations' variances; with them, first-order ``Uz_err``, ``growth_err``,
        ``rotation_err`` (correlations left out).
    sensitivity : bool
        Also return ``growth_sensitivity`` (shape (N, 9)): the growth's derivative with
        respect to each observation, ``M^-T c`` for ``growth = c . theta``.

    Returns
    -------
    dict of str to ndarray, each shape (N,)
        ``Ux, Uy, Uz, growth, rotation, Zx_t, Zy_t`` (and the errors); NaN where the
        inputs are not finite.
    """
    N = Z.size
    ok = np.isfinite(obs).all(0) & np.isfinite(Z) & np.isfinite(Zx) & np.isfinite(Zy)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # the system's columns: the observations of each unit motion, all nine in one
        # call (unit motion j of pixel n at column j N + n)
        units = np.repeat(np.eye(9), N, axis=1)
        tile = lambda a: np.tile(a, 9)  # noqa: E731
        cols = affine_observations(units, tile(Z), tile(Zx), tile(Zy), tile(x0), tile(y0), f)
        M = np.ascontiguousarray(cols.reshape(9, 9, N).transpose(2, 0, 1))
        M[~ok] = np.eye(9)
        # every output is linear in theta, q = c_q . theta = c_q . M^-1 o = (M^-T c_q) . o:
        # one solve with M^T for all of them (docs/model.md), whose columns also give the
        # outputs' first-order variances sum_j (M^-T c_q)_j^2 v_j and the growth's
        # sensitivity to each observation, no inverse
        coef = _rate_coefficients(Zx, Zy)
        C = np.zeros((N, 9, 7))
        C[:, 0, 0] = C[:, 1, 1] = C[:, 2, 2] = 1.0
        for q, name in enumerate(("growth", "rotation", "Zx_t", "Zy_t"), start=3):
            C[:, :, q] = coef[name]
        A = np.linalg.solve(M.transpose(0, 2, 1), np.where(ok[:, None, None], C, 0.0))
        vals = np.einsum("njq,jn->qn", A, np.where(ok, obs, 0.0))
        vals[:, ~ok] = np.nan
        out = dict(zip(("Ux", "Uy", "Uz", "growth", "rotation", "Zx_t", "Zy_t"), vals))
        if var_obs is not None:
            sd = np.sqrt(np.einsum("njq,nj->qn", A[:, :, 2:5] ** 2, var_obs))
            sd[:, ~ok] = np.nan
            out["Uz_err"], out["growth_err"], out["rotation_err"] = sd
        if sensitivity:
            G = A[:, :, 3].copy()
            G[~ok] = np.nan
            out["growth_sensitivity"] = G
    return out


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
