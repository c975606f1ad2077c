"""Synthetic camera-grid volumes with exact ground truth."""

from .sinusoid import SinusoidParams, SyntheticVolume, add_noise, check_params, make_sinusoid

__all__ = ["SinusoidParams", "SyntheticVolume", "add_noise", "check_params", "make_sinusoid"]
