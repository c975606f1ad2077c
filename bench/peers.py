"""Peer methods run through one interface, and the HCI benchmark's metrics.

Every depth method here takes a static light field ``views`` of shape (n, n, H, W) (view
``(r, c)``, the centre view the reference; HCI geometry, see :mod:`gridflow.hci`) and
returns ``(disparity, confidence)`` maps of shape (H, W) for the centre view, disparity
in pixels per camera step with the HCI sign.

* ``gridflow``: the structure-tensor TLS estimator of this project on the static light
  field (model ``bcc`` without a time axis), on the central ``grid x grid`` views;
* ``gridflow_refocus``: the same over a range of integer shears (see
  :func:`gridflow.estimator.lightfield.estimate_refocused`), for disparities beyond
  +-1 px per view, each pixel's shear the one nearest to a coarse disparity
  (``select="coarse"``), on the central 5 x 5 views;
* ``gridflow_occlusion``: the shears again, each pixel's estimate chosen among camera
  sub-grids and shifted windows by a guided aggregation of the model error
  (``select="occlusion"``), on all views (5 x 5 sub-grids at the centre, edges and
  corners of a larger grid);
* ``gridflow_lines``: as ``gridflow_occlusion`` with 1-D camera sub-grids along the
  centre row and column (``select="lines"``), on all views of that row and column;
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
        as wrong (BadPix) and are left out of the MSE; pixels where the truth is not
        finite are not scored.
    border : int
        Pixels left out at each side (the benchmark's 15).

    Returns
    -------
    dict
        ``mse_x100, badpix_007, badpix_003, badpix_001`` (percent), ``n_pixels`` (scored),
        ``n_nonfinite`` (of those, estimates that are not finite).
    """
    e = np.asarray(d_est, float)[border:-border or None, border:-border or None]
    g = np.asarray(d_gt, float)[border:-border or None, border:-border or None]
    # pixels without truth (a rendered scene's background) are not scored
    has = np.isfinite(g)
    e, g = e[has], g[has]
    ok = np.isfinite(e)
    err = np.abs(e - g)
    out = {"mse_x100": float(100.0 * np.mean(err[ok] ** 2)) if ok.any() else float("nan"),
           "n_pixels": int(g.size), "n_nonfinite": int((~ok).sum())}
    for tau, key in ((0.07, "badpix_007"), (0.03, "badpix_003"), (0.01, "badpix_001")):
        out[key] = float(100.0 * np.mean(~ok | (err > tau)))
    return out


def _gauss(sigma: float, rmax: int | None = None) -> np.ndarray:
    r = max(1, int(np.ceil(3 * sigma)))
    r = r if rmax is None else min(r, rmax)
    x = np.arange(-r, r + 1, dtype=float)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def _gauss_deriv(sigma: float, rmax: int | None = None) -> np.ndarray:
    r = max(1, int(np.ceil(3 * sigma)))
    r = r if rmax is None else min(r, rmax)
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
        integration a Gaussian over the views (same scales, in views; both truncated to
        the views there are and renormalised).

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
        # across the views only the views there are: kernels truncated to n and
        # renormalised (a repeated edge view would bias the derivative)
        Ec = correlate1d(Es, _gauss_deriv(inner, cc), axis=0, mode="nearest")
        Exs = correlate1d(Ex, _gauss(inner, cc), axis=0, mode="nearest")
        go = _gauss(outer)
        wv = _gauss(outer, cc)
        rv = wv.size // 2
        sel = np.arange(cc - rv, cc + rv + 1)

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


def _central(views, grid):
    n = views.shape[0]
    grid = n if grid is None else int(grid)
    c0 = (n - grid) // 2
    return views[c0:c0 + grid, c0:c0 + grid]


def _gridflow_refocus(views, grid: int | None = 5, shifts=(-3, -2, -1, 0, 1, 2, 3)):
    from gridflow.estimator.lightfield import estimate_refocused

    # dense, as the benchmark scores every pixel: pixels without an admissible estimate
    # are filled from their neighbours (``filled``)
    res = estimate_refocused(_central(views, grid), shifts=shifts, select="coarse", fill=True)
    return res["disparity"], res["confidence"]


def _gridflow_occlusion(views, grid: int | None = None, shifts=(-3, -2, -1, 0, 1, 2, 3),
                        select: str = "occlusion"):
    from gridflow.estimator.lightfield import estimate_refocused

    res = estimate_refocused(_central(views, grid), shifts=shifts, select=select, fill=True)
    return res["disparity"], res["confidence"]


def _gridflow_lines(views, grid: int | None = None, shifts=(-3, -2, -1, 0, 1, 2, 3)):
    return _gridflow_occlusion(views, grid, shifts, select="lines")


DEPTH_METHODS = {
    "gridflow": _gridflow,
    "gridflow_refocus": _gridflow_refocus,
    "gridflow_occlusion": _gridflow_occlusion,
    "gridflow_lines": _gridflow_lines,
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


# --- motion: the centre camera's frames, against gridflow's 3-D motion --------------------

def image_flow(maps: dict, focal_length: float, principal_point) -> dict:
    """Image motion (px per frame) at the reference view from depth and 3-D motion.

    ``dx/dt = (f U_X - x U_Z) / Z`` (likewise y), x relative to the principal point: the
    flow gridflow's parameters describe (``u_x + u_z x``), from estimated or true maps
    ``Z, Ux, Uy, Uz`` of shape (H, W).
    """
    Z = np.asarray(maps["Z"], float)
    H, W = Z.shape
    x = np.arange(W, dtype=float)[None, :] - principal_point[0]
    y = np.arange(H, dtype=float)[:, None] - principal_point[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return {"flow_x": (focal_length * maps["Ux"] - x * maps["Uz"]) / Z,
                "flow_y": (focal_length * maps["Uy"] - y * maps["Uz"]) / Z}


def _centre_frames(volume: np.ndarray, k: int):
    T, Sy, Sx = volume.shape[:3]
    return (np.asarray(volume[k - 1, Sy // 2, Sx // 2], float),
            np.asarray(volume[k + 1, Sy // 2, Sx // 2], float))


def flow_ilk(volume: np.ndarray, k: int, radius: int = 15) -> dict:
    """scikit-image's iterative Lucas-Kanade between frames k-1 and k+1 of the centre
    camera, halved: the flow at frame k (central difference).  ``radius`` 15: a window
    comparable to gridflow's (σ = 16); skimage's default 7 fails on the sinusoid's 8-px
    texture (its coarse-to-fine pyramid aliases: median flow -15.5 px for a true 0.5)."""
    from skimage.registration import optical_flow_ilk

    a, b = _centre_frames(volume, k)
    v, u = optical_flow_ilk(a, b, radius=radius)
    return {"flow_x": u / 2.0, "flow_y": v / 2.0}


def flow_farneback(volume: np.ndarray, k: int) -> dict:
    """OpenCV's Farnebäck flow between frames k-1 and k+1 of the centre camera, halved.
    Images are mapped affinely onto 0-255 (float32): the method's parameters assume that
    range."""
    import cv2

    a, b = _centre_frames(volume, k)
    lo, hi = min(a.min(), b.min()), max(a.max(), b.max())
    s = 255.0 / (hi - lo) if hi > lo else 1.0
    f = cv2.calcOpticalFlowFarneback(((a - lo) * s).astype(np.float32),
                                     ((b - lo) * s).astype(np.float32), None,
                                     0.5, 3, 15, 3, 5, 1.2, 0)
    return {"flow_x": f[..., 0] / 2.0, "flow_y": f[..., 1] / 2.0}


def compare_motion(data, models=("bcc", "hf", "full"), **settings) -> list[dict]:
    """gridflow's models and the two optical-flow peers on one volume, scored alike.

    Parameters
    ----------
    data : GridVolume
        With truth ``Z, Ux, Uy, Uz`` at the reference camera and frame.
    models : sequence of str
    **settings
        Estimator settings.

    Returns
    -------
    list of dict
        One row per method and flow component: ``method, quantity, q, measure, q_abs,
        q_rel, n_pixels, seconds``; Eq. 22 over gridflow's interior (pixels with a full
        window), where every method is free of border effects.
    """
    from gridflow.estimator import estimate_models

    from .metrics import evaluate

    k = settings.get("ref_frame") or (data.volume.shape[0] - 1) // 2
    truth = image_flow(data.truth, data.focal_length, data.principal_point)
    t0 = time.perf_counter()
    ests = estimate_models(data.volume, data.focal_length, data.camera_spacing, models=models,
                           principal_point=data.principal_point, **settings)
    t_grid = time.perf_counter() - t0
    mask = next(iter(ests.values())).interior
    results = {f"gridflow_{m}": (image_flow(e.maps, data.focal_length, data.principal_point),
                                 t_grid) for m, e in ests.items()}
    for name, fn in (("ilk", flow_ilk), ("farneback", flow_farneback)):
        t0 = time.perf_counter()
        fl = fn(data.volume, k)
        results[name] = (fl, time.perf_counter() - t0)
    rows = []
    for name, (fl, secs) in results.items():
        for r in evaluate(fl, truth, mask):
            rows.append({"method": name, **r, "seconds": secs})
    return rows
