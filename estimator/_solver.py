"""The fast path's null-space solver (numba): the parameter vectors of every pixel of a
packed tensor.

The parameter vectors ``P = E M^-1`` do not depend on the basis of the null space, so
they are iterated themselves (:func:`_lanes_p`): ``P <- (J + δI)^-1 P`` with
``δ = RIDGE trace J`` (the reference path's ridge, :data:`estimator.nullspace.RIDGE`),
renormalised so that the fixed rows are the unit matrix, from the least-squares start or
the lane's previous pixel, until the estimated error left is below ``_P_TOL`` (no
orthonormalisation, no Rayleigh-Ritz step).  Pixels go through in blocks of ``_LANES``
with the pixel as the inner loop, from tiles copied out of the packed planes (parallel
over chunks).  The reference path's checks are made by sufficient tests (see
:func:`_lanes_p`); a pixel they do not settle goes to the exact scalar path
(:func:`_pixel`: inverse subspace iteration with a Rayleigh-Ritz step, up to
``MAX_ITER``, then a full Jacobi eigen-decomposition).  Measured on 512x512 sinusoids:
HF and full settle every pixel in the lanes, noise-free, with σ_n = 0.025 and under brightness change; where
a model has broken down (BCC under brightness change) every pixel takes the scalar path,
and after a block that settles nothing the lanes are skipped for ``_SKIP_BLOCKS``.  The
weights ``(J_qq + δI)^-1_rr`` come from the same Cholesky factor (rows ordered so that
the fixed rows are last).

The kernels share their state as four named tuples of arrays (numba passes them as
structs; their fields are resolved at compile time): :class:`SolverSpec` (the model's
row layout and the tolerances), :class:`LaneWork` and :class:`ScalarWork` (the work
arrays of a chunk's lane and scalar paths) and :class:`SolverOutput`.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit, prange

from .models import Model
from .nullspace import COMBINED_ROWS, M_TOL, RANK_TOL, RIDGE, NullSpace

__all__ = ["null_space_packed", "null_space_parts", "MAX_ITER"]

# Subspace iterations of the scalar path before it falls back to a full eigen-decomposition.
MAX_ITER = 8
# The shift of the inverse iteration: the reference path's ridge, so that the weights g
# (from the same factor of J + δI) are those of estimator.nullspace.null_space.
_SHIFT = RIDGE
# Convergence of the scalar path's subspace iteration: residual below this times trace J.
_CONV = 1e-13
# Chunks of pixels the parallel loop hands out (each with its own work arrays).
_CHUNKS = 256

SolverSpec = namedtuple("SolverSpec", "idx perm k nq grows rank_tol m_tol max_iter")
SolverSpec.__doc__ = """The model's layout and the tolerances.

idx (n, n) plane of each entry of J; perm (n,) the rows in solving order (non-fixed
first, the k fixed rows last); k the null-space dimension; nq = n - k; grows the
positions (in perm order) of the rows whose weights g are wanted; rank_tol, m_tol the
validity tolerances of estimator.nullspace; max_iter the scalar path's iterations."""
LaneWork = namedtuple("LaneWork", "A L dl Li X Y Pn Minv G H lw P g err settled warm")
LaneWork.__doc__ = """Work arrays of the lane solver, the lane (pixel) index last.

A (n, n, nl) J; L, dl its Cholesky factor and reciprocal diagonal; Li (nq, nq, nl)
L_qq^-1; X, Y, Pn (n, k, nl) the iterate, the solve and the renormalised iterate; Minv,
G, H (k, k, nl); lw (10, nl) per-lane scalars; P, g, err the lanes' results; settled,
warm (nl,) per-lane flags."""
ScalarWork = namedtuple("ScalarWork", "A B L X Y AY H V th y b M MtM Vk wk Minv E ew")
ScalarWork.__doc__ = """Work arrays of the scalar path (one pixel).

A, B, L (n, n) J, J + δI and its Cholesky factor; X, Y, AY (n, k + 1) the subspace; H,
V (k + 1, k + 1) and th (k + 1,) its Rayleigh-Ritz problem; y, b (n,); M, MtM, Vk, Minv
(k, k) and wk (k,) for the checks and P = X M^-1; E (n, n) and ew (n,) the fallback's
eigen-decomposition."""
SolverOutput = namedtuple("SolverOutput", "P g err valid nfall")
SolverOutput.__doc__ = """Results, pixel last: P (n, k, N), g (n, N), err (N,), valid
(N,) and nfall (_CHUNKS, 2) the counts of pixels sent to the scalar path and to the full decomposition."""


@njit(cache=True)
def _cholesky(A, L):
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if s <= 0.0:
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            t = A[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
    return True


@njit(cache=True)
def _chol_solve(L, b, y, x):
    """Solve L L^T x = b in place of x (y is workspace)."""
    n = L.shape[0]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True)
def _jacobi(H, V, w):
    """Eigen-decomposition of a small symmetric H (destroyed): ascending w, columns of V."""
    m = H.shape[0]
    for i in range(m):
        for j in range(m):
            V[i, j] = 1.0 if i == j else 0.0
    for _ in range(50):
        off = 0.0
        diag = 0.0
        for i in range(m):
            diag += H[i, i] * H[i, i]
            for j in range(i + 1, m):
                off += H[i, j] * H[i, j]
        if off <= 1e-32 * diag or off == 0.0:
            break
        for p in range(m):
            for q in range(p + 1, m):
                if H[p, q] == 0.0:
                    continue
                theta = (H[q, q] - H[p, p]) / (2.0 * H[p, q])
                t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(m):
                    hkp, hkq = H[k, p], H[k, q]
                    H[k, p] = c * hkp - s * hkq
                    H[k, q] = s * hkp + c * hkq
                for k in range(m):
                    hpk, hqk = H[p, k], H[q, k]
                    H[p, k] = c * hpk - s * hqk
                    H[q, k] = s * hpk + c * hqk
                for k in range(m):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - s * vkq
                    V[k, q] = s * vkp + c * vkq
    for i in range(m):
        w[i] = H[i, i]
    # sort ascending (insertion sort: m <= 4, or n for the scalar path's fallback)
    for i in range(1, m):
        j = i
        while j > 0 and w[j - 1] > w[j]:
            w[j - 1], w[j] = w[j], w[j - 1]
            for k in range(m):
                V[k, j - 1], V[k, j] = V[k, j], V[k, j - 1]
            j -= 1


@njit(cache=True)
def _iterate(ws, tr, k, max_iter):
    """Shifted inverse subspace iteration; ``ws.X`` (n, m) start in, Ritz vectors out.

    On entry ``ws.L`` must hold the Cholesky factor of ``A + δI``.  Convergence is judged
    on the k-th vector, the slowest of the null space (rate θ_k / θ_{k+2})."""
    A, X, L, Y, AY, H, Vh, th, y, b = (ws.A, ws.X, ws.L, ws.Y, ws.AY, ws.H, ws.V, ws.th,
                                        ws.y, ws.b)
    n, m = X.shape
    for _ in range(max_iter):
        for j in range(m):
            for r in range(n):
                b[r] = X[r, j]
            _chol_solve(L, b, y, Y[:, j])
        # orthonormalise Y (modified Gram-Schmidt, twice)
        for j in range(m):
            for _ in range(2):
                for i in range(j):
                    d = 0.0
                    for r in range(n):
                        d += Y[r, i] * Y[r, j]
                    for r in range(n):
                        Y[r, j] -= d * Y[r, i]
            nrm = 0.0
            for r in range(n):
                nrm += Y[r, j] * Y[r, j]
            if nrm == 0.0:
                return False
            nrm = np.sqrt(nrm)
            for r in range(n):
                Y[r, j] /= nrm
        # Rayleigh-Ritz: AY = A Y, H = Y^T AY
        for p in range(m):
            for r in range(n):
                s = 0.0
                for c in range(n):
                    s += A[r, c] * Y[c, p]
                AY[r, p] = s
        for p in range(m):
            for q in range(p, m):
                s = 0.0
                for r in range(n):
                    s += Y[r, q] * AY[r, p]
                H[p, q] = s
                H[q, p] = s
        _jacobi(H, Vh, th)
        for r in range(n):
            for j in range(m):
                s = 0.0
                for q in range(m):
                    s += Y[r, q] * Vh[q, j]
                X[r, j] = s
        # residual of the k-th Ritz pair: A x - θ x = AY v - θ Y v
        j = k - 1
        r2 = 0.0
        for r in range(n):
            v = -th[j] * X[r, j]
            for q in range(m):
                v += AY[r, q] * Vh[q, j]
            r2 += v * v
        if np.sqrt(r2) <= _CONV * tr:
            return True
    return False


@njit(cache=True)
def _accept(ws, tr, spec):
    """The validity checks of :func:`estimator.nullspace.null_space` on a found subspace
    (``ws.X``, ``ws.th``): the (k+1)-th eigenvalue clear of zero (texture), and M, the
    fixed rows of the k null vectors, well conditioned (the ds, dt directions lie in the
    null space); leaves M in ``ws.M``."""
    X, th, M, MtM, Vk, wk = ws.X, ws.th, ws.M, ws.MtM, ws.Vk, ws.wk
    k, nq, rank_tol, m_tol = spec.k, spec.nq, spec.rank_tol, spec.m_tol
    if not th[k] > rank_tol * tr:
        return False
    for a in range(k):
        for bb in range(k):
            M[a, bb] = X[nq + a, bb]
    for a in range(k):
        for bb in range(k):
            s = 0.0
            for r in range(k):
                s += M[r, a] * M[r, bb]
            MtM[a, bb] = s
    _jacobi(MtM, Vk, wk)
    return np.sqrt(max(wk[0], 0.0)) > m_tol


@njit(cache=True)
def _pixel(ws, tr, have, spec, i, out):
    """One pixel, scalar: the fallback of the lane solver (and its definition).

    ``ws.A`` holds J (rows in ``spec.perm`` order), ``ws.X`` a start (used if ``have``).
    Writes P, g, err, valid of pixel ``i`` into ``out``; returns (solved, fell back to
    the full decomposition)."""
    A, X, L, B, th = ws.A, ws.X, ws.L, ws.B, ws.th
    k, max_iter = spec.k, spec.max_iter
    err, valid = out.err, out.valid
    n = A.shape[0]
    m = k + 1
    valid[i] = False
    if not (tr > 0.0 and np.isfinite(tr)):
        return False, False
    for a in range(n):
        for bb in range(n):
            B[a, bb] = A[a, bb]
        B[a, a] += _SHIFT * tr
    if not _cholesky(B, L):
        return False, False
    if not have:
        # deterministic, dense start: every component non-zero, so that no
        # eigenvector is missed when J decouples exactly (a static scene has
        # I_t = 0: the dt direction is a unit vector, and a start orthogonal to
        # it would never find it)
        for r in range(n):
            for j in range(m):
                X[r, j] = np.cos(1.0 + 0.618 * (r + 1) * (j + 1))
    ok = _iterate(ws, tr, k, max_iter)
    good = ok and _accept(ws, tr, spec)
    fell = False
    if not good:
        # the full decomposition after non-convergence, and also when the iteration's
        # subspace fails the checks (it could miss a direction its start lacked)
        fell = True
        # the full eigen-decomposition by Jacobi rotations, not LAPACK's eigh: LAPACK's
        # sums depend on the machine's CPU kernels, so its last bits (and a pixel's
        # validity near a threshold) would differ from one machine to another
        for a in range(n):
            for bb in range(n):
                B[a, bb] = A[a, bb]
        _jacobi(B, ws.E, ws.ew)
        for r in range(n):
            for j in range(m):
                X[r, j] = ws.E[r, j]
        for j in range(m):
            th[j] = ws.ew[j]
        good = _accept(ws, tr, spec)
    err[i] = th[k - 1]
    if not good:
        return False, fell
    _finish(ws, spec, i, out)
    valid[i] = True
    return True, fell


@njit(cache=True)
def _finish(ws, spec, i, out):
    """P = X_k M^-1 and the weights g of an accepted pixel (M as left by _accept)."""
    X, M, MtM, Minv, L, y = ws.X, ws.M, ws.MtM, ws.Minv, ws.L, ws.y
    k, nq, perm, grows = spec.k, spec.nq, spec.perm, spec.grows
    P, g = out.P, out.g
    n = X.shape[0]
    # Minv by Gauss-Jordan with partial pivoting (k <= 3)
    for a in range(k):
        for bb in range(k):
            MtM[a, bb] = M[a, bb]
            Minv[a, bb] = 1.0 if a == bb else 0.0
    for col in range(k):
        piv = col
        for r in range(col + 1, k):
            if abs(MtM[r, col]) > abs(MtM[piv, col]):
                piv = r
        for cc in range(k):
            MtM[col, cc], MtM[piv, cc] = MtM[piv, cc], MtM[col, cc]
            Minv[col, cc], Minv[piv, cc] = Minv[piv, cc], Minv[col, cc]
        d = MtM[col, col]
        for cc in range(k):
            MtM[col, cc] /= d
            Minv[col, cc] /= d
        for r in range(k):
            if r != col:
                f = MtM[r, col]
                for cc in range(k):
                    MtM[r, cc] -= f * MtM[col, cc]
                    Minv[r, cc] -= f * Minv[col, cc]
    for r in range(n):
        for cc in range(k):
            s = 0.0
            for bb in range(k):
                s += X[r, bb] * Minv[bb, cc]
            P[perm[r], cc, i] = s
    # g_r = (J_qq + δI)^-1_rr = |L_qq^-1 e_r|^2 (forward substitution only)
    for t in range(grows.size):
        r0 = grows[t]
        s2 = 0.0
        for a in range(nq):
            if a < r0:
                y[a] = 0.0
                continue
            s = 1.0 if a == r0 else 0.0
            for kk in range(r0, a):
                s -= L[a, kk] * y[kk]
            y[a] = s / L[a, a]
            s2 += y[a] * y[a]
        g[perm[r0], i] = s2


# Pixels per lane block: the lane kernels loop over the block innermost, so that LLVM
# can use SIMD across pixels.  _lanes_p takes the count from an array's shape, not from
# this constant: LLVM fully unrolls loops of a constant trip count, and numba leaves its
# SLP vectoriser off, so unrolled lanes ran as scalar code; a loop of run-time length is
# vectorised by the loop vectoriser.  Measured on the 512^2 benchmark tensor (full
# model, 2 threads, best of 12 in one process): 8 constant lanes 0.248 s, 16 run-time
# lanes 0.195 s, 32 0.171 s; in another run 8 constant 0.259 s, 32 0.181 s, 64 0.165 s.
_LANES = 32
# Steps of the parameter-vector iteration before a pixel goes to the scalar path, and
# its stopping rule: the error left after the last step, estimated as change * rho with
# rho = change / previous change (linear convergence at rate lambda_k / lambda_k+1),
# below _P_TOL times max(1, max|P|) (P's fixed rows are a unit matrix).
P_ITERS = 5
# Pixels per tile copied out of the packed planes (120 x 256 doubles: 240 KB, in L2).
_TILE = 256
# Lane blocks skipped after one in which no lane settled (128 pixels).
_SKIP_BLOCKS = 4
# 1e-11: on the 512^2 benchmark volume it settled the blocks (then of 8 pixels) in 2.04
# steps on average instead of 3.02 at 1e-13 (the solver 17 % faster), and moves P by at
# most 9e-11 of max|P| (the model error by 2e-14), far inside the fast path's stated
# agreement with the reference (1e-6 of each quantity's scale;
# tests/test_estimator_properties.py).
_P_TOL = 1e-11
_FM = {"contract", "arcp"}


@njit(fastmath=_FM, error_model="numpy", cache=True)
def _lanes_p(Jp, N, i0, spec, lanes):
    """One block of _LANES pixels ``i0 ...`` (columns of the planes ``Jp``, of which the
    first ``N`` are pixels; lanes beyond repeat the last) by the parameter-vector
    iteration, in the lane work space ``lanes`` (:class:`LaneWork`).

    P = E M^-1 does not depend on the basis of the null space, so instead of an
    orthonormal basis and a Rayleigh-Ritz step the vectors P themselves are iterated:
    ``P <- (J + δI)^-1 P``, renormalised so that the fixed rows are the unit matrix
    again.  The start is the previous block's P in the same lane (``warm[p]``), else the
    least-squares solution ``P_q = -(J_qq + δI)^-1 J_qf`` (it differs from the TLS one by
    O(λ_k / λ_k+1)).  The reference path's checks are made by sufficient tests on
    numbers the iteration has anyway; a lane failing one is not ``settled`` and goes to
    the exact scalar path:

    * texture: by interlacing λ_k+1(J) >= λ_min(J_qq) >= 1 / trace((J_qq + δI)^-1) - δ;
    * M well conditioned: for an orthonormal basis E of span(P) the singular values of
      its fixed rows are those of (P^T P)^(-1/2), so smin >= 1 / sqrt(trace(P^T P)).

    The model error λ_k is the largest Ritz value of span(P), from ``P^T J P`` and
    ``P^T P``; ``J P`` comes from the last solve (``J Y = X - δ Y``).
    """
    idx, perm, k, nq, grows = spec.idx, spec.perm, spec.k, spec.nq, spec.grows
    rank_tol, m_tol = spec.rank_tol, spec.m_tol
    A, L, dl, Li, X, Y, Pn = lanes.A, lanes.L, lanes.dl, lanes.Li, lanes.X, lanes.Y, lanes.Pn
    Minv, G, H, lw = lanes.Minv, lanes.G, lanes.H, lanes.lw
    P_out, g_out, err_out = lanes.P, lanes.g, lanes.err
    settled, warm = lanes.settled, lanes.warm
    n = A.shape[0]
    nl = lw.shape[1]                 # = _LANES, at run time (see _LANES)
    # gather (rows in perm order: the k fixed rows last)
    for a in range(n):
        for bb in range(a, n):
            e = idx[perm[a], perm[bb]]
            for p in range(nl):
                v = Jp[e, min(i0 + p, N - 1)]
                A[a, bb, p] = v
                A[bb, a, p] = v
    for p in range(nl):
        t = 0.0
        for a in range(n):
            t += A[a, a, p]
        lw[0, p] = t                              # trace
        lw[1, p] = _SHIFT * t                     # δ
        settled[p] = t > 0.0 and np.isfinite(t)
    # Cholesky of A + δI, reciprocal diagonal in dl; a bad pivot marks the lane
    for j in range(n):
        for p in range(nl):
            lw[2, p] = A[j, j, p] + lw[1, p]
        for kk in range(j):
            for p in range(nl):
                lw[2, p] -= L[j, kk, p] * L[j, kk, p]
        for p in range(nl):
            s = lw[2, p]
            good = s > 0.0
            settled[p] = settled[p] and good
            d = np.sqrt(s) if good else 1.0
            L[j, j, p] = d
            dl[j, p] = 1.0 / d
        for i in range(j + 1, n):
            for p in range(nl):
                lw[3, p] = A[i, j, p]
            for kk in range(j):
                for p in range(nl):
                    lw[3, p] -= L[i, kk, p] * L[j, kk, p]
            for p in range(nl):
                L[i, j, p] = lw[3, p] * dl[j, p]
    # Li = L_qq^-1 (lower), column by column; trace and selected diagonal of Li^T Li
    for c in range(nq):
        for i in range(c):
            for p in range(nl):
                Li[i, c, p] = 0.0
        for p in range(nl):
            Li[c, c, p] = dl[c, p]
        for i in range(c + 1, nq):
            for p in range(nl):
                lw[3, p] = 0.0
            for kk in range(c, i):
                for p in range(nl):
                    lw[3, p] -= L[i, kk, p] * Li[kk, c, p]
            for p in range(nl):
                Li[i, c, p] = lw[3, p] * dl[i, p]
    for p in range(nl):
        lw[4, p] = 0.0                            # trace of (J_qq + δI)^-1
    for c in range(nq):
        for p in range(nl):
            lw[5, p] = 0.0
        for i in range(c, nq):
            for p in range(nl):
                lw[5, p] += Li[i, c, p] * Li[i, c, p]
        for p in range(nl):
            lw[4, p] += lw[5, p]
        for t in range(grows.size):
            if grows[t] == c:
                for p in range(nl):
                    g_out[t, p] = lw[5, p]
    for p in range(nl):
        settled[p] = settled[p] and (1.0 / lw[4, p] - lw[1, p] > rank_tol * lw[0, p])
    # start
    cold = False
    for p in range(nl):
        cold = cold or not warm[p]
    if cold:
        # P_q = -Li^T (Li J_qf); lanes with a warm start keep theirs
        for c in range(k):
            for i in range(nq):
                for p in range(nl):
                    Y[i, c, p] = 0.0
                for kk in range(i + 1):
                    for p in range(nl):
                        Y[i, c, p] += Li[i, kk, p] * A[kk, nq + c, p]
            for i in range(nq):
                for p in range(nl):
                    lw[3, p] = 0.0
                for kk in range(i, nq):
                    for p in range(nl):
                        lw[3, p] += Li[kk, i, p] * Y[kk, c, p]
                for p in range(nl):
                    X[i, c, p] = X[i, c, p] if warm[p] else -lw[3, p]
            for i in range(k):
                for p in range(nl):
                    X[nq + i, c, p] = 1.0 if i == c else 0.0
    for p in range(nl):
        lw[6, p] = 0.0                            # previous change
        lw[7, p] = 0.0                            # converged (0/1)
    for it in range(P_ITERS):
        # Y = (L L^T)^-1 X
        for c in range(k):
            for r in range(n):
                for p in range(nl):
                    Y[r, c, p] = X[r, c, p]
                for kk in range(r):
                    for p in range(nl):
                        Y[r, c, p] -= L[r, kk, p] * Y[kk, c, p]
                for p in range(nl):
                    Y[r, c, p] *= dl[r, p]
            for r in range(n - 1, -1, -1):
                for kk in range(r + 1, n):
                    for p in range(nl):
                        Y[r, c, p] -= L[kk, r, p] * Y[kk, c, p]
                for p in range(nl):
                    Y[r, c, p] *= dl[r, p]
        # Minv = (fixed rows of Y)^-1 by the adjugate
        if k == 3:
            for p in range(nl):
                a00, a01, a02 = Y[nq, 0, p], Y[nq, 1, p], Y[nq, 2, p]
                a10, a11, a12 = Y[nq + 1, 0, p], Y[nq + 1, 1, p], Y[nq + 1, 2, p]
                a20, a21, a22 = Y[nq + 2, 0, p], Y[nq + 2, 1, p], Y[nq + 2, 2, p]
                c00 = a11 * a22 - a12 * a21
                c01 = a02 * a21 - a01 * a22
                c02 = a01 * a12 - a02 * a11
                inv = 1.0 / (a00 * c00 + a10 * c01 + a20 * c02)
                Minv[0, 0, p] = c00 * inv
                Minv[0, 1, p] = c01 * inv
                Minv[0, 2, p] = c02 * inv
                Minv[1, 0, p] = (a12 * a20 - a10 * a22) * inv
                Minv[1, 1, p] = (a00 * a22 - a02 * a20) * inv
                Minv[1, 2, p] = (a02 * a10 - a00 * a12) * inv
                Minv[2, 0, p] = (a10 * a21 - a11 * a20) * inv
                Minv[2, 1, p] = (a01 * a20 - a00 * a21) * inv
                Minv[2, 2, p] = (a00 * a11 - a01 * a10) * inv
        elif k == 2:
            for p in range(nl):
                a00, a01 = Y[nq, 0, p], Y[nq, 1, p]
                a10, a11 = Y[nq + 1, 0, p], Y[nq + 1, 1, p]
                inv = 1.0 / (a00 * a11 - a01 * a10)
                Minv[0, 0, p] = a11 * inv
                Minv[0, 1, p] = -a01 * inv
                Minv[1, 0, p] = -a10 * inv
                Minv[1, 1, p] = a00 * inv
        else:
            # k = 1 (a static 1-D grid: ds_x alone)
            for p in range(nl):
                Minv[0, 0, p] = 1.0 / Y[nq, 0, p]
        # Pn = Y Minv; change and size
        for p in range(nl):
            lw[8, p] = 0.0                        # change
            lw[9, p] = 1.0                        # max(1, max|Pn|)
        for r in range(n):
            for c in range(k):
                for p in range(nl):
                    lw[3, p] = 0.0
                for bb in range(k):
                    for p in range(nl):
                        lw[3, p] += Y[r, bb, p] * Minv[bb, c, p]
                for p in range(nl):
                    v = lw[3, p]
                    Pn[r, c, p] = v
                    lw[8, p] = max(lw[8, p], abs(v - X[r, c, p]))
                    lw[9, p] = max(lw[9, p], abs(v))
        done = True
        for p in range(nl):
            ch = lw[8, p]
            rho = ch / lw[6, p] if lw[6, p] > 0.0 else 1.0
            conv = ch == 0.0 or (rho < 0.5 and ch * rho <= _P_TOL * lw[9, p])
            lw[7, p] = 1.0 if conv else 0.0
            lw[6, p] = ch
            done = done and (conv or not settled[p])
        if done:
            break
        if it < P_ITERS - 1:
            for r in range(n):
                for c in range(k):
                    for p in range(nl):
                        X[r, c, p] = Pn[r, c, p]
    # G = Pn^T Pn, H = Pn^T X Minv - δ G  (X: the input of the last solve)
    for r in range(n):
        for c in range(k):
            for p in range(nl):
                lw[3, p] = 0.0
            for q in range(k):
                for p in range(nl):
                    lw[3, p] += X[r, q, p] * Minv[q, c, p]
            for p in range(nl):
                Y[r, c, p] = lw[3, p]             # X Minv = J Pn + δ Pn
    for a in range(k):
        for bb in range(a, k):
            for p in range(nl):
                G[a, bb, p] = 0.0
                H[a, bb, p] = 0.0
            for r in range(n):
                for p in range(nl):
                    G[a, bb, p] += Pn[r, a, p] * Pn[r, bb, p]
                    H[a, bb, p] += Pn[r, a, p] * Y[r, bb, p]
            for p in range(nl):
                H[a, bb, p] -= lw[1, p] * G[a, bb, p]
                G[bb, a, p] = G[a, bb, p]
    for p in range(nl):
        trg = 0.0
        for a in range(k):
            trg += G[a, a, p]
        settled[p] = settled[p] and lw[7, p] == 1.0 and trg * m_tol * m_tol < 1.0
    # largest Ritz value: eigenvalues of C = Lg^-1 H Lg^-T, G = Lg Lg^T
    for p in range(nl):
        if k == 3:
            g00, g10, g11 = G[0, 0, p], G[1, 0, p], G[1, 1, p]
            g20, g21, g22 = G[2, 0, p], G[2, 1, p], G[2, 2, p]
            l00 = np.sqrt(g00)
            l10 = g10 / l00
            l20 = g20 / l00
            l11 = np.sqrt(g11 - l10 * l10)
            l21 = (g21 - l20 * l10) / l11
            l22 = np.sqrt(g22 - l20 * l20 - l21 * l21)
            h00, h01, h02 = H[0, 0, p], H[0, 1, p], H[0, 2, p]
            h11, h12, h22 = H[1, 1, p], H[1, 2, p], H[2, 2, p]
            # W = Lg^-1 H (rows), then C = W Lg^-T
            w00 = h00 / l00
            w01 = h01 / l00
            w02 = h02 / l00
            w10 = (h01 - l10 * w00) / l11
            w11 = (h11 - l10 * w01) / l11
            w12 = (h12 - l10 * w02) / l11
            w20 = (h02 - l20 * w00 - l21 * w10) / l22
            w21 = (h12 - l20 * w01 - l21 * w11) / l22
            w22 = (h22 - l20 * w02 - l21 * w12) / l22
            c00 = w00 / l00
            c10 = w10 / l00
            c20 = w20 / l00
            c11 = (w11 - l10 * c10) / l11
            c21 = (w21 - l10 * c20) / l11
            c22 = (w22 - l20 * c20 - l21 * c21) / l22
            # symmetric 3x3: the largest eigenvalue by the trigonometric formula
            q = (c00 + c11 + c22) / 3.0
            p1 = c10 * c10 + c20 * c20 + c21 * c21
            p2 = (c00 - q) ** 2 + (c11 - q) ** 2 + (c22 - q) ** 2 + 2.0 * p1
            pp = np.sqrt(p2 / 6.0)
            if pp > 0.0:
                b00, b11, b22 = (c00 - q) / pp, (c11 - q) / pp, (c22 - q) / pp
                b10, b20, b21 = c10 / pp, c20 / pp, c21 / pp
                det = (b00 * (b11 * b22 - b21 * b21) - b10 * (b10 * b22 - b21 * b20)
                       + b20 * (b10 * b21 - b11 * b20))
                rr = min(1.0, max(-1.0, det / 2.0))
                err_out[p] = q + 2.0 * pp * np.cos(np.arccos(rr) / 3.0)
            else:
                err_out[p] = q
        elif k == 2:
            g00, g10, g11 = G[0, 0, p], G[1, 0, p], G[1, 1, p]
            l00 = np.sqrt(g00)
            l10 = g10 / l00
            l11 = np.sqrt(g11 - l10 * l10)
            h00, h01, h11 = H[0, 0, p], H[0, 1, p], H[1, 1, p]
            w00 = h00 / l00
            w01 = h01 / l00
            w10 = (h01 - l10 * w00) / l11
            w11 = (h11 - l10 * w01) / l11
            c00 = w00 / l00
            c10 = w10 / l00
            c11 = (w11 - l10 * c10) / l11
            mean = 0.5 * (c00 + c11)
            err_out[p] = mean + np.sqrt(0.25 * (c00 - c11) ** 2 + c10 * c10)
        else:
            err_out[p] = H[0, 0, p] / G[0, 0, p]
        settled[p] = settled[p] and np.isfinite(err_out[p])
    for r in range(n):
        for c in range(k):
            for p in range(nl):
                P_out[r, c, p] = Pn[r, c, p]


@njit(parallel=True, cache=True)
def _solve_all(Jp, spec, out, c_lo, c_hi):
    """The pixels of chunks ``c_lo .. c_hi - 1`` of the packed planes ``Jp`` (E, N), the
    N pixels cut into ``_CHUNKS`` chunks, in parallel; pixel ``i`` is written at
    ``i - base`` of ``out``, ``base`` the first pixel of chunk ``c_lo``.

    Each chunk starts cold and warm-starts within itself only, so the results do not
    depend on which chunks a call takes: the chunks of a tensor may be solved a few at a
    time (:func:`null_space_parts`), into outputs of those pixels alone.

    Rows are taken in the order ``spec.perm`` (non-fixed rows first, the k fixed rows
    last), so that the leading block of the Cholesky factor of J + δI is that of
    J_qq + δI, which gives the weights g.

    Pixels go through in blocks of _LANES (:func:`_lanes_p`, each lane warm-started from
    the pixel _LANES to its left); a pixel the lanes do not settle goes through the
    scalar path :func:`_pixel` (inverse subspace iteration, then Jacobi)."""
    N = Jp.shape[1]
    n = spec.idx.shape[0]
    k = spec.k
    nq = n - k
    m = k + 1
    nl = _LANES
    per = _chunk_blocks(N)
    base = c_lo * per * nl
    for ci in prange(c_hi - c_lo):
        c = c_lo + ci
        lanes = LaneWork(A=np.empty((n, n, nl)), L=np.zeros((n, n, nl)),
                         dl=np.empty((n, nl)), Li=np.zeros((nq, nq, nl)),
                         X=np.zeros((n, k, nl)), Y=np.empty((n, k, nl)),
                         Pn=np.empty((n, k, nl)), Minv=np.empty((k, k, nl)),
                         G=np.empty((k, k, nl)), H=np.empty((k, k, nl)),
                         lw=np.empty((10, nl)), P=np.empty((n, k, nl)),
                         g=np.empty((spec.grows.size, nl)), err=np.empty(nl),
                         settled=np.zeros(nl, dtype=np.bool_),
                         warm=np.zeros(nl, dtype=np.bool_))
        scalar = ScalarWork(A=np.empty((n, n)), B=np.empty((n, n)), L=np.zeros((n, n)),
                            X=np.empty((n, m)), Y=np.empty((n, m)), AY=np.empty((n, m)),
                            H=np.empty((m, m)), V=np.empty((m, m)), th=np.empty(m),
                            y=np.empty(n), b=np.empty(n), M=np.empty((k, k)),
                            MtM=np.empty((k, k)), Vk=np.empty((k, k)), wk=np.empty(k),
                            Minv=np.empty((k, k)), E=np.empty((n, n)), ew=np.empty(n))
        tile = np.empty((Jp.shape[0], _TILE))
        # state[0]: scalar.X holds a solved subspace; state[1]: lane blocks still to skip
        state = np.zeros(2, dtype=np.int64)
        c0 = c * per * nl
        c1 = min(N, (c + 1) * per * nl)
        for t0 in range(c0, c1, _TILE):
            nt = min(_TILE, c1 - t0)
            # a tile of the planes, copied plane by plane (contiguous runs): the lanes then
            # gather from cache instead of from ~100 planes spread over memory
            for e in range(Jp.shape[0]):
                for j in range(nt):
                    tile[e, j] = Jp[e, t0 + j]
            _tile_blocks(tile, nt, t0, base, spec, lanes, scalar, state, out, ci)


@njit(cache=True)
def _chunk_blocks(N):
    """Lane blocks per chunk of N pixels (the last chunks may be short or empty)."""
    return ((N + _LANES - 1) // _LANES + _CHUNKS - 1) // _CHUNKS


@njit(cache=True)
def _tile_blocks(tile, nt, t0, base, spec, lanes, scalar, state, out, c):
    """The lane blocks of one tile (pixels t0 .. t0 + nt - 1, written at ``i - base`` of
    ``out``), and the scalar path for the pixels they do not settle (``c``: the chunk's
    row of the fallback counts)."""
    idx, perm, k, grows = spec.idx, spec.perm, spec.k, spec.grows
    A, X, settled, warm = lanes.A, lanes.X, lanes.settled, lanes.warm
    Pl, gl, el = lanes.P, lanes.g, lanes.err
    As = scalar.A
    P, g, err, valid, nfall = out.P, out.g, out.err, out.valid, out.nfall
    n = idx.shape[0]
    nl = _LANES
    for b0 in range(0, nt, nl):
        if state[1] > 0:
            # the lanes settled nothing in a recent block (a broken-down model, a
            # textureless region): straight to the scalar path for a while
            state[1] -= 1
            for p in range(min(nl, nt - b0)):
                settled[p] = False
                warm[p] = False
                for a in range(n):
                    for bb in range(n):
                        A[a, bb, p] = tile[idx[perm[a], perm[bb]], b0 + p]
        else:
            _lanes_p(tile, nt, b0, spec, lanes)
            any_settled = False
            for p in range(min(nl, nt - b0)):
                any_settled = any_settled or settled[p]
            if not any_settled:
                state[1] = _SKIP_BLOCKS
        for p in range(min(nl, nt - b0)):
            i = t0 + b0 + p - base
            if settled[p]:
                for r in range(n):
                    for cc in range(k):
                        P[perm[r], cc, i] = Pl[r, cc, p]
                        X[r, cc, p] = Pl[r, cc, p]
                for t in range(grows.size):
                    g[perm[grows[t]], i] = gl[t, p]
                err[i] = el[p]
                valid[i] = True
                warm[p] = True
            else:
                tr = 0.0
                for a in range(n):
                    for bb in range(n):
                        As[a, bb] = A[a, bb, p]
                    tr += As[a, a]
                # warm start: the subspace of the last pixel this path solved (when the
                # lanes fail, as where a model has broken down, they fail for runs of
                # neighbouring pixels, taken here in order)
                solved, fell = _pixel(scalar, tr, state[0] == 1, spec, i, out)
                state[0] = 1 if solved else 0
                nfall[c, 0] += 1
                if fell:
                    nfall[c, 1] += 1
                warm[p] = False


def null_space_packed(planes: np.ndarray, index: np.ndarray, model: Model) -> NullSpace:
    """The parameter vectors of the solution space from a packed tensor.

    Parameters
    ----------
    planes : ndarray, shape (E, N)
        Packed tensor planes (flattened pixels), as from
        :func:`estimator.spectral.structure_tensor_fft`.
    index : ndarray of int, shape (n, n)
        Plane of entry (a, b) of this model's J (a sub-block of the packed tensor's
        index, :meth:`estimator.tensor.PackedTensor.sub_index`).
    model : Model

    Returns
    -------
    NullSpace
        As :func:`estimator.nullspace.null_space` (``g`` is filled for the combined rows
        only; ``P`` (N, n, k) and ``g`` (N, n) are transposed views of pixel-last
        arrays), with ``fallbacks``: the number of pixels the lane solver handed to the
        scalar path and, of those, how many fell back to the full (Jacobi) decomposition.
    """
    return _solve_chunks(planes, _spec(index, model), 0, _CHUNKS)


def null_space_parts(planes: np.ndarray, index: np.ndarray, model: Model, stops, *,
                     ahead: int = 16):
    """:func:`null_space_packed` part by part: the NullSpace of pixels ``[0, stops[0])``,
    then ``[stops[0], stops[1])``, ... (a generator), each the same bits as the same
    pixels of :func:`null_space_packed`'s.

    The chunks are solved as the parts reach them, at least ``ahead`` at a time (so that
    every thread has chunks to take), so only a few chunks' outputs are held at once
    instead of every pixel's: under the affine model at 512^2 (197 136 interior pixels,
    n = 21, k = 3) P, g, the model errors and the flags of a whole band are 134 MB,
    those of 16 chunks (800 pixels each) 8.7 MB.

    Parameters
    ----------
    planes, index, model
        As :func:`null_space_packed`.
    stops : sequence of int
        The increasing ends of the parts, the last at most N.
    ahead : int
        The fewest chunks solved in one parallel call.

    Yields
    ------
    NullSpace
        The part's pixels (``fallbacks`` those of the chunks solved for it, ``(0, 0)``
        where it needed none).
    """
    N = planes.shape[1]
    spec = _spec(index, model)
    width = _chunk_blocks(N) * _LANES              # pixels a chunk
    held, s0, s1, c_next = None, 0, 0, 0           # solved and held: [s0, s1)
    a = 0
    for b in stops:
        if not a <= b <= N:
            raise ValueError(f"stops must increase within [0, {N}], got {list(stops)}")
        fell = (0, 0)
        if b > s1:
            c_hi = min(_CHUNKS, max(-(-b // width), c_next + ahead))
            new = _solve_chunks(planes, spec, c_next, c_hi)
            fell = new.fallbacks
            if a == s1:
                held, s0 = new, s1
            else:
                # what is left of the last call's chunks, then the new ones (pixel-last
                # arrays joined along the pixels)
                keep = slice(a - s0, None)
                held = NullSpace(*(np.concatenate([h[keep].T, x.T], axis=-1).T
                                   for h, x in zip(held[:4], new[:4])), fell)
                s0 = a
            c_next, s1 = c_hi, min(N, c_hi * width)
        part = slice(a - s0, b - s0)
        yield NullSpace(*(x[part] for x in held[:4]), fell)
        a = b


def _spec(index: np.ndarray, model: Model) -> SolverSpec:
    n = model.n
    k = model.null_dim
    fixed = [model.index(r) for r in model.fixed_rows]
    perm = np.array([i for i in range(n) if i not in fixed] + fixed, dtype=np.int64)
    wanted = [model.index(r) for r in COMBINED_ROWS if r in model.rows]
    grows = np.array([int(np.flatnonzero(perm == r)[0]) for r in wanted], dtype=np.int64)
    return SolverSpec(idx=np.ascontiguousarray(index, dtype=np.int64), perm=perm, k=k,
                      nq=n - k, grows=grows, rank_tol=RANK_TOL, m_tol=M_TOL,
                      max_iter=MAX_ITER)


def _solve_chunks(planes: np.ndarray, spec: SolverSpec, c_lo: int, c_hi: int) -> NullSpace:
    """The NullSpace of the pixels of chunks ``c_lo .. c_hi - 1`` (:func:`_solve_all`)."""
    N = planes.shape[1]
    width = _chunk_blocks(N) * _LANES
    m = max(0, min(N, c_hi * width) - min(N, c_lo * width))
    n, k = spec.idx.shape[0], spec.k
    # pixel-last storage: the kernels write each pixel's entries at stride 1 along the
    # lanes, and the disentangling reads each entry as a contiguous (N,) vector; the
    # caller sees the usual (N, n, k) and (N, n) shapes as transposed views.  P is
    # written for every valid pixel and set to NaN below for the others; g only for the
    # combined rows, so the rest starts as NaN.
    out = SolverOutput(P=np.empty((n, k, m)), g=np.full((n, m), np.nan),
                       err=np.full(m, np.nan), valid=np.zeros(m, dtype=bool),
                       nfall=np.zeros((c_hi - c_lo, 2), dtype=np.int64))
    _solve_all(planes, spec, out, c_lo, c_hi)
    P, g, valid = out.P.transpose(2, 0, 1), out.g.T, out.valid
    P[~valid] = np.nan
    g[~valid] = np.nan
    return NullSpace(P, g, out.err, valid,
                     (int(out.nfall[:, 0].sum()), int(out.nfall[:, 1].sum())))
