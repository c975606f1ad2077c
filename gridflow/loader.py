"""Loading camera-grid image folders (edge: file I/O).

A folder holds one image per (frame, camera row, camera column) and a ``grid.json``::

    {
      "focal_length": 650.0,              # pixels
      "camera_spacing": [0.4, 0.4],       # [ds_x, ds_y], world units
      "grid": [5, 5],                     # [Sy, Sx] (Sy = 1: horizontal 1-D grid)
      "frames": 9,
      "pattern": "t{t:02d}_y{sy}_x{sx}.png",   # file name of frame t, camera (sy, sx)
      "reference_camera": [2, 2],         # optional; must be the centre camera
      "reference_frame": 4,               # optional; default the centre frame
      "principal_point": [127.5, 127.5],  # optional [cx, cy]; default the image centre
      "truth": {"Z": "truth/Z.npy"}       # optional (H, W) .npy ground-truth maps
    }

Images: 8- or 16-bit PNG (grey; RGB is converted to luminance), or float TIFF.  Integer
images are scaled to [0, 1] by their bit depth; all images must share size and type.
Intensities must be linear in radiance (the brightness model assumes it).
"""

from __future__ import annotations

import json
import re
import string
from pathlib import Path

import numpy as np

from .volume import GridVolume

__all__ = ["load_folder", "LoaderError"]

_IMAGE_EXT = {".png", ".tif", ".tiff"}


class LoaderError(ValueError):
    """A camera-grid folder that cannot be loaded; the message names file and problem."""


def _read_manifest(folder: Path) -> dict:
    path = folder / "grid.json"
    if not path.exists():
        raise LoaderError(f"{folder}: no grid.json manifest (see the README: camera-grid folders)")
    try:
        m = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise LoaderError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(m, dict):
        raise LoaderError(f"{path}: must hold a JSON object")
    missing = {"focal_length", "camera_spacing", "grid", "frames", "pattern"} - set(m)
    if missing:
        raise LoaderError(f"{path}: missing key(s) {sorted(missing)}")
    try:
        sy, sx = (int(v) for v in m["grid"])
        frames = int(m["frames"])
        f = float(m["focal_length"])
        ds = [float(v) for v in m["camera_spacing"]]
    except (TypeError, ValueError) as exc:
        raise LoaderError(f"{path}: grid, frames, focal_length or camera_spacing malformed "
                          f"({exc})") from None
    if sy < 1 or sx < 1 or frames < 1 or len(ds) != 2 or not f > 0:
        raise LoaderError(f"{path}: grid {m['grid']}, frames {frames}, focal_length {f} or "
                          f"camera_spacing {m['camera_spacing']} out of range")
    fields = {name for _, name, _, _ in string.Formatter().parse(m["pattern"]) if name}
    if fields != {"t", "sy", "sx"}:
        raise LoaderError(f"{path}: pattern {m['pattern']!r} must use the fields {{t}}, "
                          "{sy} and {sx}")
    rc = m.get("reference_camera")
    if rc is not None and [int(v) for v in rc] != [(sy - 1) // 2, (sx - 1) // 2]:
        raise LoaderError(f"{path}: reference_camera {rc} is not the centre camera "
                          f"[{(sy - 1) // 2}, {(sx - 1) // 2}]; gridflow estimates at the "
                          "centre of an odd grid")
    m.update(_grid=(sy, sx), _frames=frames, _f=f, _ds=ds)
    return m


def _read_image(path: Path) -> tuple[np.ndarray, str]:
    import imageio.v3 as iio

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise LoaderError(f"{path}: unreadable file ({exc})") from None
    try:
        # from bytes: imageio leaves file handles open when it tries its plugins on a
        # corrupt file
        img = iio.imread(data, extension=path.suffix.lower())
    except Exception as exc:  # imageio raises many types for corrupt files
        raise LoaderError(f"{path}: unreadable image ({exc})") from None
    kind = str(img.dtype)
    if img.ndim == 3 and img.shape[-1] in (3, 4):
        img = img[..., :3] @ np.array([0.2126, 0.7152, 0.0722])   # linear luminance
    elif img.ndim != 2:
        raise LoaderError(f"{path}: expected a grey or RGB image, got shape {img.shape}")
    if kind == "uint8":
        out = np.asarray(img, np.float64) / 255.0
    elif kind == "uint16":
        out = np.asarray(img, np.float64) / 65535.0
    elif kind in ("float32", "float64"):
        out = np.asarray(img, np.float64)
    else:
        raise LoaderError(f"{path}: unsupported pixel type {kind} (8/16-bit PNG or float TIFF)")
    return out, kind


def load_folder(folder) -> GridVolume:
    """Read a camera-grid folder into a volume ``(T, Sy, Sx, H, W)``.

    Raises
    ------
    LoaderError
        Missing manifest or keys, missing or extra images, mixed sizes or types, a
        manifest that contradicts the files, unreadable files or truth maps.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise LoaderError(f"{folder}: not a folder")
    m = _read_manifest(folder)
    (Sy, Sx), T = m["_grid"], m["_frames"]
    expected = {m["pattern"].format(t=t, sy=i, sx=j): (t, i, j)
                for t in range(T) for i in range(Sy) for j in range(Sx)}
    missing = sorted(n for n in expected if not (folder / n).exists())
    if missing:
        raise LoaderError(f"{folder}: {len(missing)} image(s) named by the manifest are "
                          f"missing, e.g. {missing[:3]} (grid {Sy}x{Sx}, {T} frames)")
    # Files that look like they belong to the sequence but are not in the grid: the
    # manifest contradicts the folder (wrong grid size or frame count).
    regex = re.escape(m["pattern"]).replace(r"\{t:02d\}", r"\d+")
    regex = re.sub(r"\\\{(t|sy|sx)(?::[^}]*)?\\\}", r"\\d+", regex)
    extra = sorted(p.name for p in folder.iterdir()
                   if p.suffix.lower() in _IMAGE_EXT and p.name not in expected
                   and re.fullmatch(regex, p.name))
    if extra:
        raise LoaderError(f"{folder}: {len(extra)} image(s) match the pattern but lie outside "
                          f"the manifest's grid {Sy}x{Sx} x {T} frames, e.g. {extra[:3]}")
    vol = None
    first_kind = first_name = None
    for name, (t, i, j) in expected.items():
        img, kind = _read_image(folder / name)
        if vol is None:
            vol = np.empty((T, Sy, Sx) + img.shape)
            first_kind, first_name = kind, name
        if img.shape != vol.shape[3:]:
            raise LoaderError(f"{folder / name}: size {img.shape} differs from "
                              f"{first_name} {vol.shape[3:]}")
        if kind != first_kind:
            raise LoaderError(f"{folder / name}: pixel type {kind} differs from "
                              f"{first_name} ({first_kind})")
        vol[t, i, j] = img
    H, W = vol.shape[3:]
    pp = m.get("principal_point")
    pp = ((W - 1) / 2.0, (H - 1) / 2.0) if pp is None else (float(pp[0]), float(pp[1]))
    truth = {}
    for q, rel in (m.get("truth") or {}).items():
        p = folder / rel
        try:
            arr = np.load(p, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise LoaderError(f"{p}: unreadable truth map ({exc})") from None
        if arr.shape != (H, W):
            raise LoaderError(f"{p}: truth map has shape {arr.shape}, images are {(H, W)}")
        truth[q] = arr
    meta = {"folder": str(folder), "pixel_type": first_kind,
            "ref_frame": m.get("reference_frame"), "source": m.get("source")}
    return GridVolume(vol, m["_f"], (m["_ds"][0], m["_ds"][1]), pp, truth, meta)
