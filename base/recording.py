"""Recordings: camera-grid sequences too long for memory, read a window of frames at a time,
and the time series of maps estimated from them (edge: file I/O).

A **recording** is a camera grid imaged at many time instances (frames).  Two forms:

- an image folder whose ``grid.json`` names many frames (:mod:`gridflow.loader`; the
  optional ``frame_interval`` key gives the seconds between frames, ``times_s`` each
  frame's time stamp);
- a Zarr store (a folder, conventionally ``*.zarr``) written by :func:`write_recording`::

      rec.zarr/                       group; attrs["gridflow"] = {"kind": "recording", ...}
        volume   (T, Sy, Sx, H, W)    float32 intensities, one chunk per frame
        time_s   (T,)                 optional: each frame's time stamp, s (gaps allowed)
        truth/<name>  (T, H, W)       optional ground truth per frame (synthetic data)

  with ``focal_length`` (px), ``camera_spacing`` ``[ds_x, ds_y]``, ``principal_point``
  ``[cx, cy]``, ``frame_interval`` (s, or null) and optionally ``units`` in the group's
  attributes.

Both are opened through :func:`gridflow.sources.open_source` (this module's backend:
:func:`open_recording_store`) without reading an image: :meth:`gridflow.sources.Source.
read` decodes the frames one estimate needs and checks them (size, pixel type, finite
values), naming the file or frame that differs.

A **map series** (:class:`MapStore`) is the estimate at every K-th frame: a Zarr group
readable with ``xarray.open_zarr``::

    maps.zarr/                        attrs["gridflow"] = {"kind": "maps", "key": ..., ...}
      time  (n,)          frame index of each step     (dimension coordinate)
      time_s (n,)         seconds from the first frame (where the times are known)
      interval_s (n,)     seconds between frames in each step's window (growth per hour)
      y (H,), x (W,)      pixel row and column
      <quantity> (time, y, x)  float32, one chunk per step and row band, NaN until written
      interior (y, x)     bool: pixels free of the image border's effects (one chunk per
                          row band; a mask's object shows per step as NaN in the maps)
      stamp (time, band)  int64: the frames each step read, as they were (names, sizes, times)
      done (time, band)   uint8: 1 once every map of that step's row band is written

A step is estimated whole (one band, ``attrs["gridflow"]["band_rows"]`` = H) or, where one
step's frames would not fit the memory budget, in row bands of ``band_rows`` rows, each
its own task reading only its rows (and the filters' halo around them).  Each band is its
own chunk of every array, so tasks on different processes never write the same chunk.
Each chunk is written by Zarr as a temporary file renamed into place; ``done`` is set only
after all of a band's maps, so a band interrupted half-way is done again by the next run,
and so is a done step whose frames changed since (their ``stamp``: a frame repaired or
replaced).
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import numpy as np

from .volume import (CameraGeometry, Source, SourceError, check_geometry, check_times,
                     file_states)

__all__ = ["open_recording_store", "write_recording", "check_recording", "is_recording_store",
           "MapStore", "RecordingError", "RECORDING_KIND", "MAPS_KIND"]

RECORDING_KIND = "recording"
MAPS_KIND = "maps"
FORMAT_VERSION = 1
MAPS_VERSION = 2             # 2: row bands (stamp and done per step and band)


class RecordingError(SourceError):
    """A recording or map store that cannot be used; the message names the path."""


def _zarr():
    try:
        import zarr
    except ImportError as exc:        # a dependency of gridflow; missing only by hand
        raise RecordingError("zarr is not installed: pip install zarr") from exc
    return zarr


def _compressor():
    """The codec of the frames of a recording and of a map series' maps: Blosc's LZ4 on
    the bytes shuffled by position in the float32 (the exponents and high mantissa bytes
    side by side).  Measured against Zarr's default (Zstandard, level 3): on a 5 x 5 x
    512^2 frame with sensor noise, decoding 5.4 ms against 26.5 ms at a ratio of 1.24
    against 1.08; on the 23 maps of a 512^2 affine step, encoding 14 ms against 71 ms at
    2.1 against 1.7.  A long run decodes a frame and encodes a step's maps at every step:
    with Zstandard that was a tenth of a core at a step a second, with LZ4 a fiftieth
    (a step of the affine model spends about 2 CPU seconds).  Any Zarr reader
    decodes it (xarray.open_zarr included); stores made before keep their codec."""
    from zarr.codecs import BloscCodec

    return BloscCodec(cname="lz4", clevel=5, shuffle="shuffle")


def _whole_chunks(array):
    """``array`` writing every chunk, also one equal to its fill value throughout (which
    Zarr leaves out by default): in a map series a missing chunk is then damage."""
    return array.with_config({"write_empty_chunks": True})


def _node_type(meta: Path, expected: str) -> str:
    """The ``node_type`` that the Zarr metadata file ``meta`` states, or a
    :class:`RecordingError` naming the file where it is unreadable (read here, one member at
    a time: zarr's own listing of a group loads its members concurrently, and one that
    failed left the others' errors printed at exit)."""
    try:
        node = json.loads(meta.read_text()).get("node_type")
    except (OSError, ValueError, AttributeError) as exc:
        raise RecordingError(f"{meta}: unreadable ({type(exc).__name__}: {exc}); expected "
                             f"the metadata of a Zarr {expected}") from None
    return node


def _gridflow_attrs(path: Path) -> dict | None:
    """The ``gridflow`` attributes of the Zarr group at ``path``, or None when ``path`` is
    not a Zarr v3 group (read from its ``zarr.json`` without opening anything else)."""
    meta = path / "zarr.json"
    if not meta.is_file():
        return None
    try:
        doc = json.loads(meta.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(doc, dict) or doc.get("node_type") != "group":
        return None
    g = (doc.get("attributes") or {}).get("gridflow")
    return g if isinstance(g, dict) else {}


def is_recording_store(path) -> bool:
    """Whether ``path`` is a recording written by :func:`write_recording`."""
    g = _gridflow_attrs(Path(path))
    return bool(g) and g.get("kind") == RECORDING_KIND


def open_recording_store(path) -> Source:
    """Open a recording store written by :func:`write_recording` without reading a frame
    (the ``zarr`` backend of :func:`gridflow.sources.open_source`).

    Raises
    ------
    RecordingError
        A Zarr store that is not a gridflow recording, of another format version, or
        with malformed metadata (the message names the file or array).
    """
    path = Path(path)
    g = _gridflow_attrs(path)
    if g is None:
        raise RecordingError(f"{path}: not a readable Zarr v3 group (zarr.json)")
    if g.get("kind") != RECORDING_KIND:
        raise RecordingError(f"{path}: a Zarr store that is not a gridflow recording "
                             f"(attribute gridflow.kind = {g.get('kind')!r}, expected "
                             f"{RECORDING_KIND!r})")
    # a store written by this code has version 1; one without a version is a store made
    # by the user's own code (README), read as version 1
    version = g.get("version", FORMAT_VERSION)
    if version != FORMAT_VERSION:
        raise RecordingError(f"{path}/zarr.json: a recording of format {version!r}; this "
                             f"gridflow reads format {FORMAT_VERSION}")
    return _ZarrReader.open(path)


def _keep_nearest(kept: dict, capacity: int, t: int) -> None:
    """Drop the frames of ``kept`` (frame -> entry) farthest from frame ``t`` until at
    most ``capacity`` remain: steps run in order, up or down, and least-recently-used
    would drop the very frame the next step reads next (a window read backwards missed
    every frame)."""
    while len(kept) > capacity:
        del kept[max(kept, key=lambda f: (abs(f - t), f))]


class _ZarrReader:
    def __init__(self, path: Path, group):
        self.path, self.group = path, group
        self.volume = group["volume"]
        vol = self.volume
        # the unit Zarr stores: a shard where the array is sharded, else a chunk
        self._grid = tuple(getattr(vol, "shards", None) or vol.chunks)
        self._per_frame = [range(-(-n // c)) for n, c in zip(vol.shape[1:], self._grid[1:])]
        # decoded frames (see cache_frames) and what the estimator computed from a frame
        # alone (see keep_values), each frame -> (signature, {key: value}); (frame, key)
        # -> Event while a thread computes it (_memoised)
        self._cache: dict = {}
        self._pending: dict = {}
        self._capacity = 0
        self._values: dict = {}
        self._pending_values: dict = {}
        self._value_capacity = 0
        self._lock = threading.Lock()

    @property
    def itemsize(self) -> int:
        return int(self.volume.dtype.itemsize)

    def cache_frames(self, n: int) -> None:
        """Keep up to ``n`` decoded whole frames (those farthest from the frame decoded
        last dropped first), so that steps whose windows overlap decode each frame once: at 512^2 px and 5 x 5
        views decoding 17 frames took 1.0 s and their finiteness check 0.08-0.2 s, a
        third of an affine step.  A kept frame is used only while its chunk files' names,
        sizes and modification times are those it was decoded from (a frame rewritten
        since is decoded again).  ``n = 0`` (the default) keeps none."""
        with self._lock:
            self._capacity = max(0, int(n))
            while len(self._cache) > self._capacity:
                del self._cache[next(iter(self._cache))]    # the first kept

    def keep_values(self, n: int) -> None:
        """Keep what :meth:`frame_value` computed for up to ``n`` frames (as they come,
        those farthest from the frame computed last are dropped first; lowering ``n``
        drops the first kept); ``n = 0`` (the default) keeps none."""
        with self._lock:
            self._value_capacity = max(0, int(n))
            while len(self._values) > self._value_capacity:
                del self._values[next(iter(self._values))]

    @property
    def values_kept(self) -> int:
        return self._value_capacity

    def frame_value(self, t: int, key, fn, dtype):
        """``fn(frame t)`` (decoded, checked finite, as ``dtype``), kept under ``key``
        while frame ``t``'s chunk files are those it was computed from; a value another
        thread is computing is waited for, not computed twice."""
        def compute():
            # as read() reads it: a missing chunk named, an undecodable one a
            # RecordingError
            self.check_present(t, t + 1)
            try:
                frame = self._frame(t)
            except RecordingError:
                raise
            except Exception as exc:
                raise RecordingError(self._unreadable(t, t + 1, 0, self.volume.shape[3],
                                                      exc)) from None
            return fn(frame if frame.dtype == dtype else frame.astype(dtype))

        return self._memoised(self._values, self._pending_values,
                              lambda: self._value_capacity, t, key, compute)

    def span_value(self, t: int, span: tuple, key, fn):
        """``fn()`` (a value computed from frames ``span``, which reads them through
        :meth:`frame_value`), kept with frame ``t``'s values while the chunk files of
        every frame of ``span`` are those it was computed from (their signatures, taken
        before ``fn`` runs, are part of its key; a value during whose computation one of
        them changed is not kept, and a value of the same ``key`` and ``span`` from
        earlier files is dropped); waited for, not computed twice, as
        :meth:`frame_value`."""
        for u in span:
            if not 0 <= u < self.volume.shape[0]:
                raise RecordingError(f"{self.path}/volume: frame {u} requested of "
                                     f"0..{self.volume.shape[0] - 1}")
        sources = tuple(self._signature(u) for u in span)
        full = (key, span, sources)
        with self._lock:
            hit = self._values.get(t)
            if hit is not None:
                for old in [k for k in hit[1] if isinstance(k, tuple) and len(k) == 3
                            and k[:2] == (key, span) and k != full]:
                    del hit[1][old]
        value = self._memoised(self._values, self._pending_values,
                               lambda: self._value_capacity, t, full, fn)
        if tuple(self._signature(u) for u in span) != sources:
            # a frame of the span was rewritten while the value was computed from it
            with self._lock:
                hit = self._values.get(t)
                if hit is not None:
                    hit[1].pop(full, None)
        return value

    def _memoised(self, kept: dict, pending: dict, capacity, t: int, key, compute):
        """``compute()`` for frame ``t`` under ``key``, from ``kept`` (frame ->
        (signature, {key: value})) while the frame's chunk files are those it was
        computed from, else computed and kept (up to ``capacity()`` frames, the farthest
        from ``t`` dropped first); a value another thread is computing (``pending``:
        (frame, key) -> Event) is waited for, not computed twice."""
        sig = self._signature(t)
        while True:
            with self._lock:
                hit = kept.get(t)
                if hit is not None and hit[0] == sig and key in hit[1]:
                    return hit[1][key]
                event = pending.get((t, key))
                mine = event is None
                if mine:
                    event = pending[(t, key)] = threading.Event()
            if mine:
                break
            # then look again: kept by the other thread, or (it failed, or the frame was
            # dropped since) computed here
            event.wait()
        try:
            value = compute()
            with self._lock:
                most = capacity()
                if most:
                    hit = kept.get(t)
                    entry = hit[1] if hit is not None and hit[0] == sig else {}
                    entry[key] = value
                    kept[t] = (sig, entry)
                    _keep_nearest(kept, most, t)
            return value
        finally:
            with self._lock:
                del pending[t, key]
            event.set()

    def _signature(self, frame: int) -> tuple:
        return tuple(file_states(self.files(frame, frame + 1)))

    def _frame(self, t: int) -> np.ndarray:
        """Frame ``t`` decoded and checked, from the cache where it is still current; a
        frame another thread is decoding is waited for, not decoded twice."""
        def decode():
            frame = np.asarray(self.volume[t])
            self._check_finite(frame, t)
            return frame

        return self._memoised(self._cache, self._pending, lambda: self._capacity, t,
                              "frame", decode)

    def _check_finite(self, out: np.ndarray, start: int) -> None:
        bad = ~np.isfinite(out)
        if bad.any():
            k = int(np.argwhere(bad)[0][0]) + start if out.ndim == 5 else start
            raise RecordingError(f"{self.path}/volume: frame {k} holds non-finite intensities "
                                 "(NaN or inf: a frame never written, or damaged)")

    def chunk_keys(self, frame: int) -> list[str]:
        """The store keys (paths under ``volume/``) of the chunks holding ``frame`` (with
        several frames per chunk, those shared with its neighbours: their stamp changes
        with any of them)."""
        import itertools

        enc = self.volume.metadata.encode_chunk_key
        k = frame // self._grid[0]
        return [enc((k, *idx)) for idx in itertools.product(*self._per_frame)]

    def check_present(self, start: int, stop: int) -> None:
        """Every chunk of frames ``start..stop - 1`` is in the store, or a
        :class:`RecordingError` naming the frame and the file.  Zarr reads a missing chunk
        as the array's fill value: a frame deleted from a store whose fill value is 0 would
        read as a black frame."""
        fv = self.volume.fill_value
        for t in range(start, stop):
            for key in self.chunk_keys(t):
                if not (self.path / "volume" / key).is_file():
                    raise RecordingError(
                        f"{self.path}/volume/{key}: frame {t}'s chunk is missing (never "
                        f"written or deleted; Zarr would read it as the fill value {fv}, "
                        "and does not store a chunk that equals its fill value throughout: "
                        "write recordings with fill_value NaN)")

    @classmethod
    def open(cls, path: Path) -> Source:
        zarr = _zarr()
        # what each member is, from its metadata: a volume that is a group, or a truth that
        # is one array, is named here (it was an AttributeError's traceback)
        for name, kind in (("volume", "array"), ("truth", "group")):
            meta = path / name / "zarr.json"
            if name == "truth" and not meta.exists():
                continue
            node = _node_type(meta, kind)
            if node != kind:
                want = ("an array (the frames, (T, Sy, Sx, H, W))" if name == "volume" else
                        "a group (of truth arrays, (T, H, W) each)")
                raise RecordingError(f"{path}/{name}: a Zarr {node}, expected {want}")
        try:
            group = zarr.open_group(str(path), mode="r")
            vol = group["volume"]
        except Exception as exc:        # zarr raises many kinds for a damaged store
            raise RecordingError(f"{path}: unreadable recording store ({type(exc).__name__}: "
                                 f"{exc})") from None
        a = dict(group.attrs)
        if vol.ndim != 5 or min(vol.shape) < 1:
            raise RecordingError(f"{path}/volume: shape {vol.shape}, expected (T, Sy, Sx, H, W)")
        if vol.dtype.kind != "f":
            raise RecordingError(f"{path}/volume: pixel type {vol.dtype}, expected float")

        def numbers(key, n, positive=True):
            v = a.get(key)
            ok = (isinstance(v, list) and len(v) == n
                  and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                          and np.isfinite(x) for x in v))
            if not ok or (positive and not all(x > 0 for x in v)):
                raise RecordingError(f"{path}/zarr.json: attribute {key!r} must be {n} finite "
                                     f"{'positive ' if positive else ''}numbers, got {v!r}")
            return tuple(float(x) for x in v)

        f, = _numbers_scalar(a, "focal_length", path)
        ds = numbers("camera_spacing", 2)
        T, Sy, Sx, H, W = vol.shape
        pp = (numbers("principal_point", 2, positive=False) if a.get("principal_point")
              is not None else ((W - 1) / 2.0, (H - 1) / 2.0))
        fi = a.get("frame_interval")
        if fi is not None:
            fi, = _numbers_scalar(a, "frame_interval", path)
        times = None
        if "time_s" in group:
            try:
                raw = np.asarray(group["time_s"][...])
            except Exception as exc:
                raise RecordingError(f"{path}/time_s: unreadable ({type(exc).__name__}: "
                                     f"{exc})") from None
            times = check_times(raw, T, f"{path}/time_s")
        names = ()
        if (path / "truth").is_dir():
            # each truth array opened by itself (_node_type)
            names = tuple(sorted(p.name for p in (path / "truth").iterdir() if p.is_dir()))
            for n in names:
                meta = path / "truth" / n / "zarr.json"
                if _node_type(meta, "array") != "array":
                    raise RecordingError(f"{path}/truth/{n}: not a Zarr array (expected the "
                                         f"truth {n}, (T, H, W))")
                try:
                    arr = group["truth"][n]
                except Exception as exc:
                    raise RecordingError(f"{meta}: unreadable ({type(exc).__name__}: "
                                         f"{exc})") from None
                if arr.shape != (T, H, W):
                    raise RecordingError(f"{path}/truth/{n}: shape {arr.shape}, expected "
                                         f"{(T, H, W)}")
        units = a.get("units")
        if units is not None and not isinstance(units, str):
            raise RecordingError(f"{path}/zarr.json: attribute 'units' must be a string (the "
                                 f"world unit of lengths), got {units!r}")
        return Source(path, vol.shape, CameraGeometry(f, ds, pp, fi, units or "world units"),
                      "zarr", names, None,
                      None, {"source": (a.get("gridflow") or {}).get("source")},
                      cls(path, group), times)

    def read(self, start: int, stop: int, r0: int, r1: int, dtype=np.float64) -> np.ndarray:
        T, Sy, Sx, H, W = self.volume.shape
        self.check_present(start, stop)
        if self._capacity and (r0, r1) == (0, H):
            out = np.empty((stop - start, Sy, Sx, H, W), dtype=dtype)
            try:
                for t in range(start, stop):
                    out[t - start] = self._frame(t)
            except RecordingError:
                raise
            except Exception as exc:
                raise RecordingError(self._unreadable(start, stop, r0, r1, exc)) from None
            return out
        try:
            if (r0, r1) == (0, H):
                out = np.asarray(self.volume[start:stop], dtype=dtype)
            else:
                # a band frame by frame: Zarr decodes whole chunks (one frame each), so a
                # band of many frames read at once would hold all of them decoded (measured
                # at 9 frames of 5 x 5 x 512^2: peak 357 MiB for a 74 MiB band, 257 frame by
                # frame).  Whole frames are read at once: frame by frame raised a whole
                # step's peak (1.13 -> 1.30 GiB, glibc keeping the freed chunk buffers).
                out = np.empty((stop - start, Sy, Sx, r1 - r0, W), dtype=dtype)
                for t in range(start, stop):
                    out[t - start] = self.volume[t, :, :, r0:r1]
        except Exception as exc:
            raise RecordingError(self._unreadable(start, stop, r0, r1, exc)) from None
        self._check_finite(out, start)
        return out

    def _unreadable(self, start, stop, r0, r1, exc) -> str:
        """The message for frames that Zarr could not decode: the first frame that fails
        alone, with its chunk files."""
        for t in range(start, stop):
            try:
                self.volume[t, :, :, r0:r1]
            except Exception as e:
                keys = self.chunk_keys(t)
                where = f"volume/{keys[0]}" + (f" (or another of its {len(keys)} chunks)"
                                               if len(keys) > 1 else "")
                return (f"{self.path}/{where}: frame {t} unreadable ({type(e).__name__}: "
                        f"{e})")
        return (f"{self.path}/volume: frames {start}..{stop - 1} unreadable "
                f"({type(exc).__name__}: {exc})")

    def truth(self, frame: int, names: tuple) -> dict:
        g = self.group["truth"]
        return {n: np.asarray(g[n][frame], dtype=np.float64) for n in names}

    def identity(self) -> dict:
        return {"kind": "zarr", "dtype": str(self.volume.dtype)}

    def files(self, start: int, stop: int) -> list[Path]:
        # the chunk files holding those frames (any chunk layout, any key encoding)
        return [self.path / "volume" / key for k in range(start, stop)
                for key in self.chunk_keys(k)]


def _numbers_scalar(a: dict, key: str, path: Path) -> tuple:
    v = a.get(key)
    if not (isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
            and v > 0):
        raise RecordingError(f"{path}/zarr.json: attribute {key!r} must be a finite positive "
                             f"number, got {v!r}")
    return (float(v),)


def check_recording(path, *, shape: tuple, focal_length: float, camera_spacing: tuple,
                    principal_point: tuple | None = None, frame_interval: float | None = None,
                    truth_names: tuple = ()) -> None:
    """What :func:`write_recording` checks before any frame is made or written (a command
    that renders its frames first calls it before rendering): the geometry in the ranges
    an estimate can use (:func:`gridflow.volume.check_geometry`) and room on the disk for
    the frames (their float32 size before compression), each refused naming ``path``."""
    import shutil

    from .io import OutputError

    path = Path(path)
    T, Sy, Sx, H, W = shape
    pp = ((W - 1) / 2.0, (H - 1) / 2.0) if principal_point is None else principal_point
    check_geometry(CameraGeometry(float(focal_length), tuple(float(v) for v in camera_spacing),
                                  tuple(float(v) for v in pp),
                                  None if frame_interval is None else float(frame_interval)),
                   shape, f"{path}")
    need = 4 * T * H * W * (Sy * Sx + len(truth_names))       # float32, before compression
    # the folder it goes to, or the nearest that exists (where it will be made)
    where = next(p for p in (path.parent.absolute(), *path.parent.absolute().parents)
                 if p.exists())
    free = shutil.disk_usage(where).free
    if need > free:
        raise OutputError(f"{path}: {T} frames of {Sy}x{Sx} views of {H}x{W} px need up to "
                          f"{need / 2**30:.3g} GiB (float32, before compression); "
                          f"{where} has {free / 2**30:.3g} GiB free")


def write_recording(path, frames, *, shape: tuple, focal_length: float,
                    camera_spacing: tuple, principal_point: tuple | None = None,
                    frame_interval: float | None = None, truth_names: tuple = (),
                    source: dict | None = None, progress=None, times=None,
                    units: str | None = None) -> Path:
    """Write a recording store from an iterable of frames.

    Parameters
    ----------
    path : path
        The store (a new folder; refused if it exists).  It is written under a temporary
        name beside it and renamed when complete, or removed on failure.
    frames : iterable of (ndarray, dict)
        Per frame the views ``(Sy, Sx, H, W)`` and the truth maps ``{name: (H, W)}``.
    shape : tuple
        ``(T, Sy, Sx, H, W)``.
    focal_length, camera_spacing, principal_point, frame_interval
        As :class:`gridflow.volume.CameraGeometry`.
    truth_names : tuple of str
        The truth maps each frame carries.
    source : dict, optional
        How the recording was made (stored in the attributes).
    progress : callable, optional
        Called with the number of frames written after each.
    times : sequence of float, optional
        Each frame's time stamp in seconds (array ``time_s``): a recording with gaps
        (a missed frame, lights off at night).  Default: none, the frames
        ``frame_interval`` apart.
    units : str, optional
        The world unit of lengths (``"mm"``; attribute ``units``), default "world units".
    """
    from .io import OutputError, folder_beside

    zarr = _zarr()
    path = Path(path)
    if path.exists() or path.is_symlink():
        raise OutputError(f"{path}: exists; a recording is written to a new name")
    T, Sy, Sx, H, W = shape
    if times is not None:
        times = check_times(times, T, f"{path}: times")
    check_recording(path, shape=shape, focal_length=focal_length,
                    camera_spacing=camera_spacing, principal_point=principal_point,
                    frame_interval=frame_interval, truth_names=truth_names)
    with folder_beside(path) as tmp:
        group = zarr.open_group(str(tmp), mode="w")
        group.attrs.update({"gridflow": {"kind": RECORDING_KIND, "version": FORMAT_VERSION,
                                         "source": source or {}},
                            "focal_length": float(focal_length),
                            "camera_spacing": [float(v) for v in camera_spacing],
                            "principal_point": (None if principal_point is None else
                                                [float(v) for v in principal_point]),
                            "frame_interval": (None if frame_interval is None else
                                               float(frame_interval)),
                            **({} if units is None else {"units": str(units)})})
        vol = group.create_array("volume", shape=shape, chunks=(1, Sy, Sx, H, W),
                                 dtype="float32", fill_value=np.nan,
                                 dimension_names=("frame", "sy", "sx", "y", "x"),
                                 compressors=_compressor())
        if times is not None:
            ts = group.create_array("time_s", shape=(T,), chunks=(T,), dtype="float64",
                                    dimension_names=("frame",))
            ts[:] = times
            ts.attrs.update({"units": "s", "long_name": "time stamp of each frame"})
        tg = group.create_group("truth") if truth_names else None
        tarr = {n: tg.create_array(n, shape=(T, H, W), chunks=(1, H, W), dtype="float32",
                                   fill_value=np.nan, dimension_names=("frame", "y", "x"),
                                   compressors=_compressor())
                for n in truth_names}
        k = -1
        for k, (views, truth) in enumerate(frames):
            if k >= T:
                raise ValueError(f"more than the {T} frames stated")
            vol[k] = np.asarray(views, dtype=np.float32)
            for n in truth_names:
                tarr[n][k] = np.asarray(truth[n], dtype=np.float32)
            if progress is not None:
                progress(k + 1)
        if k + 1 != T:
            raise ValueError(f"{k + 1} frames given, {T} stated")
        os.rename(tmp, path)
    return path


class MapStore:
    """The Zarr store of a map series (see the module docstring).

    Create with :meth:`create` (or reopen one made with the same key) and write steps with
    :meth:`write_step`; any process can write any step (tasks on a cluster write their own
    steps), as each step is its own chunk of every array.
    """

    def __init__(self, path: Path, group):
        self.path, self.group = path, group
        # the arrays a step writes, opened once: opening one reads its metadata through
        # Zarr's event loop, 26 round trips a step that two steps at once waited on
        # (0.04 s a step in a long affine run, measured with py-spy).  A map series' arrays
        # are never resized or replaced once created
        self._writers = {}
        self._height = None

    @property
    def attrs(self) -> dict:
        return dict(self.group.attrs)

    @property
    def key(self) -> str:
        return self.attrs["gridflow"]["key"]

    @property
    def quantities(self) -> list[str]:
        return list(self.attrs["gridflow"]["quantities"])

    @property
    def band_rows(self) -> int:
        return int(self.attrs["gridflow"]["band_rows"])

    def bands(self) -> list[tuple[int, int]]:
        """The row bands ``(r0, r1)``, top to bottom."""
        if self._height is None:
            self._height = int(self.group["y"].shape[0])
        H = self._height
        b = self.band_rows
        return [(r0, min(r0 + b, H)) for r0 in range(0, H, b)]

    @classmethod
    def create(cls, path, *, key: str, frames: list[int], shape: tuple, quantities: list,
               frame_interval: float | None, attrs: dict,
               band_rows: int | None = None, times=None, intervals=None) -> "MapStore":
        """Make a new store (``path`` must not exist: whether an existing one is taken up
        is the caller's rule, :meth:`reopen_or_refuse`).

        ``band_rows``: rows per band (default the image's height: one band); part of the
        layout, so it belongs in ``key``.  ``times``, ``intervals`` (each shape (n,), s):
        each step's time since the first frame and frame interval, from the source's time
        stamps (``time_s``, ``interval_s``); default ``frames * frame_interval`` and
        ``frame_interval`` where that is known.
        """
        from .io import OutputError, folder_beside

        path = Path(path)
        # made under a temporary name beside it and renamed when whole: a signal, a kill
        # or a full disk while it is made leaves no store (a store without its key was
        # refused by the same command as "not gridflow's")
        with folder_beside(path) as tmp:
            cls._make(tmp, key=key, frames=frames, shape=shape, quantities=quantities,
                      frame_interval=frame_interval, attrs=attrs, band_rows=band_rows,
                      times=times, intervals=intervals)
            try:
                os.rename(tmp, path)
            except OSError:
                if not path.exists():
                    raise
                raise OutputError(f"{path}: made by another run meanwhile; run the "
                                  "command again to take it up") from None
        return cls(path, _zarr().open_group(str(path), mode="r+"))

    @classmethod
    def _make(cls, path, *, key, frames, shape, quantities, frame_interval, attrs, band_rows,
              times, intervals) -> None:
        zarr = _zarr()
        H, W = shape
        n = len(frames)
        band = H if band_rows is None else max(1, min(int(band_rows), H))
        nb = -(-H // band)
        group = zarr.open_group(str(path), mode="w")
        # every chunk written, also one equal to the fill value (a single step at frame 0):
        # a missing chunk of a store is then damage (_check_structure)
        t = group.create_array("time", shape=(n,), chunks=(n,), dtype="int64",
                               dimension_names=("time",))
        _whole_chunks(t)[:] = np.asarray(frames, dtype=np.int64)
        t.attrs.update({"long_name": "frame index"})
        coords = []
        if times is None and frame_interval is not None:
            times = np.asarray(frames, dtype=np.float64) * float(frame_interval)
            intervals = np.full(n, float(frame_interval))
        if times is not None:
            ts = group.create_array("time_s", shape=(n,), chunks=(n,), dtype="float64",
                                    dimension_names=("time",))
            _whole_chunks(ts)[:] = np.asarray(times, dtype=np.float64)
            ts.attrs.update({"units": "s", "long_name": "time since the first frame"})
            coords.append("time_s")
        if intervals is not None:
            ti = group.create_array("interval_s", shape=(n,), chunks=(n,), dtype="float64",
                                    dimension_names=("time",))
            _whole_chunks(ti)[:] = np.asarray(intervals, dtype=np.float64)
            ti.attrs.update({"units": "s", "long_name": "frame interval over the step's "
                                                        "temporal window"})
            coords.append("interval_s")
        for name, size in (("y", H), ("x", W)):
            a = group.create_array(name, shape=(size,), chunks=(size,), dtype="int64",
                                   dimension_names=(name,))
            _whole_chunks(a)[:] = np.arange(size)
        for q in quantities:
            a = group.create_array(q, shape=(n, H, W), chunks=(1, band, W), dtype="float32",
                                   fill_value=np.nan, dimension_names=("time", "y", "x"),
                                   compressors=_compressor())
            if coords:
                a.attrs.update({"coordinates": " ".join(coords)})
        group.create_array("interior", shape=(H, W), chunks=(band, W), dtype="bool",
                           fill_value=False, dimension_names=("y", "x"))
        group.create_array("stamp", shape=(n, nb), chunks=(1, 1), dtype="int64", fill_value=0,
                           dimension_names=("time", "band"))
        group.create_array("done", shape=(n, nb), chunks=(1, 1), dtype="uint8", fill_value=0,
                           dimension_names=("time", "band"))
        # chunks_complete: every chunk of a done band is written, even one equal to the
        # fill value throughout (write_band), so a missing one is damage
        group.attrs.update({**attrs, "gridflow": {"kind": MAPS_KIND, "version": MAPS_VERSION,
                                                  "key": key, "quantities": list(quantities),
                                                  "band_rows": band, "chunks_complete": True,
                                                  **attrs.get("gridflow", {})}})

    @classmethod
    def reopen_or_refuse(cls, path, key: str, inputs=()) -> "MapStore | None":
        """The store at ``path`` when it holds the run ``key``; None when there is none
        yet.

        Raises
        ------
        OutputError
            ``path`` is an input (or lies inside one), is something other than a gridflow
            map store, or holds another run's results (another key).
        """
        from .io import OutputError

        path = Path(path)
        for inp in inputs:
            inp = Path(inp).resolve()
            if path.resolve() == inp or path.resolve().is_relative_to(inp):
                raise OutputError(f"{path}: is the input {inp} or lies inside it; no output "
                                  "replaces an input")
        if not (path.exists() or path.is_symlink()):
            return None
        g = _gridflow_attrs(path) if path.is_dir() and not path.is_symlink() else None
        if g is None or g.get("kind") != MAPS_KIND:
            what = ("a gridflow " + str(g.get("kind")) if g and g.get("kind") else
                    "a Zarr store that is not gridflow's" if g is not None else
                    "not a gridflow map store")
            raise OutputError(f"{path}: exists and is {what}; refusing to write a map "
                              "series into it")
        if g.get("key") != key:
            raise OutputError(
                f"{path}: holds another run's results (input, settings, steps or code "
                f"differ: key {g.get('key')} here, {key} now); remove it or choose "
                "another name")
        return cls.open(path, mode="r+")

    @classmethod
    def reopen(cls, path, key: str) -> "MapStore":
        """Open the store made for the run ``key`` for writing (a worker's task)."""
        store = cls.open(path, mode="r+")
        if store.key != key:
            raise RecordingError(f"{path}: made anew by another run while this one ran "
                                 f"(key {store.key}, expected {key})")
        return store

    @classmethod
    def open(cls, path, mode: str = "r") -> "MapStore":
        """Open an existing map store for reading."""
        zarr = _zarr()
        path = Path(path)
        if not path.exists():
            raise RecordingError(f"{path}: no such folder (a map series is written by "
                                 "gridflow estimate INPUT -o MAPS.zarr)")
        g = _gridflow_attrs(path) if path.is_dir() else None
        if g is None or g.get("kind") != MAPS_KIND:
            raise RecordingError(f"{path}: not a gridflow map series (expected a Zarr store "
                                 "written by gridflow estimate RECORDING -o MAPS.zarr)")
        if g.get("version") != MAPS_VERSION:
            raise RecordingError(f"{path}: a map series of format {g.get('version')}, written "
                                 f"by another gridflow; this one reads format {MAPS_VERSION} "
                                 "(estimate it again into a new store)")
        store = cls(path, zarr.open_group(str(path), mode=mode))
        store._check_structure()
        return store

    def _check_structure(self) -> None:
        """The arrays and attributes every map series has, or a :class:`RecordingError`
        naming what is missing or malformed (a damaged store gave tracebacks)."""
        g = self.attrs.get("gridflow") or {}
        q = g.get("quantities")
        if not (isinstance(q, list) and q and all(isinstance(x, str) for x in q)):
            raise RecordingError(f"{self.path}/zarr.json: attribute gridflow.quantities must "
                                 f"list the maps' names, got {q!r}; the map series is "
                                 "damaged (estimate it again into a new store)")
        b = g.get("band_rows")
        if not (isinstance(b, int) and not isinstance(b, bool) and b >= 1):
            raise RecordingError(f"{self.path}/zarr.json: attribute gridflow.band_rows must be "
                                 f"a positive integer, got {b!r}; the map series is damaged "
                                 "(estimate it again into a new store)")
        # each array's metadata read one by one (_node_type); the optional coordinates
        # count where their folder is: a folder without its metadata is one lost
        names = ["time", "y", "x", "interior", "stamp", "done", *q,
                 *(a for a in ("time_s", "interval_s") if (self.path / a).is_dir())]
        missing = []
        for a in names:
            meta = self.path / a / "zarr.json"
            if not meta.is_file():
                missing.append(a)
                continue
            try:
                if _node_type(meta, "array") != "array":
                    raise ValueError("not an array")
                self.group[a]
            except Exception as exc:
                raise RecordingError(f"{meta}: unreadable ({type(exc).__name__}: {exc}); "
                                     "the map series is damaged (estimate it again into a "
                                     "new store)") from None
        if missing:
            raise RecordingError(f"{self.path}: the map series has no array "
                                 f"{', '.join(missing)}; it is damaged (estimate it again "
                                 "into a new store)")
        if g.get("chunks_complete"):
            # the coordinates, written whole when the store was made: a lost one read as
            # its fill value (a step's time 0) without a word
            for a in ("time", "y", "x", "time_s", "interval_s"):
                if (self.path / a / "zarr.json").is_file() and not (
                        self.path / a / "c" / "0").is_file():
                    raise RecordingError(f"{self.path}/{a}/c/0: missing; the map series is "
                                         "damaged (estimate it again into a new store)")
        n, H = self.group["time"].shape[0], self.group["y"].shape[0]
        nb = -(-H // b)
        for a in ("stamp", "done"):
            if self.group[a].shape != (n, nb):
                raise RecordingError(f"{self.path}/{a}: shape {self.group[a].shape}, expected "
                                     f"{(n, nb)} (steps, bands); the map series is damaged")

    def missing_chunks(self) -> list[tuple[str, int, int]]:
        """``(array, step, band)`` of every band marked done whose chunk of a map or of
        the interior is not in the store (deleted, or lost), for a store whose bands are
        written whole (attribute ``chunks_complete``; none is known for older ones)."""
        if not self.attrs["gridflow"].get("chunks_complete"):
            return []
        out = []
        done = self.band_done()
        for b in range(done.shape[1]):
            if done[:, b].any() and not (self.path / "interior" / "c" / str(b) / "0").is_file():
                out += [("interior", int(i), b) for i in np.flatnonzero(done[:, b])]
        for i, b in zip(*np.nonzero(done)):
            for q in self.quantities:
                if not (self.path / q / "c" / str(i) / str(b) / "0").is_file():
                    out.append((q, int(i), int(b)))
        return out

    def check_done(self) -> None:
        """Refuse a store a done band of which lacks a chunk (:meth:`missing_chunks`),
        naming the array, the step and its frame."""
        miss = self.missing_chunks()
        if miss:
            q, i, b = miss[0]
            f = int(self.frames()[i])
            raise RecordingError(
                f"{self.path}/{q}: step {i} (frame {f}) is marked done but its chunk "
                f"{q}/c/{i}/{b}/0 is missing ({len(miss)} chunk(s) of done steps missing); "
                "run the same gridflow estimate again to redo those steps")

    def read(self, name: str, step: int | None = None) -> np.ndarray:
        """Array ``name`` (at ``step``, or whole), read; a chunk Zarr cannot decode is a
        :class:`RecordingError` naming the array and the step."""
        try:
            a = self.group[name]
            return np.asarray(a[step] if step is not None else a[...])
        except Exception as exc:
            where = "the array"
            if step is not None:
                try:
                    where = f"step {step} (frame {int(self.group['time'][step])})"
                except Exception:        # the frame index itself unreadable
                    where = f"step {step}"
            raise RecordingError(f"{self.path}/{name}: {where} unreadable "
                                 f"({type(exc).__name__}: {exc}); the map series is damaged "
                                 "there (delete the step's chunk and run the same gridflow "
                                 "estimate again, or estimate into a new store)") from None

    def done(self) -> np.ndarray:
        """Bool per step: every band written."""
        return self.band_done().all(axis=1)

    def band_done(self) -> np.ndarray:
        """Bool per step and band, shape ``(n, bands)``."""
        return np.asarray(self.read("done"), dtype=bool)

    def frames(self) -> np.ndarray:
        return np.asarray(self.read("time"))

    def step_times(self) -> tuple:
        """``(times, intervals)``: each step's time since the first frame and its frame
        interval, seconds, shape (n,) each (from the source's time stamps, or the frame
        index times the frame interval); ``(None, None)`` where neither is known."""
        g = self.group
        n = len(self.frames())
        fi = self.attrs["gridflow"].get("frame_interval")
        times = (np.asarray(self.read("time_s"), dtype=float) if "time_s" in g else None)
        if "interval_s" in g:
            intervals = np.asarray(self.read("interval_s"), dtype=float)
        else:                     # a store written before interval_s
            intervals = np.full(n, float(fi)) if fi else None
        return times, intervals

    def stamps(self) -> np.ndarray:
        """Per step and band the stamp of the frames it read (:meth:`gridflow.sources.Source.stamp`),
        shape ``(n, bands)``."""
        return np.asarray(self.read("stamp"))

    def _writer(self, name: str):
        """Array ``name``, writing every chunk (:func:`_whole_chunks`), opened once."""
        a = self._writers.get(name)
        if a is None:
            # two threads may both open it: the same array either way
            a = self._writers[name] = _whole_chunks(self.group[name])
        return a

    def write_band(self, i: int, b: int, maps: dict, interior: np.ndarray,
                   stamp: int = 0) -> None:
        """Write band ``b`` of step ``i`` (maps and interior of its rows, shape
        ``(r1 - r0, W)``) and the stamp of the frames it read, then mark it done."""
        from .io import OutputError

        r0, r1 = self.bands()[b]
        # every chunk written, also one all NaN (a band outside the interior): Zarr leaves
        # such chunks out by default, and a done band's missing chunk is then damage
        # (missing_chunks).  Each array gets the setting itself: zarr.config is one for the
        # process, and the steps write from several threads at once
        try:
            for q in self.quantities:
                self._writer(q)[i, r0:r1] = np.asarray(maps[q], dtype=np.float32)
            # the same for every step (it depends on the image size and settings alone);
            # written by each, so that any step may come first
            self._writer("interior")[r0:r1] = np.asarray(interior, dtype=bool)
            self._writer("stamp")[i, b] = stamp
            self._writer("done")[i, b] = 1
        except OSError as exc:
            # a full disk said only "[Errno 28] No space left on device": name the store
            # and the step (the band is not marked done: the next run writes it again)
            raise OutputError(f"{self.path}: writing step {i} (rows {r0}..{r1 - 1}): "
                              f"{exc.strerror or exc}") from None
