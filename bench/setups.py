"""Named setups: two readings of what the paper leaves unstated.

The paper fixes the sinusoid's wavelengths, depth, velocity, noise and window (Sec. 4.1)
but not the texture's form, the camera spacing, the image size, the temporal extent of
the neighbourhood, the filters, how the two estimates of ``u_z`` are combined, or what the
brightness errors are measured against.  A *setup* names one complete choice:

``gridflow``
    gridflow's most accurate choices (the defaults of :class:`SinusoidParams` and
    :class:`EstimatorSettings`): sum texture, 0.5 px disparity, 192² images, Ω over ±2
    frames, ``matched5`` filters, inverse-variance combination, the zoom-blur
    correction, brightness errors against the local truth ``a + a_x X``.  Use it to learn
    what the method can do.
``paper``
    a reading of the paper's unstated parameters chosen to bring its observations about:
    product texture, "amplitude 1" read as peak-to-peak (``amplitude = 0.5``), 1 px
    disparity between neighbouring cameras, 160² images, Ω over ±1 frame, plain averaging
    of the two estimates of ``v, z_x, z_y, u_z``, the data rows without the zoom-blur
    correction (the paper has none), brightness errors against the global value ``a``;
    filters as gridflow's.  The paper combines the two estimates "according to their
    error estimates" after a decorrelating rotation it does not give; read as equal
    weights, its noise and brightness-constancy observations hold (7, 10), read as
    gridflow's inverse-variance weights they do not (``docs/reproduction.md``).  Its
    calibration is measured in ``docs/reproduction.md`` (*The two setups*).  Use it to
    compare with the paper's figures.

A sweep spec selects one with ``[sweep] setup = "paper"``; its own ``[base]`` and
``[estimator]`` entries override the setup's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Setup", "SETUPS", "get_setup"]


@dataclass(frozen=True)
class Setup:
    """A named choice of everything the paper leaves open.

    Attributes
    ----------
    name : str
    description : str
    base : dict
        Generator parameters (``SinusoidParams`` fields) replacing the defaults.
    estimator : dict
        Estimator settings (``EstimatorSettings`` fields) replacing the defaults.
    brightness_reference : {"local", "global"}
        What the errors of ``a1`` and ``a2`` are measured against: the local truth
        ``a + a_x X + a_y Y`` at each pixel, or the global value ``a`` (Eq. 22 read with
        ``Q_ref`` the swept parameter's value).
    """

    name: str
    description: str
    base: dict = field(default_factory=dict)
    estimator: dict = field(default_factory=dict)
    brightness_reference: str = "local"


SETUPS = {
    "gridflow": Setup(
        "gridflow", "gridflow's most accurate choices (the library defaults)"),
    "paper": Setup(
        "paper", "the reading of the paper's unstated parameters under which its "
                 "observations hold",
        base={"texture": "product", "amplitude": 0.5, "height": 160, "width": 160,
              "spacing": (0.1, 0.1)},
        estimator={"temporal_radius": 1, "combine": "mean", "zoom_correction": False},
        brightness_reference="global"),
}


def get_setup(name: str) -> Setup:
    """The setup called ``name``; ValueError naming the known ones otherwise."""
    try:
        return SETUPS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown setup {name!r}; expected one of {sorted(SETUPS)}") from None
