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

A model (:class:`Model`) is two axes travelling together: a **motion model**
(:class:`MotionModel`: how the surface patch moves, which geometric rows the data vector
has and how their parameters turn into depth, slopes and velocity) and a **brightness
model** (:class:`BrightnessModel`: how its brightness changes, which rows of ``I`` are
added).  The paper's motion model is ``translation``: a patch moving without deforming,
rows 1-9; ``affine`` adds the ``t I_x``-rows of a velocity varying across the surface.
The brightness models are BCC (no rows), HF (rows 10 and 13) and the full model (rows
10-15).  A 1-D camera grid (``ds_y = 0``) drops rows 5 and 8 under translation (row 8
under affine motion); a static light field (one frame) drops row 9 and has no ``dt``
column.  Each axis is defined once, in :data:`MOTION_MODELS` and
:data:`BRIGHTNESS_MODELS`; :data:`MOTIONS` and :data:`MODELS` are their names.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ROWS", "ALL_ROWS", "ZOOM_ROWS", "ZOOM_ROW_SIGNALS", "zoom_rows", "MotionModel",
           "BrightnessModel", "TRANSLATION", "AFFINE", "MOTION_MODELS", "BRIGHTNESS_MODELS",
           "MODELS", "MOTIONS", "Model", "get_model", "one_frame_problem", "covering_rows"]

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

# A model has two axes, each an object below: the motion model (how the surface patch
# moves) and the brightness model (how its brightness changes).  Each carries its rows,
# its outputs and what it asks of the data, so that the driver, get_model and the bench
# read properties instead of comparing names.

def _has_t_factor(rows: tuple[str, ...]) -> bool:
    # a row with a factor t (temporal power >= 1) is constant, and so useless, unless t
    # varies over the temporal window: the model needs a time axis with frames either side
    return any(ROWS[r][1] > 0 for r in rows)


@dataclass(frozen=True)
class MotionModel:
    """How the surface patch moves: the geometric rows of d and what they give.

    Its disentangling (parameter vectors to world velocities) is a function in
    :mod:`estimator.disentangle` registered for this object there
    (:func:`estimator.disentangle.disentangles`): this module is below that one and
    cannot name it.

    Attributes
    ----------
    name : str
        What the settings (``motion=``), the CLI and the sweeps call it.
    rows : tuple of str
        The geometric rows of d in order, the fixed rows ``I_sx, I_sy, I_t`` included
        (keys of :data:`ROWS`).
    outputs : tuple of str
        The quantities its parameters give besides ``Z, Zx, Zy, disparity``.
    rows_dropped_1d : tuple of str
        The rows a 1-D grid (``ds_y = 0``) drops: those that would carry only ``ds_y``
        or a parameter the model fixes at zero.
    temporal_radius : int
        The temporal window's default radius (frames either side of the reference
        frame), where the volume has the frames.
    pools_rates : bool
        Whether its depth motion and tilt rates are pooled over the leaf
        (:mod:`estimator.pooling`).
    """

    name: str
    rows: tuple[str, ...]
    outputs: tuple[str, ...]
    rows_dropped_1d: tuple[str, ...]
    temporal_radius: int = 2
    pools_rates: bool = False

    @property
    def needs_time(self) -> bool:
        """Whether it needs frames either side of the reference frame (rows with a factor
        t): such a motion has no meaning for a light field of one frame."""
        return _has_t_factor(self.rows)


@dataclass(frozen=True)
class BrightnessModel:
    """How the patch's brightness changes: the rows of ``I`` it adds to d.

    Attributes
    ----------
    name : str
        What ``model=``, the CLI and the sweeps call it.
    rows : tuple of str
        The rows it adds (keys of :data:`ROWS`), after the motion model's.
    outputs : tuple of str
        The brightness parameters it estimates.
    """

    name: str
    rows: tuple[str, ...]
    outputs: tuple[str, ...]

    @property
    def needs_time(self) -> bool:
        """Whether it needs frames either side of the reference frame: a change of
        brightness is one over time (rows with a factor t)."""
        return _has_t_factor(self.rows)


_TRANSLATION_ROWS = ("Ix", "Iy", "IxDx", "IxDy", "IyDx", "IyDy", "Isx", "Isy", "It")
TRANSLATION = MotionModel(
    "translation", _TRANSLATION_ROWS, ("Ux", "Uy", "Uz"),
    # under translation the dt part of I_y Δx (d(dy/dt)/dx) is zero, so on a 1-D grid,
    # without its ds_y part, the row is empty
    rows_dropped_1d=("IyDx", "Isy"))
AFFINE = MotionModel(
    "affine", _TRANSLATION_ROWS + ("tIx", "tIy", "tIxDx", "tIxDy", "tIyDx", "tIyDy"),
    ("Ux", "Uy", "Uz", "growth", "rotation", "Zx_t", "Zy_t", "Uz_err", "growth_err",
     "rotation_err", "pooled", "growth_sd"),
    # under affine motion the dt part of I_y Δx is a free flow gradient: kept
    rows_dropped_1d=("Isy",),
    # growth is told from depth motion by the disparity's change in time, whose error
    # falls steeply with the window's length (docs/model.md, *Pooled depth rates*)
    temporal_radius=6, pools_rates=True)
# name (what motion= and the CLI take) -> motion model
MOTION_MODELS: dict[str, MotionModel] = {m.name: m for m in (TRANSLATION, AFFINE)}
MOTIONS = tuple(MOTION_MODELS)

# name (what model= and the CLI take) -> brightness model
BRIGHTNESS_MODELS: dict[str, BrightnessModel] = {b.name: b for b in (
    BrightnessModel("bcc", (), ()),
    BrightnessModel("hf", ("I", "tI"), ("a1", "a2")),
    BrightnessModel("full", ("I", "IDx", "IDy", "tI", "tIDx", "tIDy"),
                    ("a1", "a2", "a1x", "a1y", "a2x", "a2y")),
)}
MODELS = tuple(BRIGHTNESS_MODELS)

# what the camera axes give under every model
_PLANE_OUTPUTS = ("Z", "Zx", "Zy", "disparity")


@dataclass(frozen=True)
class Model:
    """A brightness model combined with a motion model on a camera grid.

    Attributes
    ----------
    brightness : BrightnessModel
        One of :data:`BRIGHTNESS_MODELS`.
    motion : MotionModel
        One of :data:`MOTION_MODELS`.
    rows : tuple of str
        Data rows in order (keys of :data:`ROWS`).
    grid_dims : {1, 2}
        2 for a 2-D camera grid (null space of dimension 3), 1 for a horizontal 1-D grid
        (dimension 2).
    static : bool
        A light field of one frame: no time axis, no motion, no brightness change.
    """

    brightness: BrightnessModel
    motion: MotionModel
    rows: tuple[str, ...]
    grid_dims: int
    static: bool = False

    @property
    def name(self) -> str:
        """The brightness model's name (what ``model=`` and ``Estimate.model`` say)."""
        return self.brightness.name

    @property
    def needs_time(self) -> bool:
        """Whether either axis needs frames either side of the reference frame."""
        return self.brightness.needs_time or self.motion.needs_time

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
            return _PLANE_OUTPUTS
        return _PLANE_OUTPUTS + self.motion.outputs + self.brightness.outputs


def _lookup(model, registry: dict, kind: type, what: str):
    # a name (what the settings hold) or the object itself (a model not in the registry)
    if isinstance(model, kind):
        return model
    if model not in registry:
        raise ValueError(f"unknown {what} {model!r}; expected one of {tuple(registry)}")
    return registry[model]


def one_frame_problem(brightness, motion: MotionModel) -> str | None:
    """Why ``brightness`` (brightness models) with ``motion`` cannot be estimated from a
    light field of one frame, or None if they can: the message the driver's
    :class:`~estimator.settings.InputError` and :func:`get_model`'s ``ValueError`` give.

    Only the axes that need no time axis apply (the cameras alone give depth and slopes).
    """
    still_motion = [m.name for m in MOTION_MODELS.values() if not m.needs_time]
    still = [b.name for b in BRIGHTNESS_MODELS.values() if not b.needs_time]
    if motion.needs_time:
        return (f"motion {motion.name!r} needs a time axis; a light field of one frame has "
                f"no motion (motion {still_motion[0]!r}, model {still[0]!r})")
    bad = [b.name for b in brightness if b.needs_time]
    if bad:
        return (f"models {bad} need a time axis (brightness change over frames); a light "
                f"field of one frame takes model {still[0]!r}")
    return None


def get_model(name: str | BrightnessModel, grid_dims: int = 2, static: bool = False,
              motion: str | MotionModel = TRANSLATION.name) -> Model:
    """The brightness model ``name`` with the motion model ``motion`` on a
    ``grid_dims``-dimensional camera grid.

    Parameters
    ----------
    name : str or BrightnessModel
        A name of :data:`MODELS`, or a brightness model object.
    grid_dims : {1, 2}
    static : bool
        A light field of one frame.  Only the axes that need no time axis apply
        (``bcc`` with ``translation``); the rows are the geometric ones without ``I_t``,
        and the null space has one dimension per camera axis.
    motion : str or MotionModel
        A name of :data:`MOTIONS`, or a motion model object.

    Raises
    ------
    ValueError
        An unknown name, a bad ``grid_dims``, or a model that needs a time axis for a
        static light field (:func:`one_frame_problem`).
    """
    brightness = _lookup(name, BRIGHTNESS_MODELS, BrightnessModel, "model")
    motion = _lookup(motion, MOTION_MODELS, MotionModel, "motion model")
    if grid_dims not in (1, 2):
        raise ValueError(f"grid_dims must be 1 or 2, got {grid_dims}")
    rows = motion.rows + brightness.rows
    if static:
        problem = one_frame_problem((brightness,), motion)
        if problem:
            raise ValueError(problem)
        rows = tuple(r for r in rows if r != "It")
    if grid_dims == 1:
        rows = tuple(r for r in rows if r not in motion.rows_dropped_1d)
    return Model(brightness, motion, rows, grid_dims, static)


def covering_rows(models) -> tuple[str, ...]:
    """The rows of every model in ``models``, in the order of :data:`ROWS`: the tensor
    computed once for all of them (each model's J is a sub-block of it)."""
    used = {r for m in models for r in m.rows}
    return tuple(r for r in ALL_ROWS if r in used)


def zoom_rows(rows: tuple[str, ...]) -> tuple[str, ...]:
    """``rows`` followed by the zoom-blur correction rows of those that have one: the
    rows of the tensor J_ext from which the corrected J is formed."""
    return tuple(rows) + tuple(ZOOM_ROWS[r] for r in rows if r in ZOOM_ROWS)
