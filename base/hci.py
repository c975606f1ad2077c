"""The HCI 4-D light field benchmark format (Honauer et al., ACCV 2016) (edge: file I/O).

A scene folder holds ``input_Cam000.png … input_CamNNN.png`` (view ``i`` at grid row
``i // n``, column ``i % n`` of an ``n x n`` grid; the centre view is the reference),
optionally ``parameters.cfg`` (intrinsics, baseline, focus distance) and the ground truth
of the centre view, ``gt_disp_lowres.pfm`` and ``gt_depth_lowres.pfm`` (PFM: float32,
rows stored bottom-up).

Geometry: a centre-view pixel ``(x, y)`` with disparity ``d`` appears in view ``(r, c)``
at ``(x - d (c - cc), y - d (r - cc))`` (x right, y down, ``cc`` the centre index).  The
cameras converge at ``focus_distance``: ``1/Z = d / (f_px b) + 1/Z_focus`` with ``f_px =
focal_length_mm / sensor_size_mm * resolution`` and ``b`` the baseline.

In gridflow's frame a point moves by ``v ds`` pixels per camera step (``v = -f/Z`` for
parallel cameras), so ``d = -v ds``: :func:`load_hci` returns the views with
``camera_spacing = (1, 1)`` (one camera step) and the estimator's ``disparity`` output is
``d`` directly.  RGB views are converted to luminance with the Rec. 709 weights, as the
other loaders do; the benchmark's PNGs are sRGB-encoded and used as stored (the
structure tensor needs intensities that brightness-constancy holds for across views,
which the encoding does not change; the brightness-change models would need them
linearised).
"""

from __future__ import annotations

import configparser
import os
import re
from pathlib import Path

import numpy as np

from .errors import GridflowError
from .volume import GridVolume, physical_memory

__all__ = ["HCIError", "is_hci_scene", "load_hci", "read_pfm", "write_pfm", "read_parameters",
           "write_hci", "depth_from_disparity", "disparity_from_depth"]

_VIEW = re.compile(r"^input_Cam(\d{3})\.png$")
#: the files of a scene that its estimate reads (views, parameters, ground truth)
HCI_FILES = re.compile(r"^(input_Cam\d{3}\.png|parameters\.cfg|gt_(disp|depth)_lowres\.pfm)$")


class HCIError(GridflowError):
    """An HCI scene folder that cannot be read; the message names file and problem."""


def is_hci_scene(folder) -> bool:
    """Whether ``folder`` looks like an HCI scene: it holds ``input_Cam000.png``, or views
    ``input_CamNNN.png`` and no ``grid.json`` (a scene missing its first view is then
    refused by :func:`load_hci` naming what it found, not as a camera-grid folder without
    a manifest)."""
    p = Path(folder)
    if not p.is_dir():
        return False
    if (p / "input_Cam000.png").is_file():
        return True
    return not (p / "grid.json").exists() and any(_VIEW.match(q.name) for q in p.iterdir())


def read_pfm(path) -> np.ndarray:
    """A single-channel PFM image as float32, rows top-down.

    Raises
    ------
    HCIError
        Not a PFM file, a colour PFM, a size that does not match the data.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise HCIError(f"{path}: unreadable file ({exc})") from None
    parts = raw.split(b"\n", 3)
    if len(parts) < 4 or parts[0].strip() not in (b"Pf", b"PF"):
        raise HCIError(f"{path}: not a PFM file (expected the header 'Pf')")
    if parts[0].strip() == b"PF":
        raise HCIError(f"{path}: a colour PFM; expected a single-channel map")
    try:
        w, h = (int(v) for v in parts[1].split())
        scale = float(parts[2])
    except ValueError:
        raise HCIError(f"{path}: bad PFM header {parts[1]!r} {parts[2]!r}") from None
    if w <= 0 or h <= 0 or scale == 0 or not np.isfinite(scale):
        raise HCIError(f"{path}: bad PFM size {w}x{h} or scale {scale}")
    data = parts[3]
    if len(data) != 4 * w * h:
        raise HCIError(f"{path}: {len(data)} bytes of data for a {w}x{h} map "
                       f"(expected {4 * w * h})")
    arr = np.frombuffer(data, dtype="<f4" if scale < 0 else ">f4").reshape(h, w)
    return np.ascontiguousarray(arr[::-1]).astype(np.float32)


def write_pfm(path, image: np.ndarray) -> None:
    """Write a 2-D map as a little-endian single-channel PFM (rows bottom-up)."""
    from .io import atomic_write

    a = np.asarray(image, dtype="<f4")
    if a.ndim != 2:
        raise HCIError(f"a PFM map must be 2-D, got shape {a.shape}")
    with atomic_write(path) as fh:
        fh.write(f"Pf\n{a.shape[1]} {a.shape[0]}\n-1\n".encode())
        fh.write(np.ascontiguousarray(a[::-1]).tobytes())


def read_parameters(path) -> dict:
    """``parameters.cfg`` as ``{section: {key: value}}`` (numbers converted)."""
    path = Path(path)
    cp = configparser.ConfigParser()
    try:
        text = path.read_text()
        cp.read_string(text)
    except (OSError, UnicodeDecodeError, configparser.Error) as exc:
        raise HCIError(f"{path}: unreadable parameters file ({exc})") from None
    out = {}
    for sec in cp.sections():
        out[sec] = {}
        for k, v in cp[sec].items():
            try:
                out[sec][k] = float(v) if any(ch in v for ch in ".eE") else int(v)
            except ValueError:
                out[sec][k] = v
    return out


def _geometry(params: dict, path: Path, width: int) -> dict:
    """Focal length (px), baseline (m), focus distance (m) from a parameters dict.

    Each key is read on its own and named when it is missing or not a finite positive
    number; the resolution must be a whole number equal to the views' width (8.5 is not
    read as 8, nor 1e999 as an overflow)."""
    def number(sec: str, key: str) -> float:
        try:
            raw = params[sec][key]
        except KeyError:
            raise HCIError(f"{path}: [{sec}] {key} missing (needs intrinsics "
                           "focal_length_mm, sensor_size_mm, image_resolution_x_px; "
                           "extrinsics baseline_mm, focus_distance_m)") from None
        try:
            value = float(raw)
        except (TypeError, ValueError, OverflowError):
            value = float("nan")
        if not (np.isfinite(value) and value > 0):
            raise HCIError(f"{path}: [{sec}] {key} = {raw}: expected a finite positive "
                           "number")
        return value

    f_mm = number("intrinsics", "focal_length_mm")
    sensor = number("intrinsics", "sensor_size_mm")
    res = number("intrinsics", "image_resolution_x_px")
    b = number("extrinsics", "baseline_mm") / 1000.0
    zf = number("extrinsics", "focus_distance_m")
    if res != width:
        raise HCIError(f"{path}: [intrinsics] image_resolution_x_px = "
                       f"{params['intrinsics']['image_resolution_x_px']}, but the views are "
                       f"{width} pixels wide")
    if not (np.isfinite(f_mm / sensor * res) and b > 0):
        raise HCIError(f"{path}: [intrinsics] focal_length_mm / sensor_size_mm * "
                       f"image_resolution_x_px = {f_mm / sensor * res}, [extrinsics] "
                       f"baseline_mm / 1000 = {b}: not a finite focal length in pixels and "
                       "a positive baseline")
    return {"focal_length_px": f_mm / sensor * res, "baseline_m": b, "focus_distance_m": zf}


def depth_from_disparity(d: np.ndarray, geometry: dict) -> np.ndarray:
    """Depth (m) from HCI disparity (px per camera step): ``1/Z = d/(f b) + 1/Z_focus``."""
    fb = geometry["focal_length_px"] * geometry["baseline_m"]
    with np.errstate(divide="ignore", invalid="ignore"):
        return 1.0 / (np.asarray(d, float) / fb + 1.0 / geometry["focus_distance_m"])


def disparity_from_depth(z: np.ndarray, geometry: dict) -> np.ndarray:
    """HCI disparity (px per camera step) of depth ``z`` (m)."""
    fb = geometry["focal_length_px"] * geometry["baseline_m"]
    with np.errstate(divide="ignore", invalid="ignore"):
        return fb * (1.0 / np.asarray(z, float) - 1.0 / geometry["focus_distance_m"])


def load_hci(folder, views: int | None = None) -> GridVolume:
    """Read an HCI scene as a one-frame camera-grid volume.

    Parameters
    ----------
    folder : path
    views : int, optional
        Odd size of the central sub-grid to use (e.g. 5 for the central 5 x 5 of 9 x 9);
        default all views.

    Returns
    -------
    GridVolume
        ``volume`` of shape (1, n, n, H, W), float64 luminance in [0, 1];
        ``camera_spacing = (1, 1)`` (one camera step: the estimator's ``disparity`` is the
        HCI disparity); ``truth`` holds ``disparity`` (and ``depth`` in metres) where the
        folder has them; ``meta["hci"]`` the geometry from ``parameters.cfg`` (if any)
        and the grid used.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise HCIError(f"{folder}: not a folder")
    chosen, n, use = _chosen_views(folder, views)
    volume = _read_views(folder, chosen, use)
    H, W = volume.shape[3:]
    meta = {"source": "hci", "folder": str(folder), "grid": [n, n], "views_used": use}
    geometry = None
    cfg = folder / "parameters.cfg"
    if cfg.is_file():
        geometry, meta["hci"] = _scene_geometry(cfg, W)
    truth = {}
    for name, key in (("gt_disp_lowres.pfm", "disparity"), ("gt_depth_lowres.pfm", "depth")):
        if (folder / name).is_file():
            t = read_pfm(folder / name).astype(np.float64)
            if t.shape != (H, W):
                raise HCIError(f"{folder / name}: {t.shape} does not match the views' {(H, W)}")
            truth[key] = t
    f = geometry["focal_length_px"] if geometry else float(W)
    return GridVolume(volume=volume, focal_length=f, camera_spacing=(1.0, 1.0),
                      principal_point=((W - 1) / 2.0, (H - 1) / 2.0), truth=truth, meta=meta)


def _chosen_views(folder: Path, views: int | None) -> tuple[list[Path], int, int]:
    """The files of the central ``views x views`` views (all by default), the grid's size
    and the number used; a grid with views missing or of an even size refused naming
    what it lacks."""
    found = {}
    for p in folder.iterdir():
        m = _VIEW.match(p.name)
        if m:
            found[int(m.group(1))] = p
    count = len(found)
    n = int(round(np.sqrt(count)))
    if count == 0 or n * n != count or n % 2 == 0 or sorted(found) != list(range(count)):
        # the grid the views come closest to (the smallest odd square holding the highest
        # index), and the files it lacks
        top = max(found, default=-1) + 1
        m = int(np.ceil(np.sqrt(max(top, 1))))
        m += 1 - m % 2
        missing = [f"input_Cam{i:03d}.png" for i in range(m * m) if i not in found]
        lack = (f"; missing for a {m} x {m} grid: {', '.join(missing[:3])}"
                + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
                if missing else "")
        last = f" (the last input_Cam{top - 1:03d}.png)" if count else ""
        raise HCIError(f"{folder}: expected input_Cam000.png ... for an odd n x n grid of "
                       f"views, found {count} views{last}{lack}")
    if n < 3:
        raise HCIError(f"{folder}: a {n} x {n} grid of views; a light field needs at least "
                       "3 x 3 (input_Cam000.png ... input_Cam008.png)")
    use = n if views is None else int(views)
    if use % 2 == 0 or not 3 <= use <= n:
        raise HCIError(f"{folder}: views = {views} (--views): expected an odd number from 3 "
                       f"to the scene's {n}")
    c0 = (n - use) // 2
    chosen = [found[r * n + c] for r in range(c0, c0 + use) for c in range(c0, c0 + use)]
    # a FIFO would block the read, a device (a link to /dev/zero) never end it
    irregular = [p.name for p in chosen if not p.is_file()]
    if irregular:
        raise HCIError(f"{folder}: {len(irregular)} view(s) are not regular files, e.g. "
                       f"{irregular[:3]}")
    return chosen, n, use


def _read_views(folder: Path, chosen: list[Path], use: int) -> np.ndarray:
    """The views as a ``(1, use, use, H, W)`` volume, each checked against the first
    (size, pixel type); refused before the second is decoded when they would take more
    than half the memory."""
    from .loader import LoaderError, read_image

    volume = None
    first = first_kind = None
    try:
        for k, p in enumerate(chosen):
            img, kind = read_image(p)
            if volume is None:
                mem = physical_memory()
                if mem is not None and use * use * img.size * 8 > mem // 2:
                    raise HCIError(f"{folder}: {use}x{use} views of {img.shape[1]}x"
                                   f"{img.shape[0]} need more than half the memory of "
                                   "this machine")
                volume = np.empty((1, use, use) + img.shape)
                first, first_kind = p.name, kind
            if img.shape != volume.shape[3:]:
                raise HCIError(f"{p}: size {img.shape} differs from {first} "
                               f"{volume.shape[3:]}")
            if kind != first_kind:
                raise HCIError(f"{p}: pixel type {kind} differs from {first} ({first_kind}): "
                               "the views would be scaled differently")
            volume[0, k // use, k % use] = img
    except LoaderError as exc:
        raise HCIError(str(exc)) from None
    return volume


def _scene_geometry(cfg: Path, W: int) -> tuple[dict, dict]:
    """The geometry of ``parameters.cfg`` and the scene's ``meta["hci"]`` (with the
    disparity range the benchmark states, where it does: an input, not ground truth)."""
    params = read_parameters(cfg)
    geometry = _geometry(params, cfg, W)
    hci = {**geometry, "scene": params.get("meta", {}).get("scene")}
    m = params.get("meta", {})
    if "disp_min" in m or "disp_max" in m:
        lo, hi = m.get("disp_min"), m.get("disp_max")
        if not (isinstance(lo, float | int) and isinstance(hi, float | int)
                and np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
            raise HCIError(f"{cfg}: [meta] disp_min, disp_max: expected two finite "
                           f"numbers with disp_min <= disp_max, got {lo!r}, {hi!r}")
        hci["disp_range"] = [float(lo), float(hi)]
    return geometry, hci


def write_hci(folder, views: np.ndarray, *, disparity: np.ndarray | None = None,
              parameters: dict | None = None) -> list[Path]:
    """Write a light field in the HCI layout (for other tools).

    Parameters
    ----------
    folder : path
        Created if needed; existing ``input_Cam*.png`` files are not overwritten.  The
        scene is written to a temporary folder beside it first and moved into place by
        renames, so a failure part-way (a full disk) leaves no partial scene.
    views : ndarray, shape (n, n, H, W)
        Intensities in [0, 1] (clipped), written as 8-bit grey PNGs; n odd.
    disparity : ndarray, shape (H, W), optional
        Centre-view disparity (px per camera step, HCI sign), as ``gt_disp_lowres.pfm``.
    parameters : dict, optional
        ``{section: {key: value}}`` for ``parameters.cfg``.

    Returns
    -------
    list of Path
        The files written.
    """
    import imageio.v3 as iio

    from .io import folder_beside

    folder = Path(folder)
    v = np.asarray(views, dtype=float)
    if v.ndim != 4 or v.shape[0] != v.shape[1] or v.shape[0] % 2 == 0:
        raise HCIError(f"views must have shape (n, n, H, W) with n odd, got {v.shape}")
    n = v.shape[0]
    names = [f"input_Cam{i:03d}.png" for i in range(n * n)]
    if folder.exists() and not folder.is_dir():
        raise FileExistsError(f"{folder}: exists and is not a folder")
    clash = [folder / nm for nm in names if (folder / nm).exists()]
    if clash:
        raise FileExistsError(f"{clash[0]}: exists; write the scene into an empty folder")
    # the whole scene goes to a temporary folder beside the target first, then into
    # place by renames: a failure part-way (a full disk) leaves no partial scene
    with folder_beside(folder) as tmp:
        files = []
        for i, nm in enumerate(names):
            img = np.round(np.clip(v[i // n, i % n], 0.0, 1.0) * 255).astype(np.uint8)
            (tmp / nm).write_bytes(iio.imwrite("<bytes>", img, extension=".png"))
            files.append(nm)
        if disparity is not None:
            write_pfm(tmp / "gt_disp_lowres.pfm", disparity)
            files.append("gt_disp_lowres.pfm")
        if parameters:
            cp = configparser.ConfigParser()
            for sec, kv in parameters.items():
                cp[sec] = {k: str(val) for k, val in kv.items()}
            with open(tmp / "parameters.cfg", "w") as fh:
                cp.write(fh)
            files.append("parameters.cfg")
        if not folder.exists():
            os.rename(tmp, folder)
        else:
            for nm in files:
                os.replace(tmp / nm, folder / nm)
    written = [folder / nm for nm in files]
    return written
