"""How one step of a source is estimated: the estimator's single pass, or a static light
field refocused over integer shears.  Both take a window of frames and give
``{model: Estimate}``; the pipeline (:mod:`gridflow.pipeline.run`) and the sinks do not
care which ran.

A strategy states what the planner needs without re-deriving the estimator's rules: the
frames either side of a step it reads (:attr:`reach`, from
:func:`gridflow.estimator.temporal_reach`), the rows either side of a row band
(:attr:`halo`, from :func:`gridflow.estimator.band_halo`; None where only whole images
can be estimated), the maps' border without a whole window (:attr:`border`, from
:func:`gridflow.estimator.window_halo`) and the maps it writes (:meth:`quantities`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gridflow.estimator import Estimate, EstimatorSettings
from gridflow.volume import CameraGeometry

__all__ = ["SinglePass", "Refocus", "with_depth"]


@dataclass(frozen=True)
class SinglePass:
    """The estimator's single pass over a window of frames (:func:`gridflow.estimator.
    estimate_models`), several brightness models sharing one structure tensor.

    Attributes
    ----------
    models : tuple of str
        Brightness models (:data:`gridflow.estimator.MODELS`).
    settings : dict
        Estimator settings (:class:`gridflow.estimator.EstimatorSettings`; ``ref_frame``
        is set per step).
    mask : None, "auto" or ndarray of bool, shape (H, W)
        The object's pixels, so that windows use only them (``estimate_models``'s
        ``mask``): one for every step, or ``"auto"``, segmented per step from the centre
        camera's image at the step's frame (:func:`gridflow.estimator.segment_object`).
    """

    models: tuple
    settings: dict = field(default_factory=dict)
    mask: object = field(default=None, compare=False)

    name = "single pass"

    def __post_init__(self):
        # bad settings fail before any data is read
        EstimatorSettings(**{k: v for k, v in self.settings.items() if k != "ref_frame"})

    @property
    def estimator_settings(self) -> EstimatorSettings:
        return EstimatorSettings(**{k: v for k, v in self.settings.items()
                                    if k != "ref_frame"})

    # the estimator takes float32 frames as they are (the same maps bit for bit)
    takes_float32 = True

    @property
    def reach(self) -> int:
        from gridflow.estimator import temporal_reach

        return temporal_reach(self.estimator_settings)

    @property
    def halo(self) -> int:
        from gridflow.estimator import band_halo
        from gridflow.estimator.filters import get_filter_pair
        from gridflow.estimator.masks import erosion_reach

        s = self.estimator_settings
        # a band's mask is cut from the image's: its edge must not erode the rows the
        # band's windows read
        extra = 0 if self.mask is None else erosion_reach(get_filter_pair(s.filters).radius)
        return band_halo(s) + extra

    @property
    def border(self) -> int:
        from gridflow.estimator import window_halo

        return window_halo(self.estimator_settings)

    @property
    def motion(self) -> str:
        return self.estimator_settings.motion

    def quantities(self, shape) -> dict[str, list[str]]:
        """The maps each model writes for a source of ``shape`` ``(T, Sy, Sx, H, W)`` (a
        1-D grid drops some, a light field of one frame has no motion), ``model_error``
        last."""
        from gridflow.estimator.models import get_model

        dims = 1 if shape[1] == 1 else 2
        return {m: list(get_model(m, dims, shape[0] == 1, self.motion).outputs)
                + ["model_error"] for m in self.models}

    def step_mask(self, source, frame: int) -> np.ndarray | None:
        """The mask of the step at ``frame`` of ``source``, whole images (H, W)."""
        if self.mask is None or not isinstance(self.mask, str):
            return self.mask
        from gridflow.estimator import segment_object

        Sy, Sx = source.shape[1:3]
        # through frame_value: where a worker keeps its frames' values the view is
        # kept for the later steps that read this frame (it is not decoded again)
        view = source.frame_value(frame, ("centre view", Sy // 2, Sx // 2),
                                  lambda f: f[Sy // 2, Sx // 2].copy(), np.float64)
        return segment_object(view)

    def run(self, window: np.ndarray, geometry: CameraGeometry, ref: int,
            progress=None, mask=None) -> dict[str, Estimate]:
        """Estimate at frame ``ref`` of ``window`` ``(T, Sy, Sx, H, W)``, with ``mask``
        (the window's rows of :meth:`step_mask`) where given."""
        from gridflow.estimator import estimate_models

        return estimate_models(window, geometry.focal_length, geometry.camera_spacing,
                               models=self.models, principal_point=geometry.principal_point,
                               mask=mask, **{**self.settings, "ref_frame": ref})


@dataclass(frozen=True)
class Refocus:
    """A static light field refocused over integer shears (:func:`gridflow.estimator.
    lightfield.estimate_refocused`): model ``bcc``, whole images only.

    Attributes
    ----------
    shears : tuple of int
        The shears (px per view).
    select, sigma, window, filters, fill, median
        As :func:`gridflow.estimator.lightfield.estimate_refocused`.
    """

    shears: tuple
    select: str
    sigma: float
    window: int
    filters: str
    fill: bool = True
    median: int = 3

    name = "refocused"
    models = ("bcc",)
    reach = 0
    halo = None           # the choice, the fill and the median reach across the image
    border = None

    mask = None

    def quantities(self, shape) -> dict[str, list[str]]:
        return {"bcc": ["disparity", "Z", "model_error", "confidence", "shear", "filled"]}

    def step_mask(self, source, frame: int) -> None:
        return None

    def run(self, window: np.ndarray, geometry: CameraGeometry, ref: int,
            progress=None, mask=None) -> dict[str, Estimate]:
        """Refocus the views of frame ``ref`` of ``window``; ``Z`` from the disparity for
        parallel cameras (:func:`with_depth` replaces it where the source knows better)."""
        from gridflow.estimator.lightfield import estimate_refocused

        est = estimate_refocused(window[ref], self.shears, sigma=self.sigma,
                                 window=self.window, filters=self.filters,
                                 select=self.select, fill=self.fill, median=self.median,
                                 progress=progress)
        # parallel cameras: disparity = -v ds_x with v = -f / Z
        with np.errstate(divide="ignore", invalid="ignore"):
            Z = geometry.focal_length * geometry.camera_spacing[0] / est["disparity"]
        maps = {"disparity": est["disparity"], "Z": Z,
                **{k: est[k] for k in ("model_error", "confidence", "shear", "filled")}}
        return {"bcc": Estimate(maps, "bcc", est.interior,
                                {**est.settings, "Z_units": geometry.units})}


def with_depth(ests: dict[str, Estimate], hci: dict | None) -> dict[str, Estimate]:
    """Where the source is an HCI scene with its geometry (converging cameras), ``Z`` in
    metres from the disparity and the focus distance; the slopes stay those of the
    parallel-camera reading (camera steps as the unit of length)."""
    if not hci:
        return ests
    from gridflow.hci import depth_from_disparity

    out = {}
    for m, est in ests.items():
        if "disparity" not in est:
            out[m] = est
            continue
        maps = {**est.maps, "Z": depth_from_disparity(est["disparity"], hci)}
        out[m] = Estimate(maps, est.model, est.interior,
                          {**est.settings, "Z_units": "m (HCI geometry)"})
    return out
