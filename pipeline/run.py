"""One run from any source to any sink: what ``gridflow estimate INPUT -o OUTPUT`` does.

1. The output's suffix chooses the sink (:func:`gridflow.pipeline.sinks.sink_for`); its
   name is checked before the input is read.
2. The input is opened lazily by the one registry of formats
   (:func:`gridflow.sources.open_source`).
3. The strategy is chosen (:func:`choose_strategy`): a light field of one frame on a
   square grid is refocused, a sequence gets the estimator's single pass.
4. The plan (:func:`plan_run`): the steps (one for an ``.npz``; every K-th frame whose
   window fits for a map series), each step's window of frames (the strategy's reach,
   from :func:`gridflow.estimator.temporal_reach`), the row bands (the strategy's halo,
   from :func:`gridflow.estimator.band_halo`) that fit the memory budget.
5. Each (step, band) not done yet is a task (:func:`run_step`): read its rows of its
   frames, estimate, write into the sink; in this process, on Dask's threads, or on a
   ``dask.distributed`` cluster (``connect``).

A single volume is a recording of one step: the same options and defaults whatever the
output.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from gridflow.errors import UsageError

from .strategies import Refocus, SinglePass, with_depth

__all__ = ["RunOptions", "RunReport", "Plan", "estimate", "choose_strategy", "plan_run",
           "run_step", "step_memory", "DEFAULT_MODEL"]

#: the brightness model of a sequence (a light field of one frame: bcc)
DEFAULT_MODEL = "full"

# the process itself (interpreter, libraries, numba's kernels), counted once per task;
# measured: a tiny step 212 MiB.  What a step holds besides is its window as read and what
# the estimator holds beyond it (gridflow.estimator.estimate_memory, an envelope of
# measured peaks).
_PROCESS = 0.22 * 2**30


@dataclass(frozen=True)
class RunOptions:
    """What to estimate and where: every option of ``gridflow estimate``, None where not
    given (the defaults are chosen from the source: :func:`choose_strategy`).

    Attributes
    ----------
    models : tuple of str, optional
        Brightness models; default ``("full",)``, ``("bcc",)`` for a light field of one
        frame.
    settings : dict
        Estimator settings given (:class:`gridflow.estimator.EstimatorSettings`; those
        not given keep its defaults, whatever the output: ``motion`` ``translation``,
        the more precise where nothing grows; ``affine`` for growth maps).
        ``ref_frame``: the one step's frame.
    every, first, last : int, optional
        Steps of a map series: every K-th frame from ``first`` to ``last`` (default every
        frame whose window lies in the source).
    views : int, optional
        HCI scenes: the central views used.
    shears : None, "auto", "none" or sequence of int
        Light fields of one frame (:func:`choose_strategy`).
    select : str, optional
    fill : bool, optional
    median : int, optional
        Refocusing (:func:`gridflow.estimator.lightfield.estimate_refocused`).
    workers : int, optional
        Tasks at once on this machine.
    memory : float, optional
        Memory budget, GiB.
    band_rows : int, optional
        Rows per band.
    connect : str, optional
        A ``dask.distributed`` scheduler address.
    mask : str, optional
        ``"auto"`` (the object segmented per step from the centre camera's image:
        :func:`gridflow.estimator.segment_object`) or a mask file (``.npy`` or an image,
        nonzero on the object, the reference camera's size): windows use only the
        object's pixels (the single pass only).
    progress : bool
        Messages before long steps and a progress bar, on stderr.
    limit : int, optional
        Stop after this many tasks (tests of resuming).
    """

    models: tuple | None = None
    settings: dict = field(default_factory=dict)
    every: int | None = None
    first: int | None = None
    last: int | None = None
    views: int | None = None
    shears: object = None
    select: str | None = None
    fill: bool | None = None
    median: int | None = None
    workers: int | None = None
    memory: float | None = None
    band_rows: int | None = None
    connect: str | None = None
    mask: str | None = None
    progress: bool = False
    limit: int | None = None


@dataclass
class RunReport:
    """What :func:`estimate` did.

    Attributes
    ----------
    lines : list of str
        What to print.
    seconds : float
        Wall time of the estimates.
    steps : int
        Steps in the run.
    skipped : int
        Steps done by an earlier run and kept.
    done : int
        Steps done in the output now.
    now : float
        Steps estimated by this call.
    """

    lines: list = field(default_factory=list)
    seconds: float = 0.0
    steps: int = 0
    skipped: int = 0
    done: int = 0
    now: float = 0.0


@dataclass(frozen=True)
class Plan:
    """A run's steps, windows and bands (small, picklable apart from ``source``).

    Attributes
    ----------
    source : gridflow.sources.Source
    strategy : SinglePass or Refocus
    frames : tuple of int
        The frame of each step.
    windows : tuple of (int, int)
        Each step's frames ``lo .. hi - 1``.
    bands : tuple of (int, int)
        Row bands ``(r0, r1)``.
    halo : int
        Rows either side of a band its estimate reads.
    reach : int
        Frames either side of a step its estimate reads, where the source has them.
    notes : tuple of str
        What the planning left out and why (steps whose window spans a gap).
    times : tuple of float or None
        Each step's time, seconds since the first frame, where the source knows it.
    intervals : tuple of float or None
        Each step's frame interval, seconds: the mean over its window's frames.
    """

    source: object
    strategy: object
    frames: tuple
    windows: tuple
    bands: tuple
    halo: int
    reach: int
    notes: tuple = ()
    times: tuple | None = None
    intervals: tuple | None = None

    def stamp(self, i: int) -> int:
        lo, hi = self.windows[i]
        return self.source.stamp(lo, hi)

    @property
    def window_frames(self) -> int:
        """Frames in the longest step's window."""
        return max(hi - lo for lo, hi in self.windows)


def _say(progress: bool, text: str) -> None:
    if progress:
        print(text, file=sys.stderr, flush=True)


def _square(rows: int, cols: int) -> bool:
    """A grid refocusing can use: square, with an odd number of views, at least 3."""
    return rows == cols and rows % 2 == 1 and rows >= 3


def _views_used(n: int, select: str) -> str:
    """Which of an n x n grid's views a refocusing choice reads (its default sub-grids)."""
    if select in ("lines", "epi"):
        return f"the centre row and column, {2 * n - 1} views"
    if select == "occlusion":
        m = min(5, n)
        return f"{m}x{m} sub-grids at the centre, edges and corners, {n * n} views"
    return f"all {n * n} views"


# settings that only the estimator's single pass over a volume uses: refused where a
# light field is refocused, instead of being ignored
_SINGLE_PASS_ONLY = {"temporal_radius": "--temporal-radius", "ref_frame": "--ref-frame",
                     "method": "--method", "slant_correction": "--no-slant-correction",
                     "zoom_correction": "--no-zoom-correction",
                     "combine": "--combine", "motion": "--motion",
                     "growth_support": "--growth-support"}


def choose_strategy(source, o: RunOptions) -> tuple[object, list[str]]:
    """The single pass or refocusing, with the defaults that fit ``source``.

    A light field of one frame on a square grid (an HCI scene, a static camera-grid
    folder, a one-frame volume) is refocused unless ``shears="none"``: over the disparity
    range its ``parameters.cfg`` states, else one estimated from the data; a sequence
    gets the estimator's single pass.

    Returns
    -------
    strategy : SinglePass or Refocus
    notes : list of str
        Lines to report (why not refocused, the disparity range used).
    """
    T, gr, gc = source.shape[:3]
    settings = dict(o.settings)
    refocus_given = [flag for flag, given in (("--select", o.select is not None),
                                              ("--median", o.median is not None),
                                              ("--no-fill", o.fill is False)) if given]
    single_pass = o.shears == "none"
    refocus = not single_pass and (o.shears is not None or (T == 1 and _square(gr, gc)))
    notes = []
    path = source.path
    if o.shears is None and not refocus and T == 1:
        notes.append(f"not refocused: {path} is a {gr}x{gc} grid (refocusing needs a square "
                     "grid with an odd number of views); the single pass")
    if not refocus and refocus_given:
        why = ("--shears none asks for the single pass" if single_pass else
               f"{path} has {T} frames" if T > 1 else f"{path} is a {gr}x{gc} grid")
        raise UsageError(f"{', '.join(refocus_given)}: refocusing only; {why}, so the "
                         "estimator's single pass runs")
    if refocus:
        if o.mask is not None:
            raise UsageError("--mask: the estimator's single pass only; a light field of one "
                             "frame is refocused (--shears none for the single pass)")
        return _refocus_strategy(source, o, settings, notes)
    models = o.models or (("bcc",) if T == 1 else (DEFAULT_MODEL,))
    return SinglePass(tuple(models), settings, mask=_load_mask(o.mask, source)), notes


def _load_mask(spec, source):
    """``--mask``: None, ``"auto"``, or the file's mask as booleans of the source's image
    size; a file that is not one is refused by name."""
    if spec is None or spec == "auto":
        return spec
    from pathlib import Path

    path = Path(spec)
    H, W = source.shape[3:]
    if not path.is_file():
        raise UsageError(f"--mask {spec}: no such file (give 'auto' or a .npy or image file "
                         f"of {H}x{W} px, nonzero on the object)")
    try:
        if path.suffix.lower() == ".npy":
            m = np.load(path, allow_pickle=False)
        else:
            import imageio.v3 as iio

            m = iio.imread(path)
    except Exception as exc:                               # noqa: BLE001
        raise UsageError(f"--mask {spec}: cannot be read as a .npy or an image ({exc})") \
            from None
    m = np.asarray(m)
    if m.ndim == 3:                                        # an RGB(A) image: any channel
        m = m[..., :3].max(axis=-1) if m.shape[-1] in (3, 4) else m
    if m.shape != (H, W) or not np.issubdtype(m.dtype, np.number) and m.dtype != bool:
        raise UsageError(f"--mask {spec}: expected {H}x{W} px (the reference camera's "
                         f"image of {source.path}), got shape {m.shape} ({m.dtype})")
    mask = m != 0
    if not mask.any():
        raise UsageError(f"--mask {spec}: no pixel is on the object (all zero)")
    return mask


def _motion_needs_time(name: str) -> bool:
    """Whether a motion model (by name) needs a time axis; an unknown name is left to the
    settings' own check."""
    from gridflow.estimator.models import MOTION_MODELS

    return name not in MOTION_MODELS or MOTION_MODELS[name].needs_time


def _refocus_strategy(source, o: RunOptions, settings: dict, notes: list):
    from gridflow.estimator import DEFAULTS, InputError
    from gridflow.estimator.lightfield import (SELECT_DEFAULTS, SELECTS, check_shears,
                                              estimate_shear_range, stated_shears)
    from gridflow.errors import FileFormatError

    path = source.path
    T, n, m = source.shape[:3]
    if T != 1:
        raise UsageError(f"--shears refocuses a light field of one frame; {path} has "
                         f"{T} frames")
    if o.models not in (None, ("bcc",)):
        raise UsageError(f"a light field of one frame is refocused with model bcc, got "
                         f"--model {','.join(o.models)} (--shears none: the single pass)")
    given = [flag for key, flag in _SINGLE_PASS_ONLY.items() if key in settings
             and not (key == "motion" and not _motion_needs_time(settings[key]))
             and not (key in ("slant_correction", "zoom_correction") and settings[key])]
    if given:
        raise UsageError(f"{', '.join(given)}: the estimator's single pass only; a light "
                         f"field of one frame ({path}) is refocused (--shears none: the "
                         "single pass)")
    if not _square(n, m):
        raise UsageError(f"--shears needs a square grid with an odd number of views (at "
                         f"least 3), {path} has {n}x{m}")
    select = SELECTS[0] if o.select is None else o.select
    filters = settings.get("filters", DEFAULTS["filters"])
    H, W = source.shape[3:]
    shears = "auto" if o.shears is None else o.shears
    hci = source.meta.get("hci")
    if shears == "auto":
        stated = (hci or {}).get("disp_range")
        try:
            shears = stated_shears(stated)
            if shears is not None:
                check_shears(shears, n, H, W, what="the stated disparity range")
        except InputError as e:
            raise FileFormatError(f"{Path(path) / 'parameters.cfg'}: [meta] disp_min, "
                                  f"disp_max: {e}") from None
        if shears is not None:
            notes.append(f"disparity range {stated[0]:g} .. {stated[1]:g} px per view, as "
                         f"{path} states (parameters.cfg)")
        else:
            _say(o.progress, f"{path} states no disparity range: a coarse pass estimates "
                 "it ...")
            shears, info = estimate_shear_range(source.read(0, 1)[0], filters=filters)
            check_shears(shears, n, H, W, what="the disparity range estimated from the data")
            notes.append(f"disparity range {info['lo']:.2f} .. {info['hi']:.2f} px per view, "
                         f"estimated from the data (coarse pass at 1/{info['k']} resolution; "
                         "none stated: --shears MIN MAX to give one)")
    else:
        try:
            check_shears(shears, n, H, W, what="--shears")
        except InputError as e:
            raise UsageError(str(e)) from None
    sigma = settings.get("sigma")
    window = settings.get("window")
    return Refocus(tuple(int(s) for s in shears), select,
                   SELECT_DEFAULTS[select][0] if sigma is None else sigma,
                   SELECT_DEFAULTS[select][1] if window is None else window, filters,
                   True if o.fill is None else o.fill,
                   3 if o.median is None else o.median), notes


def _steps(source, strategy, o: RunOptions, sink) -> tuple[tuple, tuple]:
    """The steps' frames and windows.  One step (an ``.npz``, or ``ref_frame`` given): at
    the given or stated reference frame, its window cut to the frames there are.  A map
    series: every ``every``-th frame from ``first`` to ``last``, each with its whole
    window."""
    T = source.frames
    reach = strategy.reach
    ref = strategy.settings.get("ref_frame") if isinstance(strategy, SinglePass) else None
    series_given = [f for f, v in (("--every", o.every), ("--first", o.first),
                                   ("--last", o.last)) if v is not None]
    if ref is not None and series_given:
        raise UsageError(f"--ref-frame and {', '.join(series_given)}: --ref-frame asks for "
                         "one step at that frame, the others for a series of steps")
    if sink.max_steps == 1 and series_given:
        raise UsageError(f"{', '.join(series_given)}: for a series of steps (-o MAPS.zarr); "
                         f"-o {sink.output} holds one step (--ref-frame chooses its frame)")
    if sink.max_steps == 1 or ref is not None or T == 1:
        k = ref if ref is not None else (source.ref_frame if source.ref_frame is not None
                                         else (T - 1) // 2)
        if not 0 <= k < T:
            raise UsageError(f"--ref-frame {k}: {source.path} has frames 0..{T - 1}")
        return (k,), ((max(0, k - reach), min(T, k + reach + 1)),)
    lo, hi = reach, T - 1 - reach
    if hi < lo:
        raise UsageError(f"{source.path}: {T} frames; a step needs {2 * reach + 1} (its "
                         f"temporal window and the filters either side: --temporal-radius)")
    every = 1 if o.every is None else o.every
    first = lo if o.first is None else int(o.first)
    last = hi if o.last is None else int(o.last)
    if not lo <= first <= last <= hi:
        raise UsageError(f"steps from frame {first} to {last}: expected {lo} <= first <= "
                         f"last <= {hi} (the frames whose window lies in the recording)")
    frames = tuple(range(first, last + 1, every))
    return frames, tuple((k - reach, k + reach + 1) for k in frames)


def step_memory(shape, window_frames: int, rows: int | None = None, halo: int = 0, *,
                itemsize: int = 8, strategy=None, framed: bool = False) -> int:
    """Bytes one task needs: the process, its window of ``window_frames`` frames of a
    source of ``shape`` ``(T, Sy, Sx, H, W)`` as read (``itemsize`` bytes a sample) and
    what the estimator holds beyond it (:func:`gridflow.estimator.estimate_memory`, for
    ``strategy``'s settings and models: default the full model and the default
    settings); with ``rows`` (fewer than the image's) those of a band of that many rows
    and ``halo`` rows either side, plus one decoded frame (a band is read frame by
    frame from whole-frame chunks).  ``framed``: a whole step of a worker that keeps its
    frames' values (counted by :func:`_framed_need`), which decodes one frame at a time
    and holds no window, nor signals of its own where the estimator keeps them."""
    from gridflow.estimator import estimate_memory

    T, Sy, Sx, H, W = shape
    banded = rows is not None and rows < H
    r = min(H, rows + 2 * halo) if banded else H
    settings = getattr(strategy, "estimator_settings", None)
    models = getattr(strategy, "models", ("full",))
    method = settings.method if settings is not None else "fast"
    kept = framed and not banded
    try:
        est = estimate_memory((window_frames, Sy, Sx, r, W), settings, models, method,
                              kept_signals=kept and getattr(strategy, "mask", None) is None)
    except ValueError:
        # models this input cannot take (a light field of one frame given --model full):
        # the estimator refuses them with its own message when the step runs; planned here
        # as the model every input takes
        est = estimate_memory((window_frames, Sy, Sx, r, W), None, ("bcc",), method)
    frame = Sy * Sx * H * W * itemsize
    window = frame if kept else window_frames * Sy * Sx * r * W * itemsize
    return int(_PROCESS + window + est + (frame if banded else 0))


def _framed_need(shape, window_frames: int, every: int | None, tasks: int, *,
                 itemsize: int, strategy) -> int | None:
    """Bytes ``tasks`` whole steps at once need where their worker keeps each frame's
    values (steps ``every`` frames apart share frames: :func:`frame_cache`): the steps
    (:func:`step_memory`, ``framed``) and the frames kept for them; None where steps
    do not share frames or the strategy reads whole windows."""
    from gridflow.estimator import kept_frame_bytes

    if every is None or every >= window_frames or not isinstance(strategy, SinglePass):
        return None
    settings = strategy.estimator_settings
    try:
        per_frame = kept_frame_bytes(
            (window_frames,) + tuple(shape[1:]), settings, strategy.models, settings.method,
            itemsize, masked=strategy.mask is not None)
    except ValueError:
        # models this input cannot take: refused by the estimator when the step runs
        return None
    steps = tasks * step_memory(shape, window_frames, itemsize=itemsize, strategy=strategy,
                                framed=True)
    return steps + (window_frames + (tasks - 1) * every) * per_frame


def _budget(memory: float | None) -> int:
    from gridflow.volume import physical_memory

    if memory is not None:
        if not (isinstance(memory, (int, float)) and math.isfinite(memory) and memory > 0):
            raise UsageError(f"--memory must be a positive finite number of GiB, got "
                             f"{memory!r}")
        have = physical_memory()
        if have and memory * 2**30 > 64 * have:
            raise UsageError(f"--memory {memory:g} GiB: more than 64 times this machine's "
                             f"{have / 2**30:.1f} GiB; give the budget the steps may use")
        return int(memory * 2**30)
    have = physical_memory()
    return int(0.5 * have) if have else 4 * 2**30


def _band_rows(shape, window_frames: int, halo, o: RunOptions, budget: int, *,
               itemsize: int = 8, strategy=None, every: int | None = None) -> int:
    """Rows per band: all (one band) where a step fits the budget (as read, or with its
    frames' values kept, steps ``every`` frames apart: :func:`_framed_need`) or the
    strategy needs whole images; else the widest bands that fit (``band_rows`` chooses
    them instead)."""
    T, Sy, Sx, H, W = shape
    if halo is None:
        if o.band_rows is not None:
            raise UsageError("--band-rows: a refocused light field is estimated whole")
        return H
    if o.band_rows is not None:
        return min(int(o.band_rows), H)

    def need(rows=None):
        return step_memory(shape, window_frames, rows, halo, itemsize=itemsize,
                           strategy=strategy)

    # whole steps with their frames kept, where this machine's budget plans them (a
    # cluster's workers keep frames only within their own memory limits: frame_cache)
    framed = (_framed_need(shape, window_frames, every, 1, itemsize=itemsize,
                           strategy=strategy) if o.connect is None else None)
    if need() <= budget or (framed is not None and framed <= budget):
        return H
    if need(halo + 1) > budget and 3 * halo + 1 >= H:
        # the narrowest band and its halo span the whole image: bands cannot help (under
        # affine motion the pooled rates' reach is far larger than a 512-row image)
        raise UsageError(
            f"a step reads the whole image (a band's estimate reads {halo} rows either "
            f"side of it, the image has {H}): {window_frames} frames of {Sy}x{Sx} views "
            f"of {H}x{W} px need about {need() / 2**30:.2f} GiB, more than the memory "
            f"budget {budget / 2**30:.2f} GiB (--memory GIB)")
    if need(halo + 1) > budget:
        raise UsageError(
            f"even a band of {halo + 1} rows (and the {halo} rows either side its estimate "
            f"reads) of {window_frames} frames of {Sy}x{Sx} views of {W} px needs about "
            f"{need(halo + 1) / 2**30:.2f} GiB, more than the memory budget "
            f"{budget / 2**30:.2f} GiB (--memory GIB)")
    # the widest band that fits (the need grows with the rows)
    lo, hi = halo + 1, H - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if need(mid) <= budget else (lo, mid - 1)
    return lo


def _read_itemsize(source, strategy) -> int:
    """Bytes a sample of the windows a step reads (estimate_step: float32 where the
    source stores it and the strategy takes it)."""
    return 4 if source.itemsize == 4 and getattr(strategy, "takes_float32", False) else 8


def plan_run(source, strategy, o: RunOptions, sink) -> Plan:
    """The steps, windows and bands of a run (nothing is read or written)."""
    frames, windows = _steps(source, strategy, o, sink)
    frames, windows, notes, times, intervals = _timed_steps(source, frames, windows,
                                                            sink.max_steps == 1 or
                                                            len(frames) == 1)
    halo = strategy.halo
    n = max(hi - lo for lo, hi in windows)
    rows = _band_rows(source.shape, n, halo, o, _budget(o.memory),
                      itemsize=_read_itemsize(source, strategy), strategy=strategy,
                      every=_every(frames))
    H = source.shape[3]
    bands = tuple((r0, min(r0 + rows, H)) for r0 in range(0, H, rows))
    return Plan(source, strategy, frames, windows, bands, halo or 0, strategy.reach,
                notes, times, intervals)


# a frame interval this far from the recording's median interval is a gap: timers jitter
# by a few per cent, a missed frame doubles the interval.  The temporal filters assume
# evenly spaced frames: within this tolerance a rate is off by about as much as the
# intervals differ, a window across a gap is wrong by the gap's factor
GAP_TOLERANCE = 0.25


def _timed_steps(source, frames, windows, one: bool):
    """The steps whose window spans no gap in the source's time stamps, with notes on
    those left out, and each step's time and frame interval (s).  A single step (an
    ``.npz``, ``--ref-frame``) whose window spans a gap is refused."""
    times = source.time_stamps()
    if times is None:
        return frames, windows, (), None, None
    d = np.diff(times)
    if d.size == 0:
        return frames, windows, (), (0.0,) * len(frames), None
    nominal = float(np.median(d))
    irregular = np.flatnonzero(np.abs(d / nominal - 1.0) > GAP_TOLERANCE)   # k -> k + 1

    def spans(lo, hi):
        return [int(k) for k in irregular if lo <= k and k + 1 < hi]

    def say(ks):
        shown = ", ".join(f"frames {k} -> {k + 1}: {d[k]:g} s" for k in ks[:3])
        more = f" and {len(ks) - 3} more" if len(ks) > 3 else ""
        return (f"{shown}{more} (the median interval {nominal:g} s; "
                f"{GAP_TOLERANCE:.0%} off it is a gap)")

    keep = [i for i, w in enumerate(windows) if not spans(*w)]
    notes = ()
    if len(keep) < len(frames):
        gone = [frames[i] for i in range(len(frames)) if i not in set(keep)]
        ks = sorted({k for i in range(len(frames)) if i not in set(keep)
                     for k in spans(*windows[i])})
        if one:
            lo, hi = windows[0]
            raise UsageError(f"{source.path}: the step at frame {frames[0]} reads frames "
                             f"{lo}..{hi - 1}, whose time stamps have a gap: {say(ks)}; "
                             "the temporal filters need evenly spaced frames: choose "
                             "another frame (--ref-frame)")
        if not keep:
            raise UsageError(f"{source.path}: every step's window spans a gap in the time "
                             f"stamps: {say(ks)}")
        notes = (f"left out {len(gone)} step(s) at frames {gone[0]}..{gone[-1]} whose "
                 f"temporal window spans a gap in the time stamps: {say(ks)}",)
    frames = tuple(frames[i] for i in keep)
    windows = tuple(windows[i] for i in keep)
    step_t = tuple(float(times[k] - times[0]) for k in frames)
    step_dt = tuple(float((times[hi - 1] - times[lo]) / (hi - lo - 1)) if hi - lo > 1
                    else nominal for lo, hi in windows)
    return frames, windows, notes, step_t, step_dt


def _crop(ests: dict, rows: slice, settings: dict) -> dict:
    from gridflow.estimator import Estimate

    return {m: Estimate({q: v[rows] for q, v in e.items()}, e.model, e.interior[rows],
                        {**e.settings, **settings}) for m, e in ests.items()}


def estimate_step(plan: Plan, i: int, b: int, progress=None) -> tuple[dict, int]:
    """Estimate band ``b`` of step ``i``: ``({model: Estimate} of the band's rows, the
    stamp of the frames read)``.  Reads only the step's window of frames, and of them
    only the band's rows and ``plan.halo`` rows either side, so that the band's maps are
    those of the whole image (the estimate at a pixel reads no farther)."""
    from gridflow.estimator import Estimate, InputError

    src = plan.source
    lo, hi = plan.windows[i]
    k = plan.frames[i]
    # the stamp before the read: a frame replaced during the read makes the next run
    # redo this step rather than keep it
    stamp = src.stamp(lo, hi)
    H, W = src.shape[3:]
    r0, r1 = plan.bands[b]
    halo, border = plan.halo, plan.strategy.border or 0
    if len(plan.bands) > 1 and (r1 <= border or r0 >= H - border):
        # a band within the image's border: no pixel there has a whole window
        names = plan.strategy.quantities(src.shape)
        nan = {m: Estimate({q: np.full((r1 - r0, W), np.nan) for q in qs}, m,
                           np.zeros((r1 - r0, W), dtype=bool)) for m, qs in names.items()}
        return nan, stamp
    a0, a1 = (max(0, r0 - halo), min(H, r1 + halo)) if len(plan.bands) > 1 else (0, H)
    # float32 where the source stores it and the strategy takes it: half the memory and
    # no conversion, the same maps
    stored = _read_itemsize(src, plan.strategy) == 4
    dtype = np.float32 if stored else np.float64
    if (src.values_kept and (a0, a1) == (0, H) and isinstance(plan.strategy, SinglePass)):
        # the window frame by frame: each frame's camera sums (and largest magnitude,
        # reference view) and, where the estimator keeps them, filtered signals computed
        # once for the steps that share it, and no window assembled (the maps are the
        # same bit for bit: FramedVolume)
        from gridflow.estimator.signals import FramedVolume

        window = FramedVolume(
            (hi - lo,) + tuple(src.shape[1:]), np.dtype(dtype),
            lambda t, key, fn: src.frame_value(lo + t, key, fn, dtype),
            lambda t, span, key, fn: src.span_value(lo + t, [lo + u for u in span], key, fn))
    else:
        window = src.read(lo, hi, rows=(a0, a1), dtype=dtype)
    try:
        mask = plan.strategy.step_mask(src, k)
        ests = plan.strategy.run(window, src.geometry.for_rows(a0), k - lo, progress,
                                 mask=None if mask is None else mask[a0:a1])
    except InputError as exc:
        where = (f"frames {lo}..{hi - 1} (step at frame {k})" if (lo, hi) != (0, src.frames)
                 else "")
        text = str(exc)
        if str(src.path) not in text:
            text = f"{src.path}: {where + ': ' if where else ''}{text}"
        raise InputError(text) from None
    ests = with_depth(ests, src.meta.get("hci"))
    # the reference frame as the source counts its frames, not the window
    fix = {"ref_frame": k} if isinstance(plan.strategy, SinglePass) else {}
    if mask is not None:
        fix["mask"] = plan.strategy.mask if isinstance(plan.strategy.mask, str) else "given"
    return _crop(ests, slice(r0 - a0, r1 - a0), fix), stamp


_OPENING = threading.Lock()


@lru_cache(maxsize=4)
def _opened(source: str, views, sink_spec: str):
    """The source and the map series' sink, opened once per worker process and run."""
    import json

    from gridflow.sources import open_source

    from .sinks import MapSeriesSink

    return open_source(source, views=views), MapSeriesSink.reopen(json.loads(sink_spec))


def run_step(job: dict, i: int, b: int) -> dict:
    """A task on a worker: estimate band ``b`` of step ``i`` of the run ``job`` (paths,
    strategy and plan, no data) and write it into the map series; returns its timing."""
    import json

    try:
        import numba

        numba.set_num_threads(max(1, min(job["threads"], numba.config.NUMBA_NUM_THREADS)))
    except ImportError:
        pass
    t0 = time.perf_counter()
    # one opening per process: threads that start together must not each open their
    # own (each would keep its own decoded frames)
    with _OPENING:
        source, sink = _opened(job["source"], job["views"], json.dumps(job["sink"],
                                                                        sort_keys=True))
    # what the estimator computes from each frame alone is kept for the frames a worker's
    # steps share (Source.frame_value: one decode a frame, waited for by a second thread
    # that needs it); decoded frames are not kept beside it
    source.keep_values(job.get("cache_frames", 0))
    source.cache_frames(0)
    ests, stamp = estimate_step(replace(job["plan"], source=source), i, b)
    t1 = time.perf_counter()
    sink.write(i, b, ests, stamp)
    return {"step": i, "band": b, "estimate_s": t1 - t0, "write_s": time.perf_counter() - t1}


def _every(frames) -> int | None:
    """The largest spacing of consecutive steps (None for one step)."""
    return max((b - a for a, b in zip(frames, frames[1:])), default=None)


def _framed(plan: Plan, tasks: int) -> int | None:
    """:func:`_framed_need` of ``plan``'s whole steps, ``tasks`` at once (None where its
    steps are cut into bands or do not share frames)."""
    if len(plan.bands) != 1:
        return None
    return _framed_need(plan.source.shape, plan.window_frames, _every(plan.frames), tasks,
                        itemsize=_read_itemsize(plan.source, plan.strategy),
                        strategy=plan.strategy)


def _local(plan: Plan, o: RunOptions) -> tuple[int, int, int]:
    """(tasks at once, numba threads each, budget bytes) on this machine."""
    cores = os.cpu_count() or 1
    budget = _budget(o.memory)
    n = o.workers if o.workers is not None else cores
    if not (isinstance(n, int) and n >= 1):
        raise UsageError(f"--workers must be a positive number, got {o.workers!r}")
    r0, r1 = plan.bands[0]
    frames = plan.window_frames
    need = step_memory(plan.source.shape, frames, r1 - r0, plan.halo,
                       itemsize=_read_itemsize(plan.source, plan.strategy),
                       strategy=plan.strategy)
    one = _framed(plan, 1)
    if one is not None and one <= budget:
        # whole steps whose worker keeps its frames' values: as many at once as fit with
        # the frames kept for them (frame_cache keeps them for that many)
        k = 1
        while k < n and _framed(plan, k + 1) <= budget:
            k += 1
        return k, max(1, cores // k), budget
    if need > budget:
        T, Sy, Sx, H, W = plan.source.shape
        raise UsageError(f"a band of {r1 - r0} rows needs about {need / 2**30:.2f} GiB ("
                         f"{frames} frames of {Sy}x{Sx} views of {W} px, {plan.halo} rows "
                         f"either side), more than the memory budget {budget / 2**30:.2f} "
                         "GiB (--memory GIB, --band-rows)")
    n = max(1, min(n, budget // need))
    return n, max(1, cores // n), budget


def frame_cache(plan: Plan, tasks: int, budget: int) -> int:
    """Frames a worker keeps the values of (:meth:`gridflow.volume.Source.keep_values`:
    each frame's camera sums, centre view and, where the estimator keeps them,
    filtered signals, :func:`gridflow.estimator.kept_frame_bytes`) for
    ``tasks`` steps at once: a window and the frames the further steps reach beyond it,
    so that steps one frame apart decode and filter one frame each; none where steps are
    cut into row bands (memory is short there), where steps do not share frames, or where
    the frames would not fit in the ``budget`` bytes beside the steps' own
    (:func:`_framed_need`)."""
    need = _framed(plan, tasks)
    if need is None or need > budget:
        return 0
    return plan.window_frames + (tasks - 1) * _every(plan.frames)


def _check_options(o: RunOptions) -> None:
    for name, v in (("--every", o.every), ("--band-rows", o.band_rows),
                    ("--workers", o.workers)):
        if v is not None and not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
            raise UsageError(f"{name} must be a positive integer, got {v!r}")
    if o.connect is not None and (o.workers is not None or o.memory is not None):
        given = [f for f, v in (("--workers", o.workers), ("--memory", o.memory)) if v]
        raise UsageError(f"{', '.join(given)}: for this machine's own tasks; with "
                         "--connect the cluster's workers decide")
    if o.memory is not None:
        _budget(o.memory)


def estimate(input, output, options: RunOptions | None = None) -> RunReport:
    """Estimate the source ``input`` into the sink ``output``: the one pipeline behind
    ``gridflow estimate`` (module docstring).

    Parameters
    ----------
    input : path
        Any source :func:`gridflow.sources.open_source` opens: a volume ``.npz``, a
        camera-grid folder, an HCI scene folder, a recording store.
    output : path
        ``.npz``: one step, one file per model (``_MODEL`` before the suffix for
        several); ``.zarr``: a map series per model, resumable.
    options : RunOptions

    Returns
    -------
    RunReport
    """
    from gridflow.sources import open_source

    from .sinks import sink_for

    o = options or RunOptions()
    settings = {k: v for k, v in o.settings.items() if v is not None}
    o = replace(o, settings=settings)
    _check_options(o)
    # the outputs are checked before the input is read (a bad name, an unwritable folder
    # or a name too long must not cost the decoding of a scene); again once the models
    # are known
    sink = sink_for(output, o.models or ("full",), inputs=[input])
    views = o.views
    if views is None and (o.shears == "none" or o.select == "coarse"):
        # what the 5-tap camera filters reach; refocusing's sub-grids use all views
        from gridflow.hci import is_hci_scene

        views = 5 if is_hci_scene(input) else None
    source = open_source(input, views=views)
    strategy, notes = choose_strategy(source, o)
    sink = sink_for(output, strategy.models, inputs=[input])
    if sink.max_steps == 1 and (o.connect or o.workers is not None):
        given = [f for f, v in (("--connect", o.connect), ("--workers", o.workers))
                 if v is not None]
        raise UsageError(f"{', '.join(given)}: for a series of steps (-o MAPS.zarr); -o "
                         f"{output} is one step, estimated in this process")
    plan = plan_run(source, strategy, o, sink)
    notes = list(notes) + list(plan.notes)
    _check_fits(plan)
    # a cluster that does not answer is reported before the store is made
    client = None
    if o.connect and sink.max_steps != 1:
        from .executors import make_client

        client = make_client(scheduler=o.connect, option="--connect")
    try:
        report, changed = _prepare_and_run(plan, sink, o, views, notes, client, output)
    finally:
        if client is not None:
            client.close()
    report.lines += sink.close()
    report.lines += _summary(plan, sink, o, report, changed, output)
    return report


def _prepare_and_run(plan: Plan, sink, o: RunOptions, views, notes, client, output):
    """Make or reopen the sink's outputs, then run the tasks not done yet: ``(report,
    the steps redone because their frames changed)``."""
    sink.prepare(plan)
    todo, changed, kept = sink.todo(plan)
    if sink.damaged:
        q, i = sink.damaged[0]
        steps = sorted({j for _, j in sink.damaged})
        msg = (f"{output}: {len(steps)} step(s) marked done lack a chunk of their maps or "
               f"the interior (e.g. {q} of step {i}, frame {plan.frames[i]}); estimating "
               "them again")
        _say(o.progress, msg)
        notes = list(notes) + [msg]
    if o.limit is not None:
        todo = todo[:o.limit]
    report = RunReport(lines=notes, steps=len(plan.frames), skipped=kept)
    if kept:
        _say(o.progress, f"{output}: {kept} of {len(plan.frames)} steps already done, "
             "resuming")
    if changed:
        _say(o.progress, f"{output}: {len(changed)} done step(s) read frames that changed "
             "since; estimating them again")
    t0 = time.perf_counter()
    if sink.max_steps == 1:
        _run_here(plan, sink, todo, o)
        report.now = report.done = len(plan.frames)
    else:
        _run_tasks(plan, sink, todo, o, views, report, client)
    report.seconds = time.perf_counter() - t0
    return report, changed


def _run_here(plan: Plan, sink, todo, o: RunOptions) -> None:
    """One step in this process (an ``.npz``), with a bar over the shears when
    refocusing."""
    bar = None
    s = plan.strategy
    T, Sy, Sx, H, W = plan.source.shape
    if isinstance(s, Refocus):
        _say(o.progress, f"refocusing {Sy}x{Sx} views ({_views_used(Sy, s.select)}) over "
             f"shears {s.shears[0]} .. {s.shears[-1]} ({s.select}; sigma {s.sigma:g} px, "
             f"{s.window} taps) ...")
        if o.progress:
            from tqdm import tqdm

            bar = tqdm(total=len(s.shears), unit="shear", file=sys.stderr, leave=False)

    def step(done, total):
        if bar is not None:
            bar.update(done - bar.n)

    try:
        for i, b in todo:
            ests, stamp = estimate_step(plan, i, b, progress=step)
            sink.write(i, b, ests, stamp)
    finally:
        if bar is not None:
            bar.close()


def _check_fits(plan: Plan) -> None:
    """Refuse, before any output is made, an image too small for the window and filters
    (the estimator's own rule, :func:`gridflow.estimator.window_halo`)."""
    from gridflow.estimator import InputError

    halo = plan.strategy.border
    H, W = plan.source.shape[3:]
    if halo is not None and (H <= 2 * halo or W <= 2 * halo):
        s = plan.strategy.estimator_settings
        raise InputError(f"{plan.source.path}: image {H}x{W} too small for a {s.window}-tap "
                         f"window and {s.filters} filters: need more than {2 * halo} pixels "
                         "per side (--sigma, --window)")


def _run_tasks(plan: Plan, sink, todo, o: RunOptions, views, report: RunReport,
               client=None) -> None:
    """The (step, band) tasks of a map series, on Dask (local threads or ``client``'s
    cluster)."""
    import dask

    T, Sy, Sx, H, W = plan.source.shape
    nb = len(plan.bands)
    job = {"source": str(Path(plan.source.path).resolve()), "views": views,
           "sink": sink.spec(), "plan": replace(plan, source=None), "threads": 1}
    if client is not None:
        where = f"the dask cluster at {o.connect}"
        workers = list(client.scheduler_info()["workers"].values())
        n = sum(w.get("nthreads", 1) for w in workers)
        # each worker process keeps its own frames, where they fit its memory limit
        # beside its threads' steps (none where a worker states no limit)
        limits = [w.get("memory_limit") or 0 for w in workers]
        job["cache_frames"] = (frame_cache(plan, max(w.get("nthreads", 1) for w in workers),
                                           min(limits))
                               if workers and all(limits) else 0)
    else:
        n, threads, budget = _local(plan, o)
        job["threads"] = threads
        job["cache_frames"] = frame_cache(plan, n, budget)
        unit = "step" if nb == 1 else "band"
        where = (f"this machine: {n} {unit}(s) at once, {threads} numba thread(s) each, "
                 f"memory budget {budget / 2**30:.1f} GiB")
    cut = "" if nb == 1 else f", each in {nb} row bands of {plan.bands[0][1]} rows"
    frames = plan.window_frames
    _say(o.progress, f"{len({i for i, _ in todo})} steps ({frames} frames of {Sy}x{Sx} "
         f"views of {W}x{H} px each{cut}) on {where} ...")
    report.lines.append(f"ran on {where}")
    bar = None
    if o.progress:
        from tqdm import tqdm

        bar = tqdm(total=len(plan.frames) * nb, initial=len(plan.frames) * nb - len(todo),
                   unit="step" if nb == 1 else "band", file=sys.stderr, dynamic_ncols=True)
    finished = 0
    try:
        if client is not None:
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

            # keys in step order: the threaded scheduler breaks ties between independent
            # tasks by key, and random keys ran the steps in random order, so that a
            # worker's kept frames (frame_cache) were mostly not those the next step reads
            tasks = [dask.delayed(run_step, pure=False)(
                job, i, b, dask_key_name=f"step-{i:09d}-{b:05d}") for i, b in todo]
            try:
                with Tick():
                    dask.compute(*tasks, scheduler="threads", num_workers=n)
            finally:
                # the sources opened here keep decoded frames: not beyond the run
                _opened.cache_clear()
    finally:
        if bar is not None:
            bar.close()
    report.now = finished / nb


def _summary(plan: Plan, sink, o: RunOptions, report: RunReport, changed, output) -> list:
    s = plan.strategy
    T, Sy, Sx, H, W = plan.source.shape
    if isinstance(s, Refocus):
        est = sink.ests["bcc"] if sink.max_steps == 1 else None
        if est is None:
            return [f"wrote {output}: refocused over shears {list(s.shears)} ({s.select})"]
        d = est["disparity"]
        filled = est["filled"] > 0
        valid = est.interior & ~filled
        n_none = int((~np.isfinite(d)).sum())
        return [f"wrote {output}: {Sy}x{Sx} views ({_views_used(Sy, s.select)}) refocused "
                f"over shears {list(s.shears)} ({s.select}); {int(valid.sum())} of {d.size} "
                f"pixels estimated, {int(filled.sum())} filled from their neighbours "
                f"('filled'), {n_none} without a value",
                f"estimated in {report.seconds:.2f} s"]
    if sink.max_steps == 1:
        backend = next(iter(sink.ests.values())).settings["backend"]
        method = s.settings.get("method", "fast")
        lo, hi = plan.windows[0]
        frames = f"{T} frames" if (lo, hi) == (0, T) else f"frames {lo}..{hi - 1} of {T}"
        return [f"estimated {', '.join(s.models)} (motion {s.motion}) in "
                f"{report.seconds:.2f} s (method {method}: the {backend} backend; {Sy}x{Sx} "
                f"views, {frames})"]
    lines = []
    if changed:
        lines.append(f"{len(changed)} step(s) estimated again: frames they read changed "
                     f"since (steps at frames {[plan.frames[i] for i in changed][:5]}...)")
    report.done = done_now = sink.done_steps()
    rate = report.now / report.seconds if report.seconds > 0 else float("nan")
    names = ", ".join(str(p) for p in sink.outputs.values())
    lines.append(f"wrote {names}: {done_now} of {len(plan.frames)} steps done "
                 f"({report.now:g} now in {report.seconds:.1f} s, {rate:.3f} steps/s; "
                 f"{report.skipped} done by an earlier run); model {', '.join(s.models)}, "
                 f"motion {getattr(s, 'motion', 'translation')}; open with xarray.open_zarr("
                 f"'{next(iter(sink.outputs.values()))}', consolidated=False)")
    return lines
