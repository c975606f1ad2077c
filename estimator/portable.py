"""Small numerics that round the same on every machine.

numpy's transcendental functions (``exp``, ``log10``, ``sin``) and BLAS's sums are SIMD
code chosen by the CPU the process runs on, so their last bits differ from one machine
to another; a result that passes through them, and every choice made on it, cannot be
reproduced to the byte elsewhere.  These helpers take the C library's functions and
exactly rounded sums instead, where the cost is small (kernels of a few dozen taps, one
map of logarithms).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["gaussian_taps", "log10"]


def gaussian_taps(sigma: float, radius: int) -> np.ndarray:
    """The normalised Gaussian of ``sigma`` at the offsets ``-radius..radius``.

    Returns
    -------
    ndarray, shape (2 radius + 1,)
    """
    g = np.array([math.exp(-0.5 * (o / sigma) ** 2) for o in range(-radius, radius + 1)])
    return g / math.fsum(g.tolist())


def log10(a) -> np.ndarray:
    """``log10`` elementwise, of any shape, through long double (which numpy does not
    vectorise: the C library's ``log10l``), rounded back to float64."""
    return np.log10(np.asarray(a, dtype=np.longdouble)).astype(np.float64)
