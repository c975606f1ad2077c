"""Structure-tensor TLS estimation of depth, slopes, 3-D motion and brightness change
from a camera-grid image sequence (Schuchert & Scharr, DAGM 2007, Sec. 3)."""

from .core import Estimate, EstimatorSettings, InputError, estimate, estimate_models
from .models import MODELS

__all__ = ["Estimate", "EstimatorSettings", "InputError", "estimate", "estimate_models", "MODELS"]
