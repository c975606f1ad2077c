"""Every range check at its limit and one past it: the estimator's settings and input
checks, the camera-grid manifest, the sweep spec.  A check written ``<=`` for ``<`` (or
the other way round) fails here, where a value far out of range would not tell."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

from builders import noise_folder, refused, sweep_spec
from gridflow.estimator import EstimatorSettings, InputError, estimate
from gridflow.generators import make_sinusoid

TINY = 5e-324                  # the smallest positive float


# --- estimator settings ----------------------------------------------------------------------

@pytest.mark.parametrize("name, ok, bad", [
    ("sigma", TINY, 0.0), ("sigma", 1e308, float("inf")), ("sigma", TINY, -0.0),
    ("window", 3, 1), ("window", 3, 2), ("window", 65, 64),
    ("temporal_radius", 0, -1), ("ref_frame", 0, -1), ("band_rows", 1, 0),
])
def test_settings_at_the_limit_and_one_past(name, ok, bad):
    try:
        assert getattr(EstimatorSettings(**{name: ok}), name) == ok
    except InputError as exc:
        pytest.fail(f"refused at the limit: {exc}")
    with pytest.raises(InputError, match=name):
        EstimatorSettings(**{name: bad})


# --- the estimator's checks against the volume -----------------------------------------------

def _vol(**kw):
    kw = dict(dict(height=24, width=24, frames=5, grid=(3, 3)), **kw)
    return make_sinusoid(**kw)


def _estimate(sv, **kw):
    kw = dict(dict(model="bcc", sigma=2.0, window=9), **kw)
    return estimate(sv.volume, sv.focal_length, sv.camera_spacing, **kw)


def _accepted(sv, **kw):
    """An estimate that must run: a refusal fails the test as a check."""
    try:
        return _estimate(sv, **kw)
    except InputError as exc:
        pytest.fail(f"refused at the limit: {exc}")


def test_image_size_at_the_limit():
    """A 9-tap window and 5-tap filters reach 4 + 2 = 6 pixels: 13 pixels a side leave
    one interior pixel, 12 none."""
    e = _accepted(_vol(height=13, width=13))
    assert e.interior.sum() == 1
    with pytest.raises(InputError, match="too small"):
        _estimate(_vol(height=12, width=13))
    with pytest.raises(InputError, match="too small"):
        _estimate(_vol(height=13, width=12))


def test_camera_grid_at_the_limit():
    """Three cameras along x are the fewest the 3-tap camera filters need; grids are odd."""
    assert _accepted(_vol(grid=(1, 3))).settings["filters_sx"] == "matched3"
    sv = _vol(grid=(1, 3))
    with pytest.raises(InputError, match="too few cameras along x"):
        estimate(sv.volume[:, :, :1], sv.focal_length, sv.camera_spacing, model="bcc",
                 sigma=2.0, window=9)
    with pytest.raises(InputError, match="even size"):
        estimate(_vol(grid=(3, 5)).volume[:, :, :4], sv.focal_length, sv.camera_spacing,
                 model="bcc", sigma=2.0, window=9)


@pytest.mark.parametrize("model, fewest", [("bcc", 3), ("hf", 5), ("full", 5)])
def test_frames_at_the_limit(model, fewest):
    """bcc needs the 3-tap temporal filter (3 frames); the brightness models also need t
    to vary over the window (5 frames: the 3-tap filter and a radius of 1)."""
    sv = _vol(frames=fewest)
    assert _accepted(sv, model=model).settings["temporal_radius"] == (0 if fewest == 3 else 1)
    with pytest.raises(InputError, match="too few frames"):
        _estimate(_vol(frames=fewest - 1), model=model)


def test_temporal_radius_and_reference_frame_at_the_limit():
    """9 frames around frame 4 with the 5-tap temporal filter leave a radius of 2; the
    reference frame is an index below T."""
    sv = _vol(frames=9)
    assert _accepted(sv).settings["temporal_radius"] == 2       # the default: the most
    assert _accepted(sv, temporal_radius=2).settings["temporal_radius"] == 2
    with pytest.raises(InputError, match="temporal_radius 3 does not fit"):
        _estimate(sv, temporal_radius=3)
    lf = _vol(frames=1)
    assert _accepted(lf, ref_frame=0).settings["ref_frame"] == 0
    with pytest.raises(InputError, match="ref_frame 1 outside the 1 frames"):
        _estimate(lf, ref_frame=1)
    assert _accepted(sv, ref_frame=6, temporal_radius=0).settings["ref_frame"] == 6
    with pytest.raises(InputError, match="ref_frame 9 outside the 9 frames"):
        _estimate(sv, ref_frame=9)


# (spacings just above 0: 1e-12, where the smallest float would overflow v = P / ds)
@pytest.mark.parametrize("arg, ok, bad", [("focal_length", TINY, 0.0),
                                          ("camera_spacing", (1e-12, 1e-12), (0.0, 0.05)),
                                          ("camera_spacing", (1e-12, 1e-12), (0.05, 0.0))])
def test_geometry_at_the_limit(arg, ok, bad):
    sv = _vol()
    kw = dict(focal_length=sv.focal_length, camera_spacing=sv.camera_spacing)
    try:
        estimate(sv.volume, **dict(kw, **{arg: ok}), model="bcc", sigma=2.0, window=9)
    except InputError as exc:
        pytest.fail(f"refused at the limit: {exc}")
    with pytest.raises(InputError, match=arg):
        estimate(sv.volume, **dict(kw, **{arg: bad}), model="bcc", sigma=2.0, window=9)


# --- the camera-grid manifest ----------------------------------------------------------------

# a folder of 8-bit noise (truncated), 12 x 10 px: _folder(path, T=3, Sy=3, Sx=3, **manifest)
_folder = partial(noise_folder, dtype=np.uint8, rounded=False)


def _load(path):
    """Load a folder that must be accepted: a refusal fails the test as a check (the
    value at the limit is valid), not as an error."""
    from gridflow.loader import LoaderError, load_folder

    try:
        return load_folder(path)
    except LoaderError as exc:
        pytest.fail(f"refused at the limit: {exc}")


def _refused(path, match):
    from gridflow.loader import LoaderError, load_folder

    refused(LoaderError, match, load_folder, path)


@pytest.mark.parametrize("key, ok, bad, match", [
    ("reference_frame", 2, 3, "'reference_frame' must be a frame index 0..2"),
    ("reference_frame", 0, -1, "'reference_frame' must be a frame index 0..2"),
    ("focal_length", TINY, 0.0, "'focal_length' must be a positive number"),
    ("camera_spacing", [TINY, TINY], [0.0, 0.2], "'camera_spacing'"),
    ("camera_spacing", [TINY, TINY], [0.1, 0.0], "'camera_spacing'"),
    ("reference_camera", [1, 1], [1, 2], "'reference_camera'"),
])
def test_manifest_key_at_the_limit_and_one_past(tmp_path, key, ok, bad, match):
    f = _folder(tmp_path / "ok", **{key: ok})
    _load(f)
    _refused(_folder(tmp_path / "bad", **{key: bad}), match)


def test_manifest_grid_and_frames_at_the_limit(tmp_path):
    """One frame and a 1 x 3 grid are the least a manifest may name (ds_y may then be 0,
    not below); 0 frames, a grid side of 0 and even sizes are refused."""
    d = _load(_folder(tmp_path / "one", T=1, Sy=1, Sx=3, camera_spacing=[0.1, 0.0]))
    assert d.volume.shape == (1, 1, 3, 12, 10)
    _refused(_folder(tmp_path / "neg", T=1, Sy=1, Sx=3, camera_spacing=[0.1, -TINY]),
             "'camera_spacing'")
    _refused(_folder(tmp_path / "zero", T=1, Sy=1, Sx=3, frames=0), "'frames' must be")
    _refused(_folder(tmp_path / "side", T=1, Sy=1, Sx=3, grid=[0, 3]), "'grid' must be")
    _refused(_folder(tmp_path / "even", T=1, Sy=1, Sx=3, grid=[1, 2]), "even size")


def test_manifest_image_count_at_the_limit(tmp_path, monkeypatch):
    import gridflow.loader as loader

    f = _folder(tmp_path / "f")                      # 27 images
    monkeypatch.setattr(loader, "MAX_IMAGES", 27)
    _load(f)
    monkeypatch.setattr(loader, "MAX_IMAGES", 26)
    _refused(f, "more than 26")


def test_memory_check_at_the_limit(tmp_path, monkeypatch):
    """The loader refuses a float64 volume above 0.8 of physical memory: 3 x 3 x 3 x 12 x
    10 doubles are 25 920 bytes, at the limit with 32 400 bytes of memory, one past with
    32 399."""
    import gridflow.loader as loader

    f = _folder(tmp_path / "f")
    monkeypatch.setattr(loader, "physical_memory", lambda: 32400)
    _load(f)
    monkeypatch.setattr(loader, "physical_memory", lambda: 32399)
    _refused(f, "memory")


# --- the sweep spec ----------------------------------------------------------------------------

SPEC = {"sweep": {"name": "b", "models": ["bcc"], "noise": [0.0], "seeds": [0]},
        "base": {"height": 40, "width": 40, "frames": 5},
        "estimator": {"sigma": 2.0, "window": 9},
        "axis": [{"param": "a1", "values": [0.0]}]}


def _accepted_spec(**sections):
    from gridflow.bench.spec import SpecError

    try:
        return _spec(**sections)
    except SpecError as exc:
        pytest.fail(f"refused at the limit: {exc}")


# SPEC with sections merged in: _spec(**sections) -> SweepSpec
_spec = partial(sweep_spec, SPEC)


@pytest.mark.parametrize("sweep, ok, bad, match", [
    ("noise", [0.0], [-TINY], "noise must be"),
    ("seeds", [0], [-1], "seeds must be"),
])
def test_spec_list_at_the_limit(sweep, ok, bad, match):
    from gridflow.bench.spec import SpecError

    _accepted_spec(sweep={sweep: ok})
    with pytest.raises(SpecError, match=match):
        _spec(sweep={sweep: bad})


def test_spec_sizes_are_integral():
    from gridflow.bench.spec import SpecError

    assert _accepted_spec(base={"height": 40.0}).base["height"] == 40
    with pytest.raises(SpecError, match="height must be an integer"):
        _spec(base={"height": 40.5})


def test_spec_memory_check_at_the_limit(monkeypatch):
    """A point's volume may take a quarter of physical memory: 5 frames x 5 x 5 cameras x
    40 x 40 doubles are 1 600 000 bytes, at the limit with 6 400 000 bytes, one past with
    6 399 999."""
    import gridflow.bench.spec as spec
    from gridflow.bench.spec import SpecError

    monkeypatch.setattr(spec, "physical_memory", lambda: 6_400_000)
    _accepted_spec()
    monkeypatch.setattr(spec, "physical_memory", lambda: 6_399_999)
    with pytest.raises(SpecError, match="more than a quarter"):
        _spec()
