"""Compile (or load from numba's cache) the fast path's kernels up front.

``make`` runs :func:`compile_kernels` once per installation, with a message, so that the
first real estimate is not a long silence (20-40 s of compilation)::

    python -m gridflow.estimator.warmup
"""

from __future__ import annotations

import logging

import numpy as np

from .backends import NUMBA_MIN_PIXELS
from .driver import estimate

__all__ = ["compile_kernels"]


def compile_kernels() -> None:
    """Estimate a tiny random volume, just large enough for the numba backend, in float64
    and float32 (the input kernels are compiled per dtype), and once with the affine
    motion model (its solve's kernel)."""
    side = int(np.ceil(np.sqrt(NUMBA_MIN_PIXELS)))
    rng = np.random.default_rng(0)
    volume = rng.random((5, 3, 3, side, side))
    for dtype in (np.float64, np.float32):
        estimate(volume.astype(dtype), 100.0, (0.05, 0.05), model="full", sigma=2.0,
                 window=9)
    estimate(volume, 100.0, (0.05, 0.05), model="full", motion="affine", sigma=2.0, window=9)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="gridflow: %(message)s")
    compile_kernels()
