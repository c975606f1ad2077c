"""A camera-grid sequence: in memory (:class:`GridVolume`), read lazily from a file or
folder (:class:`Source`, opened by :func:`gridflow.sources.open_source`), and the camera
geometry both carry (:class:`CameraGeometry`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import FileFormatError

__all__ = ["GridVolume", "CameraGeometry", "Source", "SourceError", "source_from_volume",
           "physical_memory"]


def physical_memory() -> int | None:
    """Bytes of physical memory of this machine, or None where the system does not say
    (checks that refuse volumes larger than the machine then pass)."""
    import os

    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


@dataclass(frozen=True)
class CameraGeometry:
    """How a camera grid images the scene: what every estimate needs beside the pixels.

    Attributes
    ----------
    focal_length : float
        Pixels.
    camera_spacing : tuple of float
        ``(ds_x, ds_y)``, world units (:attr:`units`) between neighbouring cameras.
    principal_point : tuple of float
        ``(cx, cy)``, pixels (column, row) relative to the image's top-left pixel.
    frame_interval : float or None
        Seconds between frames, where the data states it.
    units : str
        The unit of length of ``camera_spacing`` and so of the estimated ``Z`` and ``U``.
    """

    focal_length: float
    camera_spacing: tuple
    principal_point: tuple
    frame_interval: float | None = None
    units: str = "world units"

    def for_rows(self, r0: int) -> "CameraGeometry":
        """The geometry of the image rows from ``r0`` on (a row band): the principal
        point moves up by ``r0`` rows."""
        cx, cy = self.principal_point
        return CameraGeometry(self.focal_length, self.camera_spacing, (cx, cy - r0),
                              self.frame_interval, self.units)

    def as_dict(self) -> dict:
        """JSON-ready: the attributes with units in their names."""
        return {"focal_length_px": float(self.focal_length),
                "camera_spacing": [float(v) for v in self.camera_spacing],
                "principal_point_px": [float(v) for v in self.principal_point],
                "frame_interval_s": (None if self.frame_interval is None
                                     else float(self.frame_interval)),
                "units": self.units}


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

    @property
    def geometry(self) -> CameraGeometry:
        """The camera geometry as one object (:class:`CameraGeometry`)."""
        return CameraGeometry(float(self.focal_length), tuple(self.camera_spacing),
                              tuple(self.principal_point), self.meta.get("frame_interval"),
                              self.meta.get("units") or "world units")


def file_states(paths) -> list[tuple]:
    """What a stored frame's "has it changed" checks compare (reading every byte is not an
    option).

    Parameters
    ----------
    paths : iterable of pathlib.Path

    Returns
    -------
    list of tuple
        ``(path, size, mtime_ns)`` per file, ``(path, None, None)`` for one missing.
    """
    out = []
    for p in paths:
        try:
            st = p.stat()
            out.append((p, st.st_size, st.st_mtime_ns))
        except FileNotFoundError:
            out.append((p, None, None))
    return out


class SourceError(FileFormatError):
    """An input that no backend opens, or that its backend refuses; names the path."""


# The ranges a geometry is accepted in: beyond them an estimate overflows or loses every
# digit, so a number there is a mistake (a unit, an exponent), refused where it is read.
# The depth Z = f ds / d of a disparity d down to 1e-6 px stays below float32's 3.4e38 while
# f ds <= 1e30; no camera has a focal length of 1e8 px (a 1e8-px-wide image would see
# 0.6 degrees at f = 1e10); a principal point a hundred image widths off the image is no
# lens's.
MAX_FOCAL_PX = 1e8
MAX_F_TIMES_SPACING = 1e30
MAX_PP_OFFSET_IMAGES = 100


def check_geometry(geometry, shape, where: str) -> None:
    """Refuse a camera geometry outside the ranges an estimate can use, naming ``where``
    (the file and key) and the number: a focal length that is not a finite number in
    (0, :data:`MAX_FOCAL_PX`] px; a spacing that is not finite, or whose product with the
    focal length exceeds :data:`MAX_F_TIMES_SPACING` in size; a principal point that is not finite
    or lies more than :data:`MAX_PP_OFFSET_IMAGES` image sizes from the image; a frame
    interval that is not a finite positive number of seconds.  ``shape`` is ``(..., H,
    W)``."""
    H, W = shape[-2:]
    f = geometry.focal_length
    if not (np.isfinite(f) and 0 < f <= MAX_FOCAL_PX):
        raise SourceError(f"{where}: focal length {f!r} px; expected a finite number in "
                          f"(0, {MAX_FOCAL_PX:g}] px")
    for name, b in zip(("ds_x", "ds_y"), geometry.camera_spacing):
        if not (np.isfinite(b) and abs(b) * f <= MAX_F_TIMES_SPACING):
            raise SourceError(f"{where}: camera spacing {name} = {b!r}; expected a finite "
                              f"number with |spacing| x focal length <= "
                              f"{MAX_F_TIMES_SPACING:g}")
    span = MAX_PP_OFFSET_IMAGES * max(H, W)
    for name, c, n in zip(("cx", "cy"), geometry.principal_point, (W, H)):
        if not (np.isfinite(c) and -span <= c <= n - 1 + span):
            raise SourceError(f"{where}: principal point {name} = {c!r} px; expected a "
                              f"finite number within {MAX_PP_OFFSET_IMAGES} image sizes "
                              f"of the image ({-span:g}..{n - 1 + span:g})")
    fi = geometry.frame_interval
    if fi is not None and not (np.isfinite(fi) and fi > 0):
        raise SourceError(f"{where}: frame interval {fi!r} s; expected a finite positive "
                          "number of seconds")


def check_times(values, frames: int, where: str) -> np.ndarray:
    """Per-frame time stamps as read from a file: ``frames`` finite numbers of seconds,
    strictly increasing, or :class:`SourceError` naming ``where`` (the file and key) and
    the first frame that is not.

    Returns
    -------
    ndarray of float64, shape (frames,)
    """
    try:
        t = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise SourceError(f"{where}: time stamps must be numbers of seconds, got "
                          f"{str(values)[:80]}") from None
    if t.shape != (frames,):
        raise SourceError(f"{where}: {t.size} time stamps for {frames} frames (one per "
                          "frame, seconds)")
    bad = ~np.isfinite(t)
    if bad.any():
        raise SourceError(f"{where}: time stamp of frame {int(np.flatnonzero(bad)[0])} is "
                          f"{t[bad][0]} (expected a finite number of seconds)")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise SourceError(f"{where}: frame {k} at {t[k]:g} s is not after frame {k - 1} at "
                          f"{t[k - 1]:g} s (time stamps must increase)")
    return t


@dataclass
class Source:
    """A camera-grid sequence read lazily, whatever its format.

    Attributes
    ----------
    path : Path
    shape : tuple of int
        ``(T, Sy, Sx, H, W)``.
    geometry : CameraGeometry
        Focal length (px), camera spacing, principal point (px), frame interval (s).
    kind : str
        The backend that opened it (:data:`BACKENDS`).
    truth_names : tuple of str
        Quantities with ground truth (:meth:`truth`).
    truth_frame : int or None
        The one frame the truth belongs to (a volume's reference frame), or None where
        every frame has its own (a recording).
    ref_frame : int or None
        The reference frame the source states (a folder's ``reference_frame``), if any.
    meta : dict
        Format-specific provenance (an HCI scene's geometry, a generator's parameters).
    times : ndarray of float, shape (T,), optional
        Each frame's time stamp in seconds, strictly increasing, where the source has
        them (:func:`check_times`); :meth:`time_stamps` falls back on the interval.
    """

    path: Path
    shape: tuple
    geometry: CameraGeometry
    kind: str
    truth_names: tuple = ()
    truth_frame: int | None = None
    ref_frame: int | None = None
    meta: dict = field(default_factory=dict)
    _reader: object = field(default=None, repr=False)
    times: object = field(default=None, repr=False)

    def time_stamps(self):
        """Each frame's time in seconds, shape (T,): the source's own time stamps
        (:attr:`times`: a recording's ``time_s``, a folder's ``times_s``), else frame
        index times the frame interval; None where neither is known."""
        if self.times is not None:
            return np.asarray(self.times, dtype=np.float64)
        fi = self.geometry.frame_interval
        return None if fi is None else np.arange(self.shape[0]) * float(fi)

    # the geometry's parts, read often enough to have names of their own
    @property
    def focal_length(self) -> float:
        return self.geometry.focal_length

    @property
    def camera_spacing(self) -> tuple:
        return self.geometry.camera_spacing

    @property
    def principal_point(self) -> tuple:
        return self.geometry.principal_point

    @property
    def frame_interval(self) -> float | None:
        return self.geometry.frame_interval

    @property
    def frames(self) -> int:
        return self.shape[0]

    def read(self, start: int, stop: int, rows: tuple | None = None,
             dtype=np.float64) -> np.ndarray:
        """Frames ``start .. stop - 1``, shape ``(stop - start, Sy, Sx, H, W)``, as float64
        or, for a source that stores float32 (:attr:`itemsize` 4), as ``dtype`` float32:
        as stored, which the estimator takes and gives the same maps from bit for bit, in
        half the memory.  With ``rows = (r0, r1)`` only image rows ``r0 .. r1 - 1`` (a
        row band: its memory is the band's, not the frame's, where the format allows)."""
        dtype = np.dtype(dtype)
        if dtype not in (np.float32, np.float64):
            raise SourceError(f"{self.path}: frames read as float32 or float64, got {dtype!r}")
        if dtype == np.float32 and self.itemsize != 4:
            raise SourceError(f"{self.path}: frames read as float32 only where the source "
                              f"stores float32 (this one: {self.itemsize}-byte samples); "
                              "read them as float64")
        if not 0 <= start < stop <= self.frames:
            raise SourceError(f"{self.path}: frames {start}..{stop - 1} requested of "
                              f"0..{self.frames - 1}")
        H = self.shape[3]
        r0, r1 = (0, H) if rows is None else (int(rows[0]), int(rows[1]))
        if not 0 <= r0 < r1 <= H:
            raise SourceError(f"{self.path}: rows {r0}..{r1 - 1} requested of 0..{H - 1}")
        return self._reader.read(start, stop, r0, r1, dtype)

    @property
    def itemsize(self) -> int:
        """Bytes per sample of the frames a read returns at their narrowest: 4 for a
        recording stored as float32 (what a kept frame holds), else 8 (float64: the
        formats that decode images or hold a volume read as float64)."""
        return int(getattr(self._reader, "itemsize", 8))

    def cache_frames(self, n: int) -> None:
        """Keep up to ``n`` decoded frames for later reads where the format decodes frames
        (a recording store: steps whose windows overlap decode each frame once); a no-op
        for the others."""
        keep = getattr(self._reader, "cache_frames", None)
        if keep is not None:
            keep(n)

    def keep_values(self, n: int) -> None:
        """Keep what :meth:`frame_value` computes for up to ``n`` frames where the format
        decodes frames (a recording store); a no-op for the others."""
        keep = getattr(self._reader, "keep_values", None)
        if keep is not None:
            keep(n)

    @property
    def values_kept(self) -> int:
        """Frames whose :meth:`frame_value` results are kept (0: none)."""
        return int(getattr(self._reader, "values_kept", 0))

    def frame_value(self, t: int, key, fn, dtype=np.float64):
        """``fn(frame)`` for frame ``t`` (shape (Sy, Sx, H, W), read as ``dtype``, as
        :meth:`read` reads it), kept under ``key`` for later calls where
        :meth:`keep_values` asked for it: the estimator's per-frame work of a
        :class:`gridflow.estimator.signals.FramedVolume`, done once for the steps that
        share the frame."""
        dtype = np.dtype(dtype)
        if dtype == np.float32 and self.itemsize != 4:
            # read()'s rule: float32 only as stored (a float64 frame would be rounded)
            return fn(self.read(int(t), int(t) + 1, dtype=dtype)[0])
        value = getattr(self._reader, "frame_value", None)
        if value is not None and self.values_kept:
            # the type is part of the key: a value computed from the frame as float32
            # is not one computed from it as float64
            return value(int(t), (dtype.str, key), fn, dtype)
        return fn(self.read(int(t), int(t) + 1, dtype=dtype)[0])

    def span_value(self, t: int, span, key, fn):
        """``fn()``, a value computed from frames ``span`` (through :meth:`frame_value`),
        kept under frame ``t`` and ``key`` where :meth:`keep_values` asked for it, for
        later calls while the frames of ``span`` are those it was computed from: a
        frame's filtered signals, from the camera sums of the frames its temporal taps
        reach (:class:`gridflow.estimator.signals.FramedVolume`)."""
        value = getattr(self._reader, "span_value", None)
        if value is not None and self.values_kept:
            return value(int(t), tuple(int(u) for u in span), key, fn)
        return fn()

    def truth(self, frame: int, names=None) -> dict[str, np.ndarray]:
        """Ground truth at the reference camera and ``frame``: name to ``(H, W)`` float64,
        for ``names`` (default all of :attr:`truth_names`); empty where the source has
        none for that frame."""
        if not (isinstance(frame, (int, np.integer)) and 0 <= frame < self.frames):
            raise SourceError(f"{self.path}: truth of frame {frame!r} requested of "
                              f"0..{self.frames - 1}")
        if not self.truth_names or (self.truth_frame is not None
                                    and frame != self.truth_frame):
            return {}
        names = self.truth_names if names is None else tuple(names)
        return self._reader.truth(frame, names)

    def identity(self) -> dict:
        """What identifies the source for a resume key: its path, kind, shape, geometry
        and pixel type; not its content (frames may be added or repaired: each step keeps
        a :meth:`stamp` of the frames it read instead)."""
        g = self.geometry
        return {"path": str(Path(self.path).resolve()), "shape": list(self.shape),
                "focal_length": g.focal_length, "camera_spacing": list(g.camera_spacing),
                "principal_point": list(g.principal_point),
                "frame_interval": g.frame_interval, **self._reader.identity(),
                **({} if self.times is None else
                   {"times_s": [float(t) for t in np.asarray(self.times)]})}

    def stamp(self, start: int, stop: int) -> int:
        """A 63-bit stamp of frames ``start .. stop - 1`` as stored: their files' names,
        sizes and modification times (reading every byte is not an option).  A step whose
        frames' stamp changed since it was estimated is estimated again."""
        import hashlib

        h = hashlib.sha1()
        for p, size, mtime in file_states(self._reader.files(start, stop)):
            if size is None:
                h.update(f"{p.name}\0missing\n".encode())
            else:
                h.update(f"{p.name}\0{size}\0{mtime}\n".encode())
        return int.from_bytes(h.digest()[:8], "little") >> 1

    def load(self) -> GridVolume:
        """The whole sequence in memory, with the truth of :attr:`truth_frame` (or of the
        reference frame)."""
        vol = self.read(0, self.frames)
        k = self.truth_frame if self.truth_frame is not None else (
            self.ref_frame if self.ref_frame is not None else (self.frames - 1) // 2)
        meta = {**self.meta, "ref_frame": self.ref_frame,
                "frame_interval": self.geometry.frame_interval}
        return GridVolume(vol, self.geometry.focal_length, self.geometry.camera_spacing,
                          self.geometry.principal_point, self.truth(k), meta)


class ArrayReader:
    """The reader of a source already in memory (a volume file, an HCI scene): ``files``
    are the files it was read from, for :meth:`Source.stamp`."""

    def __init__(self, volume: np.ndarray, truth: dict, files: list, identity: dict):
        self.volume, self._truth, self._files, self._identity = volume, truth, files, identity

    def read(self, start: int, stop: int, r0: int, r1: int, dtype=np.float64) -> np.ndarray:
        return np.asarray(self.volume[start:stop, :, :, r0:r1], dtype=dtype)

    def truth(self, frame: int, names: tuple) -> dict:
        return {n: np.asarray(self._truth[n], dtype=np.float64) for n in names
                if n in self._truth}

    def identity(self) -> dict:
        return dict(self._identity)

    def files(self, start: int, stop: int) -> list[Path]:
        return list(self._files)


def source_from_volume(path, data: GridVolume, kind: str, files=None,
                       ref_frame: int | None = None) -> Source:
    """A :class:`Source` over a volume in memory (its truth at the reference frame)."""
    T, Sy, Sx, H, W = data.volume.shape
    ref = ref_frame if ref_frame is not None else data.meta.get("ref_frame")
    truth_frame = ref if ref is not None else (T - 1) // 2
    reader = ArrayReader(data.volume, dict(data.truth), files or [Path(path)],
                         {"kind": kind, "dtype": str(data.volume.dtype)})
    return Source(Path(path), data.volume.shape, data.geometry, kind,
                  tuple(sorted(data.truth)), truth_frame, ref, dict(data.meta), reader)
