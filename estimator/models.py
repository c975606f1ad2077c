"""Data vector d and parameter vector p of Eq. 19 (rebuilt in docs/model.md), and the
models as a brightness model combined with a motion model.

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

A model is a **motion model** (how the surface patch moves: which geometric rows the data
vector has and how their parameters turn into depth, slopes and velocity) combined with
a **brightness model** (how its brightness changes: which rows of ``I`` are added).  The
paper's motion model is ``translation``: a patch moving without deforming, rows 1-9.  The
brightness models are BCC (no rows), HF (rows 10 and 13) and the full model (rows
10-15).  A 1-D camera grid (``ds_y = 0``) drops rows 5 and 8; a static light field (one
frame) drops row 9 and has no ``dt`` column.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ROWS", "ALL_ROWS", "ZOOM_ROWS", "ZOOM_ROW_SIGNALS", "zoom_rows", "MODELS",
           "MOTIONS", "BRIGHTNESS_OUTPUTS", "Model", "get_model", "covering_rows"]

# name -> (base signal, temporal power, spatial monomial)
ROWS: dict[str, tuple[str, int, str]] = {
    "Ix": ("x", 0, ""), "Iy": ("y", 0, ""),
    "IxDx": ("x", 0, "x"), "IxDy": ("x", 0, "y"),
    "IyDx": ("y", 0, "x"), "IyDy": ("y", 0, "y"),
    "Isx": ("sx", 0, ""), "Isy": ("sy", 0, ""), "It": ("t", 0, ""),
    "I": ("I", 0, ""), "IDx": ("I", 0, "x"), "IDy": ("I", 0, "y"),
    "tI": ("I", 1, ""), "tIDx": ("I", 1, "x"), "tIDy": ("I", 1, "y"),
    # the affine motion model's rows: disparity and projected slopes changing in time
    "tIx": ("x", 1, ""), "tIy": ("y", 1, ""),
    "tIxDx": ("x", 1, "x"), "tIxDy": ("x", 1, "y"),
    "tIyDx": ("y", 1, "x"), "tIyDy": ("y", 1, "y"),
}
ALL_ROWS = tuple(ROWS)

# The zoom-blur correction (docs/model.md, *The zoom blur*).  A row whose parameter is a
# coefficient's rate of change across the image (a monomial Δx or Δy: slope, divergence,
# brightness gradient) is, after the prefilter along that axis, the monomial times the
# prefiltered signal *plus* the prefilter's first moment applied to the signal.  That
# second part is a row of its own base signal (no monomial) whose parameter is the
# corrected row's: the corrected row is their sum, J = T J_ext T^T.
# The correction's base signal of a row, by the row's (base signal, monomial):
# estimator.signals.ZOOM_SIGNALS makes them.  A row ``r`` with one gets the correction row
# ``"z" + r`` of that signal and the same temporal power.
_ZOOM_SIGNAL_OF = {("x", "x"): "zxx", ("x", "y"): "zxy", ("y", "x"): "zyx",
                   ("y", "y"): "zyy", ("I", "x"): "zIx", ("I", "y"): "zIy"}
ZOOM_ROWS: dict[str, str] = {r: "z" + r for r, (sig, _, mono) in ROWS.items()
                             if (sig, mono) in _ZOOM_SIGNAL_OF}
# the correction rows' (base signal, temporal power, monomial)
ZOOM_ROW_SIGNALS: dict[str, tuple[str, int, str]] = {
    "z" + r: (_ZOOM_SIGNAL_OF[(sig, mono)], tpow, "")
    for r, (sig, tpow, mono) in ROWS.items() if (sig, mono) in _ZOOM_SIGNAL_OF}

# Motion models: the geometric rows of d (the fixed rows I_sx, I_sy, I_t included) and
# the quantities their parameters give.
_TRANSLATION = ("Ix", "Iy", "IxDx", "IxDy", "IyDx", "IyDy", "Isx", "Isy", "It")
_MOTION_ROWS = {
    "translation": _TRANSLATION,
    "affine": _TRANSLATION + ("tIx", "tIy", "tIxDx", "tIxDy", "tIyDx", "tIyDy"),
}
_MOTION_OUTPUTS = {
    "translation": ("Ux", "Uy", "Uz"),
    "affine": ("Ux", "Uy", "Uz", "growth", "rotation", "Zx_t", "Zy_t", "Uz_err",
               "growth_err", "rotation_err"),
}
# rows a 1-D grid (ds_y = 0) drops: their ds_y part is gone, and under translation their
# dt part (d(dy/dt)/dx) is zero; under affine motion it is a free flow gradient, kept
_ROWS_1D_DROPPED = {"translation": ("IyDx", "Isy"), "affine": ("Isy",)}
MOTIONS = tuple(_MOTION_ROWS)

# Brightness models: the rows of I they add, and the quantities they estimate.
_BRIGHTNESS_ROWS = {
    "bcc": (),
    "hf": ("I", "tI"),
    "full": ("I", "IDx", "IDy", "tI", "tIDx", "tIDy"),
}
BRIGHTNESS_OUTPUTS = {
    "bcc": (),
    "hf": ("a1", "a2"),
    "full": ("a1", "a2", "a1x", "a1y", "a2x", "a2y"),
}
MODELS = tuple(_BRIGHTNESS_ROWS)


@dataclass(frozen=True)
class Model:
    """A brightness model combined with a motion model on a camera grid.

    Attributes
    ----------
    name : {"bcc", "hf", "full"}
        The brightness model.
    rows : tuple of str
        Data rows in order (keys of :data:`ROWS`).
    grid_dims : {1, 2}
        2 for a 2-D camera grid (null space of dimension 3), 1 for a horizontal 1-D grid
        (dimension 2).
    static : bool
        A light field of one frame: no time axis, no motion, no brightness change.
    motion : {"translation"}
        The motion model (:data:`MOTIONS`).
    """

    name: str
    rows: tuple[str, ...]
    grid_dims: int
    static: bool = False
    motion: str = "translation"

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
        """The quantities estimated, besides ``model_error``."""
        if self.static:
            return ("Z", "Zx", "Zy", "disparity")
        return (("Z", "Zx", "Zy", "disparity") + _MOTION_OUTPUTS[self.motion]
                + BRIGHTNESS_OUTPUTS[self.name])


def get_model(name: str, grid_dims: int = 2, static: bool = False,
              motion: str = "translation") -> Model:
    """The brightness model ``name`` with the motion model ``motion`` on a
    ``grid_dims``-dimensional camera grid.

    ``static``: a light field of one frame.  Only brightness constancy across the views
    applies (``bcc``); the rows are the geometric ones without ``I_t``, and the null space
    has one dimension per camera axis."""
    if name not in _BRIGHTNESS_ROWS:
        raise ValueError(f"unknown model {name!r}; expected one of {MODELS}")
    if motion not in _MOTION_ROWS:
        raise ValueError(f"unknown motion model {motion!r}; expected one of {MOTIONS}")
    if grid_dims not in (1, 2):
        raise ValueError(f"grid_dims must be 1 or 2, got {grid_dims}")
    rows = _MOTION_ROWS[motion] + _BRIGHTNESS_ROWS[name]
    if static:
        if name != "bcc":
            raise ValueError(f"model {name!r} needs a time axis (brightness change over "
                             "frames); a light field of one frame takes model 'bcc'")
        rows = tuple(r for r in rows if r != "It")
    if static and motion != "translation":
        raise ValueError(f"motion {motion!r} needs a time axis; a light field of one frame "
                         "has no motion")
    if grid_dims == 1:
        rows = tuple(r for r in rows if r not in _ROWS_1D_DROPPED[motion])
    return Model(name, rows, grid_dims, static, motion)


def covering_rows(models) -> tuple[str, ...]:
    """The rows of every model in ``models``, in the order of :data:`ROWS`: the tensor
    computed once for all of them (each model's J is a sub-block of it)."""
    used = {r for m in models for r in m.rows}
    return tuple(r for r in ALL_ROWS if r in used)


def zoom_rows(rows: tuple[str, ...]) -> tuple[str, ...]:
    """``rows`` followed by the zoom-blur correction rows of those that have one: the
    rows of the tensor J_ext from which the corrected J is formed."""
    return tuple(rows) + tuple(ZOOM_ROWS[r] for r in rows if r in ZOOM_ROWS)
