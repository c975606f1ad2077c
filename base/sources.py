"""Sources: every input format behind one lazy interface and one registry (edge: file I/O).

In the style of xarray's backends: each format is a :class:`SourceBackend` that says
whether it can open a path (:meth:`~SourceBackend.guess_can_open`) and opens it as a
:class:`Source` without decoding more than it must.  :func:`open_source` is the one
dispatcher every command uses; :data:`BACKENDS` lists the formats in the order they are
asked.

=========  ==============================================  =================================
name       what                                            reads
=========  ==============================================  =================================
``zarr``   a recording store (:mod:`gridflow.recording`)   the frames asked for, lazily
``folder`` a camera-grid image folder with ``grid.json``   the images asked for, lazily
           (:mod:`gridflow.loader`)
``hci``    an HCI 4-D light field scene folder             all views on open (one frame)
           (:mod:`gridflow.hci`)
``npz``    a volume ``.npz`` (:mod:`gridflow.io`)           the whole volume on open
=========  ==============================================  =================================

A :class:`Source` gives its shape ``(T, Sy, Sx, H, W)``, its camera geometry as one
object (:class:`gridflow.volume.CameraGeometry`), frames or row bands on demand
(:meth:`Source.read`), ground truth where it has it (:meth:`Source.truth`: per frame in a
recording, at the reference frame in a volume), what identifies it for a resume key
(:meth:`Source.identity`) and a cheap stamp of the files a window of frames was read from
(:meth:`Source.stamp`).
"""

from __future__ import annotations

from pathlib import Path

from .volume import Source, SourceError, check_geometry, source_from_volume

__all__ = ["Source", "SourceBackend", "BACKENDS", "open_source", "guess_backend",
           "SourceError"]


class SourceBackend:
    """One input format: whether it can open a path, and opening it.

    Subclasses set :attr:`name` and :attr:`description` and implement
    :meth:`guess_can_open` (cheap: file names and small metadata only) and :meth:`open`.
    """

    name = ""
    description = ""

    def guess_can_open(self, path: Path) -> bool:
        raise NotImplementedError

    def open(self, path: Path, **options) -> Source:
        raise NotImplementedError


class ZarrBackend(SourceBackend):
    name = "zarr"
    description = "a gridflow recording store (Zarr, gridflow record)"

    def guess_can_open(self, path):
        return path.is_dir() and (path / "zarr.json").is_file()

    def open(self, path, **options):
        from .recording import open_recording_store

        return open_recording_store(path)


class FolderBackend(SourceBackend):
    name = "folder"
    description = "a camera-grid image folder with grid.json"

    def guess_can_open(self, path):
        return path.is_dir() and (path / "grid.json").exists()

    def open(self, path, **options):
        from .loader import open_folder

        return open_folder(path)


class HciBackend(SourceBackend):
    name = "hci"
    description = "an HCI 4-D light field scene folder (input_Cam000.png ...)"

    def guess_can_open(self, path):
        from .hci import is_hci_scene

        return is_hci_scene(path)

    def open(self, path, views: int | None = None, **options):
        from .hci import HCI_FILES, load_hci

        data = load_hci(path, views=views)
        files = sorted(p for p in Path(path).iterdir() if HCI_FILES.match(p.name))
        return source_from_volume(path, data, self.name, files=files)


class NpzBackend(SourceBackend):
    name = "npz"
    description = "a volume .npz (gridflow generate, or numpy.savez: README)"

    def guess_can_open(self, path):
        return path.suffix.lower() == ".npz" and not path.is_dir()

    def open(self, path, **options):
        from .io import load_volume

        return source_from_volume(path, load_volume(path), self.name)


#: The formats, in the order they are asked whether they can open a path.
BACKENDS: tuple[SourceBackend, ...] = (ZarrBackend(), FolderBackend(), HciBackend(),
                                       NpzBackend())


def guess_backend(path) -> SourceBackend:
    """The backend that opens ``path``, or a :class:`SourceError` saying what each format
    needs."""
    p = Path(path)
    if not p.exists() and not p.is_symlink():
        raise SourceError(f"{path}: no such file or folder")
    for b in BACKENDS:
        if b.guess_can_open(p):
            return b
    kinds = "; ".join(f"{b.description}" for b in BACKENDS)
    raise SourceError(f"{path}: not an input gridflow reads (expected {kinds})")


def open_source(path, *, views: int | None = None) -> Source:
    """Open ``path`` with the backend that can (:data:`BACKENDS`).

    Parameters
    ----------
    path : path
    views : int, optional
        HCI scenes: the central ``views x views`` views (odd); refused for other formats.

    Raises
    ------
    SourceError, FileFormatError
        No backend opens it, or its backend finds it malformed (the message names the
        file and what was expected).
    """
    backend = guess_backend(path)
    if views is not None and backend.name != "hci":
        from .errors import UsageError

        raise UsageError(f"--views chooses the central views of an HCI scene; {path} is "
                         f"{backend.description}, which uses all its views")
    src = backend.open(Path(path), views=views)
    # every format's geometry in the ranges an estimate can use (each backend checks its
    # own keys' types; the ranges are one rule for all)
    check_geometry(src.geometry, src.shape, f"{path}")
    return src
