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
      "truth": {"Z": "truth/Z.npy"},      # optional (H, W) .npy ground-truth maps
      "frame_interval": 120.0,            # optional; seconds between frames (a recording's
                                          # time stamps)
      "times_s": [0, 120, 240, ...]       # optional; each frame's time stamp, s (a recording
                                          # with gaps: a missed frame, lights off at night)
    }

Images: 8- or 16-bit PNG (grey; RGB is converted to luminance), or float TIFF.  Integer
images are scaled to [0, 1] by their bit depth; all images must share size and type.
Intensities must be linear in radiance (the brightness model assumes it).
"""

from __future__ import annotations

import json
import os
import re
import string
from pathlib import Path

import numpy as np

from .errors import GridflowError
from .volume import GridVolume, physical_memory

__all__ = ["load_folder", "open_folder", "read_image", "LoaderError"]

_IMAGE_EXT = {".png", ".tif", ".tiff"}


class LoaderError(GridflowError):
    """A camera-grid folder that cannot be loaded; the message names file and problem."""


_REQUIRED = ("focal_length", "camera_spacing", "grid", "frames", "pattern")
_OPTIONAL = ("reference_camera", "reference_frame", "principal_point", "truth", "units",
             "source", "frame_interval", "times_s")
# a format spec of a pattern field: at most a zero-padded width and a 'd' ({t:02d})
_FIELD_SPEC = re.compile(r"0?[1-9]?d?")
# more images than this in one folder is not a camera-grid sequence this loader can hold
MAX_IMAGES = 1_000_000


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)


def _numbers(m: dict, key: str, path: Path, n: int) -> list[float]:
    v = m[key]
    if not (isinstance(v, list) and len(v) == n and all(_is_number(x) for x in v)):
        raise LoaderError(f"{path}: '{key}' must be a list of {n} finite numbers, got {v!r}")
    return [float(x) for x in v]


def _inside(folder: Path, rel: str, path: Path, key: str) -> Path:
    """``folder / rel``, refused unless it stays inside the folder."""
    p = folder / rel
    if not p.resolve().is_relative_to(folder.resolve()):
        raise LoaderError(f"{path}: '{key}' names {rel!r}, which lies outside the folder")
    return p


def _read_manifest(folder: Path) -> dict:
    path = folder / "grid.json"
    if not path.exists():
        raise LoaderError(f"{folder}: no grid.json manifest (see the README: camera-grid folders)")
    if not path.is_file():
        raise LoaderError(f"{path}: not a regular file")
    try:
        m = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise LoaderError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(m, dict):
        raise LoaderError(f"{path}: must hold a JSON object")
    missing = [k for k in _REQUIRED if k not in m]
    if missing:
        raise LoaderError(f"{path}: missing key(s) {missing}")
    unknown = sorted(set(m) - set(_REQUIRED) - set(_OPTIONAL))
    if unknown:
        raise LoaderError(f"{path}: unknown key(s) {unknown}; expected "
                          f"{list(_REQUIRED) + list(_OPTIONAL)}")
    g = m["grid"]
    if not (isinstance(g, list) and len(g) == 2 and all(_is_int(v) and v >= 1 for v in g)):
        raise LoaderError(f"{path}: 'grid' must be [Sy, Sx], two integers >= 1, got {g!r}")
    sy, sx = g
    if sy % 2 == 0 or sx % 2 == 0:
        raise LoaderError(f"{path}: 'grid' {g} has an even size; the reference camera is the "
                          "centre of an odd grid")
    frames = m["frames"]
    if not (_is_int(frames) and frames >= 1):
        raise LoaderError(f"{path}: 'frames' must be an integer >= 1, got {frames!r}")
    if sy * sx * frames > MAX_IMAGES:
        raise LoaderError(f"{path}: 'grid' {g} x 'frames' {frames} names {sy * sx * frames} "
                          f"images, more than {MAX_IMAGES}")
    f = m["focal_length"]
    if not (_is_number(f) and f > 0):
        raise LoaderError(f"{path}: 'focal_length' must be a positive number of pixels, "
                          f"got {f!r}")
    ds = _numbers(m, "camera_spacing", path, 2)
    if ds[0] <= 0 or (sy > 1 and ds[1] <= 0) or ds[1] < 0:
        raise LoaderError(f"{path}: 'camera_spacing' {ds} must be positive (ds_y may be 0 "
                          "only on a 1-D grid)")
    pattern = m["pattern"]
    if not isinstance(pattern, str) or not pattern:
        raise LoaderError(f"{path}: 'pattern' must be a file name pattern, got {pattern!r}")
    try:
        parsed = [(name, spec, conv) for _, name, spec, conv in
                  string.Formatter().parse(pattern) if name is not None]
    except ValueError as exc:
        raise LoaderError(f"{path}: 'pattern' {pattern!r} is malformed ({exc})") from None
    names = {name for name, _, _ in parsed}
    if names != {"t", "sy", "sx"}:
        raise LoaderError(f"{path}: 'pattern' {pattern!r} must use the fields {{t}}, {{sy}} "
                          "and {sx}, and no others")
    for name, spec, conv in parsed:
        if conv or not _FIELD_SPEC.fullmatch(spec or ""):
            raise LoaderError(f"{path}: 'pattern' field {{{name}:{spec}}} is not allowed; use "
                              "{t}, {t:d} or a zero-padded width such as {t:02d}")
    rc = m.get("reference_camera")
    if rc is not None and rc != [(sy - 1) // 2, (sx - 1) // 2]:
        raise LoaderError(f"{path}: 'reference_camera' {rc!r} is not the centre camera "
                          f"[{(sy - 1) // 2}, {(sx - 1) // 2}]; gridflow estimates at the "
                          "centre of an odd grid")
    rf = m.get("reference_frame")
    if rf is not None and not (_is_int(rf) and 0 <= rf < frames):
        raise LoaderError(f"{path}: 'reference_frame' must be a frame index 0..{frames - 1}, "
                          f"got {rf!r}")
    pp = None
    if m.get("principal_point") is not None:
        pp = _numbers(m, "principal_point", path, 2)
    truth = m.get("truth") or {}
    if not (isinstance(truth, dict)
            and all(isinstance(k, str) and isinstance(v, str) for k, v in truth.items())):
        raise LoaderError(f"{path}: 'truth' must map quantity names to .npy file names, "
                          f"got {truth!r}")
    truth = {q: _inside(folder, rel, path, f"truth.{q}") for q, rel in truth.items()}
    fi = m.get("frame_interval")
    if fi is not None and not (_is_number(fi) and fi > 0):
        raise LoaderError(f"{path}: 'frame_interval' must be a positive number of seconds "
                          f"between frames, got {fi!r}")
    if m.get("times_s") is not None:
        from .volume import SourceError, check_times

        try:
            m["_times"] = check_times(m["times_s"], frames, f"{path}: 'times_s'")
        except SourceError as e:
            raise LoaderError(str(e)) from None
    for key, kind in (("units", str), ("source", dict)):
        if m.get(key) is not None and not isinstance(m[key], kind):
            raise LoaderError(f"{path}: '{key}' must be a {kind.__name__}, got {m[key]!r}")
    m.update(_grid=(sy, sx), _frames=frames, _f=float(f), _ds=ds, _pp=pp, _truth=truth)
    return m


def read_image(path: Path) -> tuple[np.ndarray, str]:
    """One image as float64 ``(H, W)`` luminance (integer images scaled to [0, 1] by their
    bit depth, RGB to linear luminance) and its pixel type as stored."""
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
        # linear luminance, as elementwise products and sums: a matrix product's BLAS
        # rounds by the machine's CPU (results must be the same to the byte everywhere)
        rgb = np.asarray(img, np.float64)
        img = rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722
    elif img.ndim != 2:
        raise LoaderError(f"{path}: expected a grey or RGB image, got shape {img.shape}")
    if kind == "uint8":
        out = np.asarray(img, np.float64) / 255.0
    elif kind == "uint16":
        out = np.asarray(img, np.float64) / 65535.0
    elif kind in ("float32", "float64"):
        out = np.asarray(img, np.float64)
        bad = ~np.isfinite(out)
        if bad.any():
            y, x = np.argwhere(bad)[0]
            raise LoaderError(f"{path}: {int(bad.sum())} non-finite pixel(s) (NaN or inf), "
                              f"the first at (y, x) = ({y}, {x}); the estimator needs "
                              "finite intensities")
    else:
        raise LoaderError(f"{path}: unsupported pixel type {kind} (8/16-bit PNG or float TIFF)")
    return out, kind


def open_folder(folder):
    """Open a camera-grid folder without decoding an image beyond the first (the
    ``folder`` backend of :func:`gridflow.sources.open_source`): every key of
    ``grid.json`` is checked, and the manifest against the folder.

    Returns
    -------
    gridflow.sources.Source
        Frames read on demand (:meth:`~gridflow.sources.Source.read`, each image checked
        against the first: size and pixel type); the manifest's ``truth`` maps belong to
        its reference frame (default the centre frame).

    Raises
    ------
    LoaderError
        Missing manifest or keys, unknown keys, values of the wrong type or range, a
        pattern that names one file twice or a path outside the folder, missing or extra
        images, files that are not regular files, an unreadable first image.
    """
    from .volume import CameraGeometry, Source

    folder = Path(folder)
    m, expected, paths = index_folder(folder)
    (Sy, Sx), T = m["_grid"], m["_frames"]
    by_frame = [[None] * (Sy * Sx) for _ in range(T)]
    for name, (t, i, j) in expected.items():
        by_frame[t][i * Sx + j] = paths[name]
    first = by_frame[0][0]
    img, kind = read_image(first)       # the size and type every image must have
    H, W = img.shape
    pp = m["_pp"]
    pp = ((W - 1) / 2.0, (H - 1) / 2.0) if pp is None else (pp[0], pp[1])
    ref = m.get("reference_frame")
    geometry = CameraGeometry(m["_f"], (m["_ds"][0], m["_ds"][1]), pp,
                              m.get("frame_interval"), m.get("units") or "world units")
    reader = FolderReader(folder, m, by_frame, first, (H, W), kind)
    return Source(folder, (T, Sy, Sx, H, W), geometry, "folder", tuple(sorted(m["_truth"])),
                  ref if ref is not None else (T - 1) // 2, ref,
                  {"folder": str(folder), "pixel_type": kind, "source": m.get("source")},
                  reader, m.get("_times"))


class FolderReader:
    """Reads a camera-grid folder's frames (or row bands of them) on demand."""

    def __init__(self, path, m, by_frame, first, shape, kind):
        self.path, self.m, self.by_frame = path, m, by_frame
        self.first, self.image_shape, self.kind = first, shape, kind

    def read(self, start: int, stop: int, r0: int, r1: int, dtype=np.float64) -> np.ndarray:
        Sy, Sx = self.m["_grid"]
        if start == 0 and stop == self.m["_frames"]:
            _check_memory(self.path, (stop - start, Sy, Sx, r1 - r0, self.image_shape[1]))
        out = np.empty((stop - start, Sy, Sx, r1 - r0, self.image_shape[1]), dtype=dtype)
        for t in range(start, stop):
            for k, p in enumerate(self.by_frame[t]):
                if not p.is_file():
                    raise LoaderError(f"{p}: frame {t}, camera ({k // Sx}, {k % Sx}) is "
                                      "missing or not a regular file")
                img, kind = read_image(p)
                check_like(p, img, kind, self.first.name, self.image_shape, self.kind)
                out[t - start, k // Sx, k % Sx] = img[r0:r1]
        return out

    def truth(self, frame: int, names: tuple) -> dict:
        return {q: read_truth(q, self.m["_truth"][q], self.image_shape) for q in names}

    def identity(self) -> dict:
        return {"kind": "folder", "pattern": self.m["pattern"], "pixel_type": self.kind}

    def files(self, start: int, stop: int) -> list[Path]:
        return [p for t in range(start, stop) for p in self.by_frame[t]]


def load_folder(folder) -> GridVolume:
    """Read a camera-grid folder into a volume ``(T, Sy, Sx, H, W)`` (:func:`open_folder`,
    then every frame; refused before any image beyond the first is decoded when the
    volume would not fit this machine's memory).

    Raises
    ------
    LoaderError
        As :func:`open_folder`; also mixed sizes or types, a volume larger than this
        machine's memory, unreadable files or truth maps.
    """
    return open_folder(folder).load()


def check_like(path: Path, img: np.ndarray, kind: str, first_name: str, shape: tuple,
               first_kind: str) -> None:
    """Refuse an image whose size or pixel type differs from the first one's."""
    if img.shape != tuple(shape):
        raise LoaderError(f"{path}: size {img.shape} differs from {first_name} "
                          f"{tuple(shape)}")
    if kind != first_kind:
        raise LoaderError(f"{path}: pixel type {kind} differs from {first_name} "
                          f"({first_kind})")


def read_truth(q: str, p: Path, shape: tuple) -> np.ndarray:
    """A ``(H, W)`` truth map ``.npy`` named by the manifest, checked."""
    if not p.is_file():
        raise LoaderError(f"{p}: truth map '{q}' is missing or not a regular file")
    try:
        arr = np.load(p, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise LoaderError(f"{p}: unreadable truth map ({exc})") from None
    if arr.shape != tuple(shape):
        raise LoaderError(f"{p}: truth map has shape {arr.shape}, images are {tuple(shape)}")
    return arr


def index_folder(folder) -> tuple[dict, dict, dict]:
    """A camera-grid folder's checked manifest and its images, none of them read.

    Returns
    -------
    manifest : dict
        ``grid.json`` with ``_grid``, ``_frames``, ``_f``, ``_ds``, ``_pp``, ``_truth``.
    expected : dict of str to (t, sy, sx)
        Every image name the manifest names, in frame order.
    paths : dict of str to Path
        Each name's path (a regular file inside the folder).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise LoaderError(f"{folder}: not a folder")
    m = _read_manifest(folder)
    (Sy, Sx), T = m["_grid"], m["_frames"]
    manifest = folder / "grid.json"
    # a manifest that names far more images than the folder holds files is refused before
    # the names are even listed (a typo such as "frames": 25444 must not take minutes);
    # up to 10 000 names are listed, which takes milliseconds, to name the missing files
    n_files = sum(len(files) for _, _, files in os.walk(folder))
    if T * Sy * Sx > max(n_files, 10_000):
        raise LoaderError(f"{manifest}: 'grid' {[Sy, Sx]} x 'frames' {T} names {T * Sy * Sx} "
                          f"images, but the folder holds only {n_files} files")
    expected = {}
    for t in range(T):
        for i in range(Sy):
            for j in range(Sx):
                name = m["pattern"].format(t=t, sy=i, sx=j)
                if name in expected:
                    raise LoaderError(
                        f"{manifest}: 'pattern' {m['pattern']!r} is ambiguous: frame {t}, "
                        f"camera ({i}, {j}) and frame {expected[name][0]}, camera "
                        f"{expected[name][1:]} both name {name!r} (pad the fields, e.g. "
                        "{t:02d})")
                expected[name] = (t, i, j)
    paths = {name: _inside(folder, name, manifest, "pattern") for name in expected}
    missing = sorted(n for n, p in paths.items() if not p.exists())
    if missing:
        raise LoaderError(f"{folder}: {len(missing)} image(s) named by the manifest are "
                          f"missing, e.g. {missing[:3]} (grid {Sy}x{Sx}, {T} frames)")
    irregular = sorted(n for n, p in paths.items() if not p.is_file())
    if irregular:
        raise LoaderError(f"{folder}: {len(irregular)} image(s) are not regular files, e.g. "
                          f"{irregular[:3]}")
    # Files that look like they belong to the sequence but are not in the grid: the
    # manifest contradicts the folder (wrong grid size or frame count).
    regex = re.sub(r"\\\{(t|sy|sx)(?::[^}]*)?\\\}", r"\\d+", re.escape(m["pattern"]))
    extra = sorted(p.name for p in folder.iterdir()
                   if p.suffix.lower() in _IMAGE_EXT and p.name not in expected
                   and re.fullmatch(regex, p.name))
    if extra:
        raise LoaderError(f"{folder}: {len(extra)} image(s) match the pattern but lie outside "
                          f"the manifest's grid {Sy}x{Sx} x {T} frames, e.g. {extra[:3]}")
    return m, expected, paths


def _check_memory(folder: Path, shape: tuple) -> None:
    """Refuse a volume that would not fit in this machine's memory (float64)."""
    need = 8 * int(np.prod(shape, dtype=np.int64))
    have = physical_memory()
    if have is not None and need > 0.8 * have:
        raise LoaderError(f"{folder}: the volume {shape} needs {need / 2**30:.1f} GiB as "
                          f"float64, more than this machine's memory allows "
                          f"({have / 2**30:.1f} GiB)")
