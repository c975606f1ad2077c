"""Structure-tensor TLS estimation of depth, slopes, 3-D motion and brightness change
from a camera-grid image sequence (Schuchert & Scharr, DAGM 2007, Sec. 3).

The public interface is :func:`estimate` (one model), :func:`estimate_models` (several
sharing one structure tensor), the :class:`Estimate` they return, the
:class:`EstimatorSettings` they accept and the choices: :data:`MODELS` (brightness
models), :data:`MOTIONS` (motion models), :data:`METHODS`, :data:`COMBINE`,
:data:`FILTER_NAMES`.  The parts (``docs/architecture.md``): :mod:`.settings`,
:mod:`.models`, :mod:`.filters`, :mod:`.signals`, :mod:`.tensor`, :mod:`.spectral`,
:mod:`.nullspace`, :mod:`.disentangle`, :mod:`.backends` (with the numba kernels in
:mod:`._kernels` and :mod:`._solver`), :mod:`.pooling`, :mod:`.masks`, :mod:`.driver`,
:mod:`.lightfield`.

The driver's names are imported on first use (PEP 562), so that importing a light
submodule (``gridflow.estimator.filters``, ``.models``) does not pay for scipy.
"""

from .filters import FILTER_NAMES
from .models import MODELS, MOTIONS
from .result import Estimate
from .settings import COMBINE, DEFAULTS, METHODS, EstimatorSettings, InputError

__all__ = ["Estimate", "EstimatorSettings", "InputError", "estimate", "estimate_models",
           "window_halo", "band_halo", "temporal_reach", "estimate_memory",
           "kept_frame_bytes", "segment_object", "MODELS",
           "MOTIONS", "METHODS", "COMBINE", "FILTER_NAMES", "DEFAULTS"]

_LAZY = {"estimate": "driver", "estimate_models": "driver", "window_halo": "driver",
         "band_halo": "driver", "temporal_reach": "driver", "estimate_memory": "driver",
         "kept_frame_bytes": "driver", "segment_object": "masks"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
