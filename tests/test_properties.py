"""Property-based hardening (hypothesis): malformed generator parameters, estimator inputs
and sweep specs give a clear error or documented NaN, never a crash, hang or silent wrong
number.  The counts of inputs tried are printed in the test summary."""

from collections import Counter
from datetime import timedelta

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gridflow.estimator import InputError, estimate
from gridflow.generators import SinusoidParams, make_sinusoid
from gridflow.bench.sweep import SpecError, SweepSpec

TRIED = Counter()     # reported by conftest.pytest_terminal_summary

# A deadline per example is the hang check; it is generous because the machine is shared.
COMMON = dict(deadline=timedelta(seconds=20), derandomize=True,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])



@pytest.fixture(scope="module", autouse=True)
def _compiled():
    """Compile the numba kernels before any example runs: the first call compiles for
    ~20 s on a fresh checkout, which must not count against the per-example deadline."""
    sv = make_sinusoid(height=24, width=24, frames=5, grid=(3, 3))
    estimate(sv.volume, sv.focal_length, sv.camera_spacing, sigma=2.0, window=7)


nasty_float = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                        st.floats(-1e3, 1e3), st.just(0.0))


@settings(max_examples=300, **COMMON)
@given(params=st.fixed_dictionaries({}, optional={
    "a1": nasty_float, "a1x": nasty_float, "a2": nasty_float, "a2x": nasty_float,
    "a2y": nasty_float, "Z_X": nasty_float, "Z_Y": nasty_float, "U_Z": nasty_float,
    "f": nasty_float, "Z0": nasty_float, "noise": nasty_float,
    "wavelength_x": nasty_float, "frame_interval": nasty_float,
    "height": st.integers(-2, 12), "width": st.integers(-2, 12),
    "frames": st.integers(-1, 5), "seed": st.integers(-1, 3),
    "grid": st.tuples(st.integers(-1, 3), st.integers(-1, 3)),
    "spacing": st.tuples(nasty_float, nasty_float)}))
def test_generator_never_returns_garbage(params):
    try:
        p = SinusoidParams().replace(**params)
        sv = make_sinusoid(p)
    except (ValueError, TypeError) as exc:
        assert str(exc)
        TRIED["generator: rejected with a clear error"] += 1
        return
    TRIED["generator: rendered"] += 1
    assert sv.volume.shape == (p.frames, p.grid[0], p.grid[1], p.height, p.width)
    assert np.isfinite(sv.volume).all()


DTYPES = [np.float64, np.float32, np.float16, np.int16, np.uint8, np.bool_, np.complex64]


@st.composite
def volumes(draw):
    if draw(st.booleans()):
        # plausible: a valid grid, enough frames, images just large enough for the window,
        # so the estimate itself is exercised on odd content
        shape = (draw(st.integers(5, 9)), draw(st.sampled_from([1, 3])),
                 draw(st.sampled_from([3, 5])), draw(st.integers(11, 20)),
                 draw(st.integers(11, 20)))
        dtype = draw(st.sampled_from([np.float64, np.float32]))
    else:
        shape = draw(st.one_of(
            st.lists(st.integers(0, 4), min_size=0, max_size=6).map(tuple),
            st.tuples(st.integers(1, 9), st.sampled_from([1, 2, 3, 5]),
                      st.sampled_from([1, 2, 3, 5]), st.integers(1, 24), st.integers(1, 24))))
        dtype = draw(st.sampled_from(DTYPES))
    kind = draw(st.sampled_from(["random", "constant", "huge", "tiny", "nan", "inf", "zeros"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    v = rng.random(shape)
    if kind == "constant":
        v[...] = 0.7
    elif kind == "huge":
        v = v * 1e300
    elif kind == "tiny":
        v = v * 1e-300
    elif kind == "zeros":
        v[...] = 0
    with np.errstate(all="ignore"):
        v = v.astype(dtype)
    if kind in ("nan", "inf") and v.size and np.issubdtype(v.dtype, np.floating):
        v.flat[draw(st.integers(0, v.size - 1))] = np.nan if kind == "nan" else np.inf
    return v, kind


@settings(max_examples=300, **COMMON)
@given(vk=volumes(), model=st.sampled_from(["bcc", "hf", "full"]),
       f=st.sampled_from([1000.0, 1000.0, 1000.0, 0.0, -1.0, float("nan")]))
def test_estimator_never_crashes_or_returns_garbage(vk, model, f):
    vol, kind = vk
    try:
        e = estimate(vol, f, (0.05, 0.05), model=model, sigma=2.0, window=7)
    except InputError as exc:
        assert str(exc)
        TRIED[f"estimator: rejected ({kind})"] += 1
        return
    TRIED[f"estimator: estimated ({kind})"] += 1
    H, W = vol.shape[-2:]
    for name, arr in e.maps.items():
        assert arr.shape == (H, W)
        ok = np.isfinite(arr) | np.isnan(arr)
        if name == "model_error" and kind == "huge":
            ok |= np.isposinf(arr)          # documented: not representable, inf
        assert ok.all(), name
        assert np.isnan(arr[~e.interior]).all()
    if kind in ("constant", "zeros"):       # no texture: nothing may be estimated
        assert all(np.isnan(a).all() for a in e.maps.values())


spec_value = st.one_of(st.none(), st.integers(-3, 3), st.floats(allow_nan=True),
                       st.text(max_size=5), st.lists(st.floats(-1e3, 1e3), max_size=3))


@settings(max_examples=200, **COMMON)
@given(raw=st.fixed_dictionaries({}, optional={
    "sweep": st.fixed_dictionaries({}, optional={"models": spec_value, "noise": spec_value,
                                                 "seeds": spec_value, "name": spec_value}),
    "base": st.dictionaries(st.sampled_from(["height", "a1", "frames", "colour"]), spec_value,
                            max_size=2),
    "axis": st.lists(st.fixed_dictionaries({}, optional={
        "param": st.sampled_from(["a1", "a2x", "U_Z", "a9", "grid"]),
        "values": spec_value}), max_size=2)}))
def test_sweep_specs_are_validated_before_running(raw):
    try:
        spec = SweepSpec.from_dict(raw)
    except (SpecError, TypeError, ValueError) as exc:
        assert str(exc)
        TRIED["sweep spec: rejected"] += 1
        return
    TRIED["sweep spec: accepted"] += 1
    assert spec.points()
