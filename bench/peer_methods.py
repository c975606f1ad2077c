"""The peers as methods of the benchmark's interface (:mod:`gridflow.bench.methods`), so that
they run through the sweeps, ``gridflow estimate --method`` and the leaderboard as any
user's method does::

    gridflow sweep growth -o g.csv --method gridflow \\
        --method gridflow.bench.peer_methods:farneback_divergence

* :func:`epi_structure_tensor`: depth from the EPI structure tensor (Wanner and
  Goldluecke; :func:`gridflow.bench.peers.epi_structure_tensor`) of the reference frame's
  views: ``disparity`` and ``Z``.
* :func:`farneback_divergence`, :func:`ilk_divergence`: what plant labs report as growth,
  the divergence of a 2-D optical flow of the centre camera (OpenCV Farnebäck, scikit-image
  iterative Lucas-Kanade) between the frames ``k -+ r`` around the reference frame ``k``
  (``r`` as far as the volume reaches, at most 6), averaged over gridflow's window
  (:func:`gridflow.bench.growth_maps.divergence_2d`): ``growth``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["epi_structure_tensor", "farneback_divergence", "ilk_divergence"]

# frames either side of the reference that the 2-D flows span at most (growth_maps' choice:
# the frames gridflow's default temporal window spans)
_MAX_REACH = 6


def epi_structure_tensor(volume, focal_length, camera_spacing, *, principal_point=None):
    """Depth of the reference frame's centre view from its epipolar-plane images.

    Parameters
    ----------
    volume : ndarray, shape (T, Sy, Sx, H, W)
        A square camera grid (Sy == Sx) with equal spacing in x and y.

    Returns
    -------
    dict
        ``disparity`` (px per camera step, the HCI sign) and ``Z = f ds_x / disparity``
        (world units), each shape (H, W).
    """
    from .peers import epi_structure_tensor as epi

    T, Sy, Sx = volume.shape[:3]
    if Sy != Sx or Sx < 3:
        raise ValueError(f"the EPI structure tensor needs a square grid of at least 3 x 3 "
                         f"views, got {Sy} x {Sx}")
    bx, by = (float(b) for b in camera_spacing)
    if not np.isclose(bx, by, rtol=1e-9, atol=0.0):
        # its horizontal and vertical EPIs both read a disparity per camera step, which are
        # one disparity only where the steps are equal
        raise ValueError(f"the EPI structure tensor needs equal camera spacing in x and y, "
                         f"got {bx:g} and {by:g}")
    d = np.asarray(epi(np.asarray(volume[(T - 1) // 2], float))[0], float)
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = focal_length * camera_spacing[0] / d
    return {"disparity": d, "Z": np.where(np.isfinite(Z) & (Z > 0), Z, np.nan)}


def _divergence(volume, flow):
    from .growth_maps import divergence_2d

    T = volume.shape[0]
    k = (T - 1) // 2
    r = min(_MAX_REACH, k, T - 1 - k)
    if r < 1:
        raise ValueError(f"a 2-D flow needs frames either side of the reference, got {T}")
    return {"growth": divergence_2d(flow(np.asarray(volume), k, r=r))}


def farneback_divergence(volume, focal_length, camera_spacing, *, principal_point=None):
    """Growth per frame as a 2-D tool reports it: the divergence of OpenCV's Farnebäck flow
    of the centre camera (``growth``, shape (H, W))."""
    from .peers import flow_farneback

    return _divergence(volume, flow_farneback)


def ilk_divergence(volume, focal_length, camera_spacing, *, principal_point=None):
    """As :func:`farneback_divergence` with scikit-image's iterative Lucas-Kanade flow."""
    from .peers import flow_ilk

    return _divergence(volume, flow_ilk)
