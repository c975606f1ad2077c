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

import fcntl
import json
import os
import tempfile
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .errors import FileFormatError, GridflowError
from .volume import GridVolume

__all__ = ["save_volume", "load_volume", "save_estimate", "save_estimates", "load_estimate",
           "load_npz_maps",
           "atomic_write", "atomic_write_set", "check_output", "OutputError",
           "check_input_file", "remove_temporaries"]


# Every temporary file or folder this process has made and not yet renamed or removed,
# with the process and the thread that made it (a forked child inherits the registry but
# not the files; another thread's may still be being written).  A writer removes its own
# on failure, but one spot cannot be guarded from inside: a signal acted on as
# ``__exit__`` starts (CPython looks for signals at a function's start), before its try.
# The CLI's interrupt handler, and atexit, remove what is left.
_LIVE: dict[str, tuple] = {}        # absolute name: (pid, thread, its open file or None)


def _keep(path, fh=None) -> None:
    import threading

    _LIVE[os.path.abspath(path)] = (os.getpid(), threading.current_thread(), fh)


def _drop(path) -> None:
    _LIVE.pop(os.path.abspath(path), None)


def remove_temporaries() -> list[str]:
    """Remove the temporary files and folders this process's atomic writers made and
    neither renamed nor removed (an interrupt at a moment no writer can guard); the
    targets are untouched.  Those of another thread that is still running are left to
    it (it may be writing them).  SIGINT and SIGTERM wait until it is done.

    Returns
    -------
    list of str
        The absolute names removed.
    """
    import shutil
    import threading

    removed = []
    me = threading.current_thread()
    with signals_deferred():
        for path, (pid, thread, fh) in list(_LIVE.items()):
            if pid != os.getpid() or (thread is not me and thread.is_alive()):
                continue
            if fh is not None:
                try:
                    fh.close()
                except OSError:         # a failed flush: the file is removed anyway
                    pass
            try:
                if os.path.isdir(path) and not os.path.islink(path):
                    shutil.rmtree(path)
                else:
                    os.unlink(path)
                removed.append(path)
            except FileNotFoundError:
                pass
            except OSError:             # a folder made read-only since: left, not raised
                continue
            _drop(path)
    return removed


def _register_atexit() -> None:
    import atexit

    atexit.register(remove_temporaries)


_register_atexit()


class OutputError(GridflowError):
    """An output path that must not be written; raised before anything is written."""


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_output(path, *, suffixes, inputs=(), what: str = "output") -> Path:
    """Check an output path before any work is done; every command that writes uses it.

    Refused (with :class:`OutputError`, nothing written): a name whose extension is not
    one of ``suffixes`` (the format written), an existing path that is not a regular file
    (a folder, a device such as ``/dev/null``, a FIFO, a symbolic link: the atomic rename
    would replace it), a path that is one of ``inputs`` (no output replaces an input) or
    lies inside an input folder (nor lands inside one), and
    a parent that exists but is not a folder, a name longer than the file system allows,
    and a folder that cannot be written (read-only, or a read-only file system).

    Parameters
    ----------
    path : path-like
    suffixes : str or tuple of str
        Allowed extensions, with the dot (``".npz"``); ``None`` for a folder output.
    inputs : iterable of path-like
        The command's inputs.
    what : str
        What the path is, for the message (``"-o"``, ``"--csv"``).

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    limit = name_max(path.parent)
    long = [part for part in path.parts if len(os.fsencode(part)) > limit]
    if long:
        raise OutputError(f"{what} {path}: the name {long[0][:40]}... has "
                          f"{len(os.fsencode(long[0]))} bytes; this file system allows "
                          f"{limit}")
    if suffixes is None:                    # an output folder
        if path.exists() and not path.is_dir():
            raise OutputError(f"{what} {path}: exists and is not a folder")
        _refuse_inside(path, inputs, what)
        _check_writable(path if path.is_dir() else path.parent, path, what)
        return path
    suffixes = (suffixes,) if isinstance(suffixes, str) else tuple(suffixes)
    if path.suffix.lower() not in suffixes:
        raise OutputError(f"{what} {path}: expected a {' or '.join(suffixes)} file name "
                          f"(the format written), got {path.suffix or 'no extension'!r}")
    if path.is_symlink() or (path.exists() and not path.is_file()):
        raise OutputError(f"{what} {path}: exists and is not a regular file; refusing to "
                          "replace it")
    for inp in inputs:
        inp = Path(inp)
        if _same_file(path, inp) or path.resolve() == inp.resolve():
            raise OutputError(f"{what} {path}: is an input of this command ({inp}); "
                              "choose another output name")
    _refuse_inside(path, inputs, what)
    parent = _existing_ancestor(path.parent)
    if not parent.is_dir():
        raise OutputError(f"{what} {path}: {parent} is not a folder")
    _check_writable(parent, path, what)
    return path


def _refuse_inside(path: Path, inputs, what: str) -> None:
    """Refuse an output that would land inside an input folder (a Zarr store, an image
    folder): writing there changes the input."""
    target = path.resolve()
    for inp in inputs:
        inp = Path(inp)
        if target == inp.resolve():
            raise OutputError(f"{what} {path}: is the input of this command ({inp}); "
                              "choose another output name")
        if inp.is_dir() and target.is_relative_to(inp.resolve()):
            raise OutputError(f"{what} {path}: lies inside {inp}, which is the input of "
                              "this command; no output is written inside an input, choose "
                              "another place")


def _check_writable(folder: Path, path: Path, what: str) -> None:
    """Refuse an output whose folder (or nearest existing ancestor) cannot be written:
    the work would be done and then lost at the rename."""
    folder = _existing_ancestor(folder)
    if not os.access(folder, os.W_OK | os.X_OK):
        why = "a read-only file system" if _read_only_fs(folder) else "not writable"
        raise OutputError(f"{what} {path}: cannot write into {folder} ({why})")


def _existing_ancestor(folder: Path) -> Path:
    """``folder`` or its nearest ancestor that exists (the one an output's folders would
    be made in)."""
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


def _read_only_fs(folder: Path) -> bool:
    try:
        return bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def name_max(folder) -> int:
    """The longest file name the file system of ``folder`` (or its nearest existing
    ancestor) allows (255 where it does not say)."""
    folder = _existing_ancestor(Path(folder))
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError):
        return 255


def temp_prefix(path) -> str:
    """The prefix of the temporary file or folder an output is written to before it is
    renamed into place: the output's name, shortened so that the temporary name
    (prefix, 8 random characters, ``.tmp``) fits the file system's name limit."""
    path = Path(path)
    keep = max(1, name_max(path.parent) - 16)
    return f".{path.name[:keep]}."


def check_input_file(path, what: str = "input") -> Path:
    """An input that must be an existing regular file (a FIFO would block reading)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{what} {path}: no such file")
    if not path.is_file():
        raise FileFormatError(f"{what} {path}: not a regular file")
    return path


def current_umask() -> int:
    """The process's umask (reading it means setting it: set back at once)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


class atomic_write:
    """Context manager yielding a file whose content replaces ``path`` on success.

    The content goes to a temporary file beside ``path`` that is renamed over it only when
    the block succeeds; on any failure (also a failed close or rename) the temporary file
    is removed and ``path`` is untouched.  An existing ``path`` that is not a regular file
    is refused (see :func:`check_output`).
    """

    def __init__(self, path, mode: str = "wb"):
        self.path = Path(path)
        self.mode = mode
        self.tmp = None             # the temporary file's name, once it exists
        self.fh = None

    def __enter__(self):
        if self.path.is_symlink() or (self.path.exists() and not self.path.is_file()):
            raise OutputError(f"{self.path}: exists and is not a regular file; refusing to "
                              "replace it")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError):
            raise OutputError(f"{self.path}: its folder {self.path.parent} cannot be made "
                              "(a file of that name is in the way)") from None
        try:
            # a signal between the file's creation and the line that keeps its name would
            # leave it behind (CI saw one in 100 random-time signals): SIGINT and SIGTERM
            # wait until the name is kept, and then raise inside this try
            with signals_deferred():
                fd, tmp = tempfile.mkstemp(prefix=temp_prefix(self.path), suffix=".tmp",
                                           dir=self.path.parent)
                self.tmp = tmp
                _keep(tmp)
                try:
                    self.fh = os.fdopen(fd, self.mode)
                except BaseException:
                    os.close(fd)
                    raise
                _keep(tmp, self.fh)
            # returned inside the try: an interrupt on the way out of __enter__ has no
            # __exit__ to remove the temporary
            return self.fh
        except BaseException:
            self.discard()
            raise

    def discard(self) -> None:
        """Close and remove the temporary file, if there is one; ``path`` is untouched."""
        try:
            if self.fh is not None:
                self.fh.close()
        finally:
            if self.tmp is not None:
                _unlink(self.tmp)

    def __exit__(self, exc_type, exc, tb):
        try:
            self.fh.close()
            if exc_type is None:
                # mkstemp makes the file private (0600); give it the usual umask permissions
                os.chmod(self.tmp, 0o666 & ~current_umask())
                os.replace(self.tmp, self.path)
                _drop(self.tmp)
                return False
        except BaseException:
            self.discard()          # closes the file too, if the interrupt came first
            raise
        self.discard()
        return False


def _unlink(path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    _drop(path)


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
    path = check_input_file(path)
    # numpy reads a file that is no zip archive as a pickle and answers with advice to
    # allow pickles: say what the file is not instead
    if not zipfile.is_zipfile(path):
        raise FileFormatError(f"{path}: not a zip archive, so not an .npz file (write one "
                              "with numpy.savez or gridflow generate)")
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise FileFormatError(f"{path}: not a readable .npz file ({exc})") from exc


_VOLUME_KEYS = {"volume", "focal_length", "camera_spacing", "principal_point", "meta"}


def _numbers(z, key: str, path, n: int) -> np.ndarray:
    """``n`` finite numbers stored under ``key``, or a ValueError naming file and key."""
    try:
        arr = np.asarray(z[key], dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise FileFormatError(f"{path}: '{key}' must hold numbers ({exc})") from None
    if arr.size != n or not np.all(np.isfinite(arr)):
        want = "a finite scalar" if n == 1 else f"{n} finite numbers"
        raise FileFormatError(f"{path}: '{key}' must be {want}, got {arr.tolist()}")
    return arr


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
            raise FileFormatError(f"{path}: missing array(s) {sorted(missing)}; a volume file needs "
                             "volume, focal_length, camera_spacing")
        try:
            vol = z["volume"]
        except Exception as exc:  # corrupted member
            raise FileFormatError(f"{path}: cannot read 'volume' ({exc})") from exc
        if vol.ndim != 5:
            raise FileFormatError(f"{path}: 'volume' must have shape (T, Sy, Sx, H, W); got {vol.shape}")
        unknown = sorted(k for k in keys - _VOLUME_KEYS if not k.startswith("truth_"))
        if unknown:
            raise FileFormatError(f"{path}: unknown array(s) {unknown}; a volume file holds "
                             f"{sorted(_VOLUME_KEYS)} and truth_<name> maps")
        f = _numbers(z, "focal_length", path, 1)
        sp = _numbers(z, "camera_spacing", path, 2)
        if not f[0] > 0:
            raise FileFormatError(f"{path}: 'focal_length' must be a positive number of pixels, "
                             f"got {f[0]}")
        H, W = vol.shape[-2:]
        if "principal_point" in keys:
            pp = _numbers(z, "principal_point", path, 2)
            pp = (float(pp[0]), float(pp[1]))
        else:
            pp = ((W - 1) / 2.0, (H - 1) / 2.0)
        truth = {}
        for k in keys:
            if k.startswith("truth_"):
                arr = z[k]
                if arr.shape != (H, W):
                    raise FileFormatError(f"{path}: '{k}' has shape {arr.shape}, expected {(H, W)}")
                truth[k[6:]] = arr
        meta = _meta(z, path) if "meta" in keys else {}
    return GridVolume(vol, float(f[0]), (float(sp[0]), float(sp[1])), pp, truth, meta)


def _meta(z, path) -> dict:
    try:
        meta = json.loads(str(z["meta"]))
    except (json.JSONDecodeError, ValueError) as exc:
        raise FileFormatError(f"{path}: 'meta' is not a JSON string ({exc})") from None
    if not isinstance(meta, dict):
        raise FileFormatError(f"{path}: 'meta' must hold a JSON object")
    return meta


def _estimate_arrays(est) -> dict:
    """The arrays of an estimate ``.npz``: the maps, ``interior`` and ``meta`` (JSON)."""
    arrays = {k: np.asarray(v, np.float64) for k, v in est.maps.items()}
    arrays["interior"] = est.interior
    arrays["meta"] = np.array(json.dumps({"model": est.model, "settings": est.settings}))
    return arrays


def save_estimate(path, est) -> None:
    """Write an :class:`estimator.Estimate` as an estimate ``.npz``."""
    with atomic_write(path) as fh:
        np.savez(fh, **_estimate_arrays(est))


def save_estimates(outputs: dict) -> None:
    """Write several :class:`estimator.Estimate` as ``.npz`` files that replace their paths
    together (:class:`atomic_write_set`): a failure part-way (a full disk) leaves none of
    them changed, and two runs writing the same set leave one run's set, not a mix.

    Parameters
    ----------
    outputs : dict of path to Estimate
    """
    paths = list(outputs)
    with atomic_write_set(paths) as handles:
        for fh, est in zip(handles, outputs.values()):
            np.savez(fh, **_estimate_arrays(est))


class atomic_write_set:
    """Context manager yielding one file per path; all replace their paths only when the
    block succeeds for all of them.

    Each content goes to a temporary file beside its path (:class:`atomic_write`); on
    success they are renamed over their paths while an exclusive lock (``flock``) is held
    on the first path's folder, so that two processes writing the same set one after the
    other leave the later one's set whole.  On any failure every temporary file is removed
    and no path is touched.  SIGINT and SIGTERM are held back during the renames (a
    signal there would leave a mixed set); only SIGKILL, which nothing can hold back, can
    stop them part-way.
    """

    def __init__(self, paths, mode: str = "wb"):
        self.writers = [atomic_write(p, mode) for p in paths]

    def __enter__(self):
        try:
            for w in self.writers:
                w.__enter__()
            # built and returned inside the try: an interrupt while the handles are
            # gathered (CI met one) has no __exit__ to remove the temporaries
            return [w.fh for w in self.writers]
        except BaseException:
            self._discard()
            raise

    def _discard(self):
        # every writer whose temporary file exists, also one a signal hit right after its
        # __enter__ returned (counting the handles received would miss it)
        errors = []
        for w in self.writers:
            try:
                w.discard()
            except BaseException as exc:        # close the others all the same
                errors.append(exc)
        if errors:
            raise errors[0]

    def __exit__(self, exc_type, exc, tb):
        try:
            if exc_type is not None:
                self._discard()
                return False
            for w in self.writers:
                w.fh.close()
            # an interrupt between two renames would leave a set of outputs from two
            # runs, and one between opening the lock's folder and closing it would keep
            # the lock for the process's life: SIGINT and SIGTERM wait until both are done
            with signals_deferred():
                fd = os.open(self.writers[0].path.parent, os.O_RDONLY)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX)
                    mode = 0o666 & ~current_umask()
                    for w in self.writers:
                        os.chmod(w.tmp, mode)
                        os.replace(w.tmp, w.path)
                        _drop(w.tmp)
                finally:
                    os.close(fd)            # releases the lock
        except BaseException:
            self._discard()
            raise
        return False


@contextmanager
def folder_beside(path):
    """A temporary folder beside ``path`` to build a folder output in (yielded), with a new
    folder's permissions; the caller renames it to ``path`` when whole.  Whatever is left
    of it when the block ends (a failure, a signal, or no rename) is removed, so an
    interrupted output leaves nothing at ``path``."""
    import shutil

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = None
    try:
        # the folder and the name that removes it come into being together: a signal in
        # between would leave the folder behind
        with signals_deferred():
            tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(path), suffix=".tmp",
                                        dir=path.parent))
            _keep(tmp)
        # mkdtemp's folder is the owner's alone
        os.chmod(tmp, 0o777 & ~current_umask())
        yield tmp
    finally:
        if tmp is not None:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
            _drop(tmp)


@contextmanager
def signals_deferred():
    """SIGINT and SIGTERM received inside the block are acted on when it ends.

    The Python-level handlers are swapped for ones that only note the signal (blocking
    it with ``pthread_sigmask`` is not enough: in a process with other threads, BLAS's
    or numba's, the kernel hands a process-wide signal to one that does not block it).
    Handlers can only be set from the main thread; elsewhere the block runs as it is.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    kinds = (signal.SIGINT, signal.SIGTERM)
    got: list[int] = []
    old = {s: signal.getsignal(s) for s in kinds}
    for s in kinds:
        signal.signal(s, lambda signum, frame: got.append(signum))
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
        if got:
            handler = old[got[0]]
            if callable(handler):
                handler(got[0], None)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(got[0])


def load_npz_maps(path) -> dict[str, np.ndarray]:
    """Read an ``.npz`` of maps (a method's output, :mod:`gridflow.bench.methods`): every
    array under its name; a ``meta`` entry, if any, is left out."""
    with _open_npz(path) as z:
        try:
            return {k: z[k] for k in z.files if k != "meta"}
        except (ValueError, OSError, zipfile.BadZipFile) as exc:
            raise FileFormatError(f"{path}: an array does not read ({exc})") from None


def load_estimate(path) -> tuple[dict[str, np.ndarray], np.ndarray, dict]:
    """Read an estimate ``.npz``; returns ``(maps, interior, meta)``."""
    with _open_npz(path) as z:
        if "interior" not in z.files:
            raise FileFormatError(f"{path}: not an estimate file (no 'interior' array)")
        maps = {k: z[k] for k in z.files if k not in ("interior", "meta")}
        interior = z["interior"].astype(bool)
        meta = _meta(z, path) if "meta" in z.files else {}
        shapes = {k: v.shape for k, v in maps.items() if v.shape != interior.shape}
        if interior.ndim != 2 or shapes:
            raise FileFormatError(f"{path}: every map must have the shape of 'interior' "
                             f"{interior.shape}; these differ: {shapes}")
    return maps, interior, meta
