"""The in-memory form of a camera-grid sequence, shared by generators, loaders and CLI."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["GridVolume", "physical_memory"]


def physical_memory() -> int | None:
    """Bytes of physical memory of this machine, or None where the system does not say
    (checks that refuse volumes larger than the machine then pass)."""
    import os

    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


@dataclass
class GridVolume:
    """A camera-grid image sequence with its geometry and optional ground truth.

    Attributes
    ----------
    volume : ndarray, shape (T, Sy, Sx, H, W)
        ``V[t, sy, sx, y, x]``, linear intensities.
    focal_length : float
        Pixels.
    camera_spacing : tuple of float
        ``(ds_x, ds_y)``, world units.
    principal_point : tuple of float
        ``(cx, cy)``, pixels (column, row).
    truth : dict of str to ndarray, each shape (H, W)
        Ground truth at the reference camera and frame (may be empty).
    meta : dict
        Free-form provenance (generator parameters, scene settings).
    """

    volume: np.ndarray
    focal_length: float
    camera_spacing: tuple[float, float]
    principal_point: tuple[float, float]
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
