"""A synthetic growth recording: a textured plane that grows in its own plane at a rate that
follows a day/night rhythm, under an illumination that follows it too, seen by a camera grid
at many time instances, with exact truth per frame.

The plane is the sinusoid experiment's (:mod:`gridflow.generators.sinusoid`, exact ray
casting) held in place (no translation); its material points at frame ``k`` (time
``t = k``, in frames) sit at ``X_c + A(t) (M - X_c)`` with ``A(t) = I + (s(t) - 1) P``,
``P`` the projector onto the plane and the linear scale

    s(t) = exp(1/2 * integral_0^t g),    g(t) = g0 (1 + m sin(2 pi t / period)),

so the surface's relative rate of change of area (the growth map's quantity) is ``g(t)``
everywhere.  The brightness is the texture times ``exp(c sin(2 pi t / period))``: its
rates are ``a1 = c w cos(w t)`` per frame and ``a2 = -c w^2 sin(w t) / 2`` per frame^2
(``w = 2 pi / period``).  Numerics only: writing the frames is the caller's
(:func:`gridflow.recording.write_recording`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from gridflow.errors import ParameterError

from .sinusoid import (SinusoidParams, _intersect_mapped, _normal, _pixel_grid, ground_truth,
                       texture, texture_wavenumbers)

__all__ = ["RecordingParams", "GrowthRecording", "TRUTH_NAMES"]

# the truth kept per frame (the others of ground_truth are zero or constant here)
TRUTH_NAMES = ("Z", "Ux", "Uy", "growth", "a1", "a2")


@dataclass(frozen=True)
class RecordingParams:
    """Parameters of a growth recording; time in frames.

    Attributes
    ----------
    frames : int
        Time instances ``T``.
    height, width : int
        Image size, px.
    grid : tuple of int
        Camera grid ``(Sy, Sx)``, odd.
    spacing : tuple of float
        Camera spacing ``(ds_x, ds_y)``, world units.
    growth : float
        Mean relative growth rate ``g0`` (area), per frame.  1e-3 per frame at a frame
        every 2 minutes is 3 % per hour, a fast leaf.
    rhythm : float
        Relative amplitude ``m`` of the day/night modulation of the growth rate (< 1: the
        leaf never shrinks).
    period : float
        Frames per day.
    illumination : float
        Amplitude ``c`` of the logarithm of the brightness over the day.
    noise : float
        Standard deviation of additive Gaussian noise (per frame seeded by ``(seed, k)``).
    seed : int
    frame_interval : float
        Seconds between frames (the time stamps of the recording; the rates stay per frame).
    Z0, f, wavelength_x, wavelength_y, texture, amplitude, offset
        As :class:`gridflow.generators.SinusoidParams`.
    """

    frames: int = 200
    height: int = 512
    width: int = 512
    grid: tuple = (5, 5)
    spacing: tuple = (0.05, 0.05)
    growth: float = 1e-3
    rhythm: float = 0.8
    period: float = 100.0
    illumination: float = 0.3
    noise: float = 0.0
    seed: int = 0
    frame_interval: float = 120.0
    Z0: float = 100.0
    f: float = 1000.0
    wavelength_x: float = 8.0
    wavelength_y: float = 80.0
    texture: str = "sum"
    amplitude: float = 1.0
    offset: float = 0.0

    def as_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


class GrowthRecording:
    """Frames and truth of a growth recording, made on demand.

    Parameters
    ----------
    params : RecordingParams
    """

    def __init__(self, params: RecordingParams | None = None, **overrides):
        p = params or RecordingParams()
        if overrides:
            p = RecordingParams(**{**asdict(p), **overrides})
        self.params = p
        _check(p)
        # the sinusoid experiment's plane, held in place, one frame at a time
        self.plane = SinusoidParams(Z0=p.Z0, f=p.f, U_Z=0.0, wavelength_x=p.wavelength_x,
                                    wavelength_y=p.wavelength_y, texture=p.texture,
                                    amplitude=p.amplitude, offset=p.offset, height=p.height,
                                    width=p.width, grid=tuple(p.grid),
                                    spacing=tuple(p.spacing), frames=1)
        n = _normal(self.plane)
        self._P = np.eye(3) - np.outer(n, n)
        self._x, self._y = _pixel_grid(self.plane)

    @property
    def shape(self) -> tuple:
        """``(T, Sy, Sx, H, W)``."""
        p = self.params
        return (p.frames, p.grid[0], p.grid[1], p.height, p.width)

    def growth_rate(self, t) -> np.ndarray:
        """``g(t)``, relative area rate per frame, at time(s) ``t`` (frames)."""
        p = self.params
        return p.growth * (1.0 + p.rhythm * np.sin(2 * np.pi * np.asarray(t, float) / p.period))

    def scale(self, t: float) -> float:
        """Linear scale ``s(t)`` of the plane relative to frame 0."""
        p = self.params
        w = 2 * np.pi / p.period
        integral = p.growth * (t + p.rhythm * (1.0 - np.cos(w * t)) / w)
        return float(np.exp(0.5 * integral))

    def frame(self, k: int) -> np.ndarray:
        """The views of frame ``k``, float64, shape ``(Sy, Sx, H, W)``."""
        p, q = self.params, self.plane
        t = float(k)
        A = np.eye(3) + (self.scale(t) - 1.0) * self._P
        kx, ky = texture_wavenumbers(q)
        light = np.exp(p.illumination * np.sin(2 * np.pi * t / p.period))
        Sy, Sx = p.grid
        out = np.empty((Sy, Sx, p.height, p.width))
        rng = np.random.default_rng([p.seed, k]) if p.noise > 0 else None
        for i in range(Sy):
            sy = (i - (Sy - 1) / 2.0) * p.spacing[1]
            for j in range(Sx):
                sx = (j - (Sx - 1) / 2.0) * p.spacing[0]
                # t = 0 in the ray cast: the plane does not translate, A(t) moves it
                _, Xm, Ym = _intersect_mapped(q, A, self._x, self._y, sx, sy, 0.0)
                img = texture(q, Xm, Ym, kx, ky) * light
                if rng is not None:
                    img += p.noise * rng.standard_normal(img.shape)
                out[i, j] = img
        return out

    def truth(self, k: int) -> dict[str, np.ndarray]:
        """Truth at the reference camera and frame ``k``, per frame: ``Z``, ``Ux``, ``Uy``,
        ``growth``, ``a1``, ``a2`` (each ``(H, W)``).

        The velocity field at time ``t`` is ``(s'/s) P (X - X_c) = g(t)/2 P (X - X_c)``:
        the sinusoid experiment's growth field at rate ``g(t)``, taken at the plane's
        current points (which are the plane's points: it only grows within itself).
        """
        p = self.params
        t = float(k)
        g = float(self.growth_rate(t))
        gt = ground_truth(self.plane.replace(growth=g))
        w = 2 * np.pi / p.period
        full = lambda v: np.full(gt["Z"].shape, float(v))  # noqa: E731
        return {"Z": gt["Z"], "Ux": gt["Ux"], "Uy": gt["Uy"], "growth": gt["growth"],
                "a1": full(p.illumination * w * np.cos(w * t)),
                "a2": full(-0.5 * p.illumination * w * w * np.sin(w * t))}


def _check(p: RecordingParams) -> None:
    def positive_int(name, v, odd=False):
        if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1
                and (not odd or v % 2 == 1)):
            raise ParameterError(f"{name} must be a{'n odd' if odd else ''} positive integer, "
                                 f"got {v!r}")

    positive_int("frames", p.frames)
    positive_int("height", p.height)
    positive_int("width", p.width)
    if len(p.grid) != 2:
        raise ParameterError(f"grid must be (Sy, Sx), got {p.grid!r}")
    for v in p.grid:
        positive_int("grid", v, odd=True)
    for name in ("growth", "rhythm", "period", "illumination", "noise", "frame_interval"):
        v = getattr(p, name)
        if not np.isfinite(v):
            raise ParameterError(f"{name} must be finite, got {v!r}")
    if not 0 <= p.rhythm < 1:
        raise ParameterError(f"rhythm must lie in [0, 1) (the leaf never shrinks), got "
                             f"{p.rhythm!r}")
    if p.period <= 0 or p.frame_interval <= 0 or p.noise < 0:
        raise ParameterError("period and frame_interval must be positive and noise >= 0, got "
                             f"{p.period!r}, {p.frame_interval!r}, {p.noise!r}")
    if abs(p.growth) * p.frames * (1 + p.rhythm) > 5:
        raise ParameterError(f"growth {p.growth} over {p.frames} frames would scale the area "
                             "by more than e^5; choose a slower rate or fewer frames")
