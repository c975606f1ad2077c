"""Rendering the cube with POV-Ray into a camera-grid folder (edge: files and processes).

``render_cube(scene, root)`` renders the ``T x Sy x Sx`` images of a
:class:`scenes.CubeScene` in parallel into ``root/<scene key>/``, with the analytic ground
truth and a ``grid.json`` manifest that :func:`gridflow.loader.load_folder` reads.  Each
image is rendered from its own scene file into a temporary name and renamed into place,
so parallel renders never collide and an interrupted render leaves no half image.  The
manifest is written last: a folder with a manifest is complete, and rendering the same
scene again returns it at once (the cache).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from gridflow.io import atomic_write

from .cube import CubeScene, cube_truth

__all__ = ["RENDER_CACHE", "render_cube", "render_cube_lightfield", "povray_binary", "PovrayMissing",
           "RenderError", "IMAGE_PATTERN"]

# where renders are cached by default (relative to the working folder): every command that
# renders shares it, so a scene is rendered once
RENDER_CACHE = "work/cube"
IMAGE_PATTERN = "t{t:02d}_y{sy}_x{sx}.png"


class PovrayMissing(RuntimeError):
    """POV-Ray is not installed."""


class RenderError(RuntimeError):
    """POV-Ray failed on a scene file (its message is included)."""


def povray_binary() -> str:
    exe = shutil.which(os.environ.get("POVRAY", "povray"))
    if exe is None:
        raise PovrayMissing(
            "POV-Ray not found: the cube scenes need the `povray` program. On Debian/Ubuntu: "
            "`sudo apt-get install povray` (CI: .ci/run installs it); elsewhere see "
            "http://www.povray.org, or point $POVRAY at the binary.")
    return exe


def _render_one(exe: str, scene: CubeScene, k: int, i: int, j: int, out: Path,
                tmpdir: str) -> float:
    t0 = time.perf_counter()
    base = f"r{k}_{i}_{j}_{os.getpid()}"
    pov = Path(tmpdir) / f"{base}.pov"
    pov.write_text(scene.sdl(k, i, j))
    tmp_png = out.parent / f".{out.name}.{os.getpid()}.tmp.png"
    cmd = [exe, f"+I{pov}", f"+O{tmp_png}", f"+W{scene.width}", f"+H{scene.height}",
           "-D", "-V", "-GA", "+FN16", "Grayscale_Output=on", "File_Gamma=1.0", "-A", "+Q9",
           "+WT1", f"+L{tmpdir}"]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=tmpdir)
    if res.returncode != 0 or not tmp_png.exists():
        tmp_png.unlink(missing_ok=True)
        raise RenderError(f"POV-Ray failed on {out.name} (exit {res.returncode}):\n"
                           + (res.stderr or res.stdout)[-2000:])
    os.replace(tmp_png, out)
    return time.perf_counter() - t0


def render_cube(scene, root, *, workers: int | None = None, progress: bool = True) -> Path:
    """Render ``scene`` (cached) and return its camera-grid folder.

    ``scene`` is a :class:`CubeScene` or any scene of the same interface
    (:class:`scenes.leaf.LeafScene`): ``name``, ``key()``, ``sdl(k, i, j)``, ``truth()``,
    ``as_dict()``, the image size, grid, spacing, frames and focal length ``f``.

    Parameters
    ----------
    scene : CubeScene
    root : path
        Cache folder; the images go to ``root/<scene.key()>/``.
    workers : int, optional
        Parallel POV-Ray processes (default: all cores), one thread each.
    progress : bool
        Progress bar on stderr.

    Raises
    ------
    PovrayMissing
        If ``povray`` is not installed.
    """
    folder = Path(root).resolve() / f"{scene.name}-{scene.key()}"
    manifest = folder / "grid.json"
    if manifest.exists():
        return folder
    exe = povray_binary()
    folder.mkdir(parents=True, exist_ok=True)
    with _locked(folder):
        if manifest.exists():           # another process finished it while we waited
            return folder
        _remove_leftovers(folder)
        _render_all(exe, scene, folder, manifest, workers, progress)
    return folder


def render_cube_lightfield(cache, *, size: int = 256, grid: int = 5, spacing: float = 10.0,
                    focus: float = 420.0, progress: bool = True):
    """The cube as a static light field with large disparities (HCI-style geometry).

    One frame, no spotlight, ``grid x grid`` cameras ``spacing`` mm apart converging at
    ``focus`` mm: with the defaults the cube's disparities run from -0.6 to +3.0 px per
    view (the front corner at +3).

    Returns
    -------
    views : ndarray, shape (grid, grid, size, size)
    disparity : ndarray, shape (size, size)
        True disparity (px per camera step, HCI sign), NaN off the cube.
    scene : CubeScene
    """
    from gridflow.loader import load_folder

    scene = CubeScene(width=size, height=size, grid=(grid, grid), spacing=(spacing, spacing),
                      frames=1, static=True, spotlight=False, focus_distance=focus)
    data = load_folder(render_cube(scene, cache, progress=progress))
    return data.volume[0], scene.disparity(cube_truth(scene)["Z"]), scene


@contextmanager
def _locked(folder: Path):
    """Hold an exclusive lock on a scene folder: one process renders it at a time."""
    import fcntl

    with open(folder / ".lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _remove_leftovers(folder: Path) -> None:
    """Temporary files of a render that was killed (only called under the folder's lock,
    so none of them belongs to a running render)."""
    for p in folder.glob(".*.tmp.png"):
        p.unlink(missing_ok=True)
    for p in folder.glob(".pov-*"):
        shutil.rmtree(p, ignore_errors=True)


def _render_all(exe: str, scene: CubeScene, folder: Path, manifest: Path, workers,
                progress: bool) -> None:
    from tqdm import tqdm

    Sy, Sx = scene.grid
    jobs = [(k, i, j, folder / IMAGE_PATTERN.format(t=k, sy=i, sx=j))
            for k in range(scene.frames) for i in range(Sy) for j in range(Sx)]
    todo = [job for job in jobs if not job[3].exists()]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix=".pov-", dir=folder) as tmpdir, \
            ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1) as ex, \
            tqdm(total=len(jobs), initial=len(jobs) - len(todo), disable=not progress,
                 desc=f"render {scene.name}", unit="img") as bar:
        futs = [ex.submit(_render_one, exe, scene, k, i, j, out, tmpdir)
                for k, i, j, out in todo]
        for fut in as_completed(futs):
            fut.result()
            bar.update()
    seconds = time.perf_counter() - t0
    truth = scene.truth()
    (folder / "truth").mkdir(exist_ok=True)
    names = {}
    for name, arr in truth.items():
        with atomic_write(folder / "truth" / f"{name}.npy") as fh:
            np.save(fh, arr)
        names[name] = f"truth/{name}.npy"
    meta = {
        "focal_length": scene.f,
        "camera_spacing": list(scene.spacing),
        "grid": list(scene.grid),
        "frames": scene.frames,
        "pattern": IMAGE_PATTERN,
        "reference_camera": [(Sy - 1) // 2, (Sx - 1) // 2],
        "reference_frame": scene.ref_frame,
        "truth": names,
        "units": "mm, mm/frame; images linear, 16 bit",
        "source": {"scene": scene.as_dict(), "render_seconds": round(seconds, 1),
                   "rendered": len(todo)},
    }
    with atomic_write(manifest, "w") as fh:
        json.dump(meta, fh, indent=1)
