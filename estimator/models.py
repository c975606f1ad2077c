"""Data vector d and parameter vector p of Eq. 19 (rebuilt in docs/model.md).

Each data row is a base signal times a temporal power and a spatial monomial:

=====  ============  ====================================  ===========
 row    d             p                                    (signal, t^, Δ)
=====  ============  ====================================  ===========
  1    I_x           v ds_x + (u_x + x0 u_z) dt            (x, 0, 1)
  2    I_y           v ds_y + (u_y + y0 u_z) dt            (y, 0, 1)
  3    I_x Δx        z_x ds_x + u_z dt                     (x, 0, Δx)
  4    I_x Δy        z_y ds_x                              (x, 0, Δy)
  5    I_y Δx        z_x ds_y                              (y, 0, Δx)
  6    I_y Δy        z_y ds_y + u_z dt                     (y, 0, Δy)
  7    I_sx          ds_x                                  (sx, 0, 1)
  8    I_sy          ds_y                                  (sy, 0, 1)
  9    I_t           dt                                    (t, 0, 1)
 10    I             b1 dt                                 (I, 0, 1)
 11    I Δx          b1x dt                                (I, 0, Δx)
 12    I Δy          b1y dt                                (I, 0, Δy)
 13    I t           2 b2 dt                               (I, 1, 1)
 14    I t Δx        2 b2x dt                              (I, 1, Δx)
 15    I t Δy        2 b2y dt                              (I, 1, Δy)
=====  ============  ====================================  ===========

BCC uses rows 1-9, HF rows 1-10 and 13, the full model all 15.  A 1-D camera grid
(``ds_y = 0``) drops rows 5 and 8; a static light field (one frame) drops row 9 and has
no ``dt`` column.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ROWS", "MODELS", "Model", "get_model"]

# name -> (base signal, temporal power, spatial monomial)
ROWS: dict[str, tuple[str, int, str]] = {
    "Ix": ("x", 0, ""), "Iy": ("y", 0, ""),
    "IxDx": ("x", 0, "x"), "IxDy": ("x", 0, "y"),
    "IyDx": ("y", 0, "x"), "IyDy": ("y", 0, "y"),
    "Isx": ("sx", 0, ""), "Isy": ("sy", 0, ""), "It": ("t", 0, ""),
    "I": ("I", 0, ""), "IDx": ("I", 0, "x"), "IDy": ("I", 0, "y"),
    "tI": ("I", 1, ""), "tIDx": ("I", 1, "x"), "tIDy": ("I", 1, "y"),
}
ALL_ROWS = tuple(ROWS)

_GEOMETRY = ("Ix", "Iy", "IxDx", "IxDy", "IyDx", "IyDy", "Isx", "Isy", "It")
_ROWS_2D = {
    "bcc": _GEOMETRY,
    "hf": _GEOMETRY + ("I", "tI"),
    "full": ALL_ROWS,
}
MODELS = tuple(_ROWS_2D)

# Quantities each model estimates (besides Z, Zx, Zy, Ux, Uy, Uz and model_error).
BRIGHTNESS_OUTPUTS = {
    "bcc": (),
    "hf": ("a1", "a2"),
    "full": ("a1", "a2", "a1x", "a1y", "a2x", "a2y"),
}


@dataclass(frozen=True)
class Model:
    """A brightness model on a given camera-grid dimensionality.

    Attributes
    ----------
    name : {"bcc", "hf", "full"}
    rows : tuple of str
        Data rows in order (keys of :data:`ROWS`).
    grid_dims : {1, 2}
        2 for a 2-D camera grid (null space of dimension 3), 1 for a horizontal 1-D grid
        (dimension 2).
    """

    name: str
    rows: tuple[str, ...]
    grid_dims: int
    static: bool = False

    @property
    def n(self) -> int:
        return len(self.rows)

    @property
    def null_dim(self) -> int:
        return self.grid_dims + (0 if self.static else 1)

    @property
    def fixed_rows(self) -> tuple[str, ...]:
        """Rows carrying ``ds_x, (ds_y,) dt`` (the block M of Sec. 3, step 3); no ``dt``
        for a static light field."""
        rows = ("Isx", "Isy", "It") if self.grid_dims == 2 else ("Isx", "It")
        return rows[:-1] if self.static else rows

    def index(self, row: str) -> int:
        return self.rows.index(row)

    @property
    def outputs(self) -> tuple[str, ...]:
        if self.static:
            return ("Z", "Zx", "Zy", "disparity")
        return ("Z", "Zx", "Zy", "disparity", "Ux", "Uy", "Uz") + BRIGHTNESS_OUTPUTS[self.name]


def get_model(name: str, grid_dims: int = 2, static: bool = False) -> Model:
    """Return the model ``name`` for a ``grid_dims``-dimensional camera grid.

    ``static``: a light field of one frame.  Only brightness constancy across the views
    applies (``bcc``); the rows are the geometric ones without ``I_t``, and the null space
    has one dimension per camera axis."""
    if name not in _ROWS_2D:
        raise ValueError(f"unknown model {name!r}; expected one of {MODELS}")
    if grid_dims not in (1, 2):
        raise ValueError(f"grid_dims must be 1 or 2, got {grid_dims}")
    rows = _ROWS_2D[name]
    if static:
        if name != "bcc":
            raise ValueError(f"model {name!r} needs a time axis (brightness change over "
                             "frames); a light field of one frame takes model 'bcc'")
        rows = tuple(r for r in rows if r != "It")
    if grid_dims == 1:
        rows = tuple(r for r in rows if r not in ("IyDx", "Isy"))
    return Model(name, rows, grid_dims, static)
