"""Single volumes as files: what ``gridflow generate | evaluate`` do (``gridflow
estimate`` is the grower's pipeline, :func:`gridflow.pipeline.estimate`).

* :func:`generate`: a sinusoid volume with ground truth, as ``.npz`` and/or as an HCI
  light field scene.
* :func:`evaluate_input`: Eq. 22 of every quantity with truth, and the HCI benchmark's
  scores of the disparity.

Every function checks its outputs before any work starts (:func:`gridflow.io.
check_output`) and writes atomically; the CLI only parses arguments and prints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gridflow.errors import FileFormatError, UsageError
from gridflow.io import check_output, load_estimate, save_volume

from gridflow.metrics import evaluate, hci_metrics

__all__ = ["generate", "evaluate_input", "EvaluationReport"]


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


@dataclass
class EvaluationReport:
    """What :func:`evaluate_input` measured.

    Attributes
    ----------
    model : str
    rows : list of dict
        :func:`gridflow.metrics.evaluate`.
    hci : dict or None
        :func:`gridflow.metrics.hci_metrics` of the disparity, where both have one.
    own_interior : bool
        The truth's own ``interior`` mask restricted the pixels.
    """

    model: str
    rows: list
    hci: dict | None
    own_interior: bool


def evaluate_input(estimate_path, truth_path) -> EvaluationReport:
    """Score the estimate file ``estimate_path`` against the truth of ``truth_path`` (a
    volume, folder or recording: :func:`gridflow.sources.open_source`): Eq. 22 over the estimate's interior, leaving out
    pixels where the truth is NaN; a truth map named ``interior`` (the rendered cube has
    one) restricts it further."""
    maps, interior, meta = load_estimate(estimate_path)
    from gridflow.hci import is_hci_scene
    from gridflow.sources import open_source

    src = open_source(truth_path, views=3 if is_hci_scene(truth_path) else None)
    frame = src.truth_frame
    if frame is None:
        # a recording's truth is per frame: that of the estimate's own reference frame
        settings = meta.get("settings") if isinstance(meta.get("settings"), dict) else {}
        frame = settings.get("ref_frame")
        if not isinstance(frame, int) or not 0 <= frame < src.frames:
            raise FileFormatError(f"{estimate_path}: states no reference frame of "
                                  f"{truth_path} ({src.frames} frames) to score against")
    truth = dict(src.truth(frame))
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
