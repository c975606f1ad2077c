"""Fast kernels behind the same API: FFT moment smoothing and a numba null-space solver.

Structure tensor (:func:`structure_tensor_fft`)
    The entries are grouped by the product of base signals they share (as in
    :func:`estimator.tensor.structure_tensor`); each product is transformed once
    (``scipy.fft.rfft2``, multithreaded) and every Gaussian-moment kernel it needs (at most
    the 3x3 pairs of ``w Δ^0..2`` in x and y) is applied in the frequency domain.  With zero
    padding of the window's reach this is the same linear correlation as the 65-tap FIR,
    up to floating-point roundoff (tests: agreement with the entry-by-entry reference to
    1e-8 of each quantity's scale).  The result is *packed*: one contiguous (rows, W) plane
    per upper-triangle entry, so writing it is not strided.

Null space (:func:`null_space_fast`)
    Per pixel (numba, parallel over pixel chunks): shifted inverse subspace iteration on
    ``J + δI`` (``δ = 1e-13 trace J``) with k+1 vectors, warm-started from the previous
    pixel, with a Rayleigh-Ritz step (Jacobi) after each iteration.  For a valid pixel the
    k null eigenvalues are ~1e-7 of the next one, so 2-3 iterations reach the residual
    ``|J e - θ e| <= 1e-13 trace J`` (measured: no pixel of a 512x512 sinusoid needs more
    than 3).  A pixel that has not converged after ``MAX_ITER`` falls back to LAPACK's
    full ``eigh``.  Only k+1 eigenpairs are computed instead of n.  The weights
    ``(J_qq + δI)^-1_rr`` come from the same Cholesky factor (rows ordered so that the
    fixed rows are last), with the reference path's ridge equal to this shift.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import scipy.fft as sfft
from numba import njit, prange

from .models import Model

__all__ = ["structure_tensor_fft", "null_space_fast", "packed_index", "MAX_ITER",
           "announce_compilation", "compile_kernels"]

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
    from .core import estimate

    rng = np.random.default_rng(0)
    volume = rng.random((5, 3, 3, 24, 24))
    estimate(volume, 100.0, (0.05, 0.05), model="full", sigma=2.0, window=9)


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
_N_KERNELS = 6          # functions compiled with cache=True below


def packed_index(n: int) -> np.ndarray:
    """``idx[a, b]``: plane of entry (a, b) in a packed upper-triangle tensor."""
    idx = np.empty((n, n), dtype=np.int64)
    e = 0
    for a in range(n):
        for b in range(a, n):
            idx[a, b] = idx[b, a] = e
            e += 1
    return idx


def structure_tensor_fft(signals, tvals, rows, kernels, halo, cols=slice(None), workers=None):
    """Packed structure tensor of a band via FFT.

    Parameters and meaning as :func:`estimator.tensor.structure_tensor`, plus ``cols``:
    the columns to keep (the interior), so that no copy is needed afterwards.

    Returns
    -------
    ndarray, shape (n (n + 1) / 2, h - 2 halo, ncols), float64
        Entry (a, b) is plane ``packed_index(n)[a, b]``.
    """
    from .tensor import _entry_groups

    n = len(rows)
    F, h, W = next(iter(signals.values())).shape
    R = kernels.shape[1] // 2
    wt = np.full(F, 1.0 / F)
    shape = (sfft.next_fast_len(h + 2 * R, real=True), sfft.next_fast_len(W + 2 * R, real=True))
    # convolution kernels = flipped correlation kernels, zero-padded to the FFT size
    kx = np.zeros((3, shape[1]))
    ky = np.zeros((3, shape[0]))
    kx[:, :2 * R + 1] = kernels[:, ::-1]
    ky[:, :2 * R + 1] = kernels[:, ::-1]
    KX = sfft.rfft(kx, axis=1)
    KY = sfft.fft(ky, axis=1)
    K2 = {}
    idx = packed_index(n)
    out_rows = h - 2 * halo
    c0, c1, _ = cols.indices(W)
    Jp = np.empty((n * (n + 1) // 2, out_rows, c1 - c0))
    workers = workers or -1
    for (pair, tpow), entries in _entry_groups(rows).items():
        coef = wt * tvals.astype(float) ** tpow
        prod = np.einsum("f,fhw,fhw->hw", coef, signals[pair[0]], signals[pair[1]])
        FP = sfft.rfft2(prod, s=shape, workers=workers)
        done = {}
        for a, b, _, _, px, py in entries:
            if (px, py) not in done:
                if (px, py) not in K2:
                    K2[(px, py)] = KY[py][:, None] * KX[px][None, :]
                full = sfft.irfft2(FP * K2[(px, py)], s=shape, workers=workers)
                # output index i + R holds the correlation centred on input index i
                done[(px, py)] = full[R + halo:R + h - halo, R + c0:R + c1]
                Jp[idx[a, b]] = done[(px, py)]
            else:
                Jp[idx[a, b]] = done[(px, py)]
    return Jp


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


@njit(parallel=True, cache=True)
def _solve_all(Jp, idx, perm, k, grows, rank_tol, m_tol, max_iter, P, g, err, valid, nfall):
    """Rows are taken in the order ``perm`` (non-fixed rows first, the k fixed rows
    last), so that the leading block of the Cholesky factor of J + δI is that of
    J_qq + δI, which gives the weights g."""
    N = Jp.shape[1]
    n = idx.shape[0]
    nq = n - k
    m = k + 1
    chunk = (N + _CHUNKS - 1) // _CHUNKS
    for c in prange(_CHUNKS):
        A = np.empty((n, n))
        B = np.empty((n, n))
        X = np.zeros((n, m))
        L = np.zeros((n, n))
        Y = np.empty((n, m))
        AY = np.empty((n, m))
        H = np.empty((m, m))
        Vh = np.empty((m, m))
        th = np.empty(m)
        y = np.empty(n)
        b = np.empty(n)
        MtM = np.empty((k, k))
        Vk = np.empty((k, k))
        wk = np.empty(k)
        M = np.empty((k, k))
        Minv = np.empty((k, k))
        have = False
        for i in range(c * chunk, min(N, (c + 1) * chunk)):
            tr = 0.0
            for a in range(n):
                for bb in range(n):
                    A[a, bb] = Jp[idx[perm[a], perm[bb]], i]
                tr += A[a, a]
            valid[i] = False
            if not (tr > 0.0 and np.isfinite(tr)):
                have = False
                continue
            for a in range(n):
                for bb in range(n):
                    B[a, bb] = A[a, bb]
                B[a, a] += _SHIFT * tr
            if not _cholesky(B, L):
                have = False
                continue
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
            if not good:
                # LAPACK after non-convergence, and also when the iteration's subspace
                # fails the checks (it could miss a direction its start lacked)
                nfall[c] += 1
                w, V = np.linalg.eigh(A)
                for r in range(n):
                    for j in range(m):
                        X[r, j] = V[r, j]
                for j in range(m):
                    th[j] = w[j]
                good = _accept(X, th, k, nq, tr, rank_tol, m_tol, M, MtM, Vk, wk)
            err[i] = th[k - 1]
            have = good
            if not good:
                continue
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
            valid[i] = True


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
    P, g, model_error, valid, n_fallback
        As :func:`estimator.solve.null_space` (``g`` is filled for the combined rows
        only), plus the number of pixels that fell back to LAPACK ``eigh``.
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
    nfall = np.zeros(_CHUNKS, dtype=np.int64)
    _solve_all(Jp, np.ascontiguousarray(idx, dtype=np.int64), perm, k, grows,
               RANK_TOL, M_TOL, MAX_ITER, P, g, err, valid, nfall)
    P[~valid] = np.nan
    g[~valid] = np.nan
    return P, g, err, valid, int(nfall.sum())
