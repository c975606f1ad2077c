"""Reading and writing the interchange files (edge of the system: all file I/O is here).

Volume file (``.npz``), writable without gridflow::

    volume           float array, shape (T, Sy, Sx, H, W)
    focal_length     scalar, pixels
    camera_spacing   [ds_x, ds_y], world units
    principal_point  [cx, cy], pixels (optional; default the image centre)
    truth_<name>     (H, W) ground-truth maps (optional)

Estimate file (``.npz``): one (H, W) float map per quantity (``Z, Zx, Zy, Ux, Uy, Uz``,
the model's ``a1, a2, a1x, a1y, a2x, a2y``, ``model_error``; NaN where invalid), plus
``interior`` (bool, pixels free of border effects) and ``meta`` (a JSON string).

Writes are atomic: a temporary file in the target folder is renamed over the target, so an
interrupted write never leaves a truncated file or destroys an existing one.
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from .volume import GridVolume

__all__ = ["save_volume", "load_volume", "save_estimate", "load_estimate", "atomic_write"]


class atomic_write:
    """Context manager yielding a binary file whose content replaces ``path`` on success."""

    def __init__(self, path, mode: str = "wb"):
        self.path = Path(path)
        self.mode = mode

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, self.tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp",
                                        dir=self.path.parent)
        self.fh = os.fdopen(fd, self.mode)
        return self.fh

    def __exit__(self, exc_type, exc, tb):
        self.fh.close()
        if exc_type is None:
            # mkstemp makes the file private (0600); give it the usual umask permissions
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self.tmp, 0o666 & ~umask)
            os.replace(self.tmp, self.path)
        else:
            os.unlink(self.tmp)
        return False


def save_volume(path, data: GridVolume, *, compress: bool = False) -> None:
    """Write ``data`` as a volume ``.npz`` (see module docstring)."""
    arrays = {"volume": data.volume, "focal_length": np.float64(data.focal_length),
              "camera_spacing": np.asarray(data.camera_spacing, float),
              "principal_point": np.asarray(data.principal_point, float)}
    for name, arr in data.truth.items():
        arrays[f"truth_{name}"] = arr
    if data.meta:
        arrays["meta"] = np.array(json.dumps(data.meta))
    with atomic_write(path) as fh:
        (np.savez_compressed if compress else np.savez)(fh, **arrays)


def _open_npz(path):
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"{path}: not a readable .npz file ({exc})") from exc


def load_volume(path) -> GridVolume:
    """Read a volume ``.npz``.

    Returns
    -------
    GridVolume

    Raises
    ------
    FileNotFoundError, ValueError
        Missing or unreadable file, missing keys, wrong shapes.
    """
    with _open_npz(path) as z:
        keys = set(z.files)
        missing = {"volume", "focal_length", "camera_spacing"} - keys
        if missing:
            raise ValueError(f"{path}: missing array(s) {sorted(missing)}; a volume file needs "
                             "volume, focal_length, camera_spacing")
        try:
            vol = z["volume"]
        except Exception as exc:  # corrupted member
            raise ValueError(f"{path}: cannot read 'volume' ({exc})") from exc
        if vol.ndim != 5:
            raise ValueError(f"{path}: 'volume' must have shape (T, Sy, Sx, H, W); got {vol.shape}")
        f = np.asarray(z["focal_length"], float)
        sp = np.asarray(z["camera_spacing"], float).ravel()
        if f.size != 1:
            raise ValueError(f"{path}: 'focal_length' must be a scalar, got shape {f.shape}")
        if sp.size != 2:
            raise ValueError(f"{path}: 'camera_spacing' must be [ds_x, ds_y], got {sp.tolist()}")
        H, W = vol.shape[-2:]
        if "principal_point" in keys:
            pp = np.asarray(z["principal_point"], float).ravel()
            if pp.size != 2:
                raise ValueError(f"{path}: 'principal_point' must be [cx, cy], got {pp.tolist()}")
            pp = (float(pp[0]), float(pp[1]))
        else:
            pp = ((W - 1) / 2.0, (H - 1) / 2.0)
        truth = {}
        for k in keys:
            if k.startswith("truth_"):
                arr = z[k]
                if arr.shape != (H, W):
                    raise ValueError(f"{path}: '{k}' has shape {arr.shape}, expected {(H, W)}")
                truth[k[6:]] = arr
        meta = json.loads(str(z["meta"])) if "meta" in keys else {}
    return GridVolume(vol, float(f), (float(sp[0]), float(sp[1])), pp, truth, meta)


def save_estimate(path, est) -> None:
    """Write an :class:`estimator.Estimate` as an estimate ``.npz``."""
    arrays = {k: np.asarray(v, np.float64) for k, v in est.maps.items()}
    arrays["interior"] = est.interior
    arrays["meta"] = np.array(json.dumps({"model": est.model, "settings": est.settings}))
    with atomic_write(path) as fh:
        np.savez(fh, **arrays)


def load_estimate(path) -> tuple[dict[str, np.ndarray], np.ndarray, dict]:
    """Read an estimate ``.npz``; returns ``(maps, interior, meta)``."""
    with _open_npz(path) as z:
        if "interior" not in z.files:
            raise ValueError(f"{path}: not an estimate file (no 'interior' array)")
        maps = {k: z[k] for k in z.files if k not in ("interior", "meta")}
        interior = z["interior"].astype(bool)
        meta = json.loads(str(z["meta"])) if "meta" in z.files else {}
    return maps, interior, meta
