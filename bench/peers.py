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
* ``gridflow_epi``: as ``gridflow_lines`` with each segment of views fitted on its
  epipolar-plane images (``select="epi"``);
* ``epi_st``: the EPI structure tensor of Wanner and Goldluecke (CVPR 2012; TPAMI 2014),
  written here: orientation of the horizontal and vertical epipolar-plane images from a
  Gaussian-smoothed 2-D structure tensor, the more coherent of the two kept per pixel.

Scores: :func:`gridflow.metrics.hci_metrics` (the HCI benchmark's MSE x 100 and
BadPix) for depth, Eq. 22 of the image flow for motion.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gridflow.estimator import MODELS
from gridflow.estimator.portable import gaussian_taps, log10
from gridflow.metrics import evaluate, hci_metrics

from .cube_experiment import CUBE_SIGMA, CUBE_WINDOW

__all__ = ["epi_structure_tensor", "DEPTH_METHODS", "run_depth", "compare_motion",
           "MOTION_CASES", "run_peers", "compare_peers", "PeersReport", "score_hci_scene", "check_hci_scene"]


def _gauss(sigma: float, rmax: int | None = None) -> np.ndarray:
    # the taps from the C library's exp with exact sums (gaussian_taps): numpy's SIMD exp
    # and sums would give other bits on another CPU, and the EPI peer is a committed result
    r = max(1, int(np.ceil(3 * sigma)))
    r = r if rmax is None else min(r, rmax)
    return gaussian_taps(sigma, r)


def _gauss_deriv(sigma: float, rmax: int | None = None) -> np.ndarray:
    r = max(1, int(np.ceil(3 * sigma)))
    r = r if rmax is None else min(r, rmax)
    x = np.arange(-r, r + 1, dtype=float)
    d = -x / sigma ** 2 * gaussian_taps(sigma, r)
    return d / -math.fsum((d * x).tolist())     # unit response to a linear ramp


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
            # the weighted sum over the views term by term (a BLAS product's sums
            # round by the CPU)
            out = np.zeros(a.shape[1:])
            for w_, img in zip(wv, a[sel]):
                out += w_ * img
            return out

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
    return e["disparity"], -log10(np.maximum(e["model_error"], 1e-300))


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


def _gridflow_epi(views, grid: int | None = None, shifts=(-3, -2, -1, 0, 1, 2, 3)):
    return _gridflow_occlusion(views, grid, shifts, select="epi")


DEPTH_METHODS = {
    "gridflow": _gridflow,
    "gridflow_refocus": _gridflow_refocus,
    "gridflow_occlusion": _gridflow_occlusion,
    "gridflow_lines": _gridflow_lines,
    "gridflow_epi": _gridflow_epi,
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


def _centre_frames(volume: np.ndarray, k: int, r: int = 1):
    T, Sy, Sx = volume.shape[:3]
    return (np.asarray(volume[k - r, Sy // 2, Sx // 2], float),
            np.asarray(volume[k + r, Sy // 2, Sx // 2], float))


def flow_ilk(volume: np.ndarray, k: int, radius: int = 15, r: int = 1) -> dict:
    """scikit-image's iterative Lucas-Kanade between frames k-r and k+r of the centre
    camera, over 2r: the flow at frame k (central difference).  ``radius`` 15: a window
    comparable to gridflow's (σ = 16); skimage's default 7 fails on the sinusoid's 8-px
    texture (its coarse-to-fine pyramid aliases: median flow -15.5 px for a true 0.5)."""
    from skimage.registration import optical_flow_ilk

    a, b = _centre_frames(volume, k, r)
    v, u = optical_flow_ilk(a, b, radius=radius)
    return {"flow_x": u / (2.0 * r), "flow_y": v / (2.0 * r)}


def flow_farneback(volume: np.ndarray, k: int, r: int = 1) -> dict:
    """OpenCV's Farnebäck flow between frames k-r and k+r of the centre camera, over 2r.
    Images are mapped affinely onto 0-255 (float32): the method's parameters assume that
    range."""
    import cv2

    a, b = _centre_frames(volume, k, r)
    lo, hi = min(a.min(), b.min()), max(a.max(), b.max())
    s = 255.0 / (hi - lo) if hi > lo else 1.0
    f = cv2.calcOpticalFlowFarneback(((a - lo) * s).astype(np.float32),
                                     ((b - lo) * s).astype(np.float32), None,
                                     0.5, 3, 15, 3, 5, 1.2, 0)
    return {"flow_x": f[..., 0] / (2.0 * r), "flow_y": f[..., 1] / (2.0 * r)}


def compare_motion(data, models=MODELS, **settings) -> list[dict]:
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


# --- what `gridflow peers` runs ------------------------------------------------------------

# the sinusoids the motion comparison runs on: lateral motion (U_X, U_Y) on top of the
# paper's U_Z, under each kind of brightness change and with noise
MOTION_BASE = dict(U_X=0.05, U_Y=0.03)
MOTION_CASES = (("sinusoid", {}), ("sinusoid a1=0.1", dict(a1=0.1)),
                ("sinusoid a1x=0.002", dict(a1x=0.002)),
                ("sinusoid a2x=-0.002", dict(a2x=-0.002)),
                ("sinusoid noise 0.025", dict(noise=0.025)))


@dataclass
class PeersReport:
    """What :func:`run_peers` measured.

    Attributes
    ----------
    label : str
        The depth scene.
    depth : pandas.DataFrame
        One row per depth method: :func:`gridflow.metrics.hci_metrics` and
        ``seconds``.
    motion : pandas.DataFrame
        One row per case, method and flow component (:func:`compare_motion`).
    written : list of Path
    hci : (str, pandas.DataFrame), optional
        :func:`score_hci_scene` where :func:`compare_peers` was given a scene.
    """

    label: str
    depth: pd.DataFrame
    motion: pd.DataFrame
    written: list
    hci: tuple | None = None


def run_peers(cache, *, csv_depth, csv_motion, fig_dir, write_hci=None,
              progress: bool = True) -> PeersReport:
    """gridflow and the peer methods side by side; writes the two tables and the figure.

    Depth: every method of :data:`DEPTH_METHODS` on the cube rendered as a static light
    field with disparities up to 3 px per view
    (:func:`gridflow.scenes.render_cube_lightfield`).  Motion: gridflow's models against
    scikit-image's and OpenCV's optical flow on the sinusoids of :data:`MOTION_CASES` and
    on the cube under its spotlight.  Run times are reported, not stored: the CSVs are the
    same from run to run.

    Parameters
    ----------
    cache : path
        The render cache (``work/cube``).
    csv_depth, csv_motion : path
        Written atomically.
    fig_dir : path
        Where ``peers_depth.{png,pdf}`` go.
    write_hci : path, optional
        Also write the cube light field there as an HCI scene.
    progress : bool
        The renders' progress bars.
    """
    import pandas as pd

    from gridflow.generators import make_sinusoid
    from gridflow.io import atomic_write
    from gridflow.loader import load_folder
    from gridflow.scenes import CubeScene, render_cube, render_cube_lightfield

    from . import figures as F

    views, truth, scene = render_cube_lightfield(cache, progress=progress)
    label = (f"cube (POV-Ray), {scene.grid[0]}x{scene.grid[1]} views, disparity "
             f"{np.nanmin(truth):.2f} .. {np.nanmax(truth):.2f} px/view")
    depth = [run_depth(m, views, truth) for m in DEPTH_METHODS]
    table = pd.DataFrame([{"scene": label, **{k: v for k, v in r.items()
                                              if k not in ("disparity", "confidence")}}
                          for r in depth])
    with atomic_write(csv_depth, "w") as fh:
        table.drop(columns="seconds").to_csv(fh, index=False, float_format="%.6g")
    written = [Path(csv_depth)]
    written += F.save(F.fig_peers_depth(truth, depth, label), fig_dir, "peers_depth")
    if write_hci:
        from gridflow.hci import write_hci as write

        write(write_hci, views, disparity=truth)
        written.append(Path(write_hci))
    rows = []
    for case, kw in MOTION_CASES:
        for r in compare_motion(make_sinusoid(**MOTION_BASE, **kw)):
            rows.append({"data": case, **r})
    cube = load_folder(render_cube(CubeScene(), cache, progress=progress))
    for r in compare_motion(cube, sigma=CUBE_SIGMA, window=CUBE_WINDOW):
        rows.append({"data": "cube (spotlight)", **r})
    motion = pd.DataFrame(rows)
    with atomic_write(csv_motion, "w") as fh:
        motion.drop(columns="seconds").to_csv(fh, index=False, float_format="%.6g")
    written.append(Path(csv_motion))
    return PeersReport(label, table, motion, written)


def compare_peers(cache, *, csv_depth, csv_motion, fig_dir, write_hci=None, hci=None,
                  env=None, progress: bool = True) -> PeersReport:
    """What ``gridflow peers`` does: :func:`run_peers` (its arguments), and with ``hci``
    an HCI scene with truth, :func:`score_hci_scene` on it (the peers depthy and plenpy
    run in the environment ``env``, default :data:`PEERS_ENV`).  The optical-flow peers'
    packages, the outputs and the scene are checked first, so that a missing package or
    a bad scene is refused before the minutes of the other peers and their files."""
    from gridflow.errors import UsageError
    from gridflow.io import check_output

    try:                                # the optical-flow peers: the 'peers' extra
        import cv2  # noqa: F401
        import skimage.registration  # noqa: F401
    except ImportError as e:
        raise UsageError(f"gridflow peers needs the peer methods' packages ({e.name} is "
                         "missing): pip install 'gridflow[peers]'") from None
    for path in (csv_depth, csv_motion):
        check_output(path, suffixes=".csv", what="output")
    check_output(fig_dir, suffixes=None, what="--fig-dir")
    scene = check_hci_scene(hci) if hci else None
    r = run_peers(cache, csv_depth=csv_depth, csv_motion=csv_motion, fig_dir=fig_dir,
                  write_hci=write_hci, progress=progress)
    if hci:
        r.hci = score_hci_scene(hci, env=env or PEERS_ENV, progress=progress, scene=scene)
    return r


# the Python light-field packages run in an environment of their own (make peers-env)
EXTERNAL_DEPTH = ("depthy", "plenpy")
PEERS_ENV = ".venv-peers"


def run_external(package: str, folder, d_gt=None, *, env=PEERS_ENV,
                 timeout: float = 1800.0) -> dict:
    """Run ``depthy`` or ``plenpy`` on the HCI scene ``folder`` in the environment ``env``
    (its ``bin/python``; ``make peers-env``) through ``bench/peer_runner.py``.

    Returns
    -------
    dict
        ``method`` (package and version), ``seconds`` (the method's call, as the runner
        timed it), ``wall`` (the whole subprocess: start, imports, reading the views),
        ``disparity`` and, with ``d_gt``, :func:`hci_metrics`.
    """
    import json
    import subprocess
    import sys
    import tempfile

    from gridflow.errors import UsageError

    py = Path(env) / "bin" / "python"
    if not py.is_file():
        raise UsageError(f"{package}: its environment {env} is missing (make peers-env)")
    runner = Path(__file__).with_name("peer_runner.py")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "d.npy"
        t0 = time.perf_counter()
        p = subprocess.run([str(py), str(runner), package, str(folder), str(out)],
                           capture_output=True, text=True, timeout=timeout)
        wall = time.perf_counter() - t0
        if p.returncode != 0:
            tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["no output"]
            raise RuntimeError(f"{package} failed in {env} (exit {p.returncode}): {tail[0]}")
        info = json.loads(p.stdout.strip().splitlines()[-1])
        d = np.load(out).astype(np.float64)
    print(f"  {package} {info['version']}: {info['call']} ({info['seconds']:.1f} s)",
          file=sys.stderr, flush=True)
    r = {"method": f"{package} {info['version']}", "seconds": float(info["seconds"]),
         "wall": wall, "disparity": d}
    if d_gt is not None:
        r.update(hci_metrics(d, d_gt))
    return r


def _gridflow_default(views, disp_range):
    """What ``gridflow estimate SCENE`` does with no options: the stated range, else the
    coarse pass's; line sub-grids, fill, median."""
    from gridflow.estimator.lightfield import (estimate_refocused, estimate_shear_range,
                                               stated_shears)

    shears = stated_shears(disp_range)
    if shears is None:
        shears, _ = estimate_shear_range(views)
    res = estimate_refocused(views, shears)
    return res["disparity"], res["confidence"]


def check_hci_scene(folder):
    """The HCI scene ``folder`` loaded and checked for what :func:`score_hci_scene` needs
    (views, ``gt_disp_lowres.pfm``): run first, so that a bad scene is refused before any
    other work and before anything is written."""
    from gridflow.hci import HCIError, load_hci

    lf = load_hci(folder)
    if "disparity" not in lf.truth:
        raise HCIError(f"{folder}: no gt_disp_lowres.pfm to score against")
    return lf


def score_hci_scene(folder, *, env=PEERS_ENV, progress=True,
                    scene=None) -> tuple[str, pd.DataFrame]:
    """Every depth method on an HCI scene with truth (``gt_disp_lowres.pfm``): gridflow's
    default first (the command ``gridflow estimate SCENE`` runs), the peers depthy and
    plenpy where their environment ``env`` exists, then gridflow's other choices over the
    scene's stated disparity range where ``parameters.cfg`` gives one; on more than 5 x 5
    views also the occlusion-aware methods on the central 5 x 5 alone (what the outer
    views add).

    Returns
    -------
    description : str
    table : pandas.DataFrame
        One row per method and views used: :func:`hci_metrics` and ``seconds``.

    ``scene``: the scene already loaded by :func:`check_hci_scene` (else it is loaded).
    """
    import pandas as pd

    import sys

    from gridflow.estimator.lightfield import stated_shears

    def say(text):
        if progress:
            print(text, file=sys.stderr, flush=True)

    lf = check_hci_scene(folder) if scene is None else scene
    views, gt = lf.volume[0], lf.truth["disparity"]
    n = views.shape[0]
    disp_range = (lf.meta.get("hci") or {}).get("disp_range")
    shifts = stated_shears(disp_range)
    kw = {} if shifts is None else {"shifts": shifts}
    out = []
    missing = ""
    say(f"{folder}: gridflow's default ...")
    t0 = time.perf_counter()
    d, conf = _gridflow_default(views, disp_range)
    out.append({"method": "gridflow (default)", "seconds": time.perf_counter() - t0,
                **hci_metrics(d, gt), "views": f"{n}+{n}"})
    if (Path(env) / "bin" / "python").is_file():
        for pkg in EXTERNAL_DEPTH:
            say(f"{folder}: {pkg} in {env} ...")
            r = run_external(pkg, folder, gt, env=env)
            out.append({**r, "views": f"{n}x{n}"})
    else:
        missing = f"depthy, plenpy: not run ({env} is missing: make peers-env sets it up)"
        say(missing)
    for m in DEPTH_METHODS:
        say(f"{folder}: {m} ...")
        r = run_depth(m, views, gt, **(kw if m.startswith("gridflow_") else {}))
        used = (f"{n}x{n}" if m in ("gridflow_occlusion", "epi_st") else
                f"{n}+{n}" if m in ("gridflow_lines", "gridflow_epi")
                else f"{min(5, n)}x{min(5, n)}")
        out.append({**r, "views": used})
    if n > 5:
        for m in ("gridflow_occlusion", "gridflow_lines", "gridflow_epi"):
            r = run_depth(m, views, gt, grid=5, **kw)
            out.append({**r, "views": "5x5" if m == "gridflow_occlusion" else "5+5"})
    table = pd.DataFrame([{k: v for k, v in r.items()
                           if k not in ("disparity", "confidence", "wall")} for r in out])
    desc = f"{folder} ({n}x{n} views{'; shears ' + str(list(kw['shifts'])) if kw else ''})"
    if missing:
        desc += f"; {missing}"
    return desc, table
