"""Numba kernel of the affine model's per-pixel solve: :func:`estimator.disentangle.
solve_affine` in one parallel pass.

Per pixel it builds the 9 x 9 system ``M`` of :func:`estimator.disentangle.
affine_observations` (column ``j`` the observations of unit motion ``j``, the same
formulas evaluated on one pixel), the outputs' coefficients ``C`` (9 x 7: ``U`` and the
rates of :func:`estimator.disentangle._rate_coefficients`), solves ``M^T A = C`` by LU
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
def _observe(j, Z, a, b, x0, y0, f, col):
    """The observations (in ``_AFFINE_OBS``'s order) of the unit motion ``theta = e_j``
    at one pixel: :func:`estimator.disentangle.affine_observations`, term by term."""
    U0 = 1.0 if j == 0 else 0.0
    U1 = 1.0 if j == 1 else 0.0
    U2 = 1.0 if j == 2 else 0.0
    g1x = 1.0 if j == 3 else 0.0
    g1y = 1.0 if j == 4 else 0.0
    g1z = 1.0 if j == 5 else 0.0
    g2x = 1.0 if j == 6 else 0.0
    g2y = 1.0 if j == 7 else 0.0
    g2z = 1.0 if j == 8 else 0.0
    c = Z * (1.0 - a * x0 / f - b * y0 / f)
    wx = (f * U0 - x0 * U2) / Z
    wy = (f * U1 - y0 * U2) / Z
    Zdx = a * Z * Z / (c * f)
    Zdy = b * Z * Z / (c * f)
    dXdx = (Zdx * x0 + Z) / f
    dXdy = Zdy * x0 / f
    dYdx = Zdx * y0 / f
    dYdy = (Zdy * y0 + Z) / f
    Vdx0 = g1x * dXdx + g2x * dYdx
    Vdx1 = g1y * dXdx + g2y * dYdx
    Vdx2 = g1z * dXdx + g2z * dYdx
    Vdy0 = g1x * dXdy + g2x * dYdy
    Vdy1 = g1y * dXdy + g2y * dYdy
    Vdy2 = g1z * dXdy + g2z * dYdy
    col[0] = wx
    col[1] = wy
    col[2] = (f * Vdx0 - U2 - x0 * Vdx2) / Z - wx * Zdx / Z
    col[3] = (f * Vdy0 - x0 * Vdy2) / Z - wx * Zdy / Z
    col[4] = (f * Vdx1 - y0 * Vdx2) / Z - wy * Zdx / Z
    col[5] = (f * Vdy1 - U2 - y0 * Vdy2) / Z - wy * Zdy / Z
    # dN = g1 x e2 + e1 x g2 with e1 = (1, 0, a), e2 = (0, 1, b)
    dN0 = (g1y * b - g1z) + (-a * g2y)
    dN1 = (-g1x * b) + (a * g2x - g2z)
    dN2 = g1x + g2y
    da = -dN0 - a * dN2
    db = -dN1 - b * dN2
    # dc = dN . X_c + N . U - c dN_z, X_c = Z (x0/f, y0/f, 1), N = (-a, -b, 1)
    dc = (dN0 * (Z * x0 / f) + dN1 * (Z * y0 / f) + dN2 * Z) + (-a * U0 - b * U1 + U2) \
        - c * dN2
    v = -f / Z
    col[6] = (da * x0 + db * y0) / c - v * dc / c
    col[7] = da / c - a * dc / (c * c)
    col[8] = db / c - b * dc / (c * c)


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
        col = np.empty(9)
        for i in range(blk * _BLOCK, min(N, (blk + 1) * _BLOCK)):
            ok = np.isfinite(Z[i]) and np.isfinite(Zx[i]) and np.isfinite(Zy[i])
            for j in range(9):
                ok = ok and np.isfinite(obs[j, i])
            solved = False
            if ok:
                for j in range(9):
                    _observe(j, Z[i], Zx[i], Zy[i], x0[i], y0[i], f, col)
                    for r in range(9):
                        M[r, j] = col[r]
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
