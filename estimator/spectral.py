"""The structure tensor by FFT, packed (no numba: the small-volume path uses it too).

The entries are grouped by the product of base signals they share (as in
:func:`estimator.tensor.structure_tensor`); each product is transformed once
(``scipy.fft.rfft2``, multithreaded) and every Gaussian-moment kernel it needs (at most the
3x3 pairs of ``w Δ^0..2`` in x and y) is applied in the frequency domain.  At the kept
(interior) pixels the circular correlation is the same linear correlation as the 65-tap
FIR, up to floating-point roundoff (padding only where a kept pixel's window would wrap;
tests: agreement with the entry-by-entry reference to 1e-8 of each quantity's scale).
The result is *packed*: one contiguous (rows, W) plane per distinct entry of the upper
triangle, so writing it is not strided.
"""

from __future__ import annotations

import numpy as np

from .tensor import entry_groups

__all__ = ["structure_tensor_fft"]


def structure_tensor_fft(signals, tvals, rows, kernels, halo, cols=slice(None), *,
                         fft: str = "scipy", workers: int | None = None, product=None,
                         cmul=None, cmul2=None, combine=None):
    """Packed structure tensor of a band via FFT.

    Parameters and meaning as :func:`estimator.tensor.structure_tensor`, plus

    cols : slice
        The columns to keep (the interior), so that no copy is needed afterwards.
    fft : {"scipy", "numpy"}
        ``scipy.fft`` on ``workers`` threads (default all cores), or ``numpy.fft`` (for
        small images: it spares the ~0.1 s import of scipy.fft and gives the same result
        to roundoff).
    workers : int, optional
    product : callable, optional
        The frame-weighted products of base signals: ``product(coefs, a, b, shape,
        out)`` returns, for each row ``k`` of ``coefs`` (shape (K, F)), ``sum_f coefs[k,
        f] a[f] b[f]`` zero-padded to ``shape``, written into ``out[k]`` (``out`` of shape
        (K,) + ``shape``, reused for every pair), each summed over the frames in order as
        one product alone would be.  Default numpy's ``einsum``, one product at a time,
        unpadded, which ``rfft2`` pads; the numba backend passes its parallel kernel
        (:func:`estimator._kernels.weighted_product`).
    cmul : callable, optional
        ``cmul(a, k, out)``: the spectrum ``a`` times a kernel ``k`` broadcast along one
        axis, into ``out``, rounded as :func:`_cmul` (its default); the numba backend
        passes its parallel kernel (:func:`estimator._kernels.complex_multiply`).
    cmul2 : callable, optional
        ``cmul2(a, ky, kx, m, out)``: ``m ((a * ky) * kx)`` with ``ky`` along the rows
        and ``kx`` along the columns, into a new array (``out`` None) or added to
        ``out``, rounded as :func:`_cmul2` (its default); the numba backend passes
        :func:`estimator._kernels.complex_multiply_2d`.
    combine : tuple of (tuple of str, list of list of int), optional
        ``(out, terms)``: the tensor wanted is over the rows ``out``, row ``a`` of which
        is the sum of the rows ``terms[a]`` of ``rows`` (the zoom-blur correction:
        :func:`estimator.tensor.zoom_terms`).  Each wanted entry is then the sum of its
        terms' 2-D spectra (each times its y- and x-kernel), transformed back once in
        y and once in x, instead of every term transformed back and summed afterwards
        (:func:`estimator.tensor.zoom_corrected`): the same sums to roundoff, with
        fewer inverse transforms: with affine motion 195 x-inverses a band instead of
        429, and 195 y-inverses instead of 303 (one per term's product and y-moment);
        full model 117 x-inverses instead of 251, 117 y-inverses instead of 179.

    Returns
    -------
    Jp : ndarray, shape (E, h - 2 halo, ncols), float64
        One plane per distinct smoothed product: entries that are the same product
        smoothed with the same moment kernel (e.g. ``I_x Δx · I_y`` and ``I_x · I_y Δx``)
        share a plane, so ``E <= n (n + 1) / 2`` (102 of 120 for the full model); with
        ``combine``, one per distinct sum of them.
    idx : ndarray of int, shape (n, n)
        Entry (a, b) of J is plane ``idx[a, b]`` (n the rows of ``combine``'s ``out``
        where given).
    """
    cmul = cmul or _cmul
    cmul2 = cmul2 or _cmul2
    F, h, W = next(iter(signals.values())).shape
    R = kernels.shape[1] // 2
    wt = np.full(F, 1.0 / F)
    if fft == "scipy":
        import scipy.fft as sfft

        fast_len = sfft.next_fast_len
        kw = {"workers": workers or -1}
        over = {"overwrite_x": True}            # the inputs are temporaries
    else:
        sfft, fast_len, kw, over = np.fft, _next_smooth, {}, {}
    c0, c1, _ = cols.indices(W)
    # Circular correlation of length N equals the zero-padded linear one at the kept
    # outputs [a, b) of m samples when no tap of a kept output wraps onto data: taps
    # past the end must land in the padding (N >= b + R) and taps before the start must
    # wrap into it (N >= m + R - a).  With the estimator's halo (>= R) this is N = m: the
    # window of a kept pixel lies inside the band, so no padding is needed at all.
    shape = (fast_len(max(h, h - halo + R, h + R - halo), real=True),
             fast_len(max(W, c1 + R, W + R - c0), real=True))
    # convolution kernels = flipped correlation kernels, centred on index 0 (tap j at
    # index -j mod N), so that output index i holds the correlation centred on input i
    kx = np.zeros((3, shape[1]))
    ky = np.zeros((3, shape[0]))
    kx[:, :2 * R + 1] = kernels[:, ::-1]
    ky[:, :2 * R + 1] = kernels[:, ::-1]
    KX = sfft.rfft(np.roll(kx, -R, axis=1), axis=1)
    KY = sfft.fft(np.roll(ky, -R, axis=1), axis=1)
    groups = entry_groups(rows)
    # each smoothed product (key, px, py) of an entry of ``rows``
    term = {(a, b): (key, px, py) for key, entries in groups.items()
            for a, b, _, _, px, py in entries}
    term.update({(b, a): t for (a, b), t in list(term.items())})
    if combine is None:
        out_names, terms = rows, [[a] for a in range(len(rows))]
    else:
        out_names, terms = combine
    n = len(out_names)
    # each wanted entry as the sum of smoothed products (a multiset: a term can come
    # twice, e.g. J_ext[a, a'] + J_ext[a', a] on the diagonal); entries with the same sum
    # share a plane
    idx = np.empty((n, n), dtype=np.int64)
    sums = {}
    for a in range(n):
        for b in range(a, n):
            key = tuple(sorted(term[i, j] for i in terms[a] for j in terms[b]))
            idx[a, b] = idx[b, a] = sums.setdefault(key, len(sums))
    out_rows = h - 2 * halo
    Jp = np.empty((len(sums), out_rows, c1 - c0))
    # where each smoothed product goes: (plane, multiplicity); a plane of one term is
    # written directly, a plane of several is summed in the spectral domain (acc) and
    # transformed back once, after its last term
    goes = {}
    for key, e in sums.items():
        for t in set(key):
            goes.setdefault(t, []).append((e, key.count(t), len(key) > 1))
    acc = {e: None for key, e in sums.items() if len(key) > 1}
    # terms not yet added to each summed plane: a plane is transformed back, and its
    # spectrum let go, as soon as its last term is in (_batches orders the products so
    # that few are open at once: at most 24 of the affine model's 153 summed planes)
    left = {e: len(set(key)) for key, e in sums.items() if len(key) > 1}
    keep_rows = slice(halo, h - halo)
    keep_cols = slice(c0, c1)

    def to_plane(spectrum, e):
        # the x-inverse (complex to real) of a plane's kept rows, its kept columns into Jp
        Jp[e] = sfft.irfft(spectrum, n=shape[1], axis=1, **kw, **over)[:, keep_cols]
    # the products of one pair of signals under several powers of t in one pass over the
    # pair (``product``; with the zoom-blur correction 90 passes instead of 195 under
    # affine motion, 78 instead of 117 under translation), in an order that adds every
    # summed plane's terms as before and keeps few of them open; without ``product``,
    # one at a time in that order
    batches = _batches(list(groups), [key for key in sums if len(key) > 1])
    if product is None:
        batches = [[g] for batch in batches for g in batch]
    # work arrays reused for every product: fresh arrays of a few MB each cost their page
    # faults every time (this stage's best time at 512^2 went from 0.25-0.29 s to
    # 0.24-0.25 s, measured over runs of five calls)
    pbuf = (np.empty((max(map(len, batches)),) + shape) if product is not None else None)
    ybufs = {}
    xbuf = np.empty((out_rows, shape[1] // 2 + 1), dtype=complex)
    for batch in batches:
        pair = batch[0][0]
        coefs = np.stack([wt * tvals.astype(float) ** tpow for _, tpow in batch])
        if product is not None:
            prods = product(coefs, signals[pair[0]], signals[pair[1]], shape,
                            pbuf[:len(batch)])
        for j, (_, tpow) in enumerate(batch):
            entries = groups[(pair, tpow)]
            if product is None:
                prod = np.einsum("f,fhw,fhw->hw", coefs[j], signals[pair[0]],
                                 signals[pair[1]])
            else:
                prod = prods[j]
            if prod.shape == shape and over:
                # padded already (or needing no padding): the two passes of rfft2 one
                # after the other, so that both run on all workers (scipy.fft's rfft2
                # measured 1.2-2.2 ms at 512^2 against 1.0 ms, and 3x slower when it pads
                # an input)
                FP = sfft.fft(sfft.rfft(prod, axis=1, **kw), axis=0, **kw, **over)
            else:
                FP = sfft.rfft2(prod, s=shape, **kw)
            # The kernel is separable, so the inverse is too: for a plane of one term the
            # y-inverse once per y-moment (shared by the planes of this product), then the
            # x-inverse (complex to real) per (x, y) moment pair, on the kept rows only; a
            # summed plane adds its terms in the 2-D spectrum, each times both kernels, and
            # is transformed back once (fewer y-inverses than one per term's y-moment:
            # the 2-D products cost about as much as the 1-D ones after the y-inverse)
            ypass = {}
            for px, py in sorted({(px, py) for *_, px, py in entries}):
                for e, mult, summed in goes.get(((pair, tpow), px, py), ()):
                    if not summed:
                        if py not in ypass:
                            buf = ybufs.setdefault(py, np.empty_like(FP))
                            # scipy.fft transforms complex input in place with overwrite_x
                            ypass[py] = sfft.ifft(cmul(FP, KY[py][:, None], buf), axis=0,
                                                  **kw, **over)
                        to_plane(cmul(ypass[py][keep_rows], KX[px][None, :], xbuf), e)
                        continue
                    # the first term written, not added to zeros: allocating zeroed arrays
                    # cost 0.08 of 1.2 s at 512^2 (the same bits: 0 + x = x, up to the
                    # sign of an exact zero)
                    acc[e] = cmul2(FP, KY[py], KX[px], float(mult), acc[e])
                    left[e] -= 1
                    if not left[e]:
                        to_plane(sfft.ifft(acc[e], axis=0, **kw, **over)[keep_rows], e)
                        acc[e] = None
    if any(left.values()):
        raise AssertionError("a summed plane of the tensor missed terms")
    return Jp, idx


def _batches(order: list, summed: list) -> list[list]:
    """The groups ``order`` (``(pair, t-power)`` keys, in the order their products were
    transformed one by one) as batches of one pair's powers of t, each batch's products
    made in one pass, in an order that keeps few summed planes open.

    Every summed plane (``summed``: the planes' sorted terms, ``((pair, tpow), px, py)``)
    adds its terms in the order they have in ``order``, so that the sums are the same
    bits: a group comes after every group whose term comes before its own in one of its
    planes.  Within that, groups are taken greedily: next, the one that opens the fewest
    planes not yet open net of those it completes (ties by pair, then by ``order``), so
    that a plane's spectrum is let go soon after it is opened (under affine motion at
    most 24 of the 153 summed planes are open at once, each a 2-D half-spectrum of 2.1 MB
    at 512^2, against 110 in the batches before this order and 70 with ``order``'s
    products one at a time; 90 passes instead of 82).  A group then joins an earlier
    batch of its pair where every group that must come before it is done by then.
    """
    rank = {g: i for i, g in enumerate(order)}
    before = {g: set() for g in order}
    planes = {g: [] for g in order}             # the summed planes a group's terms go to
    left = []                                   # each summed plane's groups not yet taken
    for key in summed:
        chain = sorted({t[0] for t in key}, key=rank.__getitem__)
        for u, v in zip(chain, chain[1:]):
            before[v].add(u)
        for g in chain:
            planes[g].append(len(left))
        left.append(len(chain))
    done, opened, lean = set(), set(), []
    while len(lean) < len(order):
        def cost(g):
            opens = sum(e not in opened for e in planes[g])
            closes = sum(left[e] == 1 for e in planes[g])
            return opens - closes, g[0], rank[g]
        g = min((g for g in order if g not in done and before[g] <= done), key=cost)
        lean.append(g)
        done.add(g)
        for e in planes[g]:
            opened.add(e)
            left[e] -= 1
    done, batches = set(), []
    for i, g in enumerate(lean):
        if g in done:
            continue
        batch = [g]
        done.add(g)
        for h in lean[i + 1:]:
            if h[0] == g[0] and h not in done and before[h] <= done:
                batch.append(h)
                done.add(h)
        batches.append(batch)
    return batches


def _cmul(a: np.ndarray, k: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out = a * k`` for complex arrays (``k`` broadcast against ``a``), from real
    products and sums.

    numpy's complex multiply is SIMD code chosen by the machine's CPU, some of it with
    fused multiply-adds, so its last bits (and every estimate after it) would differ from
    one machine to another; four real products and two real sums round the same
    everywhere.
    """
    if np.shares_memory(a, out):
        raise ValueError("_cmul writes out while it reads a: they must not overlap")
    ar, ai = a.real, a.imag
    kr, ki = k.real, k.imag
    tmp = np.empty(a.shape)
    np.multiply(ar, kr, out=out.real)
    out.real -= np.multiply(ai, ki, out=tmp)
    np.multiply(ai, kr, out=out.imag)
    out.imag += np.multiply(ar, ki, out=tmp)
    return out


def _cmul2(a: np.ndarray, ky: np.ndarray, kx: np.ndarray, m: float,
           out: np.ndarray | None) -> np.ndarray:
    """``m ((a * ky) * kx)`` for a complex (rows, cols) ``a``, ``ky`` (rows,) along the
    rows and ``kx`` (cols,) along the columns, each product rounded as :func:`_cmul`'s,
    then times ``m`` (1 or 2 here: exact): a new array where ``out`` is None, else
    added to ``out``."""
    t = _cmul(a, ky[:, None], np.empty(a.shape, dtype=complex))
    prod = _cmul(t, kx[None, :], np.empty(a.shape, dtype=complex))
    if m != 1.0:
        prod.view(np.float64)[...] *= m
    if out is None:
        return prod
    out += prod
    return out


def _next_smooth(n: int, real: bool = True) -> int:
    """Smallest 5-smooth integer >= n (numpy.fft is fast on those)."""
    m = n
    while True:
        k = m
        for f in (2, 3, 5):
            while k % f == 0:
                k //= f
        if k == 1:
            return m
        m += 1
