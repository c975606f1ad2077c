"""Null space of J and the disentangling of the parameters (Sec. 3, steps 3-5).

Error estimates used to combine the twice-estimated ``v, z_x, z_y, u_z``
------------------------------------------------------------------------------
``P = E M^-1`` (E: the null-space eigenvectors, M: their rows ``I_sx, I_sy, I_t``) holds
one parameter vector per column with the fixed components ``(ds_x, ds_y, dt)`` equal to a
unit vector.  To first order (Nestares et al. [14]), a perturbation ``δJ`` of the tensor
moves column ``p_c`` by ``-(I - P S) J^+ δJ p_c`` (S selects the fixed rows), and with
data noise of variance ``σ²`` per component ``cov(δJ p_c) ≈ σ² |p_c|² J``, so

    var(P[r, c]) ∝ |p_c|² [(I - P S) J^+ (I - P S)^T]_rr = |p_c|² (J_qq^-1)_rr,

the last form (``J_qq``: J without the fixed rows and columns) being the covariance of the
same parameters estimated by least squares with the fixed rows held.  ``σ²`` is common
to all columns and cancels in the weights.  The two estimates of a quantity are averaged
with inverse-variance weights; their correlation is ignored (the paper rotates
coordinates to make it vanish; we do not).

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

__all__ = ["null_space", "disentangle"]

# A pixel is degenerate when J has more (near-)zero eigenvalues than the model's null
# space: the (k+1)-th smallest eigenvalue below this fraction of trace(J).  1e-11 is ~1e5
# float64 roundoffs of the trace, far below any textured data we measured (>= 1e-7 on the
# sinusoids).
RANK_TOL = 1e-11
# M (kxk of orthonormal vectors' rows, singular values <= 1) must be invertible for the
# ds/dt directions to be in the null space at all.
M_TOL = 1e-6
# J_qq is inverted with this ridge (times trace J): J is only positive semi-definite.
# (The fast solver uses the same value as the shift of its inverse iteration.)
RIDGE = 1e-13
# Rows whose two estimates are combined (their g is needed).
COMBINED_ROWS = ("Ix", "Iy", "IxDx", "IxDy", "IyDx", "IyDy")


def null_space(J: np.ndarray, model: Model):
    """Eigen-decompose J (LAPACK, all eigenpairs) and form the parameter vectors.

    Parameters
    ----------
    J : ndarray, shape (N, n, n), float64
    model : Model

    Returns
    -------
    P : ndarray, shape (N, n, k)
        Parameter vectors; column c has the fixed rows equal to the c-th unit vector
        (k = 3 for a 2-D grid: ds_x, ds_y, dt; k = 2 for a 1-D grid: ds_x, dt).
    g : ndarray, shape (N, n)
        ``(J_qq^-1)_rr`` for every non-fixed row (NaN on the fixed rows), the row factor
        of the error estimate.
    model_error : ndarray, shape (N,)
        Largest of the k smallest eigenvalues (Fig. 1's colour code).
    valid : ndarray of bool, shape (N,)
    """
    k = model.null_dim
    n = model.n
    fixed = [model.index(r) for r in model.fixed_rows]
    q = np.array([i for i in range(n) if i not in fixed])
    tr = np.trace(J, axis1=-2, axis2=-1)
    finite = np.isfinite(J).all(axis=(-2, -1))
    if not finite.all():                     # LAPACK must not see inf/NaN
        J = np.where(finite[:, None, None], J, np.eye(n))
    lam, V = np.linalg.eigh(J)
    E = V[..., :k]
    valid = finite & np.isfinite(tr) & (tr > 0) & (lam[..., k] > RANK_TOL * tr)
    M = E[:, fixed, :]                                   # (N, k, k)
    smin = np.linalg.svd(M, compute_uv=False)[..., -1]
    valid &= smin > M_TOL
    M[~valid] = np.eye(k)
    # P = E M^-1, i.e. P^T = solve(M^T, E^T)
    P = np.linalg.solve(np.swapaxes(M, -1, -2), np.swapaxes(E, -1, -2)).swapaxes(-1, -2)
    Jq = J[:, q[:, None], q[None, :]] + (RIDGE * np.where(valid, tr, 1.0))[:, None, None] * np.eye(q.size)
    Jq[~valid] = np.eye(q.size)
    g = np.full((J.shape[0], n), np.nan)
    g[:, q] = np.diagonal(np.linalg.inv(Jq), axis1=-2, axis2=-1)
    P[~valid] = np.nan
    g[~valid] = np.nan
    return P, g, lam[..., k - 1], valid


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
        From :func:`null_space`; derivatives are per pixel, per camera index and per frame.
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
        ``Z, Zx, Zy, Ux, Uy, Uz`` and the model's brightness parameters, per frame.
    """
    i = model.index
    f = focal_length
    dsx, dsy = spacing
    norm2 = np.einsum("nrc,nrc->nc", P, P)             # |p_c|^2

    def combine2(x1, w1, x2, w2):
        # the twice-estimated quantities: inverse-variance weights, or a plain average
        return _combine(x1, w1, x2, w2) if combine != "mean" else (x1 + x2) / 2.0

    cx, ct = P[..., 0], (None if model.static else P[..., -1])
    # From the ds columns: disparity v and projected slopes, per world unit of ds.
    v = cx[:, i("Ix")] / dsx
    zx = cx[:, i("IxDx")] / dsx
    zy = cx[:, i("IxDy")] / dsx
    if model.grid_dims == 2:
        cy = P[..., 1]
        wx = dsx ** 2 / norm2[:, 0]
        wy = dsy ** 2 / norm2[:, 1]
        v = combine2(v, wx / g[:, i("Ix")], cy[:, i("Iy")] / dsy, wy / g[:, i("Iy")])
        zx = combine2(zx, wx / g[:, i("IxDx")], cy[:, i("IyDx")] / dsy, wy / g[:, i("IyDx")])
        zy = combine2(zy, wx / g[:, i("IxDy")], cy[:, i("IyDy")] / dsy, wy / g[:, i("IyDy")])
    # disparity in pixels per camera step along x, the HCI benchmark's sign: a point moves
    # by v ds_x per step in gridflow's frame, by -d in the benchmark's
    disparity = -v * dsx
    if model.static:
        with np.errstate(divide="ignore", invalid="ignore"):
            Z = -f / v
            den = 1.0 + (zx * x0 + zy * y0) * Z / f
            return {"Z": Z, "Zx": zx * Z / den, "Zy": zy * Z / den, "disparity": disparity}
    # From the dt column: divergence u_z twice (rows 3 and 6), then the translation.
    p1, p2 = ct[:, i("Ix")], ct[:, i("Iy")]
    uz_x, uz_y = ct[:, i("IxDx")], ct[:, i("IyDy")]
    if slant_correction:
        with np.errstate(divide="ignore", invalid="ignore"):
            uz_x = uz_x - zx * p1 / v
            uz_y = uz_y - zy * p2 / v
    uz = combine2(uz_x, 1.0 / g[:, i("IxDx")], uz_y, 1.0 / g[:, i("IyDy")])
    ux = p1 - x0 * uz
    uy = p2 - y0 * uz
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = -f / v
        # Eq. 16 inverted exactly for a plane: along a plane -f/Z is affine in x and y,
        # so z_x = Z_x / (Z (1 - (Z_x x0 + Z_y y0) / f)) with *both* slopes; solving for
        # Z_x, Z_y gives the common denominator below (the paper's per-axis form is exact
        # only when the other slope is 0).
        den = 1.0 + (zx * x0 + zy * y0) * Z / f
        Zx = zx * Z / den
        Zy = zy * Z / den
        out = {
            "Z": Z,
            "Zx": Zx,
            "Zy": Zy,
            "disparity": disparity,
            "Ux": Z * ux / f,
            "Uy": Z * uy / f,
            "Uz": -Z * uz,
        }
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
