"""Peer methods run through one interface, and the HCI benchmark's metrics.

Every depth method here takes a static light field ``views`` of shape (n, n, H, W) (view
``(r, c)``, the centre view the reference; HCI geometry, see :mod:`gridflow.hci`) and
returns ``(disparity, confidence)`` maps of shape (H, W) for the centre view, disparity
in pixels per camera step with the HCI sign.

* ``gridflow``: the structure-tensor TLS estimator of this project on the static light
  field (model ``bcc`` without a time axis), on the central ``grid x grid`` views;
* ``gridflow_refocus``: the same over a range of integer shears (see
  :func:`gridflow.estimator.lightfield.estimate_refocused`), for disparities beyond
  +-1 px per view;
* ``epi_st``: the EPI structure tensor of Wanner and Goldluecke (CVPR 2012; TPAMI 2014),
  written here: orientation of the horizontal and vertical epipolar-plane images from a
  Gaussian-smoothed 2-D structure tensor, the more coherent of the two kept per pixel.

Metrics (:func:`hci_metrics`): the benchmark's MSE x 100 and BadPix(0.07, 0.03, 0.01) over
the image without a 15-pixel border.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["hci_metrics", "epi_structure_tensor", "DEPTH_METHODS", "run_depth"]


def hci_metrics(d_est: np.ndarray, d_gt: np.ndarray, border: int = 15) -> dict:
    """The HCI benchmark's scores of a disparity map.

    Parameters
    ----------
    d_est, d_gt : ndarray, shape (H, W)
        Estimated and true disparity (px per camera step).  Non-finite estimates count
        as wrong (BadPix) and are left out of the MSE, whose pixel count is reported.
    border : int
        Pixels left out at each side (the benchmark's 15).

    Returns
    -------
    dict
        ``mse_x100, badpix_007, badpix_003, badpix_001`` (percent), ``n_pixels``,
        ``n_nonfinite``.
    """
    e = np.asarray(d_est, float)[border:-border or None, border:-border or None]
    g = np.asarray(d_gt, float)[border:-border or None, border:-border or None]
    ok = np.isfinite(e)
    err = np.abs(e - g)
    out = {"mse_x100": float(100.0 * np.mean(err[ok] ** 2)) if ok.any() else float("nan"),
           "n_pixels": int(g.size), "n_nonfinite": int((~ok).sum())}
    for tau, key in ((0.07, "badpix_007"), (0.03, "badpix_003"), (0.01, "badpix_001")):
        out[key] = float(100.0 * np.mean(~ok | (err > tau)))
    return out


def _gauss(sigma: float) -> np.ndarray:
    r = max(1, int(np.ceil(3 * sigma)))
    x = np.arange(-r, r + 1, dtype=float)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def _gauss_deriv(sigma: float) -> np.ndarray:
    r = max(1, int(np.ceil(3 * sigma)))
    x = np.arange(-r, r + 1, dtype=float)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    w /= w.sum()
    d = -x / sigma ** 2 * w
    return d / -(d * x).sum()           # unit response to a linear ramp (correlation)


def epi_structure_tensor(views: np.ndarray, inner: float = 0.8, outer: float = 2.0):
    """Disparity of the centre view from the structure tensor of its epipolar-plane images.

    Parameters
    ----------
    views : ndarray, shape (n, n, H, W)
    inner, outer : float
        Inner (derivative) and outer (integration) Gaussian scales in pixels; along the
        view axis the derivative is the Gaussian derivative at the centre view and the
        integration a Gaussian over the views (same scales, in views).

    Returns
    -------
    disparity, coherence : ndarray, shape (H, W)
    """
    from scipy.ndimage import correlate1d

    v = np.asarray(views, float)
    n = v.shape[0]
    cc = n // 2
    ests, cohs = [], []
    for axis_views, axis_img in ((1, 3), (0, 2)):          # horizontal EPIs, then vertical
        # E[view, y, x] along the EPI's view axis, the other view index at the centre
        E = v[cc] if axis_views == 1 else v[:, cc]
        gi, di = _gauss(inner), _gauss_deriv(inner)
        img_ax = axis_img - 1                               # axis in E (view, y, x)
        other = 1 if img_ax == 2 else 2
        Ex = correlate1d(correlate1d(E, di, axis=img_ax, mode="nearest"), gi, axis=other,
                         mode="nearest")
        Es = correlate1d(correlate1d(E, gi, axis=img_ax, mode="nearest"), gi, axis=other,
                         mode="nearest")
        Ec = correlate1d(Es, di, axis=0, mode="nearest")    # derivative across the views
        Exs = correlate1d(Ex, gi, axis=0, mode="nearest")
        go = _gauss(outer)
        wv = _gauss(outer)
        rv = wv.size // 2
        sel = np.arange(cc - rv, cc + rv + 1).clip(0, n - 1)

        def integrate(a):
            a = correlate1d(correlate1d(a, go, axis=1, mode="nearest"), go, axis=2,
                            mode="nearest")
            return np.tensordot(wv, a[sel], axes=(0, 0))

        jxx = integrate(Exs * Exs)
        jcc = integrate(Ec * Ec)
        jxc = integrate(Exs * Ec)
        # E(c, x) = L(x + d (c - cc)): E_c = d E_x, so the line direction gives d; from
        # the eigenvector of the smaller eigenvalue (orientation), as Wanner-Goldluecke
        with np.errstate(divide="ignore", invalid="ignore"):
            d = 2.0 * jxc / (jxx - jcc + np.sqrt((jxx - jcc) ** 2 + 4.0 * jxc ** 2))
            coh = np.sqrt((jxx - jcc) ** 2 + 4.0 * jxc ** 2) / (jxx + jcc)
        ests.append(d)
        cohs.append(np.nan_to_num(coh))
    pick = cohs[1] > cohs[0]
    return np.where(pick, ests[1], ests[0]), np.maximum(cohs[0], cohs[1])


def _gridflow(views, grid: int = 5, sigma: float = 2.0, window: int = 9):
    from gridflow.estimator import estimate

    n = views.shape[0]
    c0 = (n - grid) // 2
    sub = views[c0:c0 + grid, c0:c0 + grid][None]
    e = estimate(np.ascontiguousarray(sub), float(views.shape[-1]), (1.0, 1.0), model="bcc",
                 sigma=sigma, window=window)
    return e["disparity"], -np.log10(np.maximum(e["model_error"], 1e-300))


def _gridflow_refocus(views, grid: int = 5, sigma: float = 2.0, window: int = 9,
                      shifts=(-3, -2, -1, 0, 1, 2, 3)):
    from gridflow.estimator.lightfield import estimate_refocused

    n = views.shape[0]
    c0 = (n - grid) // 2
    res = estimate_refocused(views[c0:c0 + grid, c0:c0 + grid], shifts=shifts, sigma=sigma,
                             window=window)
    return res["disparity"], res["confidence"]


DEPTH_METHODS = {
    "gridflow": _gridflow,
    "gridflow_refocus": _gridflow_refocus,
    "epi_st": lambda views: epi_structure_tensor(views),
}


def run_depth(method: str, views: np.ndarray, d_gt: np.ndarray | None = None, **kw) -> dict:
    """Run one depth method, time it and score it.

    Returns
    -------
    dict
        ``method, seconds`` and, with ``d_gt``, :func:`hci_metrics`; plus the maps under
        ``disparity`` and ``confidence``.
    """
    if method not in DEPTH_METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {sorted(DEPTH_METHODS)}")
    t0 = time.perf_counter()
    d, conf = DEPTH_METHODS[method](views, **kw)
    out = {"method": method, "seconds": time.perf_counter() - t0, "disparity": d,
           "confidence": conf}
    if d_gt is not None:
        out.update(hci_metrics(d, d_gt))
    return out
