"""Numba kernel of the affine model's per-pixel solve: :func:`estimator.disentangle.
solve_affine` in one parallel pass.

Per pixel it builds the 9 x 9 system ``M`` of :func:`estimator.disentangle.
affine_observations` (column ``j`` the observations of unit motion ``j``, the same
formulas written out for each unit motion: :func:`_system`), the outputs'
coefficients ``C`` (9 x 7: ``U`` and the rates of
:func:`estimator.disentangle._rate_coefficients`), solves ``M^T A = C`` by LU
with partial pivoting (LAPACK ``gesv``'s algorithm) and forms ``A^T o``, the errors
``sqrt(sum_j A_jq^2 v_j)`` and the growth's sensitivity ``A[:, growth]``.  The numpy
version makes each of these an array over all pixels (0.6 GB of temporaries at 512^2)
and calls LAPACK once per pixel; here a pixel's work stays in registers and cache.
Results equal the numpy version's to rounding (``tests/test_affine.py``).

Only :class:`estimator.backends.NumbaBackend` calls it; :mod:`estimator.jit` finds it for
the compilation message.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["solve_affine_kernel"]

# pixels per task: the scratch arrays are allocated once per task, not per pixel
_BLOCK = 256


@njit(inline="always")
def _system(Z, a, b, x0, y0, f, M):
    """``M`` (9 x 9) at one pixel: column ``j`` the observations (in ``_AFFINE_OBS``'s
    order) of the unit motion ``theta = e_j``, :func:`estimator.disentangle.
    affine_observations` term by term.

    Each entry is that function's expression with the unit motion's zeros and ones
    taken out (``x * 1 = x``, ``x + 0 = x``, ``0 - x = -x``, ``0 * x = 0``, ``0 / c =
    0``, ``(-a) x = -(a x)`` and the like, exact for finite values), so the entries are
    the same values as the general expression's, an exact zero's sign aside
    (``tests/test_affine.py``), and the pixel's terms (``c``, the depth's and the
    surface point's derivatives) are computed once, not once per column: the whole
    solve of 448^2 pixels on one thread went from 0.174 s (the general expression
    evaluated for each of the nine columns) to 0.115 s, a third less (measured).  Where
    ``c`` or ``Z`` is 0 (no plane through the pixel's point) the entries are not those
    of the general expression (0 where it gives NaN), and the solve's outputs were NaN
    either way in the cases tried.
    """
    c = Z * (1.0 - a * x0 / f - b * y0 / f)
    Zdx = a * Z * Z / (c * f)
    Zdy = b * Z * Z / (c * f)
    dXdx = (Zdx * x0 + Z) / f
    dXdy = Zdy * x0 / f
    dYdx = Zdx * y0 / f
    dYdy = (Zdy * y0 + Z) / f
    v = -f / Z
    cc = c * c
    Zx0f = Z * x0 / f
    Zy0f = Z * y0 / f
    # U0, U1, U2: the velocity of the pixel's surface point (wx of U0 is wy of U1)
    wx = f / Z
    M[0, 0] = wx
    M[1, 0] = 0.0
    M[2, 0] = -(wx * Zdx / Z)
    M[3, 0] = -(wx * Zdy / Z)
    M[4, 0] = 0.0
    M[5, 0] = 0.0
    M[6, 0] = v * a / c
    M[7, 0] = a * a / cc
    M[8, 0] = b * a / cc
    M[0, 1] = 0.0
    M[1, 1] = wx
    M[2, 1] = 0.0
    M[3, 1] = 0.0
    M[4, 1] = M[2, 0]
    M[5, 1] = M[3, 0]
    M[6, 1] = v * b / c
    M[7, 1] = a * b / cc
    M[8, 1] = b * b / cc
    wx = -x0 / Z
    wy = -y0 / Z
    M[0, 2] = wx
    M[1, 2] = wy
    M[2, 2] = -1.0 / Z - wx * Zdx / Z
    M[3, 2] = -(wx * Zdy / Z)
    M[4, 2] = -(wy * Zdx / Z)
    M[5, 2] = -1.0 / Z - wy * Zdy / Z
    M[6, 2] = -(v / c)
    M[7, 2] = -(a / cc)
    M[8, 2] = -(b / cc)
    # g1 = (g1x, g1y, g1z), then g2: the gradients of the velocity along the surface; the
    # rows 4, 5 of g1y and g2y are the rows 2, 3 of g1x and g2x
    for j in range(3, 9):
        M[0, j] = 0.0
        M[1, j] = 0.0
    dc = (-b * Zy0f + Z) - c
    M[2, 3] = f * dXdx / Z
    M[3, 3] = f * dXdy / Z
    M[4, 3] = 0.0
    M[5, 3] = 0.0
    M[6, 3] = -(a * x0) / c - v * dc / c
    M[7, 3] = -a / c - a * dc / cc
    M[8, 3] = -(b * dc / cc)
    dc = b * Zx0f
    M[2, 4] = 0.0
    M[3, 4] = 0.0
    M[4, 4] = M[2, 3]
    M[5, 4] = M[3, 3]
    M[6, 4] = -(b * x0) / c - v * dc / c
    M[7, 4] = -b / c - a * dc / cc
    M[8, 4] = -(b * dc / cc)
    dc = -Zx0f
    M[2, 5] = -(x0 * dXdx) / Z
    M[3, 5] = -(x0 * dXdy) / Z
    M[4, 5] = -(y0 * dXdx) / Z
    M[5, 5] = -(y0 * dXdy) / Z
    M[6, 5] = x0 / c - v * dc / c
    M[7, 5] = 1.0 / c - a * dc / cc
    M[8, 5] = -(b * dc / cc)
    dc = a * Zy0f
    M[2, 6] = f * dYdx / Z
    M[3, 6] = f * dYdy / Z
    M[4, 6] = 0.0
    M[5, 6] = 0.0
    M[6, 6] = -(a * y0) / c - v * dc / c
    M[7, 6] = -(a * dc / cc)
    M[8, 6] = -a / c - b * dc / cc
    dc = (-a * Zx0f + Z) - c
    M[2, 7] = 0.0
    M[3, 7] = 0.0
    M[4, 7] = M[2, 6]
    M[5, 7] = M[3, 6]
    M[6, 7] = -(b * y0) / c - v * dc / c
    M[7, 7] = -(a * dc / cc)
    M[8, 7] = -b / c - b * dc / cc
    dc = -Zy0f
    M[2, 8] = -(x0 * dYdx) / Z
    M[3, 8] = -(x0 * dYdy) / Z
    M[4, 8] = -(y0 * dYdx) / Z
    M[5, 8] = -(y0 * dYdy) / Z
    M[6, 8] = y0 / c - v * dc / c
    M[7, 8] = -(a * dc / cc)
    M[8, 8] = 1.0 / c - b * dc / cc


@njit(inline="always")
def _coefficients(a, b, C):
    """``C`` (9 x 7): the outputs ``Ux, Uy, Uz, growth, rotation, Zx_t, Zy_t`` as linear
    functions of theta (:func:`estimator.disentangle._rate_coefficients`)."""
    for j in range(9):
        for q in range(7):
            C[j, q] = 0.0
    C[0, 0] = 1.0
    C[1, 1] = 1.0
    C[2, 2] = 1.0
    # the inverse Gram matrix of e1 = (1, 0, a), e2 = (0, 1, b) and the dual vectors
    m11 = 1.0 + a * a
    m12 = a * b
    m22 = 1.0 + b * b
    det = m11 * m22 - m12 * m12
    i11, i12, i22 = m22 / det, -m12 / det, m11 / det
    # the right-handed orthonormal (t1, t2, n)
    nn = np.sqrt(a * a + b * b + 1.0)
    n0, n1, n2 = -a / nn, -b / nn, 1.0 / nn
    s = np.sqrt(m11)
    t10, t11, t12 = 1.0 / s, 0.0, a / s
    t20 = n1 * t12 - n2 * t11
    t21 = n2 * t10 - n0 * t12
    t22 = n0 * t11 - n1 * t10
    for k in range(2):
        # dual_k = inv[k][0] e1 + inv[k][1] e2, the coefficients of g_k (rows r..r+2)
        if k == 0:
            d0, d1, d2 = i11, i12, i11 * a + i12 * b
        else:
            d0, d1, d2 = i12, i22, i12 * a + i22 * b
        r = 3 + 3 * k
        C[r, 3], C[r + 1, 3], C[r + 2, 3] = d0, d1, d2
        p1 = d0 * t10 + d1 * t11 + d2 * t12
        p2 = d0 * t20 + d1 * t21 + d2 * t22
        C[r, 4] = 0.5 * (p1 * t20 - p2 * t10)
        C[r + 1, 4] = 0.5 * (p1 * t21 - p2 * t11)
        C[r + 2, 4] = 0.5 * (p1 * t22 - p2 * t12)
        # Zx_t = g1z - Zx g1x - Zy g1y (column 5), Zy_t alike with g2 (column 6)
        C[r, 5 + k], C[r + 1, 5 + k], C[r + 2, 5 + k] = -a, -b, 1.0


@njit(inline="always")
def _lu_solve_transposed(M, C, A, T):
    """``A = M^-T C`` (M, T: 9 x 9, C, A: 9 x 7) by LU with partial pivoting of ``M^T``
    (copied into ``T``); False where a pivot is exactly 0."""
    n = 9
    for r in range(n):
        for c in range(n):
            T[r, c] = M[c, r]
        for q in range(7):
            A[r, q] = C[r, q]
    for k in range(n):
        p = k
        big = abs(T[k, k])
        for r in range(k + 1, n):
            if abs(T[r, k]) > big:
                big = abs(T[r, k])
                p = r
        if big == 0.0:
            return False
        if p != k:
            for c in range(n):
                T[k, c], T[p, c] = T[p, c], T[k, c]
            for q in range(7):
                A[k, q], A[p, q] = A[p, q], A[k, q]
        for r in range(k + 1, n):
            m = T[r, k] / T[k, k]
            if m != 0.0:
                for c in range(k + 1, n):
                    T[r, c] -= m * T[k, c]
                for q in range(7):
                    A[r, q] -= m * A[k, q]
    for k in range(n - 1, -1, -1):
        for q in range(7):
            s = A[k, q]
            for c in range(k + 1, n):
                s -= T[k, c] * A[c, q]
            A[k, q] = s / T[k, k]
    return True


@njit(parallel=True, cache=True)
def _solve_kernel(obs, Z, Zx, Zy, x0, y0, f, var, vals, sd, sens):
    N = Z.size
    with_var = var.shape[0] == N
    with_sens = sens.shape[0] == N
    nblocks = (N + _BLOCK - 1) // _BLOCK
    for blk in prange(nblocks):
        M = np.empty((9, 9))
        T = np.empty((9, 9))
        C = np.empty((9, 7))
        A = np.empty((9, 7))
        for i in range(blk * _BLOCK, min(N, (blk + 1) * _BLOCK)):
            ok = np.isfinite(Z[i]) and np.isfinite(Zx[i]) and np.isfinite(Zy[i])
            for j in range(9):
                ok = ok and np.isfinite(obs[j, i])
            solved = False
            if ok:
                _system(Z[i], Zx[i], Zy[i], x0[i], y0[i], f, M)
                _coefficients(Zx[i], Zy[i], C)
                solved = _lu_solve_transposed(M, C, A, T)
            if not solved:
                for q in range(7):
                    vals[q, i] = np.nan
                if with_var:
                    for q in range(3):
                        sd[q, i] = np.nan
                if with_sens:
                    for j in range(9):
                        sens[i, j] = np.nan
                continue
            for q in range(7):
                s = 0.0
                for j in range(9):
                    s += A[j, q] * obs[j, i]
                vals[q, i] = s
            if with_var:
                # Uz, growth, rotation: columns 2, 3, 4
                for q in range(3):
                    s = 0.0
                    for j in range(9):
                        s += A[j, 2 + q] * A[j, 2 + q] * var[i, j]
                    sd[q, i] = np.sqrt(s)
            if with_sens:
                for j in range(9):
                    sens[i, j] = A[j, 3]


def solve_affine_kernel(obs, Z, Zx, Zy, x0, y0, f, var_obs=None, sensitivity=False):
    """:func:`estimator.disentangle.solve_affine` (same parameters and returns) as one
    parallel numba pass; NaN also where a pixel's system is exactly singular (the numpy
    version raises there)."""
    N = Z.size
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    vals = np.empty((7, N))
    var = f64(var_obs) if var_obs is not None else np.empty((0, 9))
    sd = np.empty((3, N)) if var_obs is not None else np.empty((3, 0))
    sens = np.empty((N, 9)) if sensitivity else np.empty((0, 9))
    with np.errstate(all="ignore"):
        _solve_kernel(f64(obs), f64(Z), f64(Zx), f64(Zy), f64(x0), f64(y0), float(f), var,
                      vals, sd, sens)
    out = dict(zip(("Ux", "Uy", "Uz", "growth", "rotation", "Zx_t", "Zy_t"), vals))
    if var_obs is not None:
        out["Uz_err"], out["growth_err"], out["rotation_err"] = sd
    if sensitivity:
        out["growth_sensitivity"] = sens
    return out
