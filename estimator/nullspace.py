"""The null space of J and the parameter vectors (Sec. 3, step 3), by LAPACK.

The eigenvectors of J's k smallest eigenvalues span the solutions (k = 3 on a 2-D grid,
2 on a 1-D grid, one fewer for a static light field).  With ``M`` the k x k block of
their fixed rows (``I_sx, I_sy, I_t``), ``P = E M^-1`` holds one parameter vector per
column whose fixed components ``(ds_x, ds_y, dt)`` are a unit vector.
:func:`null_space` is the reference implementation (all eigenpairs by ``eigh``); the
fast path's solver (:mod:`estimator._solver`) gives the same to its tolerance and uses
the tolerances defined here.

Error estimates used to combine the twice-estimated ``v, z_x, z_y, u_z``
------------------------------------------------------------------------------
To first order (Nestares et al. [14]), a perturbation ``δJ`` of the tensor moves column
``p_c`` by ``-(I - P S) J^+ δJ p_c`` (S selects the fixed rows), and with data noise of
variance ``σ²`` per component ``cov(δJ p_c) ≈ σ² |p_c|² J``, so

    var(P[r, c]) ∝ |p_c|² [(I - P S) J^+ (I - P S)^T]_rr = |p_c|² (J_qq^-1)_rr,

the last form (``J_qq``: J without the fixed rows and columns) being the covariance of the
same parameters estimated by least squares with the fixed rows held.  ``σ²`` is common
to all columns and cancels in the weights; :func:`null_space` returns ``g = (J_qq^-1)_rr``
and :mod:`estimator.disentangle` combines with it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .models import Model

__all__ = ["null_space", "NullSpace", "RANK_TOL", "M_TOL", "RIDGE", "COMBINED_ROWS"]


class NullSpace(NamedTuple):
    """The solution space of every pixel.

    Attributes
    ----------
    P : ndarray, shape (N, n, k)
        Parameter vectors; column c has the fixed rows equal to the c-th unit vector
        (k = 3 for a 2-D grid: ds_x, ds_y, dt; k = 2 for a 1-D grid: ds_x, dt).  NaN
        where not valid.
    g : ndarray, shape (N, n)
        ``(J_qq^-1)_rr`` for every non-fixed row (NaN on the fixed rows), the row factor
        of the error estimate.
    model_error : ndarray, shape (N,)
        Largest of the k smallest eigenvalues (Fig. 1's colour code).
    valid : ndarray of bool, shape (N,)
    fallbacks : tuple of int, optional
        The fast solver's count of pixels it solved on its scalar path and, of those, by
        its full (Jacobi) decomposition (None for the reference solver).
    """

    P: np.ndarray
    g: np.ndarray
    model_error: np.ndarray
    valid: np.ndarray
    fallbacks: tuple | None = None


# A pixel is degenerate when J has more (near-)zero eigenvalues than the model's null
# space: the (k+1)-th smallest eigenvalue below this fraction of trace(J).  1e-11 is ~1e5
# float64 roundoffs of the trace, far below any textured data we measured (>= 1e-7 on the
# sinusoids).
RANK_TOL = 1e-11
# M (kxk of orthonormal vectors' rows, singular values <= 1) must be invertible for the
# ds/dt directions to be in the null space at all.
M_TOL = 1e-6
# J_qq is inverted with this ridge (times trace J): J is only positive semi-definite.
# The fast solver (estimator._solver) uses it as the shift of its inverse iteration.
RIDGE = 1e-13
# Rows whose two estimates are combined (their g is needed).
COMBINED_ROWS = ("Ix", "Iy", "IxDx", "IxDy", "IyDx", "IyDy",
                 "tIx", "tIy", "tIxDx", "tIxDy", "tIyDx", "tIyDy")


def null_space(J: np.ndarray, model: Model):
    """Eigen-decompose J (LAPACK, all eigenpairs) and form the parameter vectors.

    Parameters
    ----------
    J : ndarray, shape (N, n, n), float64
    model : Model

    Returns
    -------
    NullSpace
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
    return NullSpace(P, g, lam[..., k - 1], valid)
