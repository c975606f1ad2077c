"""The result of an estimate: per-pixel maps, read like a dict."""

from __future__ import annotations

from collections.abc import Iterator, Mapping

import numpy as np

__all__ = ["Estimate"]


class Estimate(Mapping):
    """Result of :func:`estimator.estimate`: a read-only mapping from quantity names to maps.

    ``est["Uz"]`` is the ``(H, W)`` map of ``U_Z``; ``list(est)`` the quantities, ``"a1" in
    est`` whether the model estimates ``a1``; ``est.maps`` the underlying dict.

    Parameters and attributes
    -------------------------
    maps : dict of str to ndarray, each shape (H, W)
        ``Z, Zx, Zy, disparity, Ux, Uy, Uz`` (world units, per frame), the model's
        brightness parameters (``a1, a2`` for hf; also ``a1x, a1y, a2x, a2y`` for full)
        and ``model_error``.  NaN on border pixels and where the estimate is degenerate.
    model : str
        The brightness model (:data:`estimator.models.MODELS`).
    interior : ndarray of bool, shape (H, W)
        Pixels free of border effects (the window and filters fit inside the image).
    settings : dict
        The settings used, including the filters chosen per axis and the backend that ran.
    motion : str or None
        The motion model (:data:`estimator.models.MOTIONS`), read-only: the other axis of
        the model, beside ``model``.  Default ``settings["motion"]`` (kept there too), or
        None for a map with no motion model (a refocused light field).
    """

    def __init__(self, maps: dict[str, np.ndarray], model: str, interior: np.ndarray,
                 settings: dict | None = None, motion: str | None = None):
        self.maps = maps
        self.model = model
        self.interior = interior
        self.settings = {} if settings is None else settings
        self._motion = self.settings.get("motion") if motion is None else motion

    @property
    def motion(self) -> str | None:
        """The motion model's name (``settings["motion"]`` by default)."""
        return self._motion

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.maps[name]
        except KeyError:
            raise KeyError(f"{name!r}: this estimate holds {', '.join(self.maps)}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self.maps)

    def __len__(self) -> int:
        return len(self.maps)

    # maps of arrays do not compare as a whole: an Estimate equals only itself
    __eq__ = object.__eq__
    __hash__ = object.__hash__

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of every map."""
        return tuple(self.interior.shape)

    def valid_fraction(self) -> float:
        """Fraction of the interior pixels with a finite estimate (of ``Z``, or of the
        first map)."""
        key = "Z" if "Z" in self.maps else next(iter(self.maps), None)
        n = int(self.interior.sum())
        if key is None or n == 0:
            return 0.0
        return float(np.isfinite(self.maps[key][self.interior]).sum() / n)

    def __repr__(self) -> str:
        H, W = self.shape
        model = f"{self.model}" + (f", motion {self.motion}" if self.motion else "")
        return (f"<Estimate model {model}, {H}x{W}, valid {100 * self.valid_fraction():.1f} % "
                f"of {int(self.interior.sum())} interior pixels; "
                f"{', '.join(self.maps)}>")
