"""The estimator's choices and settings, each defined here once.

Every other part of gridflow (the CLI, the sweeps, the claims, the peers, the benchmark)
takes its choices and defaults from here, from :data:`estimator.models.MODELS` (the
brightness models) and :data:`estimator.models.MOTIONS` (the motion models) and from
:data:`estimator.filters.FILTER_NAMES`, so that they cannot drift apart.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from .filters import FILTER_NAMES
from .models import MOTION_MODELS, MOTIONS, TRANSLATION

__all__ = ["InputError", "EstimatorSettings", "METHODS", "COMBINE", "DEFAULTS"]

# Implementations of the estimator: all give the same answers (within the tolerances of
# tests/test_estimator_properties.py); which code runs is chosen in one place,
# :func:`estimator.backends.select_backend`.
METHODS = ("fast", "grouped", "reference")
# How the twice-estimated v, z_x, z_y, u_z are combined (estimator.disentangle).
COMBINE = ("inverse_variance", "mean")


class InputError(ValueError):
    """Input the estimator cannot work with; the message names the problem."""


def _integer(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


@dataclass(frozen=True)
class EstimatorSettings:
    """Estimator options (all keyword arguments of :func:`estimator.estimate`).

    Attributes
    ----------
    sigma : float
        Standard deviation of the Gaussian neighbourhood in x and y, pixels (paper: 16).
    window : int
        Taps of that Gaussian (paper: 65).
    filters : str
        Derivative / prefilter pair for x and y, and for cameras and time where they
        have enough samples (one of :data:`estimator.filters.FILTER_NAMES`);
        ``"matched3"`` is used on an axis with fewer samples than the pair needs.
    temporal_radius : int or None
        The neighbourhood spans frames ``k_ref - R .. k_ref + R`` with uniform weights.
        Default: as many as the temporal filter allows, at most 2 under translation and
        at most 6 under affine motion (the motion model's ``temporal_radius``).
    ref_frame : int or None
        Reference frame ``k_ref``; default the centre frame ``(T - 1) // 2``.
    method : {"fast", "grouped", "reference"}
        Implementation; all give the same result to roundoff.  "fast" (default): FFT
        moment smoothing, and from 128 x 128 pixels on numba kernels for the signals and
        the null space (below that, LAPACK ``eigh``: loading the kernels would cost more
        than they save; ``Estimate.settings["backend"]`` says which ran);
        "grouped": direct 65-tap smoothing of grouped products and LAPACK ``eigh``;
        "reference": the straightforward entry-by-entry tensor and ``eigh`` (the
        baseline of ``bench/``).  See :mod:`estimator.backends`.
    slant_correction : bool
        Remove the slant-motion coupling from ``U_Z`` (see :mod:`estimator.disentangle`).
    zoom_correction : bool
        Remove the zoom blur: the prefilter's first moment, which turns a coefficient
        varying across the image (divergence, slope, brightness gradient) into an
        apparent brightness change or motion (``docs/model.md``, *The zoom blur*).  The
        paper does not correct it (``False`` reads the data rows as the paper does).
    band_rows : int or None
        Output rows processed at a time (bounds memory); default bands of equal height
        whose arrays fit in about 1.5 GiB (:func:`estimator.driver.band_rows`).
    combine : {"inverse_variance", "mean"}
        How the twice-estimated ``v, z_x, z_y, u_z`` are combined: weighted by their
        first-order error estimates (default), or plainly averaged.
    motion : {"translation", "affine"}
        The motion model (:data:`estimator.models.MOTIONS`): the paper's translating
        patch (default), or a velocity varying affinely across the surface, which adds
        the growth, the rotation about the normal and the slopes' rates of change
        (``docs/model.md``, *Affine motion*).
    growth_support : float or None
        Affine motion: the standard deviation, pixels, of the bell-shaped support over
        which the depth motion and tilt rates are pooled (:mod:`estimator.pooling`);
        default ``6 * sigma`` (96 px at the default sigma); 0 solves each pixel alone.
    """

    sigma: float = 16.0
    window: int = 65
    filters: str = "matched5"
    temporal_radius: int | None = None
    ref_frame: int | None = None
    method: str = "fast"
    slant_correction: bool = True
    zoom_correction: bool = True
    band_rows: int | None = None
    combine: str = "inverse_variance"
    motion: str = TRANSLATION.name
    growth_support: float | None = None

    def __post_init__(self) -> None:
        """Refuse settings that are of the wrong type or out of range (InputError naming
        the setting); checks that need the volume are made by :func:`estimate`."""
        if isinstance(self.sigma, bool) or not isinstance(self.sigma, (int, float, np.number)) \
                or not (np.isfinite(self.sigma) and self.sigma > 0):
            raise InputError(f"sigma must be a positive number of pixels, got {self.sigma!r}")
        if not (_integer(self.window) and self.window >= 3 and self.window % 2 == 1):
            raise InputError(f"window must be an odd number of taps >= 3, got {self.window!r}")
        if self.filters not in FILTER_NAMES:
            raise InputError(f"unknown filter pair {self.filters!r}; filters must be one of "
                             f"{FILTER_NAMES}")
        for name in ("temporal_radius", "ref_frame"):
            v = getattr(self, name)
            if v is not None and not (_integer(v) and v >= 0):
                raise InputError(f"{name} must be a non-negative integer or None, got {v!r}")
        if self.method not in METHODS:
            raise InputError(f"method must be one of {METHODS}, got {self.method!r}")
        for name in ("slant_correction", "zoom_correction"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InputError(f"{name} must be true or false, got "
                                 f"{getattr(self, name)!r}")
        if self.combine not in COMBINE:
            raise InputError(f"combine must be one of {COMBINE}, got {self.combine!r}")
        if self.motion not in MOTIONS:
            raise InputError(f"motion must be one of {MOTIONS}, got {self.motion!r}")
        gs = self.growth_support
        if gs is not None and (isinstance(gs, bool) or not isinstance(gs, (int, float, np.number))
                               or not (np.isfinite(gs) and gs >= 0)):
            raise InputError(f"growth_support must be a non-negative number of pixels or "
                             f"None, got {gs!r}")
        if self.band_rows is not None and not (_integer(self.band_rows) and self.band_rows >= 1):
            raise InputError(f"band_rows must be a positive integer or None, got "
                             f"{self.band_rows!r}")

    @property
    def pooling_sigma(self) -> float:
        """The pooling support in pixels (0: none) for this motion model."""
        if not MOTION_MODELS[self.motion].pools_rates:
            return 0.0
        return 6.0 * float(self.sigma) if self.growth_support is None \
            else float(self.growth_support)

    def as_dict(self) -> dict:
        """The settings as a plain dict (what results and provenance record)."""
        return asdict(self)


# The documented defaults, by name (the CLI's help and the sweeps' provenance read them).
DEFAULTS = {f.name: f.default for f in fields(EstimatorSettings)}
