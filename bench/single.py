"""Single volumes as files: what ``gridflow generate | estimate | evaluate`` do.

* :func:`generate`: a sinusoid volume with ground truth, as ``.npz`` and/or as an HCI
  light field scene.
* :func:`load_input`: a volume ``.npz``, a camera-grid image folder (``grid.json``) or an
  HCI scene folder, as a :class:`gridflow.volume.GridVolume`.
* :func:`estimate_input`: estimate one or several models and write one ``.npz`` each;
  a static light field refocused over integer shears with ``shears``.
* :func:`evaluate_input`: Eq. 22 of every quantity with truth, and the HCI benchmark's
  scores of the disparity.

Every function checks its outputs before any work starts (:func:`gridflow.io.
check_output`) and writes atomically; the CLI only parses arguments and prints.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gridflow.errors import FileFormatError, UsageError
from gridflow.estimator import Estimate, EstimatorSettings, estimate_models
from gridflow.estimator.lightfield import (SELECT_DEFAULTS, SELECTS, check_shears,
                                          estimate_refocused, stated_shears)
from gridflow.estimator.settings import InputError
from gridflow.io import (check_output, load_estimate, load_volume, save_estimate,
                         save_estimates, save_volume)

from .metrics import evaluate, hci_metrics

__all__ = ["generate", "load_input", "model_outputs", "estimate_input",
           "EstimateReport", "evaluate_input", "EvaluationReport"]


def generate(params, *, output=None, hci=None, float32: bool = False) -> list[str]:
    """Render a sinusoid volume and write it as ``output`` (.npz) and/or as the HCI scene
    folder ``hci`` (the reference frame's views, 8-bit, with ``gt_disp_lowres.pfm``).

    Parameters
    ----------
    params : SinusoidParams
    output, hci : path, optional
        At least one.
    float32 : bool
        Store the volume as float32.

    Returns
    -------
    list of str
        One line per file or folder written.
    """
    from gridflow.generators import make_sinusoid

    if not (output or hci):
        raise UsageError("give -o OUTPUT.npz, --hci FOLDER, or both")
    if output:
        check_output(output, suffixes=".npz", what="-o")
    if hci and (params.grid[0] != params.grid[1] or params.spacing[0] != params.spacing[1]):
        raise UsageError(f"--hci needs a square grid with equal spacing, got grid "
                         f"{list(params.grid)} spacing {list(params.spacing)}")
    data = make_sinusoid(params, dtype=np.float32 if float32 else np.float64)
    lines = []
    if hci:
        from gridflow.hci import write_hci

        p = data.params
        views = data.volume[p.ref_frame].astype(np.float64)
        lo, hi = float(views.min()), float(views.max())
        # 8-bit views of the reference frame; an affine map onto [0, 1] does not change
        # the disparity (parallel cameras: d = f ds / Z, px per camera step)
        views = (views - lo) / (hi - lo if hi > lo else 1.0)
        disparity = data.focal_length * p.spacing[0] / data.truth["Z"]
        files = write_hci(hci, views, disparity=disparity)
        lines.append(f"wrote {hci}: {len(files)} files (HCI layout, {p.grid[0]}x{p.grid[1]} "
                     f"views of frame {p.ref_frame}, disparity {disparity.min():.3g} .. "
                     f"{disparity.max():.3g} px per view)")
    if output:
        save_volume(output, data)
        lines.append(f"wrote {output}: volume {data.volume.shape} {data.volume.dtype}")
    return lines


def load_input(path, views: int | None = None):
    """A volume ``.npz``, a camera-grid folder with ``grid.json``, or an HCI scene folder
    (``input_Cam000.png ...``; ``views``: the central views x views used, default all)."""
    p = Path(path)
    if p.is_dir():
        from gridflow.hci import is_hci_scene, load_hci

        if is_hci_scene(p):                      # an HCI 4-D light field benchmark scene
            return load_hci(p, views=views)
        from gridflow.loader import load_folder  # camera-grid image folder with grid.json

        return load_folder(p)
    return load_volume(p)


def model_outputs(output, models) -> dict[str, Path]:
    """One model: OUTPUT itself; several: OUTPUT with _MODEL before the suffix."""
    out = Path(output)
    if len(models) == 1:
        return {models[0]: out}
    return {m: out.with_name(f"{out.stem}_{m}{out.suffix}") for m in models}


@dataclass
class EstimateReport:
    """What :func:`estimate_input` did: one line per output written and the time."""

    lines: list = field(default_factory=list)
    seconds: float = 0.0


# settings that only the estimator's single pass over a volume uses: refused where a
# light field is refocused, instead of being ignored
_SINGLE_PASS_ONLY = {"temporal_radius": "--temporal-radius", "ref_frame": "--ref-frame",
                     "method": "--method", "slant_correction": "--no-slant-correction",
                     "zoom_correction": "--no-zoom-correction",
                     "combine": "--combine", "motion": "--motion"}


@contextmanager
def _naming(path):
    """An error the estimator finds in the data (non-finite values, a pixel type it cannot
    use) names the input it came from."""
    try:
        yield
    except InputError as exc:
        if str(path) in str(exc):
            raise
        raise InputError(f"{path}: {exc}") from None


def estimate_input(path, output, *, models=None, settings: dict | None = None, views=None,
                   shears=None, select: str | None = None, fill: bool | None = None,
                   median: int | None = None, progress: bool = False) -> EstimateReport:
    """Estimate the volume, image folder or light field ``path``; write ``output``.

    A light field of one frame on a square grid (an HCI scene, a static camera-grid
    folder, a one-frame volume) is refocused by default (``shears=None``): over the
    disparity range its ``parameters.cfg`` states, else one estimated from the data
    (:func:`gridflow.estimator.lightfield.estimate_shear_range`), each pixel's estimate
    chosen among 1-D camera sub-grids (``select="lines"``), with the light-field
    smoothing scale and a dense, filled result with its confidence.  A volume of several
    frames gets the estimator's single pass.

    Parameters
    ----------
    path : path
        Input (:func:`load_input`).
    output : path
        ``.npz``; with several models one file each (:func:`model_outputs`).
    models : tuple of str, optional
        Default ``("full",)``, or ``("bcc",)`` for a light field of one frame.
    settings : dict
        The estimator settings given (:class:`gridflow.estimator.EstimatorSettings`; those
        not given keep their defaults); a ``ref_frame`` of None takes the image folder's
        ``reference_frame``.  Refocusing uses ``sigma``, ``window`` (None: the choice's
        defaults) and ``filters`` and refuses the single pass's other settings.
    views : int, optional
        HCI scenes: the central views x views used.  Default all, or 5 (what 5-tap camera
        filters reach) for the single pass and ``select="coarse"``.
    shears : None, "auto", "none" or tuple of int
        None: refocus a light field of one frame (as ``"auto"``), the single pass
        otherwise.  ``"auto"``: the stated disparity range, else one estimated from the
        data.  ``"none"``: the single pass.  A tuple: those integer shears.
    select : {"lines", "occlusion", "coarse"}, optional
        How each pixel's shear is chosen (default ``"lines"``).
    fill, median
        Refocusing: give pixels without an estimate one from their neighbours (a dense
        map; default True), and the size of the median filter over the disparity (default
        3; 0: none); :func:`gridflow.estimator.lightfield.estimate_refocused`.  ``select``,
        ``fill`` and ``median`` given for the single pass are refused, not ignored.
    progress : bool
        Print what is about to happen before each long step, and a progress bar over the
        shears, on stderr.
    """
    settings = {k: v for k, v in (settings or {}).items() if v is not None}
    # refocusing's own settings, as given (refused below where the single pass runs)
    refocus_given = [flag for flag, given in (("--select", select is not None),
                                              ("--median", median is not None),
                                              ("--no-fill", fill is False)) if given]
    select = SELECTS[0] if select is None else select
    fill = True if fill is None else fill
    median = 3 if median is None else median
    single_pass = shears == "none"
    # bad settings fail before the volume loads (refocusing uses three of them)
    EstimatorSettings(**(settings if single_pass else
                         {k: v for k, v in settings.items()
                          if k in ("sigma", "window", "filters")}))
    if views is not None:
        from gridflow.hci import is_hci_scene

        if not (Path(path).is_dir() and is_hci_scene(Path(path))):
            raise UsageError(f"--views chooses the central views of an HCI scene; {path} is "
                             "not one (a volume or camera-grid folder uses all its views)")
    # the outputs are checked before the input is read (a bad name, an unwritable folder
    # or a name too long must not cost the decoding of a scene); again below, once the
    # models are known
    for p in (model_outputs(output, models).values() if models else [output]):
        check_output(p, suffixes=".npz", inputs=[path], what="-o")
    if views is None:
        # all views where refocusing's sub-grids use the outer ones, else what the 5-tap
        # camera filters reach
        views = 5 if (single_pass or select == "coarse") else None
    data = load_input(path, views=views)
    T, gr, gc = data.volume.shape[:3]
    refocus = not single_pass and (shears is not None or (T == 1 and _square(gr, gc)))
    notes = []
    if shears is None and not refocus and T == 1:
        notes.append(f"not refocused: {path} is a {gr}x{gc} grid (refocusing needs a square "
                     "grid with an odd number of views); the single pass")
    if not refocus and refocus_given:
        why = ("--shears none asks for the single pass" if single_pass else
               f"{path} has {T} frames" if T > 1 else
               f"{path} is a {gr}x{gc} grid")
        raise UsageError(f"{', '.join(refocus_given)}: refocusing only; {why}, so the "
                         "estimator's single pass runs")
    if refocus:
        check_output(output, suffixes=".npz", inputs=[path], what="-o")
        with _naming(path):
            return _estimate_refocused(path, data, output, models, settings,
                                       "auto" if shears is None else shears, select,
                                       progress, fill=fill, median=median)
    if models is None:
        models = ("bcc",) if T == 1 else ("full",)
    outputs = model_outputs(output, models)
    for p in outputs.values():
        check_output(p, suffixes=".npz", inputs=[path], what="-o")
    if settings.get("ref_frame") is None:
        # an image folder's grid.json may name its reference frame (--ref-frame overrides)
        settings["ref_frame"] = data.meta.get("ref_frame")
    t0 = time.perf_counter()
    with _naming(path):
        ests = estimate_models(data.volume, data.focal_length, data.camera_spacing,
                               models=models, principal_point=data.principal_point,
                               **settings)
    report = EstimateReport(lines=notes, seconds=time.perf_counter() - t0)
    geometry = data.meta.get("hci")
    for m, est in ests.items():
        if geometry and "disparity" in est.maps:
            # converging HCI cameras: depth in metres from the disparity and the focus
            # distance (parameters.cfg); the slopes stay those of the parallel-camera
            # reading (camera steps as the unit of length)
            from gridflow.hci import depth_from_disparity

            est.maps["Z"] = depth_from_disparity(est.maps["disparity"], geometry)
            est.settings["Z_units"] = "m (HCI geometry)"
    # all outputs or none: a failure part-way (a full disk) or a second run writing the
    # same names leaves no mixed set
    save_estimates({outputs[m]: est for m, est in ests.items()})
    for m, est in ests.items():
        n_ok = int(np.isfinite(est["Z"][est.interior]).sum())
        report.lines.append(f"wrote {outputs[m]}: model {m}, {n_ok}/"
                            f"{int(est.interior.sum())} interior pixels valid")
    backend = next(iter(ests.values())).settings["backend"]
    report.lines.append(f"estimated {', '.join(models)} in {report.seconds:.2f} s "
                        f"(method {settings.get('method', 'fast')}: the {backend} backend; "
                        f"{gr}x{gc} views, {T} frames)")
    return report


def _square(rows: int, cols: int) -> bool:
    """A grid refocusing can use: square, with an odd number of views, at least 3."""
    return rows == cols and rows % 2 == 1 and rows >= 3


def _views_used(n: int, select: str) -> str:
    """Which of an n x n grid's views a refocusing choice reads (its default sub-grids)."""
    if select == "lines":
        return f"the centre row and column, {2 * n - 1} views"
    if select == "occlusion":
        m = min(5, n)
        return f"{m}x{m} sub-grids at the centre, edges and corners, {n * n} views"
    return f"all {n * n} views"


def _estimate_refocused(path, data, output, models, settings, shears, select,
                        progress=False, fill=True, median=3) -> EstimateReport:
    """A static light field refocused over integer shears."""
    import sys

    from gridflow.estimator.lightfield import estimate_shear_range

    def say(text):
        if progress:
            print(text, file=sys.stderr, flush=True)

    T = data.volume.shape[0]
    if T != 1:
        raise UsageError(f"--shears refocuses a light field of one frame; {path} has "
                         f"{T} frames")
    if models not in (None, ("bcc",)):
        raise UsageError(f"a light field of one frame is refocused with model bcc, got "
                         f"--model {','.join(models)} (--shears none: the single pass)")
    given = [flag for key, flag in _SINGLE_PASS_ONLY.items() if key in settings
             and not (key == "motion" and settings[key] == "translation")
             and not (key in ("slant_correction", "zoom_correction") and settings[key])]
    if given:
        raise UsageError(f"{', '.join(given)}: the estimator's single pass only; a light "
                         f"field of one frame ({path}) is refocused (--shears none: the "
                         "single pass)")
    views = data.volume[0]
    if not _square(*views.shape[:2]):
        raise UsageError(f"--shears needs a square grid with an odd number of views (at "
                         f"least 3), {path} has {views.shape[0]}x{views.shape[1]}")
    n = views.shape[0]
    geometry = data.meta.get("hci")
    filters = settings.get("filters", "matched5")
    lines = []
    H, W = views.shape[-2:]
    if shears == "auto":
        stated = (geometry or {}).get("disp_range")
        try:
            shears = stated_shears(stated)
            if shears is not None:
                check_shears(shears, n, H, W, what="the stated disparity range")
        except InputError as e:
            raise FileFormatError(f"{Path(path) / 'parameters.cfg'}: [meta] disp_min, "
                                  f"disp_max: {e}") from None
        if shears is not None:
            lines.append(f"disparity range {stated[0]:g} .. {stated[1]:g} px per view, as "
                         f"{path} states (parameters.cfg)")
        else:
            say(f"{path} states no disparity range: a coarse pass estimates it ...")
            shears, info = estimate_shear_range(views, filters=filters)
            check_shears(shears, n, H, W, what="the disparity range estimated from the data")
            lines.append(f"disparity range {info['lo']:.2f} .. {info['hi']:.2f} px per view, "
                         f"estimated from the data (coarse pass at 1/{info['k']} resolution; "
                         "none stated: --shears MIN MAX to give one)")
    else:
        try:
            check_shears(shears, n, H, W, what="--shears")
        except InputError as e:
            raise UsageError(str(e)) from None
    shears = tuple(int(s) for s in shears)
    sigma = settings.get("sigma")
    window = settings.get("window")
    sigma = SELECT_DEFAULTS[select][0] if sigma is None else sigma
    window = SELECT_DEFAULTS[select][1] if window is None else window
    say(f"refocusing {n}x{n} views ({_views_used(n, select)}) over shears "
        f"{shears[0]} .. {shears[-1]} ({select}; sigma {sigma:g} px, {window} taps) ...")
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(shears), unit="shear", file=sys.stderr, leave=False)

    def step(done, total):
        if bar is not None:
            bar.update(done - bar.n)

    t0 = time.perf_counter()
    try:
        res = estimate_refocused(views, shears, sigma=sigma, window=window, filters=filters,
                                 select=select, fill=fill, median=median, progress=step)
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - t0
    d = res["disparity"]
    if geometry:
        from gridflow.hci import depth_from_disparity

        Z, units = depth_from_disparity(d, geometry), "m (HCI geometry)"
    else:
        # parallel cameras: disparity = -v ds_x with v = -f / Z
        with np.errstate(divide="ignore", invalid="ignore"):
            Z = data.focal_length * data.camera_spacing[0] / d
        units = "as camera_spacing"
    maps = {"disparity": d, "Z": Z, "model_error": res["model_error"],
            "confidence": res["confidence"], "shear": res["shear"],
            "filled": res["filled"].astype(float)}
    est = Estimate(maps=maps, model="bcc", interior=res["valid"] | res["filled"],
                   settings={"shears": list(shears), "select": select, "sigma": sigma,
                             "window": window, "filters": filters, "fill": fill,
                             "median": median,
                             "views": list(views.shape[:2]), "Z_units": units})
    save_estimate(output, est)
    n_px = d.size
    n_none = int((~np.isfinite(d)).sum())
    lines += [f"wrote {output}: {n}x{n} views ({_views_used(n, select)}) refocused over "
              f"shears {list(shears)} ({select}); {int(res['valid'].sum())} of {n_px} pixels "
              f"estimated, {int(res['filled'].sum())} filled from their neighbours "
              f"('filled'), {n_none} without a value",
              f"estimated in {seconds:.2f} s"]
    return EstimateReport(lines, seconds)


@dataclass
class EvaluationReport:
    """What :func:`evaluate_input` measured.

    Attributes
    ----------
    model : str
    rows : list of dict
        :func:`gridflow.bench.metrics.evaluate`.
    hci : dict or None
        :func:`gridflow.bench.metrics.hci_metrics` of the disparity, where both have one.
    own_interior : bool
        The truth's own ``interior`` mask restricted the pixels.
    """

    model: str
    rows: list
    hci: dict | None
    own_interior: bool


def evaluate_input(estimate_path, truth_path) -> EvaluationReport:
    """Score the estimate file ``estimate_path`` against the truth of ``truth_path`` (a
    volume or folder, :func:`load_input`): Eq. 22 over the estimate's interior, leaving out
    pixels where the truth is NaN; a truth map named ``interior`` (the rendered cube has
    one) restricts it further."""
    maps, interior, meta = load_estimate(estimate_path)
    truth = dict(load_input(truth_path, views=3).truth)
    if not truth:
        raise FileFormatError(f"{truth_path}: holds no truth maps to evaluate against")
    shape = next(iter(truth.values())).shape
    if interior.shape != shape:
        raise FileFormatError(f"{estimate_path}: maps of shape {interior.shape} do not match the "
                       f"truth of {truth_path} {shape}")
    own = truth.pop("interior", None)
    if own is not None:
        interior = interior & own.astype(bool)
    if not interior.any():
        raise FileFormatError(f"{estimate_path}: no pixel to score (its interior"
                              + (f" within the interior of {truth_path}" if own is not None
                                 else "") + " is empty)")
    rows = evaluate(maps, truth, interior)
    if not rows:
        raise FileFormatError(f"{estimate_path} and {truth_path} share no quantity names")
    hci = None
    if "disparity" in maps and "disparity" in truth:
        hci = hci_metrics(maps["disparity"], truth["disparity"])
        if hci["n_pixels"] == 0:
            raise FileFormatError(f"{truth_path}: its disparity truth has no finite value "
                                  "inside the benchmark's 15-pixel border")
    return EvaluationReport(meta.get("model", "?"), rows, hci, own is not None)
