"""Numba kernels of the fast path: input scan, camera sums and the null-space solver.

The structure tensor itself is computed by FFT in :mod:`estimator.spectral` (scipy only).

Input scan (:func:`scan_volume`) and camera sums (:func:`camera_sums`)
    One parallel pass over the volume each: the count of non-finite values with max |V|,
    and the weighted sums over the camera taps that :func:`estimator.tensor.
    camera_time_signals` needs (same result as its numpy default, to roundoff).

Null space (:func:`null_space_fast`)
    Pixels go through in blocks of ``_LANES`` (numba, parallel over chunks of blocks),
    each lane warm-started from the subspace found ``_LANES`` pixels to its left:
    Cholesky of ``J + δI`` (``δ = 1e-13 trace J``), ``LANE_ITERS`` = 2 steps of shifted
    inverse subspace iteration with k+1 vectors, then one Rayleigh-Ritz step (Jacobi,
    branch-free over the lanes).  A pixel is settled when the residual of its k-th Ritz
    pair is at most ``1e-13 trace J`` and it passes the reference path's checks; for a
    valid pixel the k null eigenvalues are ~1e-7 of the next one, so two steps settle
    nearly all (measured on 512x512 sinusoids, full model: all of them without noise,
    all but 0.9 % with σ_n = 0.025).  Any other pixel goes on in the scalar path
    (:func:`_pixel`: the same iteration with a Rayleigh-Ritz step each time, up to
    ``MAX_ITER``) and, failing that, to LAPACK's full ``eigh``.  The weights
    ``(J_qq + δI)^-1_rr`` come from the same Cholesky factor (rows ordered so that the
    fixed rows are last), with the reference path's ridge equal to this shift.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
from numba import njit, prange

from .models import Model
from .spectral import packed_index, structure_tensor_fft

__all__ = ["structure_tensor_fft", "null_space_fast", "packed_index", "MAX_ITER",
           "announce_compilation", "compile_kernels", "camera_sums", "scan_volume"]

_log = logging.getLogger("gridflow.estimator")
_announced = False


def _kernels_cached() -> bool:
    """Whether numba's on-disk cache (``cache=True``) already holds this module's kernels,
    newer than the source: if not, the first call compiles them (20-40 s)."""
    src = Path(__file__)
    folders = [src.parent / "__pycache__"]
    if os.environ.get("NUMBA_CACHE_DIR"):
        folders.append(Path(os.environ["NUMBA_CACHE_DIR"]))
    mtime = src.stat().st_mtime
    found = [f for d in folders for f in d.rglob(f"{src.stem}.*.nbi")
             if f.stat().st_mtime >= mtime] if any(d.is_dir() for d in folders) else []
    return len({f.name for f in found}) >= _N_KERNELS


def compile_kernels() -> None:
    """Compile (or load from numba's cache) every kernel by estimating a tiny random volume.

    Lets an installation pay the one-off compilation up front (``make`` does) instead of in
    the first real estimate.
    """
    from .core import NUMBA_MIN_PIXELS, estimate

    side = int(np.ceil(np.sqrt(NUMBA_MIN_PIXELS)))      # large enough for the numba path
    rng = np.random.default_rng(0)
    volume = rng.random((5, 3, 3, side, side))
    for dtype in (np.float64, np.float32):               # the input kernels per dtype
        estimate(volume.astype(dtype), 100.0, (0.05, 0.05), model="full", sigma=2.0,
                 window=9)


def announce_compilation() -> None:
    """Log (once per process, INFO on the ``gridflow`` logger) that the kernels are being
    compiled when numba's cache does not hold them yet, so a long first call is not silent."""
    global _announced
    if not _announced:
        _announced = True
        if not _kernels_cached():
            _log.info("compiling the estimator's numba kernels (once per installation, "
                      "20-40 s) ...")

MAX_ITER = 8
_SHIFT = 1e-13
_CONV = 1e-13
_CHUNKS = 256
_N_KERNELS = 13         # functions compiled with cache=True below


@njit(parallel=True, cache=True)
def _camera_sums_kernel(volume, needed, iy0, ix0, r0, r1, weights, out):
    C, ny, nx = weights.shape
    h = r1 - r0
    W = volume.shape[4]
    for job in prange(needed.size * h):
        j = job // h
        y = job - j * h
        k = needed[j]
        for c in range(C):
            for x in range(W):
                out[c, j, y, x] = 0.0
            for i in range(ny):
                for l in range(nx):
                    w = weights[c, i, l]
                    if w != 0.0:
                        src = volume[k, iy0 + i, ix0 + l, r0 + y]
                        for x in range(W):
                            out[c, j, y, x] += w * src[x]


def camera_sums(volume, needed, iy0, ix0, rows, weights):
    """Parallel drop-in for ``tensor._camera_sums_numpy`` (same arguments and result):
    each output row is one task, so the volume is read once, on all cores."""
    r0, r1, step = rows.indices(volume.shape[3])
    if step != 1:
        from .tensor import _camera_sums_numpy
        return _camera_sums_numpy(volume, needed, iy0, ix0, rows, weights)
    out = np.empty((weights.shape[0], needed.size, r1 - r0, volume.shape[4]))
    _camera_sums_kernel(volume, needed, iy0, ix0, r0, r1, weights, out)
    return out


@njit(parallel=True, cache=True)
def _scan_kernel(flat, bad, amax):
    """Per image (row of ``flat``): the count of non-finite values and max |V|."""
    for i in prange(flat.shape[0]):
        nb = 0
        m = 0.0
        for v in flat[i]:
            if np.isfinite(v):
                a = abs(v)
                if a > m:
                    m = a
            else:
                nb += 1
        bad[i] = nb
        amax[i] = m


def scan_volume(volume):
    """``(number of non-finite values, max |V| over the finite ones)`` of a C-contiguous
    volume, in one parallel pass; None when the array is not contiguous."""
    if not volume.flags.c_contiguous or volume.size == 0:
        return None
    flat = volume.reshape(-1, volume.shape[-1] * volume.shape[-2])
    bad = np.empty(flat.shape[0], dtype=np.int64)
    amax = np.empty(flat.shape[0])
    _scan_kernel(flat, bad, amax)
    return int(bad.sum()), float(amax.max())


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
    # sort ascending (insertion sort, m <= 4)
    for i in range(1, m):
        j = i
        while j > 0 and w[j - 1] > w[j]:
            w[j - 1], w[j] = w[j], w[j - 1]
            for k in range(m):
                V[k, j - 1], V[k, j] = V[k, j], V[k, j - 1]
            j -= 1


@njit(cache=True)
def _iterate(A, tr, X, L, Y, AY, H, Vh, th, y, b, k, max_iter):
    """Shifted inverse subspace iteration; X (n, m) start in, Ritz vectors out.

    On entry L must hold the Cholesky factor of ``A + δI``.  Convergence is judged on the
    k-th vector, the slowest of the null space (rate θ_k / θ_{k+2})."""
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
def _accept(X, th, k, nq, tr, rank_tol, m_tol, M, MtM, Vk, wk):
    """The validity checks of :func:`estimator.solve.null_space` on a found subspace: the
    (k+1)-th eigenvalue clear of zero (texture), and M, the fixed rows of the k null
    vectors, well conditioned (the ds, dt directions lie in the null space)."""
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
def _pixel(A, tr, X, have, L, B, Y, AY, H, Vh, th, y, b, M, MtM, Vk, wk, Minv,
           k, nq, perm, grows, rank_tol, m_tol, max_iter, i, P, g, err, valid):
    """One pixel, scalar: the fallback of the lane solver (and its definition).

    ``A`` holds J (rows in ``perm`` order), ``X`` a start (used if ``have``).  Writes
    P, g, err, valid of pixel ``i``; returns (solved, fell back to LAPACK)."""
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
    ok = _iterate(A, tr, X, L, Y, AY, H, Vh, th, y, b, k, max_iter)
    good = ok and _accept(X, th, k, nq, tr, rank_tol, m_tol, M, MtM, Vk, wk)
    fell = False
    if not good:
        # LAPACK after non-convergence, and also when the iteration's subspace
        # fails the checks (it could miss a direction its start lacked)
        fell = True
        w, V = np.linalg.eigh(A)
        for r in range(n):
            for j in range(m):
                X[r, j] = V[r, j]
        for j in range(m):
            th[j] = w[j]
        good = _accept(X, th, k, nq, tr, rank_tol, m_tol, M, MtM, Vk, wk)
    err[i] = th[k - 1]
    if not good:
        return False, fell
    _finish(X, M, MtM, Minv, L, y, k, nq, perm, grows, i, P, g)
    valid[i] = True
    return True, fell


@njit(cache=True)
def _finish(X, M, MtM, Minv, L, y, k, nq, perm, grows, i, P, g):
    """P = X_k M^-1 and the weights g of an accepted pixel (M as left by _accept)."""
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
            P[i, perm[r], cc] = s
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
        g[i, perm[r0]] = s2


# Pixels per lane block: the lane kernels loop over the block innermost, so that the
# compiler can use SIMD across pixels (measured on this machine: 8 lanes run the solver
# in half the time of the per-pixel code; numba/LLVM vectorises only part of it).
_LANES = 8
# Fixed subspace iterations of the lane solver; pixels whose k-th Ritz residual is then
# above _CONV * trace go on in the scalar path (up to MAX_ITER), then to LAPACK.
LANE_ITERS = 2
_FM = {"contract", "arcp"}


@njit(fastmath=_FM, error_model="numpy", cache=True)
def _lanes_jacobi(H, V, w, m, sweeps):
    """Eigen-decompositions of _LANES small symmetric matrices at once (H: (m, m,
    lanes), destroyed): ascending w (m, lanes), eigenvectors in the columns of V.

    A fixed number of cyclic sweeps (quadratic convergence: 6 take 4x4 matrices to
    roundoff), written branch-free over the lanes."""
    nl = _LANES
    for i in range(m):
        for j in range(m):
            for p in range(nl):
                V[i, j, p] = 1.0 if i == j else 0.0
    c = np.empty(nl)
    s = np.empty(nl)
    for _ in range(sweeps):
        for pp in range(m):
            for qq in range(pp + 1, m):
                for p in range(nl):
                    hpq = H[pp, qq, p]
                    theta = (H[qq, qq, p] - H[pp, pp, p]) / (2.0 * hpq)
                    sg = 1.0 if theta >= 0 else -1.0
                    t = sg / (abs(theta) + np.sqrt(theta * theta + 1.0))
                    # hpq == 0 (or theta overflowing): no rotation
                    t = t if (hpq != 0.0 and np.isfinite(theta)) else 0.0
                    cc = 1.0 / np.sqrt(t * t + 1.0)
                    c[p] = cc
                    s[p] = t * cc
                for kk in range(m):
                    for p in range(nl):
                        hkp, hkq = H[kk, pp, p], H[kk, qq, p]
                        H[kk, pp, p] = c[p] * hkp - s[p] * hkq
                        H[kk, qq, p] = s[p] * hkp + c[p] * hkq
                for kk in range(m):
                    for p in range(nl):
                        hpk, hqk = H[pp, kk, p], H[qq, kk, p]
                        H[pp, kk, p] = c[p] * hpk - s[p] * hqk
                        H[qq, kk, p] = s[p] * hpk + c[p] * hqk
                for kk in range(m):
                    for p in range(nl):
                        vkp, vkq = V[kk, pp, p], V[kk, qq, p]
                        V[kk, pp, p] = c[p] * vkp - s[p] * vkq
                        V[kk, qq, p] = s[p] * vkp + c[p] * vkq
    for i in range(m):
        for p in range(nl):
            w[i, p] = H[i, i, p]
    # ascending order: bubble passes of compare-and-swap, branch-free per lane
    for _ in range(m - 1):
        for i in range(m - 1):
            for p in range(nl):
                sw = w[i, p] > w[i + 1, p]
                a, bq = w[i, p], w[i + 1, p]
                w[i, p] = bq if sw else a
                w[i + 1, p] = a if sw else bq
                for kk in range(m):
                    va, vb = V[kk, i, p], V[kk, i + 1, p]
                    V[kk, i, p] = vb if sw else va
                    V[kk, i + 1, p] = va if sw else vb


@njit(fastmath=_FM, error_model="numpy", cache=True)
def _lanes_block(Jp, idx, perm, i0, k, A, L, dinv, X, Y, AY, H, Vh, th, tr, ok, res):
    """Lane part of one block of pixels ``i0 .. i0 + lanes - 1``: gather J, Cholesky of
    J + δI, LANE_ITERS inverse subspace iterations from X, one Rayleigh-Ritz step.
    Leaves X = Ritz vectors, th = Ritz values, res = the k-th pair's squared residual,
    ok = factorisation succeeded.  Pixels past the end repeat the last one."""
    N = Jp.shape[1]
    n, m = X.shape[0], X.shape[1]
    nl = _LANES
    for a in range(n):
        for bb in range(a, n):
            e = idx[perm[a], perm[bb]]
            for p in range(nl):
                q = min(i0 + p, N - 1)
                A[a, bb, p] = Jp[e, q]
                A[bb, a, p] = Jp[e, q]
    for p in range(nl):
        t = 0.0
        for a in range(n):
            t += A[a, a, p]
        tr[p] = t
        ok[p] = t > 0.0 and np.isfinite(t)
    # Cholesky of A + δI; a non-positive pivot marks the lane and is replaced by 1 so the
    # other lanes go on
    for j in range(n):
        for p in range(nl):
            dinv[j, p] = A[j, j, p] + _SHIFT * tr[p]
        for kk in range(j):
            for p in range(nl):
                dinv[j, p] -= L[j, kk, p] * L[j, kk, p]
        for p in range(nl):
            sp = dinv[j, p]
            good = sp > 0.0
            ok[p] = ok[p] and good
            d = np.sqrt(sp) if good else 1.0
            L[j, j, p] = d
            dinv[j, p] = 1.0 / d
        for i in range(j + 1, n):
            for p in range(nl):
                AY[i, 0, p] = A[i, j, p]
            for kk in range(j):
                for p in range(nl):
                    AY[i, 0, p] -= L[i, kk, p] * L[j, kk, p]
            for p in range(nl):
                L[i, j, p] = AY[i, 0, p] * dinv[j, p]
    for _ in range(LANE_ITERS):
        # Y = (L L^T)^-1 X: forward then back substitution, all columns and lanes
        for c in range(m):
            for r in range(n):
                for p in range(nl):
                    Y[r, c, p] = X[r, c, p]
                for kk in range(r):
                    for p in range(nl):
                        Y[r, c, p] -= L[r, kk, p] * Y[kk, c, p]
                for p in range(nl):
                    Y[r, c, p] *= dinv[r, p]
            for r in range(n - 1, -1, -1):
                for kk in range(r + 1, n):
                    for p in range(nl):
                        Y[r, c, p] -= L[kk, r, p] * Y[kk, c, p]
                for p in range(nl):
                    Y[r, c, p] *= dinv[r, p]
        # orthonormalise (modified Gram-Schmidt, twice)
        for c in range(m):
            for _ in range(2):
                for i in range(c):
                    for p in range(nl):
                        th[0, p] = 0.0
                    for r in range(n):
                        for p in range(nl):
                            th[0, p] += Y[r, i, p] * Y[r, c, p]
                    for r in range(n):
                        for p in range(nl):
                            Y[r, c, p] -= th[0, p] * Y[r, i, p]
            for p in range(nl):
                th[0, p] = 0.0
            for r in range(n):
                for p in range(nl):
                    th[0, p] += Y[r, c, p] * Y[r, c, p]
            for p in range(nl):
                th[0, p] = 1.0 / np.sqrt(th[0, p])
            for r in range(n):
                for p in range(nl):
                    Y[r, c, p] *= th[0, p]
        for r in range(n):
            for c in range(m):
                for p in range(nl):
                    X[r, c, p] = Y[r, c, p]
    # Rayleigh-Ritz: AY = A Y, H = Y^T A Y, its eigenpairs, X = Y V
    for r in range(n):
        for c in range(m):
            for p in range(nl):
                AY[r, c, p] = 0.0
            for cc in range(n):
                for p in range(nl):
                    AY[r, c, p] += A[r, cc, p] * Y[cc, c, p]
    for a in range(m):
        for bb in range(a, m):
            for p in range(nl):
                H[a, bb, p] = 0.0
            for r in range(n):
                for p in range(nl):
                    H[a, bb, p] += Y[r, a, p] * AY[r, bb, p]
            for p in range(nl):
                H[bb, a, p] = H[a, bb, p]
    _lanes_jacobi(H, Vh, th, m, 6)
    for r in range(n):
        for c in range(m):
            for p in range(nl):
                X[r, c, p] = 0.0
            for q in range(m):
                for p in range(nl):
                    X[r, c, p] += Y[r, q, p] * Vh[q, c, p]
    # residual |A x - θ x|^2 of the k-th Ritz pair
    for p in range(nl):
        res[p] = 0.0
    for r in range(n):
        for p in range(nl):
            dinv[0, p] = -th[k - 1, p] * X[r, k - 1, p]
        for q in range(m):
            for p in range(nl):
                dinv[0, p] += AY[r, q, p] * Vh[q, k - 1, p]
        for p in range(nl):
            res[p] += dinv[0, p] * dinv[0, p]


@njit(fastmath=_FM, error_model="numpy", cache=True)
def _lanes_finish(X, th, tr, ok, res, L, dinv, k, nq, rank_tol, m_tol, MM, MV, mw,
                  Minv, Pl, gl, grows, settled):
    """Checks and results of a lane block: the tests of :func:`_accept` (texture:
    θ_{k+1} > rank_tol trace; M well conditioned) and the convergence test,
    ``P = X_k M^-1`` into ``Pl`` (n, k, lanes; rows in perm order) and the weights into
    ``gl`` (grows, lanes).  ``settled[p]``: the lane's pixel is done."""
    n, m = X.shape[0], X.shape[1]
    nl = _LANES
    for a in range(k):
        for bb in range(k):
            for p in range(nl):
                MM[a, bb, p] = 0.0
            for r in range(k):
                for p in range(nl):
                    MM[a, bb, p] += X[nq + r, a, p] * X[nq + r, bb, p]
    _lanes_jacobi(MM, MV, mw, k, 6)
    for p in range(nl):
        settled[p] = (ok[p] and np.sqrt(res[p]) <= _CONV * tr[p]
                      and th[k, p] > rank_tol * tr[p]
                      and np.sqrt(max(mw[0, p], 0.0)) > m_tol)
    # M^-1 = adj(M) / det(M), M = X[nq:, :k] (k = 2 or 3; well conditioned when settled)
    if k == 3:
        for p in range(nl):
            a00, a01, a02 = X[nq, 0, p], X[nq, 1, p], X[nq, 2, p]
            a10, a11, a12 = X[nq + 1, 0, p], X[nq + 1, 1, p], X[nq + 1, 2, p]
            a20, a21, a22 = X[nq + 2, 0, p], X[nq + 2, 1, p], X[nq + 2, 2, p]
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
    else:
        for p in range(nl):
            a00, a01 = X[nq, 0, p], X[nq, 1, p]
            a10, a11 = X[nq + 1, 0, p], X[nq + 1, 1, p]
            inv = 1.0 / (a00 * a11 - a01 * a10)
            Minv[0, 0, p] = a11 * inv
            Minv[0, 1, p] = -a01 * inv
            Minv[1, 0, p] = -a10 * inv
            Minv[1, 1, p] = a00 * inv
    for r in range(n):
        for cc in range(k):
            for p in range(nl):
                Pl[r, cc, p] = 0.0
            for bb in range(k):
                for p in range(nl):
                    Pl[r, cc, p] += X[r, bb, p] * Minv[bb, cc, p]
    # g_r = (J_qq + δI)^-1_rr = |L_qq^-1 e_r|^2 (forward substitution from row r)
    for t in range(grows.size):
        r0 = grows[t]
        for p in range(nl):
            gl[t, p] = 0.0
        for a in range(r0, nq):
            for p in range(nl):
                dinv[a, p] = 1.0 if a == r0 else 0.0
            for kk in range(r0, a):
                for p in range(nl):
                    dinv[a, p] -= L[a, kk, p] * dinv[kk, p]
            for p in range(nl):
                dinv[a, p] /= L[a, a, p]
                gl[t, p] += dinv[a, p] * dinv[a, p]


@njit(parallel=True, cache=True)
def _solve_all(Jp, idx, perm, k, grows, rank_tol, m_tol, max_iter, P, g, err, valid, nfall):
    """Rows are taken in the order ``perm`` (non-fixed rows first, the k fixed rows
    last), so that the leading block of the Cholesky factor of J + δI is that of
    J_qq + δI, which gives the weights g.

    Pixels go through in blocks of _LANES (the lane kernels, each lane warm-started
    from the subspace of the pixel _LANES to its left); a pixel the lanes do not settle
    goes through the scalar path :func:`_pixel`, from the subspace the lanes reached."""
    N = Jp.shape[1]
    n = idx.shape[0]
    nq = n - k
    m = k + 1
    nl = _LANES
    nblocks = (N + nl - 1) // nl
    per = (nblocks + _CHUNKS - 1) // _CHUNKS
    for c in prange(_CHUNKS):
        A = np.empty((n, n, nl))
        L = np.zeros((n, n, nl))
        dinv = np.empty((n, nl))
        XL = np.empty((n, m, nl))
        YL = np.empty((n, m, nl))
        AYL = np.empty((n, m, nl))
        HL = np.empty((m, m, nl))
        VL = np.empty((m, m, nl))
        thL = np.empty((m, nl))
        trL = np.empty(nl)
        okL = np.zeros(nl, dtype=np.bool_)
        resL = np.empty(nl)
        MM = np.empty((k, k, nl))
        MV = np.empty((k, k, nl))
        mw = np.empty((k, nl))
        MinvL = np.empty((k, k, nl))
        Pl = np.empty((n, k, nl))
        gl = np.empty((grows.size, nl))
        settledL = np.zeros(nl, dtype=np.bool_)
        for r in range(n):
            for j in range(m):
                for p in range(nl):
                    XL[r, j, p] = np.cos(1.0 + 0.618 * (r + 1) * (j + 1))
        # scalar work space
        As = np.empty((n, n))
        Bs = np.empty((n, n))
        Ls = np.zeros((n, n))
        Xs = np.empty((n, m))
        Ys = np.empty((n, m))
        AYs = np.empty((n, m))
        Hs = np.empty((m, m))
        Vs = np.empty((m, m))
        ths = np.empty(m)
        ys = np.empty(n)
        bs = np.empty(n)
        M = np.empty((k, k))
        MtM = np.empty((k, k))
        Vk = np.empty((k, k))
        wk = np.empty(k)
        Minv = np.empty((k, k))
        for blk in range(c * per, min(nblocks, (c + 1) * per)):
            i0 = blk * nl
            _lanes_block(Jp, idx, perm, i0, k, A, L, dinv, XL, YL, AYL, HL, VL, thL,
                         trL, okL, resL)
            _lanes_finish(XL, thL, trL, okL, resL, L, dinv, k, nq, rank_tol, m_tol, MM, MV,
                          mw, MinvL, Pl, gl, grows, settledL)
            for p in range(min(nl, N - i0)):
                i = i0 + p
                if settledL[p]:
                    for r in range(n):
                        for cc in range(k):
                            P[i, perm[r], cc] = Pl[r, cc, p]
                    for t in range(grows.size):
                        g[i, perm[grows[t]]] = gl[t, p]
                    err[i] = thL[k - 1, p]
                    valid[i] = True
                else:
                    tr = trL[p]
                    for a in range(n):
                        for bb in range(n):
                            As[a, bb] = A[a, bb, p]
                    for r in range(n):
                        for j in range(m):
                            Xs[r, j] = XL[r, j, p]
                    solved, fell = _pixel(As, tr, Xs, okL[p], Ls, Bs, Ys, AYs, Hs, Vs, ths,
                                          ys, bs, M, MtM, Vk, wk, Minv, k, nq, perm, grows,
                                          rank_tol, m_tol, max_iter, i, P, g, err, valid)
                    nfall[c, 0] += 1
                    if fell:
                        nfall[c, 1] += 1
                    # warm start of this lane: the subspace found, or the dense start
                    # again after a pixel without one
                    for r in range(n):
                        for j in range(m):
                            XL[r, j, p] = (Xs[r, j] if solved
                                           else np.cos(1.0 + 0.618 * (r + 1) * (j + 1)))


def null_space_fast(Jp: np.ndarray, model: Model, idx: np.ndarray):
    """Parameter vectors of the solution space from a packed tensor.

    Parameters
    ----------
    Jp : ndarray, shape (E, N)
        Packed tensor planes (flattened pixels), as from :func:`structure_tensor_fft`.
    model : Model
    idx : ndarray of int, shape (n, n)
        Plane of entry (a, b) of this model's J (a sub-block of the packed tensor).

    Returns
    -------
    P, g, model_error, valid, (n_scalar, n_lapack)
        As :func:`estimator.solve.null_space` (``g`` is filled for the combined rows
        only), plus the number of pixels the lane solver handed to the scalar path and,
        of those, how many fell back to LAPACK ``eigh``.
    """
    from .solve import COMBINED_ROWS, M_TOL, RANK_TOL

    N = Jp.shape[1]
    n = model.n
    k = model.null_dim
    fixed = [model.index(r) for r in model.fixed_rows]
    perm = np.array([i for i in range(n) if i not in fixed] + fixed, dtype=np.int64)
    wanted = [model.index(r) for r in COMBINED_ROWS if r in model.rows]
    grows = np.array([int(np.flatnonzero(perm == r)[0]) for r in wanted], dtype=np.int64)
    P = np.full((N, n, k), np.nan)
    g = np.full((N, n), np.nan)
    err = np.full(N, np.nan)
    valid = np.zeros(N, dtype=bool)
    nfall = np.zeros((_CHUNKS, 2), dtype=np.int64)
    _solve_all(Jp, np.ascontiguousarray(idx, dtype=np.int64), perm, k, grows,
               RANK_TOL, M_TOL, MAX_ITER, P, g, err, valid, nfall)
    P[~valid] = np.nan
    g[~valid] = np.nan
    return P, g, err, valid, (int(nfall[:, 0].sum()), int(nfall[:, 1].sum()))
