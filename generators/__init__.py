"""Synthetic camera-grid volumes with exact ground truth."""

from .sinusoid import SinusoidParams, SyntheticVolume, make_sinusoid

__all__ = ["SinusoidParams", "SyntheticVolume", "make_sinusoid"]
