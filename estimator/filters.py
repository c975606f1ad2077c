"""Derivative / prefilter pairs for the 5-D structure tensor (Sec. 3, step 1).

Every axis of the volume is filtered with a separable pair: a symmetric prefilter
``p`` (smoothing) and an antisymmetric derivative ``d``.  The estimator needs two things
from the pair:

* **Consistent derivatives.**  The flow-like rows compare derivatives along different
  axes, so ``d`` must be the derivative *of the prefiltered signal*: ``d(w) = i w p(w)``
  over the band the data occupies (the sinusoid's 8-pixel wavelength is ``w = 0.785``).
* **The right response to exponentials.**  The brightness rows compare ``I_t`` with the
  prefiltered ``I``.  For ``I = exp(a t)`` the filtered ratio is
  ``D(a) / P(a)`` with ``D(a) = sum_k d_k e^{a k}`` and ``P(a) = sum_k p_k e^{a k}``; the
  estimator returns ``a`` exactly only if ``D(a)/P(a) = a``.  This is the analytic
  continuation of ``d(w) = i w p(w)`` to imaginary frequency, so a pair that matches
  the Taylor series of ``i w p(w)`` to high order is accurate for both.

``matched5`` (the default) solves that design problem in closed form: minimise
``int_0^pi (w p(w) - d(w))^2 dw`` (linear in the taps) subject to ``sum p = 1``,
unit first moment of ``d`` and equality of the ``w^3`` and ``w^5`` Taylor
coefficients.  Its relative error of ``D(a)/P(a)`` is 4e-6 at ``a = 0.5`` and 2.5e-4 at
``a = 1``, against 3.2e-3 and 1.4e-2 for Farid & Simoncelli's 5-tap pair (``fs5``,
renormalised to unit first moment), which is why it is the default: the paper's
observation 1 ("well below 0.5 % for a1 < 1") is limited by exactly this ratio.
``matched3`` is the 3-tap pair ``p = [1, 4, 1]/6``, ``d = [1, 0, -1]/2`` obeying the
same ``w^3`` condition; it serves axes with only 3 samples (3 cameras, short sequences).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = ["FilterPair", "get_filter_pair", "FILTER_NAMES"]


@dataclass(frozen=True)
class FilterPair:
    """A prefilter / derivative pair, as correlation kernels.

    Attributes
    ----------
    name : str
        Identifier (``"matched5"``, ``"fs5"``, ``"matched3"``).
    prefilter : ndarray, shape (n,)
        Symmetric smoothing kernel, sums to 1.
    derivative : ndarray, shape (n,)
        Antisymmetric kernel ordered for :func:`scipy.ndimage.correlate1d`: correlating
        the ramp ``f(k) = k`` gives exactly 1, i.e. a derivative per sample towards
        increasing index.
    """

    name: str
    prefilter: np.ndarray
    derivative: np.ndarray

    @property
    def taps(self) -> int:
        return self.prefilter.size

    @property
    def radius(self) -> int:
        return self.prefilter.size // 2

    @property
    def moment(self) -> np.ndarray:
        """The prefilter's first-moment kernel ``o p_o`` (offsets ``o = -r..r``), shape (n,).

        Correlating ``x g(x)`` with ``p`` gives ``x (p * g) + (o p) * g``: what a
        coefficient varying across the image adds to a prefiltered signal (the zoom blur,
        ``docs/model.md``)."""
        return self._offsets * self.prefilter

    @property
    def moment_derivative(self) -> np.ndarray:
        """``-p_o + o d_o``, shape (n,): the kernel that gives ``(o p) * ∂I`` from ``I``.

        For a pair exact on exponentials (``D(w) = i w P(w)``) its response is
        ``w P'(w)``, which is that of ``o p`` applied to the derivative, just as ``d``
        gives ``p * ∂I``; it inherits the pair's consistency (``matched5``: within 1.1e-3
        at the 8-px wavelength, 7e-5 at 16 px)."""
        return -self.prefilter + self._offsets * self.derivative

    @property
    def _offsets(self) -> np.ndarray:
        return np.arange(-self.radius, self.radius + 1, dtype=float)


def _from_half(name: str, p0: float, p_side: list[float], d_side: list[float]) -> FilterPair:
    """Build symmetric ``p`` and antisymmetric ``d`` from their right halves."""
    p = np.array(list(reversed(p_side)) + [p0] + list(p_side), dtype=float)
    d = np.array([-v for v in reversed(d_side)] + [0.0] + list(d_side), dtype=float)
    return FilterPair(name, p, d)


def _design_matched5() -> FilterPair:
    # Unknowns x = (p0, p1, p2, d1, d2); the residual w p(w) - d(w) is linear in x.
    # Computed in Python floats, each sum exactly rounded (math.fsum) and the sines from
    # the C library, not with numpy's SIMD sines and BLAS/LAPACK: those round by the
    # machine's CPU, and a last-bit difference in the taps would change every estimate
    # on another machine (results that must be reproducible to the byte).
    n = 4001
    w = [math.pi * i / (n - 1) for i in range(n)]
    A = [(v, 2 * v * math.cos(v), 2 * v * math.cos(2 * v), -2 * math.sin(v),
          -2 * math.sin(2 * v)) for v in w]
    H = [[math.fsum(a[i] * a[j] for a in A) / n for j in range(5)] for i in range(5)]
    C = [
        [1, 2, 2, 0, 0],                      # sum p = 1
        [0, 0, 0, 2, 4],                      # first moment of d = 1
        [0, 1, 4, -2 / 6, -16 / 6],           # w^3 coefficients of w p(w) and d(w) agree
        [0, 1 / 12, 16 / 12, -2 / 120, -64 / 120],  # w^5 coefficients agree
    ]
    b = [1.0, 1.0, 0.0, 0.0]
    kkt = [[2 * H[i][j] for j in range(5)] + [C[k][i] for k in range(4)] for i in range(5)]
    kkt += [list(map(float, C[k])) + [0.0] * 4 for k in range(4)]
    p0, p1, p2, d1, d2 = _solve(kkt, [0.0] * 5 + b)[:5]
    return _from_half("matched5", p0, [p1, p2], [d1, d2])


def _solve(M: list[list[float]], y: list[float]) -> list[float]:
    """``M x = y`` by Gaussian elimination with partial pivoting, in Python floats (a
    small system, the same to the last bit on every machine)."""
    n = len(y)
    a = [list(map(float, row)) + [float(v)] for row, v in zip(M, y)]
    for c in range(n):
        piv = max(range(c, n), key=lambda r: abs(a[r][c]))
        a[c], a[piv] = a[piv], a[c]
        for r in range(c + 1, n):
            f = a[r][c] / a[c][c]
            for k in range(c, n + 1):
                a[r][k] -= f * a[c][k]
    x = [0.0] * n
    for r in range(n - 1, -1, -1):
        x[r] = (a[r][n] - math.fsum(a[r][k] * x[k] for k in range(r + 1, n))) / a[r][r]
    return x


def _fs5() -> FilterPair:
    # Farid & Simoncelli (2004), 5-tap; derivative rescaled to unit first moment so that
    # brightness parameters (I_t against I) come out in the right units.
    # (The published prefilter sums to 0.999999; it is renormalised too.)
    p0, p1, p2, d1, d2 = 0.426375, 0.249153, 0.037659, 0.276691, 0.109604
    s, q = 2 * d1 + 4 * d2, p0 + 2 * p1 + 2 * p2
    return _from_half("fs5", p0 / q, [p1 / q, p2 / q], [d1 / s, d2 / s])


@lru_cache(maxsize=None)
def get_filter_pair(name: str) -> FilterPair:
    """Return the filter pair called ``name``.

    Parameters
    ----------
    name : {"matched5", "fs5", "matched3"}

    Returns
    -------
    FilterPair
    """
    if name == "matched5":
        return _design_matched5()
    if name == "fs5":
        return _fs5()
    if name == "matched3":
        return _from_half("matched3", 2 / 3, [1 / 6], [1 / 2])
    raise ValueError(f"unknown filter pair {name!r}; expected one of {FILTER_NAMES}")


FILTER_NAMES = ("matched5", "fs5", "matched3")
