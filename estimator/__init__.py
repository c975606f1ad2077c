"""Structure-tensor TLS estimation of depth, slopes, 3-D motion and brightness change
from a camera-grid image sequence (Schuchert & Scharr, DAGM 2007, Sec. 3).

The names below are imported on first use (PEP 562), so that importing a light
submodule (``gridflow.estimator.filters``, ``.models``) does not pay for scipy.
"""

from .models import MODELS

__all__ = ["Estimate", "EstimatorSettings", "InputError", "estimate", "estimate_models", "MODELS"]

_FROM_CORE = {"Estimate", "EstimatorSettings", "InputError", "estimate", "estimate_models"}


def __getattr__(name):
    if name in _FROM_CORE:
        from . import core

        return getattr(core, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | _FROM_CORE)
