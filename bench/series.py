"""Long recordings: the estimate at every K-th frame of a recording, written as a map series
(:class:`gridflow.recording.MapStore`), out of core and in parallel on Dask.

Each time step is one task: it reads the frames its temporal window needs
(:meth:`gridflow.recording.Recording.read`), estimates, and writes its maps into the store
itself, so nothing larger than a few numbers goes back to the client.  Locally the tasks
run on Dask's threaded scheduler, as many at once as the memory budget allows (the
estimator's numba kernels share the cores among them); ``connect`` sends them to a
``dask.distributed`` scheduler instead, whose workers must see the recording and the store
at the same paths (a shared disk).

A rerun with the same input, settings and code skips the steps already done (the store's
``done`` flags), so an interrupted run resumes; a store made by another run is refused.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from gridflow.errors import UsageError
from gridflow.recording import MapStore, Recording, RecordingError, open_recording

__all__ = ["SeriesJob", "plan_series", "run_series", "SeriesReport", "step_memory",
           "DEFAULT_MOTION", "DEFAULT_MODEL"]

DEFAULT_MODEL = "full"
# a recording is made for growth: the affine motion model (growth and rotation maps)
DEFAULT_MOTION = "affine"
# bytes the estimator holds per byte of its input window, measured (bench/README.md,
# *Long recordings*): the window as float64 plus the band's signals and tensor.  A whole
# step: 3 (the estimator bounds its own bands' tensor, so a large window costs less than
# in proportion).  A row band: its signals over all its rows at once cost more per byte,
# 6.5, on top of the process itself (interpreter, libraries, numba's kernels), counted once
# per task; measured at 512^2 px, 5 x 5 views, 9 frames, one task at a time: 16-row bands
# 669 MiB (predicted 705), 102-row bands 993 MiB (1196), a whole step 1086 MiB (1575);
# a tiny step 212 MiB.
_MEMORY_FACTOR = 3.0
_BAND_FACTOR = 6.5
_PROCESS = 0.22 * 2**30


@dataclass(frozen=True)
class SeriesJob:
    """Everything one task needs (small and picklable: paths and settings, no data).

    Attributes
    ----------
    recording, store : str
        Paths (the same on every worker).
    frames : tuple of int
        The frame of each step.
    reach : int
        Frames either side of a step's frame that its estimate reads.
    model : str
    settings : dict
        Estimator settings (``ref_frame`` is set per step).
    key : str
        The store's key (a worker's opened store is reused only for the same key).
    threads : int
        numba threads per task.
    bands : tuple of (int, int)
        The row bands ``(r0, r1)`` of the store, each a task per step.
    halo : int
        Rows either side of a band its estimate reads (the window's radius plus the
        spatial filter's).
    """

    recording: str
    store: str
    frames: tuple
    reach: int
    model: str
    settings: dict = field(default_factory=dict)
    key: str = ""
    threads: int = 1
    bands: tuple = ()
    halo: int = 0


def _reach(settings: dict) -> int:
    """Frames either side of the reference frame an estimate reads: the temporal window's
    radius (default 2) plus the temporal filter's."""
    from gridflow.estimator.filters import get_filter_pair

    radius = settings.get("temporal_radius")
    radius = 2 if radius is None else int(radius)
    taps = get_filter_pair(settings.get("filters_t") or settings.get("filters")
                           or "matched5").taps
    return radius + taps // 2


def step_memory(rec: Recording, reach: int, rows: int | None = None, halo: int = 0) -> int:
    """Bytes one task needs: the process plus, for a whole step, its window of frames as
    float64 times the estimator's factor, or with ``rows`` (fewer than the image's), the
    window of a band of that many rows and ``halo`` rows either side times the band factor
    (the constants above, measured)."""
    T, Sy, Sx, H, W = rec.shape
    per_row = (2 * reach + 1) * Sy * Sx * W * 8
    if rows is None or rows >= H:
        return int(_PROCESS + per_row * H * _MEMORY_FACTOR)
    return int(_PROCESS + per_row * min(H, rows + 2 * halo) * _BAND_FACTOR)


def _quantities(model: str, settings: dict, grid) -> list[str]:
    from gridflow.estimator.models import get_model

    dims = 1 if grid[0] == 1 else 2
    m = get_model(model, dims, motion=settings.get("motion") or "translation")
    return list(m.outputs) + ["model_error"]


def _code_key() -> str:
    """The code a step's maps depend on: the estimator and the modules a sweep row depends
    on (:func:`gridflow.bench.sweep._code_fingerprint`), this module and the recording
    format, and the library versions."""
    import gridflow.recording as recording_module

    from .sweep import _code_fingerprint, _versions

    h = hashlib.sha1()
    for f in (Path(__file__), Path(recording_module.__file__)):
        h.update(f.read_bytes())
    return json.dumps({"code": _code_fingerprint(), "series": h.hexdigest()[:12],
                       "versions": _versions()}, sort_keys=True)


def plan_series(recording, output, *, every: int = 1, model: str | None = None,
                settings: dict | None = None, first: int | None = None,
                last: int | None = None, band_rows: int | None = None, check=None):
    """Open the recording, choose the steps, make (or reopen) the store.

    ``check(rec, reach, halo)``, if given, runs before the store is made (a refusal there
    leaves nothing written); what it returns, if not None, is the rows per band (else
    ``band_rows``, default the whole image).

    Returns
    -------
    rec : Recording
    store : MapStore
    job : SeriesJob
    """
    from gridflow.estimator import EstimatorSettings, window_halo
    from gridflow.io import check_output

    settings = {k: v for k, v in (settings or {}).items() if v is not None}
    settings.setdefault("motion", DEFAULT_MOTION)
    model = model or DEFAULT_MODEL
    if not (isinstance(every, int) and every >= 1):
        raise UsageError(f"--every must be a positive number of frames, got {every!r}")
    if band_rows is not None and not (isinstance(band_rows, int) and band_rows >= 1):
        raise UsageError(f"--band-rows must be a positive number of rows, got {band_rows!r}")
    if "ref_frame" in settings:
        raise UsageError("--ref-frame: a time series estimates at every K-th frame "
                         "(--every); there is no one reference frame")
    est_settings = EstimatorSettings(**settings)   # bad settings fail before anything opens
    out = Path(output)
    if out.suffix.lower() != ".zarr":
        raise UsageError(f"-o {output}: a recording's time series is written to a Zarr "
                         "store, e.g. -o maps.zarr")
    # the output folder's name and writability before the recording is opened
    check_output(out, suffixes=None, what="-o")
    rec = open_recording(recording)
    reach = _reach(settings)
    T = rec.frames
    lo, hi = reach, T - 1 - reach
    if hi < lo:
        raise UsageError(f"{recording}: {T} frames; a step needs {2 * reach + 1} (its "
                         f"temporal window {settings.get('temporal_radius', 2)} and the "
                         "filters either side)")
    first = lo if first is None else int(first)
    last = hi if last is None else int(last)
    if not lo <= first <= last <= hi:
        raise UsageError(f"steps from frame {first} to {last}: expected {lo} <= first <= "
                         f"last <= {hi} (the frames whose window lies in the recording)")
    frames = tuple(range(first, last + 1, every))
    quantities = _quantities(model, settings, rec.shape[1:3])
    halo = window_halo(est_settings)
    if check is not None:
        band_rows = check(rec, reach, halo) or band_rows
    H = rec.shape[3]
    band_rows = H if band_rows is None else min(int(band_rows), H)
    # the layout (rows per band) is part of the key: a store chunked otherwise is another
    # run's
    blob = json.dumps({"input": rec.identity(), "settings": settings, "model": model,
                       "frames": frames, "code": _code_key(), "band_rows": band_rows},
                      sort_keys=True)
    key = hashlib.sha1(blob.encode()).hexdigest()[:16]
    attrs = {"gridflow": {"input": str(Path(recording).resolve()), "model": model,
                          "settings": settings, "every": every, "reach": reach,
                          "focal_length": rec.focal_length,
                          "camera_spacing": list(rec.camera_spacing),
                          "frame_interval": rec.frame_interval}}
    store = MapStore.create(out, key=key, frames=list(frames), shape=rec.shape[3:],
                            quantities=quantities, frame_interval=rec.frame_interval,
                            attrs=attrs, inputs=[recording], band_rows=band_rows)
    job = SeriesJob(str(Path(recording).resolve()), str(out.resolve()), frames, reach, model,
                    settings, key, bands=tuple(store.bands()), halo=halo)
    return rec, store, job


@lru_cache(maxsize=4)
def _opened(recording: str, store: str, key: str):
    """The recording and store, opened once per process and run (a worker runs many
    steps; a store made anew under the same name has another key)."""
    import zarr

    return open_recording(recording), MapStore(Path(store), zarr.open_group(store, mode="r+"))


def run_step(job: SeriesJob, i: int, b: int = 0) -> dict:
    """Estimate band ``b`` of step ``i`` of ``job`` and write it into the store; returns
    its timing.

    Runs on a worker: reads only its window of frames, and of them only the band's rows
    and ``job.halo`` rows either side, so that the band's maps are those of the whole
    image (the estimate at a pixel reads no farther).
    """
    from gridflow.estimator import estimate_models

    try:
        import numba

        numba.set_num_threads(max(1, min(job.threads, numba.config.NUMBA_NUM_THREADS)))
    except ImportError:
        pass
    rec, store = _opened(job.recording, job.store, job.key)
    k = job.frames[i]
    t0 = time.perf_counter()
    # the stamp before the read: a frame replaced during the read makes the next run
    # redo this step rather than keep it
    stamp = rec.stamp(k - job.reach, k + job.reach + 1)
    H, W = rec.shape[3:]
    r0, r1 = job.bands[b]
    if r1 <= job.halo or r0 >= H - job.halo:
        # a band within the image's border: no pixel there has a whole window
        store.write_band(i, b, {q: np.full((r1 - r0, W), np.nan) for q in store.quantities},
                         np.zeros((r1 - r0, W), dtype=bool), stamp)
        return {"step": i, "band": b, "frame": k, "read_s": 0.0, "estimate_s": 0.0,
                "write_s": 0.0}
    a0, a1 = max(0, r0 - job.halo), min(H, r1 + job.halo)
    window = rec.read(k - job.reach, k + job.reach + 1, rows=(a0, a1))
    cx, cy = rec.principal_point
    t1 = time.perf_counter()
    try:
        ests = estimate_models(window, rec.focal_length, rec.camera_spacing,
                               models=(job.model,), principal_point=(cx, cy - a0),
                               **{**job.settings, "ref_frame": job.reach})
    except Exception as exc:
        from gridflow.estimator import InputError

        if isinstance(exc, InputError):
            raise RecordingError(f"{job.recording}: frames {k - job.reach}..{k + job.reach} "
                                 f"(step at frame {k}): {exc}") from None
        raise
    est = ests[job.model]
    t2 = time.perf_counter()
    rows = slice(r0 - a0, r1 - a0)
    store.write_band(i, b, {q: est[q][rows] for q in store.quantities}, est.interior[rows],
                     stamp)
    t3 = time.perf_counter()
    return {"step": i, "band": b, "frame": k, "read_s": t1 - t0, "estimate_s": t2 - t1,
            "write_s": t3 - t2}


@dataclass
class SeriesReport:
    """What :func:`run_series` did."""

    steps: int
    skipped: int
    done: int
    seconds: float
    concurrent: int
    where: str
    lines: list = field(default_factory=list)


def _local_concurrency(rec: Recording, reach: int, halo: int, workers: int | None,
                       memory: float | None,
                       band_rows: int | None = None) -> tuple[int, int, int, int]:
    """(tasks at once, numba threads each, budget bytes, rows per band) for the local
    scheduler.  A step is one task when its frames fit the budget; otherwise it is cut
    into the widest row bands that fit (``band_rows`` chooses them instead)."""
    from gridflow.volume import physical_memory

    cores = os.cpu_count() or 1
    have = physical_memory()
    budget = int(memory * 2**30) if memory is not None else \
        int(0.5 * have) if have else 4 * 2**30
    n = workers if workers is not None else cores
    if not (isinstance(n, int) and n >= 1):
        raise UsageError(f"--workers must be a positive number, got {workers!r}")
    T, Sy, Sx, H, W = rec.shape
    what = f"{2 * reach + 1} frames of {Sy}x{Sx} views"
    if band_rows is None:
        band_rows = H
        if step_memory(rec, reach) > budget:
            per_row = (2 * reach + 1) * Sy * Sx * W * 8 * _BAND_FACTOR
            band_rows = int((budget - _PROCESS) // per_row) - 2 * halo
            if band_rows <= halo:
                raise UsageError(
                    f"even a band of {halo + 1} rows (and the {halo} rows either side its "
                    f"estimate reads) of {what} of {W} px needs about "
                    f"{step_memory(rec, reach, halo + 1, halo) / 2**30:.2f} GiB, more than "
                    f"the memory budget {budget / 2**30:.2f} GiB (--memory GIB)")
    need = step_memory(rec, reach, band_rows, halo)
    if need > budget:
        raise UsageError(f"a band of {band_rows} rows needs about {need / 2**30:.2f} GiB ("
                         f"{what} of {W} px, {halo} rows either side), more than the memory "
                         f"budget {budget / 2**30:.2f} GiB (--memory GIB, --band-rows)")
    n = max(1, min(n, budget // need))
    return n, max(1, cores // n), budget, band_rows


def run_series(recording, output, *, every: int = 1, model: str | None = None,
               settings: dict | None = None, workers: int | None = None,
               memory: float | None = None, connect: str | None = None,
               first: int | None = None, last: int | None = None,
               band_rows: int | None = None,
               progress: bool = False, limit: int | None = None) -> SeriesReport:
    """Estimate a recording at every ``every``-th frame into the Zarr store ``output``.

    Parameters
    ----------
    recording : path
        A recording store or camera-grid folder (:func:`gridflow.recording.open_recording`).
    output : path
        ``*.zarr``; made, or resumed when it holds this run's finished steps.
    every : int
        Frames between steps.
    model : str
        Brightness model (default ``full``).
    settings : dict
        Estimator settings; ``motion`` defaults to ``affine`` (growth maps).
    workers : int, optional
        Steps at once on this machine (default: the cores, fewer where the memory budget
        says so).
    memory : float, optional
        Memory budget in GiB for the steps running at once (default half the machine's).
    connect : str, optional
        A ``dask.distributed`` scheduler address; the workers need the same paths.
    first, last : int, optional
        Frames of the first and last step (default the whole recording).
    band_rows : int, optional
        Rows per task: each step is cut into row bands of this many rows, each a task
        reading only its rows and the filters' halo (default: the whole image per step,
        or locally, where one step's frames exceed the memory budget, the widest bands
        that fit it).  The maps are the same either way.
    progress : bool
        Messages and a progress bar (steps done, rate, time left) on stderr.
    limit : int, optional
        Run at most this many of the remaining tasks (benchmarks, tests).
    """
    import dask

    def say(text):
        if progress:
            print(text, file=sys.stderr, flush=True)

    say(f"opening {recording} ...")
    local = {}

    def check(rec, reach, halo):
        if not connect:          # the memory budget, before anything is written
            local["plan"] = _local_concurrency(rec, reach, halo, workers, memory, band_rows)
            return local["plan"][3]
        return None

    rec, store, job = plan_series(recording, output, every=every, model=model,
                                  settings=settings, first=first, last=last,
                                  band_rows=band_rows, check=check)
    band_done = store.band_done()
    nb = band_done.shape[1]
    # a step whose frames changed since (repaired, replaced) is done again, every band
    stamps = store.stamps()
    changed = [i for i in np.flatnonzero(band_done.any(axis=1))
               if (rec.stamp(job.frames[i] - job.reach, job.frames[i] + job.reach + 1)
                   != stamps[i][band_done[i]]).any()]
    redo = set(changed)
    todo = [(i, b) for i in range(len(job.frames)) for b in range(nb)
            if not band_done[i, b] or i in redo]
    skipped = int(sum(band_done[i].all() for i in range(len(job.frames))
                      if i not in redo))
    if limit is not None:
        todo = todo[:limit]
    T, Sy, Sx, H, W = rec.shape
    if skipped:
        say(f"{output}: {skipped} of {len(job.frames)} steps already done, resuming")
    if changed:
        say(f"{output}: {len(changed)} done step(s) read frames that changed since; "
            "estimating them again")
    if connect:
        from .executors import make_client

        client = make_client(scheduler=connect)
        where = f"the dask cluster at {connect}"
        n = sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values())
    else:
        n, threads, budget, _ = local["plan"]
        job = SeriesJob(**{**job.__dict__, "threads": threads})
        unit = "step" if nb == 1 else "band"
        where = (f"this machine: {n} {unit}(s) at once, {threads} numba thread(s) each, "
                 f"memory budget {budget / 2**30:.1f} GiB")
    cut = "" if nb == 1 else f", each in {nb} row bands of {job.bands[0][1]} rows"
    say(f"{len({i for i, _ in todo})} steps (every {every} frames, {2 * job.reach + 1} "
        f"frames of {Sy}x{Sx} views of {W}x{H} px each{cut}) on {where} ...")
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(job.frames) * nb, initial=len(job.frames) * nb - len(todo),
                   unit="step" if nb == 1 else "band", file=sys.stderr, dynamic_ncols=True)
    t0 = time.perf_counter()
    finished = 0
    try:
        if connect:
            from dask.distributed import as_completed

            futs = [client.submit(run_step, job, i, b, pure=False) for i, b in todo]
            try:
                for fut in as_completed(futs):
                    fut.result()
                    finished += 1
                    if bar is not None:
                        bar.update(1)
            except BaseException:
                client.cancel(futs)
                raise
            finally:
                client.close()
        else:
            from dask.callbacks import Callback

            class Tick(Callback):
                def _posttask(self, key, result, dsk, state, worker_id):
                    nonlocal finished
                    finished += 1
                    if bar is not None:
                        bar.update(1)

            tasks = [dask.delayed(run_step, pure=False)(job, i, b) for i, b in todo]
            with Tick():
                dask.compute(*tasks, scheduler="threads", num_workers=n)
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - t0
    done_now = int(store.done().sum())
    report = SeriesReport(len(job.frames), skipped, done_now, seconds, n, where)
    if changed:
        report.lines.append(f"{len(changed)} step(s) estimated again: frames they read "
                            f"changed since (steps at frames "
                            f"{[job.frames[i] for i in changed][:5]}...)")
    rate = finished / nb / seconds if seconds > 0 else float("nan")
    report.lines.append(f"wrote {output}: {done_now} of {len(job.frames)} steps done "
                        f"({finished / nb:g} now in {seconds:.1f} s, {rate:.3f} steps/s; {skipped} "
                        f"done by an earlier run); open with xarray.open_zarr('{output}')")
    return report


# --- a synthetic recording ---------------------------------------------------------------------

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
                  frame_interval, truth_names, source, progress: bool, what: str) -> float:
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
                        source=source,
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


def make_leaf_recording(output, scene=None, *, cache="work/cube",
                        progress: bool = False) -> list[str]:
    """Render the POV-Ray leaf as a recording (:class:`gridflow.scenes.LeafRecording`)
    into the recording store ``output``, with its truth per frame.

    The images are rendered (in parallel, cached) into a camera-grid folder under
    ``cache``, then copied frame by frame into the store beside each frame's truth
    (memory: one frame).
    """
    from gridflow.scenes import LEAF_TRUTH_NAMES, LeafRecording, render_cube

    out = _new_store(output)
    scene = scene if scene is not None else LeafRecording()
    Sy, Sx = scene.grid
    T = scene.frames
    size = f"{Sy}x{Sx} views of {scene.width}x{scene.height} px"
    if progress:
        print(f"rendering the leaf with POV-Ray: {T} frames of {size} ({T * Sy * Sx} "
              f"images, cached in {cache}) ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    folder = render_cube(scene, cache, progress=progress)
    rendered = time.perf_counter() - t0
    images = open_recording(folder)
    seconds = _write_frames(
        out, T, lambda k: (images.read(k, k + 1)[0], scene.truth_at(k)), shape=images.shape,
        focal_length=scene.f, camera_spacing=scene.spacing,
        frame_interval=scene.frame_interval, truth_names=LEAF_TRUTH_NAMES,
        source={"scene": "POV-Ray leaf recording", "params": scene.as_dict(),
                "images": folder.name}, progress=progress,
        what="copying the frames and writing their truth")
    return [f"wrote {output}: {T} frames of {size} (the POV-Ray leaf, {folder}: "
            f"{rendered:.1f} s to render or find), growth {scene.growth:g} per frame x (1 + "
            f"{scene.rhythm:g} sin(2 pi t / {scene.period:g})), in {seconds:.1f} s"]


# --- what a grower looks at ----------------------------------------------------------------------

def growth_table(maps, truth=None, *, quantity: str = "growth"):
    """Per step of the map series ``maps``: the mean, median, 10th and 90th percentile of
    ``quantity`` over the interior, and with a recording ``truth`` that has it, the truth's
    mean and Q_rel (Eq. 22); with a truth, every column is over the interior's pixels where
    the truth is given (a scene's truth is NaN off the object).  Steps not done are left
    out.

    Returns
    -------
    pandas.DataFrame
        Columns ``step, frame, time_s, mean, median, p10, p90, n_pixels`` (and
        ``truth, q_rel``).
    """
    import pandas as pd

    from gridflow.recording import MapStore

    from .metrics import q_rel

    store = MapStore.open(maps)
    if quantity not in store.quantities:
        raise UsageError(f"{maps}: holds no {quantity!r} maps (it has "
                         f"{', '.join(store.quantities)}); growth needs --motion affine")
    rec = open_recording(truth) if truth is not None else None
    if rec is not None and quantity not in rec.truth_names:
        raise UsageError(f"{truth}: holds no {quantity!r} truth (it has "
                         f"{', '.join(rec.truth_names) or 'none'})")
    g = store.group
    frames, done = store.frames(), store.done()
    interior = np.asarray(g["interior"][:], dtype=bool)
    fi = store.attrs["gridflow"].get("frame_interval")
    rows = []
    for i in np.flatnonzero(done):
        m = np.asarray(g[quantity][i], dtype=np.float64)
        mask = interior
        if rec is not None:
            # where the truth is given (a scene's truth is NaN off the object and near its
            # edge): the statistics and Q_rel over the same pixels
            t = rec.truth(int(frames[i]), names=(quantity,))[quantity]
            mask = interior & np.isfinite(t)
        v = m[mask & np.isfinite(m)]
        row = {"step": int(i), "frame": int(frames[i]),
               "time_s": float(frames[i] * fi) if fi else np.nan,
               "mean": float(v.mean()) if v.size else np.nan,
               "median": float(np.median(v)) if v.size else np.nan,
               "p10": float(np.percentile(v, 10)) if v.size else np.nan,
               "p90": float(np.percentile(v, 90)) if v.size else np.nan,
               "n_pixels": int(v.size)}
        if rec is not None:
            row["truth"] = float(t[mask].mean()) if mask.any() else np.nan
            row["q_rel"] = q_rel(m, t, mask)
        rows.append(row)
    if not rows:
        raise UsageError(f"{maps}: no step is done yet")
    return pd.DataFrame(rows)


def draw_growth(maps, table, fig_dir, *, times=None, quantity: str = "growth") -> list[Path]:
    """The growth maps at chosen frames (a strip on one colour scale) and the growth over
    the interior against time: its median (robust to the few pixels where the estimate
    breaks down, which move the mean), the mean, the 10-90 % spread and the truth where
    known.

    Returns the files written (``growth_maps.png``, ``growth_series.png``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gridflow.io import atomic_write
    from gridflow.recording import MapStore

    store = MapStore.open(maps)
    fig_dir = Path(fig_dir)
    fig_dir.mkdir(parents=True, exist_ok=True)
    frames = list(table["frame"])
    if times:
        missing = [t for t in times if t not in frames]
        if missing:
            raise UsageError(f"--times {missing}: no finished step at those frames (steps at "
                             f"{frames[0]}, {frames[1] if len(frames) > 1 else ''} ... "
                             f"{frames[-1]})")
        chosen = list(times)
    else:
        chosen = [frames[int(round(j))] for j in np.linspace(0, len(frames) - 1,
                                                             min(6, len(frames)))]
    interior = np.asarray(store.group["interior"][:], dtype=bool)
    per_frame = 100.0          # shown in % per frame
    imgs = []
    for f in chosen:
        i = int(table.loc[table["frame"] == f, "step"].iloc[0])
        m = np.asarray(store.group[quantity][i], dtype=float) * per_frame
        imgs.append(np.where(interior, m, np.nan))
    lo = np.nanpercentile(np.concatenate([m[np.isfinite(m)] for m in imgs]), 1)
    hi = np.nanpercentile(np.concatenate([m[np.isfinite(m)] for m in imgs]), 99)
    fi = store.attrs["gridflow"].get("frame_interval")
    label = (lambda f: f"frame {f} ({f * fi / 3600:.1f} h)") if fi else (lambda f: f"frame {f}")
    fig, axes = plt.subplots(1, len(chosen), figsize=(2.6 * len(chosen) + 0.8, 3.0),
                             squeeze=False, constrained_layout=True)
    for ax, f, m in zip(axes[0], chosen, imgs):
        im = ax.imshow(m, vmin=lo, vmax=hi, cmap="viridis")
        ax.set_title(label(f), fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes[0], shrink=0.85, label="growth, % area per frame")
    fig.suptitle(f"Growth maps ({maps})", fontsize=10)
    out1 = fig_dir / "growth_maps.png"
    with atomic_write(out1) as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)

    x = table["time_s"] / 3600 if fi else table["frame"]
    fig, ax = plt.subplots(figsize=(7, 3.6), constrained_layout=True)
    ax.fill_between(x, table["p10"] * per_frame, table["p90"] * per_frame, alpha=0.3,
                    color="tab:green", label="10-90 % of the pixels")
    ax.plot(x, table["median"] * per_frame, color="tab:green", lw=1.5,
            label="median, estimated")
    ax.plot(x, table["mean"] * per_frame, color="tab:green", lw=0.8, ls=":",
            label="mean, estimated")
    if "truth" in table:
        ax.plot(x, table["truth"] * per_frame, "k--", lw=1.0, label="truth")
    ax.set_xlabel("time, h" if fi else "frame")
    ax.set_ylabel("growth, % area per frame")
    ax.legend(fontsize=8, loc="best")
    ax.set_title("Growth over the interior", fontsize=10)
    out2 = fig_dir / "growth_series.png"
    with atomic_write(out2) as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
    return [out1, out2]
