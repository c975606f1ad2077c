"""Synthetic recordings with truth per frame, written as recording stores: the growth
recording of :mod:`gridflow.generators.recording` (``gridflow record``) and the POV-Ray leaf
(``gridflow record-leaf``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from gridflow.errors import UsageError
from gridflow.scenes.render import RENDER_CACHE

__all__ = ["make_recording", "make_leaf_recording"]


def _new_store(output) -> Path:
    """``output`` as a new recording store's path, or a clear error."""
    from gridflow.io import check_output

    out = Path(output)
    if out.suffix.lower() != ".zarr":
        raise UsageError(f"-o {output}: a recording is a Zarr store, e.g. -o rec.zarr")
    check_output(out, suffixes=None, what="-o")
    if out.exists():
        raise UsageError(f"-o {output}: exists; a recording is written to a new name")
    return out


def _write_frames(out: Path, T: int, frame, *, shape, focal_length, camera_spacing,
                  frame_interval, truth_names, source, progress: bool, what: str,
                  units: str | None = None) -> float:
    """Write ``frame(k) -> (views, truth)`` for k < T into the recording store ``out``,
    one frame in memory at a time, with a progress bar; returns the seconds taken."""
    from gridflow.recording import write_recording

    bar = None
    if progress:
        from tqdm import tqdm

        print(f"{what} into {out} ...", file=sys.stderr, flush=True)
        bar = tqdm(total=T, unit="frame", file=sys.stderr, dynamic_ncols=True)
    t0 = time.perf_counter()
    try:
        write_recording(out, (frame(k) for k in range(T)), shape=shape,
                        focal_length=focal_length, camera_spacing=camera_spacing,
                        frame_interval=frame_interval, truth_names=truth_names,
                        source=source, units=units,
                        progress=(lambda n: bar.update(1)) if bar is not None else None)
    finally:
        if bar is not None:
            bar.close()
    return time.perf_counter() - t0


def make_recording(output, params=None, *, progress: bool = False) -> list[str]:
    """Render a growth recording (:class:`gridflow.generators.recording.GrowthRecording`)
    into the recording store ``output``, one frame at a time (memory: one frame)."""
    from gridflow.generators.recording import TRUTH_NAMES, GrowthRecording

    out = _new_store(output)
    gen = GrowthRecording(params)
    p = gen.params
    T = p.frames
    size = f"{p.grid[0]}x{p.grid[1]} views of {p.width}x{p.height} px"
    seconds = _write_frames(
        out, T, lambda k: (gen.frame(k), gen.truth(k)), shape=gen.shape, focal_length=p.f,
        camera_spacing=p.spacing, frame_interval=p.frame_interval, truth_names=TRUTH_NAMES,
        source={"generator": "growth recording", "params": p.as_dict()}, progress=progress,
        what=f"rendering {T} frames of {size}")
    return [f"wrote {output}: {T} frames of {size}, growth {p.growth:g} per frame x (1 + "
            f"{p.rhythm:g} sin(2 pi t / {p.period:g})), in {seconds:.1f} s"]


def make_leaf_recording(output, scene=None, *, cache=RENDER_CACHE,
                        progress: bool = False) -> list[str]:
    """Render the POV-Ray leaf as a recording (:class:`gridflow.scenes.LeafRecording`)
    into the recording store ``output``, with its truth per frame.

    The images are rendered (in parallel, cached) into a camera-grid folder under
    ``cache``, then copied frame by frame into the store beside each frame's truth
    (memory: one frame).
    """
    from gridflow.recording import check_recording
    from gridflow.scenes import LEAF_TRUTH_NAMES, LeafRecording, render_cube

    out = _new_store(output)
    scene = scene if scene is not None else LeafRecording()
    Sy, Sx = scene.grid
    T = scene.frames
    # the numbers and the disk space before the renders (minutes), not after them
    check_recording(out, shape=(T, Sy, Sx, scene.height, scene.width), focal_length=scene.f,
                    camera_spacing=scene.spacing, frame_interval=scene.frame_interval,
                    truth_names=LEAF_TRUTH_NAMES)
    size = f"{Sy}x{Sx} views of {scene.width}x{scene.height} px"
    if progress:
        print(f"rendering the leaf with POV-Ray: {T} frames of {size} ({T * Sy * Sx} "
              f"images, cached in {cache}) ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    folder = render_cube(scene, cache, progress=progress)
    rendered = time.perf_counter() - t0
    from gridflow.loader import open_folder

    images = open_folder(folder)
    seconds = _write_frames(
        out, T, lambda k: (images.read(k, k + 1)[0], scene.truth_at(k)), shape=images.shape,
        focal_length=scene.f, camera_spacing=scene.spacing,
        frame_interval=scene.frame_interval, truth_names=LEAF_TRUTH_NAMES, units="mm",
        source={"scene": "POV-Ray leaf recording", "params": scene.as_dict(),
                "images": folder.name}, progress=progress,
        what="copying the frames and writing their truth")
    rate = (f"{scene.growth:g} at the base to {scene.tip_growth:g} at the tip"
            if hasattr(scene, "tip_growth") else f"{scene.growth:g}")
    return [f"wrote {output}: {T} frames of {size} (the POV-Ray leaf, {folder}: "
            f"{rendered:.1f} s to render or find), growth {rate} per frame x (1 + "
            f"{scene.rhythm:g} sin(2 pi t / {scene.period:g})), in {seconds:.1f} s"]


