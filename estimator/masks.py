"""The object's pixels: what a window may use near the edge of a leaf (``docs/model.md``,
*Masks*).

A window that reaches over a leaf's edge mixes the leaf's motion with the background's
(or with nothing): its estimate is wrong, and before masks the interior excluded every
pixel within the window's reach of the image border only.  With a mask, every window
sums the object's samples alone and divides by their weight (normalized convolution,
Knutsson & Westin 1993): a pixel near the edge is measured from the leaf pixels its
window holds.  :func:`segment_object` makes a mask from the image where the user has
none.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["object_window", "segment_object", "MIN_OBJECT_WEIGHT", "erosion_reach"]

# the least fraction of the window's weight on the object for a masked pixel to be
# estimated: a window that sees less of it has too few samples (a thin tip, a stalk)
MIN_OBJECT_WEIGHT = 0.25


def erosion_reach(filter_radius: int) -> int:
    """Pixels either side whose mask decides a pixel's eroded mask (:func:`object_window`):
    a row band cut from a mask needs this many more rows of it than its estimate's halo,
    so that the cut's edge does not erode its rows."""
    return filter_radius + 2


def object_window(mask: np.ndarray, kernel: np.ndarray, filter_radius: int):
    """What a mask of the object does to the window.

    Parameters
    ----------
    mask : ndarray of bool, shape (H, W)
        The object's pixels in the reference camera's image at the reference frame.
    kernel : ndarray, shape (window,)
        The window's weights along one axis (they sum to 1).
    filter_radius : int
        The spatial derivative filters' radius, px.

    Returns
    -------
    used : ndarray of float, shape (H, W)
        1 on the samples a window uses: the mask eroded by the filters' radius plus 2 px
        in every direction (a square: the filters' square footprint, diagonals
        included; the derivative filters read that far, the other cameras see the edge
        shifted by the disparity, the other frames by the motion, about a pixel each), 0
        elsewhere.
    weight : ndarray, shape (H, W)
        The fraction of each pixel's window weight on those samples.
    estimated : ndarray of bool, shape (H, W)
        The pixels estimated: on the used samples, with at least
        :data:`MIN_OBJECT_WEIGHT` of the window's weight on them.
    """
    used = ndimage.binary_erosion(mask, structure=np.ones((3, 3), bool),
                                  iterations=erosion_reach(filter_radius))
    u = used.astype(float)
    weight = ndimage.correlate1d(ndimage.correlate1d(u, kernel, axis=1, mode="constant"),
                                 kernel, axis=0, mode="constant")
    return u, weight, used & (weight >= MIN_OBJECT_WEIGHT)


def segment_object(image: np.ndarray, smooth: float = 2.0) -> np.ndarray:
    """The object in front of a plain background: Otsu's threshold of the image smoothed
    over ``smooth`` px (so that the texture's dark parts stay on the object), the side
    that covers less of the image's border taken as the object, its largest connected
    part with its holes filled.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        The reference camera's image.
    smooth : float
        Gaussian sigma, px.

    Returns
    -------
    ndarray of bool, shape (H, W)
        All False when the image is uniform (no object to find).
    """
    from skimage.filters import threshold_otsu

    img = ndimage.gaussian_filter(np.asarray(image, dtype=float), smooth, mode="nearest")
    if not np.ptp(img) > 0:
        return np.zeros(img.shape, dtype=bool)
    fg = img > threshold_otsu(img)
    border = np.concatenate([fg[0], fg[-1], fg[:, 0], fg[:, -1]])
    if border.mean() > 0.5:
        fg = ~fg
    labels, n = ndimage.label(fg)
    if n == 0:
        return fg
    largest = 1 + int(np.argmax(ndimage.sum_labels(fg, labels, range(1, n + 1))))
    return ndimage.binary_fill_holes(labels == largest)
