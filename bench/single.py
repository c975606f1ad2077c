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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gridflow.errors import FileFormatError, UsageError
from gridflow.estimator import Estimate, EstimatorSettings, estimate_models
from gridflow.estimator.lightfield import SELECT_DEFAULTS, estimate_refocused, stated_shears
from gridflow.io import check_output, load_estimate, load_volume, save_estimate, save_volume

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


def estimate_input(path, output, *, models=None, settings: dict | None = None, views=None,
                   shears=None, select: str = "coarse") -> EstimateReport:
    """Estimate the volume, image folder or light field ``path``; write ``output``.

    Parameters
    ----------
    path : path
        Input (:func:`load_input`).
    output : path
        ``.npz``; with several models one file each (:func:`model_outputs`).
    models : tuple of str, optional
        Default ``("full",)``, or ``("bcc",)`` for a light field of one frame.
    settings : dict
        Estimator settings (:class:`gridflow.estimator.EstimatorSettings`); a
        ``ref_frame`` of None takes the image folder's ``reference_frame``.
    views : int, optional
        HCI scenes: the central views x views used.  Default 5 (what 5-tap camera filters
        reach), all with ``shears`` and an occlusion-aware ``select``.
    shears : tuple of int or "auto", optional
        Refocus a light field of one frame over these integer disparities
        (:func:`gridflow.estimator.lightfield.estimate_refocused`); ``"auto"``: the range
        the scene states.  ``settings`` then gives ``sigma``, ``window`` (None: the
        choice's defaults) and ``filters``.
    select : {"coarse", "lines", "occlusion"}
        With ``shears``: how each pixel's shear is chosen.
    """
    settings = dict(settings or {})
    if shears is None:
        EstimatorSettings(**settings)           # bad settings fail before the volume loads
    if views is None:
        # all views where the occlusion-aware shears use the outer ones, else what the
        # 5-tap camera filters reach
        views = None if (shears is not None and select != "coarse") else 5
    data = load_input(path, views=views)
    if shears is not None:
        check_output(output, suffixes=".npz", inputs=[path], what="-o")
        return _estimate_refocused(path, data, output, models, settings, shears, select)
    if models is None:
        models = ("bcc",) if data.volume.shape[0] == 1 else ("full",)
    outputs = model_outputs(output, models)
    for p in outputs.values():
        check_output(p, suffixes=".npz", inputs=[path], what="-o")
    if settings.get("ref_frame") is None:
        # an image folder's grid.json may name its reference frame (--ref-frame overrides)
        settings["ref_frame"] = data.meta.get("ref_frame")
    t0 = time.perf_counter()
    ests = estimate_models(data.volume, data.focal_length, data.camera_spacing,
                           models=models, principal_point=data.principal_point, **settings)
    report = EstimateReport(seconds=time.perf_counter() - t0)
    geometry = data.meta.get("hci")
    for m, est in ests.items():
        if geometry and "disparity" in est.maps:
            # converging HCI cameras: depth in metres from the disparity and the focus
            # distance (parameters.cfg); the slopes stay those of the parallel-camera
            # reading (camera steps as the unit of length)
            from gridflow.hci import depth_from_disparity

            est.maps["Z"] = depth_from_disparity(est.maps["disparity"], geometry)
            est.settings["Z_units"] = "m (HCI geometry)"
        save_estimate(outputs[m], est)
        n_ok = int(np.isfinite(est["Z"][est.interior]).sum())
        report.lines.append(f"wrote {outputs[m]}: model {m}, {n_ok}/"
                            f"{int(est.interior.sum())} interior pixels valid")
    backend = next(iter(ests.values())).settings["backend"]
    report.lines.append(f"estimated {', '.join(models)} in {report.seconds:.2f} s "
                        f"(method {settings.get('method', 'fast')}: the {backend} backend)")
    return report


def _estimate_refocused(path, data, output, models, settings, shears, select) -> EstimateReport:
    """A static light field refocused over integer shears."""
    T = data.volume.shape[0]
    if T != 1:
        raise UsageError(f"--shears refocuses a light field of one frame; {path} has "
                         f"{T} frames")
    if models not in (None, ("bcc",)):
        raise UsageError(f"--shears takes model bcc (a light field of one frame), got "
                         f"{','.join(models)}")
    if settings.get("motion", "translation") != "translation":
        raise UsageError(f"--shears refocuses a light field of one frame, which has no "
                         f"motion; --motion {settings['motion']} does not apply")
    geometry = data.meta.get("hci")
    if shears == "auto":
        shears = stated_shears((geometry or {}).get("disp_range"))
        if shears is None:
            raise UsageError(f"--shears auto: {path} states no disparity range "
                             "(parameters.cfg [meta] disp_min, disp_max); give MIN MAX")
    views = data.volume[0]
    if views.shape[0] != views.shape[1]:
        raise UsageError(f"--shears needs a square grid of views, {path} has "
                         f"{views.shape[0]}x{views.shape[1]}")
    sigma = settings.get("sigma")
    window = settings.get("window")
    sigma = SELECT_DEFAULTS[select][0] if sigma is None else sigma
    window = SELECT_DEFAULTS[select][1] if window is None else window
    filters = settings.get("filters", "matched5")
    t0 = time.perf_counter()
    res = estimate_refocused(views, shears, sigma=sigma, window=window, filters=filters,
                             select=select, fill=True)
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
                             "window": window, "filters": filters,
                             "views": list(views.shape[:2]), "Z_units": units})
    save_estimate(output, est)
    lines = [f"wrote {output}: {views.shape[0]}x{views.shape[1]} views refocused over shears "
             f"{list(shears)} ({select}); {int(res['valid'].sum())} pixels estimated, "
             f"{int(res['filled'].sum())} filled from their neighbours ('filled')",
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
    rows = evaluate(maps, truth, interior)
    if not rows:
        raise FileFormatError(f"{estimate_path} and {truth_path} share no quantity names")
    hci = None
    if "disparity" in maps and "disparity" in truth:
        hci = hci_metrics(maps["disparity"], truth["disparity"])
    return EvaluationReport(meta.get("model", "?"), rows, hci, own is not None)
