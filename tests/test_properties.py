"""Property-based hardening (hypothesis): malformed generator parameters, estimator inputs,
sweep specs, image-folder manifests and output paths give a clear error or documented NaN,
never a crash, hang or silent wrong number; accepted sweep specs run end to end; textured
volumes give finite estimates.  The counts of inputs tried are printed in the test summary."""

import io
import json
import os
import tempfile
from contextlib import redirect_stderr, redirect_stdout
from datetime import timedelta
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gridflow.estimator import InputError, estimate
from gridflow.generators import SinusoidParams, make_sinusoid
from gridflow.bench.spec import SpecError, SweepSpec

from builders import TRIED, noise_folder     # TRIED: reported by conftest's summary

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
    except SpecError as exc:                # the one error type a spec may raise
        assert str(exc)
        TRIED["sweep spec: rejected"] += 1
        return
    TRIED["sweep spec: accepted"] += 1
    assert spec.points()


# --- accepted specs run end to end -----------------------------------------------------------

SWEEP_VALUES = {"a1": st.floats(-0.3, 0.3), "a1x": st.floats(-0.003, 0.003),
                "a2": st.floats(-0.05, 0.05), "a2x": st.floats(-0.003, 0.003),
                "U_Z": st.floats(-0.2, 0.2), "height": st.integers(36, 48),
                "frames": st.sampled_from([5, 7])}
N_QUANTITIES = {"bcc": 6, "hf": 8, "full": 12}


@st.composite
def runnable_specs(draw):
    params = draw(st.lists(st.sampled_from(sorted(SWEEP_VALUES)), min_size=1, max_size=2,
                           unique=True))
    axes = [{"param": p, "values": draw(st.lists(SWEEP_VALUES[p], min_size=1, max_size=2,
                                                 unique=True))} for p in params]
    base = {"width": 40, "grid": [3, 3]}
    base.update({k: v for k, v in (("height", 40), ("frames", 5)) if k not in params})
    return {"sweep": {"name": "prop",
                      "models": draw(st.lists(st.sampled_from(["bcc", "hf", "full"]),
                                              min_size=1, max_size=3, unique=True)),
                      "noise": draw(st.lists(st.sampled_from([0.0, 0.01]), min_size=1,
                                             max_size=2, unique=True)),
                      "seeds": draw(st.lists(st.integers(0, 5), min_size=1, max_size=1))},
            "base": base, "estimator": {"sigma": 2.0, "window": 9}, "axis": axes}


@settings(max_examples=12, **COMMON)
@given(raw=runnable_specs())
def test_accepted_specs_run_end_to_end(raw):
    from gridflow.bench.sweep import run_sweep

    spec = SweepSpec.from_dict(raw)
    with tempfile.TemporaryDirectory() as d:
        df = run_sweep(spec, Path(d) / "s.csv", workers=1, progress=False)
        assert (Path(d) / "s.csv").is_file() and not (Path(d) / "s.csv.parts").exists()
    n_points = len(spec.points())
    assert len(df) == n_points * sum(N_QUANTITIES[m] for m in spec.models)
    assert df.n_pixels.gt(0).all()
    # noise-free, textured: the estimate is valid on (nearly) every interior pixel
    clean = df[(df.noise == 0) & (df.quantity == "Z")]
    assert (clean.n_invalid <= 0.05 * clean.n_pixels).all(), clean
    assert np.isfinite(clean.q).all()
    TRIED["sweep spec: accepted and run end to end"] += 1


# --- finite textured input gives finite estimates ---------------------------------------------

@settings(max_examples=30, **COMMON)
@given(p=st.fixed_dictionaries({
    "U_X": st.floats(-0.05, 0.05), "U_Y": st.floats(-0.05, 0.05), "U_Z": st.floats(-0.2, 0.2),
    "Z_X": st.floats(-0.3, 0.3), "Z_Y": st.floats(-0.3, 0.3), "a1": st.floats(-0.2, 0.2),
    "a2": st.floats(-0.02, 0.02), "offset": st.sampled_from([0.0, 1.0]),
    "amplitude": st.floats(0.2, 1.0), "wavelength_x": st.floats(6.0, 12.0),
    "wavelength_y": st.floats(16.0, 80.0), "noise": st.sampled_from([0.0, 0.0, 0.01])}),
    model=st.sampled_from(["bcc", "hf", "full"]), seed=st.integers(0, 100))
def test_textured_volumes_give_finite_estimates(p, model, seed):
    sv = make_sinusoid(height=48, width=48, frames=5, grid=(3, 3), seed=seed, **p)
    e = estimate(sv.volume, sv.focal_length, sv.camera_spacing, model=model, sigma=3.0,
                 window=13)
    for name, arr in e.maps.items():
        finite = np.isfinite(arr[e.interior]).mean()
        assert finite >= 0.95, f"{name}: finite on {finite:.1%} of the interior ({p})"
    TRIED["estimator: textured volume, finite on >= 95 % of the interior"] += 1


# --- image-folder manifests: every key ---------------------------------------------------------

_MANIFEST_VALUES = {
    "focal_length": st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2, 3),
                              st.booleans(), st.text(max_size=3), st.none()),
    "camera_spacing": st.one_of(st.lists(st.floats(-1, 1), max_size=3), st.floats(0, 1),
                                st.none()),
    "grid": st.one_of(st.lists(st.integers(-1, 4), max_size=3),
                      st.lists(st.floats(0, 4), max_size=2), st.just([3, 3]), st.text(max_size=2)),
    "frames": st.one_of(st.integers(-1, 10 ** 10), st.floats(0, 1e9), st.just(3), st.none()),
    "pattern": st.one_of(st.just("t{t:02d}_y{sy}_x{sx}.png"), st.just("t{t}_y{sy}_x{sx}.png"),
                         st.just("../t{t:02d}_y{sy}_x{sx}.png"), st.just("{t}{sy}{sx}.png"),
                         st.just("t{t:99999d}_y{sy}_x{sx}.png"), st.text(max_size=8),
                         st.integers()),
    "reference_camera": st.one_of(st.lists(st.integers(-1, 3), max_size=3), st.none()),
    "reference_frame": st.one_of(st.integers(-2, 5), st.floats(0, 3), st.text(max_size=2),
                                 st.none()),
    "principal_point": st.one_of(st.lists(st.floats(allow_nan=True, allow_infinity=True),
                                          max_size=3), st.none()),
    "truth": st.one_of(st.none(), st.just({"Z": "Z.npy"}), st.just({"Z": "../x.npy"}),
                       st.just({"Z": 1}), st.lists(st.text(max_size=2), max_size=1)),
    "units": st.one_of(st.text(max_size=3), st.integers()),
    "colour": st.text(max_size=3),
}
_GOOD = {"focal_length": 500.0, "camera_spacing": [0.1, 0.2], "grid": [3, 3], "frames": 3,
         "pattern": "t{t:02d}_y{sy}_x{sx}.png"}


@pytest.fixture(scope="module")
def image_folder(tmp_path_factory):
    # 16-bit noise, truncated; each example writes its own grid.json over the builder's
    folder = noise_folder(tmp_path_factory.mktemp("grid"), rounded=False)
    np.save(folder / "Z.npy", np.ones((12, 10)))
    return folder


@settings(max_examples=250, **COMMON)
@given(changes=st.dictionaries(st.sampled_from(sorted(_MANIFEST_VALUES)), st.none(),
                               max_size=3).flatmap(
    lambda keys: st.fixed_dictionaries({k: _MANIFEST_VALUES[k] for k in keys})),
    drop=st.lists(st.sampled_from(sorted(_GOOD)), max_size=1))
def test_manifest_keys_are_honoured_or_refused(image_folder, changes, drop):
    from gridflow.loader import LoaderError, load_folder

    m = {**_GOOD, **{k: v for k, v in changes.items() if v is not None or k in _GOOD}}
    for k in drop:
        m.pop(k, None)
    (image_folder / "grid.json").write_text(json.dumps(m))
    try:
        d = load_folder(image_folder)
    except LoaderError as exc:
        assert "grid.json" in str(exc) or str(image_folder) in str(exc)
        TRIED["manifest: refused with a clear error"] += 1
        return
    # accepted: every value lies in its range, stated here independently of the loader
    # (an echo alone would pass a wrong value the loader let through)
    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)

    T, grid = m["frames"], m["grid"]
    assert isinstance(T, int) and not isinstance(T, bool) and T >= 1
    assert all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 and v % 2 == 1
               for v in grid) and len(grid) == 2
    assert number(m["focal_length"]) and m["focal_length"] > 0
    ds = m["camera_spacing"]
    assert len(ds) == 2 and all(number(v) for v in ds) and ds[0] > 0
    assert ds[1] > 0 if grid[0] > 1 else ds[1] >= 0
    rf = m.get("reference_frame")
    assert rf is None or (isinstance(rf, int) and not isinstance(rf, bool) and 0 <= rf < T)
    rc = m.get("reference_camera")
    assert rc is None or rc == [(grid[0] - 1) // 2, (grid[1] - 1) // 2]
    pp = m.get("principal_point")
    assert pp is None or (len(pp) == 2 and all(number(v) for v in pp))
    # and every key was honoured exactly as written
    assert "colour" not in m
    assert d.volume.shape == (m["frames"], m["grid"][0], m["grid"][1], 12, 10)
    assert d.focal_length == m["focal_length"] and list(d.camera_spacing) == m["camera_spacing"]
    assert d.meta["ref_frame"] == m.get("reference_frame")
    pp = m.get("principal_point")
    assert list(d.principal_point) == (pp if pp is not None else [4.5, 5.5])
    assert set(d.truth) == set(m.get("truth") or {})
    assert np.isfinite(d.volume).all()
    TRIED["manifest: accepted and honoured"] += 1


# --- output paths --------------------------------------------------------------------------------

@settings(max_examples=150, **COMMON)
@given(kind=st.sampled_from(["missing", "regular", "folder", "fifo", "symlink", "input"]),
       suffix=st.sampled_from([".npz", ".NPZ", ".csv", "", ".npz.tmp", ".npzx"]),
       parent=st.sampled_from(["here", "new", "file"]))
def test_output_path_rules(kind, suffix, parent):
    from gridflow.io import OutputError, atomic_write, check_output

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        inp = d / "input.npz"
        inp.write_bytes(b"input")
        base = {"here": d, "new": d / "new" / "sub", "file": d / "plain"}[parent]
        if parent == "file":
            base.write_text("x")
        target = inp if kind == "input" else base / f"out{suffix}"
        if parent != "file" and kind != "input":
            base.mkdir(parents=True, exist_ok=True) if kind != "missing" else None
            if kind == "regular":
                target.write_bytes(b"old")
            elif kind == "folder":
                target.mkdir()
            elif kind == "fifo":
                os.mkfifo(target)
            elif kind == "symlink":
                target.symlink_to(inp)
        refuse = (target.suffix.lower() != ".npz" or kind in ("folder", "fifo", "symlink",
                                                              "input")
                  or (parent == "file" and kind != "input"))
        before = {p: (p.read_bytes() if p.is_file() and not p.is_symlink() else None)
                  for p in d.rglob("*")}
        try:
            check_output(target, suffixes=".npz", inputs=[inp], what="-o")
        except OutputError as exc:
            assert refuse, f"{kind} {suffix} {parent}: refused: {exc}"
            after = {p: (p.read_bytes() if p.is_file() and not p.is_symlink() else None)
                     for p in d.rglob("*")}
            assert after == before
            TRIED["output path: refused"] += 1
            return
        assert not refuse, f"{kind} {suffix} {parent}: accepted"
        with atomic_write(target, "wb") as fh:
            fh.write(b"new")
        assert target.read_bytes() == b"new" and inp.read_bytes() == b"input"
        assert not [p for p in d.rglob("*.tmp")]
        TRIED["output path: accepted and written"] += 1


# --- light-field scenes: parameters.cfg values and damaged folders ------------------------------

_GEOMETRY = {("intrinsics", "focal_length_mm"): 100.0, ("intrinsics", "sensor_size_mm"): 35.0,
             ("intrinsics", "image_resolution_x_px"): 8, ("extrinsics", "baseline_mm"): 30.0,
             ("extrinsics", "focus_distance_m"): 8.0}
# what a person might write in parameters.cfg: ordinary numbers, and the wrong things
_CFG_TEXT = st.one_of(
    st.floats(1e-3, 1e3).map(repr), st.integers(-3, 40).map(str),
    st.sampled_from(["0", "-1", "-30.0", "nan", "inf", "-inf", "1e999", "1e-320", "abc", "",
                     "8.0", "8.5", "1e308", "0x10", "8 mm", "True"]))


def _hci_views():
    return np.random.default_rng(7).random((3, 3, 6, 8))


def _cfg_number(text: str):
    """What a value of parameters.cfg is, read here independently of the loader: a finite
    number, or None."""
    try:
        v = float(text)
    except ValueError:
        return None
    return v if np.isfinite(v) else None


@settings(max_examples=200, **COMMON)
@given(values=st.dictionaries(st.sampled_from(sorted(_GEOMETRY) + [("meta", "disp_min"),
                                                                   ("meta", "disp_max")]),
                              _CFG_TEXT, max_size=3))
def test_hci_parameters_are_honoured_or_refused(values):
    """Any values of parameters.cfg's geometry keys and disparity range: the scene loads
    with exactly the geometry written, or is refused with an error naming parameters.cfg
    and a key whose value is wrong; never a traceback or a silently changed number (a
    resolution of 8.5 read as 8)."""
    from gridflow.hci import HCIError, load_hci, write_hci

    with tempfile.TemporaryDirectory() as d:
        folder = Path(d) / "scene"
        params = {"intrinsics": {}, "extrinsics": {}, "meta": {}}
        merged = {**{k: repr(v) if isinstance(v, float) else str(v)
                     for k, v in _GEOMETRY.items()}, **values}
        for (sec, key), text in merged.items():
            params[sec][key] = text
        write_hci(folder, _hci_views(), parameters=params)
        # the oracle: which keys are wrong, stated here from the values alone
        wrong = set()
        for (sec, key) in _GEOMETRY:
            v = _cfg_number(merged[(sec, key)])
            if v is None or v <= 0:
                wrong.add(key)
            elif key == "image_resolution_x_px" and v != 8:
                wrong.add(key)               # not the views' width (8), or not an integer
        if "focal_length_mm" not in wrong and "sensor_size_mm" not in wrong:
            f = _cfg_number(merged[("intrinsics", "focal_length_mm")])
            s = _cfg_number(merged[("intrinsics", "sensor_size_mm")])
            if not np.isfinite(f / s * 8):
                wrong.add("focal_length_mm")
        # a range is stated by both keys; one alone is an incomplete range
        lo, hi = (_cfg_number(values[("meta", k)]) if ("meta", k) in values else None
                  for k in ("disp_min", "disp_max"))
        ranged = any(k[0] == "meta" for k in values)
        if ranged and (lo is None or hi is None or lo > hi):
            wrong |= {"disp_min", "disp_max"}
        try:
            data = load_hci(folder)
        except HCIError as exc:
            msg = str(exc)
            assert wrong, f"refused although every value is good: {msg}"
            assert str(folder / "parameters.cfg") in msg, msg
            assert any(k in msg for k in wrong), (msg, wrong)
            TRIED["light field parameters.cfg: refused naming file and key"] += 1
            return
        assert not wrong, f"accepted although {sorted(wrong)} are wrong: {merged}"
        g = data.meta["hci"]
        num = {k: _cfg_number(t) for (_, k), t in merged.items()}
        assert g["focal_length_px"] == pytest.approx(
            num["focal_length_mm"] / num["sensor_size_mm"] * 8, rel=1e-12)
        assert g["baseline_m"] == pytest.approx(num["baseline_mm"] / 1000, rel=1e-12)
        assert g["focus_distance_m"] == num["focus_distance_m"]
        if ranged:
            assert g["disp_range"] == [lo, hi]
        TRIED["light field parameters.cfg: accepted and honoured"] += 1


def _damage(folder: Path, how: str, view: int) -> str:
    """Damage one file of a 3 x 3 HCI scene of 6 x 8 views; returns the name an error
    must mention."""
    import imageio.v3 as iio

    name = f"input_Cam{view:03d}.png"
    p = folder / name
    if how == "missing":
        p.unlink()
    elif how == "fifo":
        p.unlink()
        os.mkfifo(p)
    elif how == "device":
        p.unlink()
        p.symlink_to("/dev/zero")
    elif how == "folder":
        p.unlink()
        p.mkdir()
    elif how == "empty":
        p.write_bytes(b"")
    elif how == "truncated":
        p.write_bytes(p.read_bytes()[:40])
    elif how == "text":
        p.write_text("not an image")
    elif how == "16-bit":
        iio.imwrite(p, np.full((6, 8), 30000, np.uint16))
    elif how == "size":
        iio.imwrite(p, np.zeros((6, 9), np.uint8))
    elif how == "extra view":
        name = "input_Cam009.png"
        iio.imwrite(folder / name, np.zeros((6, 8), np.uint8))
    elif how in ("truth size", "truth corrupt"):
        from gridflow.hci import write_pfm

        name = "gt_disp_lowres.pfm"
        if how == "truth size":
            write_pfm(folder / name, np.zeros((5, 8)))
        else:
            (folder / name).write_bytes(b"Pf\n8 6\n-1\n" + b"\0" * 10)
    return name


@settings(max_examples=120, **COMMON)
@given(how=st.sampled_from(["missing", "fifo", "device", "folder", "empty", "truncated",
                            "text", "16-bit", "size", "extra view", "truth size",
                            "truth corrupt"]),
       view=st.integers(0, 8))
def test_damaged_hci_scenes_are_refused_naming_the_file(how, view):
    """One file of a light-field scene damaged in any of the ways the reviews found (a
    view missing, a FIFO, a link to /dev/zero, a folder, empty, truncated, text, another
    pixel type or size, a view too many, a truth map of the wrong size or cut short): the
    scene is refused with an error naming that file, at once (the per-example deadline is
    the hang check; a FIFO read would block for ever)."""
    from gridflow.hci import HCIError, load_hci, write_hci

    with tempfile.TemporaryDirectory() as d:
        folder = Path(d) / "scene"
        write_hci(folder, _hci_views(), disparity=np.zeros((6, 8)))
        name = _damage(folder, how, view)
        with pytest.raises(HCIError) as info:
            load_hci(folder)
        assert name in str(info.value), (how, str(info.value))
        TRIED[f"light field folder: refused ({how})"] += 1


# --- estimate's options against the input they apply to -----------------------------------------

# flag -> (its value on the command line, the setting it is recorded as, that value)
_SINGLE_PASS_FLAGS = {"--temporal-radius": (["2"], "temporal_radius", 2),
                      "--ref-frame": (["4"], "ref_frame", 4),
                      "--method": (["reference"], "method", "reference"),
                      "--no-slant-correction": ([], "slant_correction", False),
                      "--no-zoom-correction": ([], "zoom_correction", False),
                      "--combine": (["mean"], "combine", "mean"),
                      "--motion": (["affine"], "motion", "affine"),
                      "--model": (["full"], "model", "full")}
_REFOCUS_FLAGS = {"--select": (["occlusion"], "select", "occlusion"),
                  "--median": (["5"], "median", 5),
                  "--no-fill": ([], "fill", False)}
_COMMON_FLAGS = {"--sigma": (["1.5"], "sigma", 1.5), "--window": (["7"], "window", 7),
                 "--filters": (["matched3"], "filters", "matched3")}
_ALL_FLAGS = {**_SINGLE_PASS_FLAGS, **_REFOCUS_FLAGS, **_COMMON_FLAGS}
# single-pass settings that need several frames: on a light field of one frame they
# cannot apply (the window's frames, a frame index past the first, the affine model's
# and the full model's temporal rows)
_NEEDS_FRAMES = {"--temporal-radius", "--ref-frame", "--motion", "--model"}


@pytest.fixture(scope="module")
def option_inputs(tmp_path_factory):
    """A volume of 9 frames (3 x 3 views) and a one-frame 5 x 5 light field scene with its
    disparity range stated (so that refocusing runs no coarse pass)."""
    from gridflow.hci import write_hci
    from gridflow.io import save_volume

    d = tmp_path_factory.mktemp("options")
    save_volume(d / "v.npz", make_sinusoid(height=24, width=24, grid=(3, 3), frames=9))
    views = np.random.default_rng(3).random((5, 5, 24, 24))
    params = {"intrinsics": {"focal_length_mm": 100.0, "sensor_size_mm": 35.0,
                             "image_resolution_x_px": 24},
              "extrinsics": {"baseline_mm": 30.0, "focus_distance_m": 8.0},
              "meta": {"disp_min": -1.0, "disp_max": 1.0}}
    write_hci(d / "scene", views, parameters=params)
    return {"volume": d / "v.npz", "scene": d / "scene"}


@settings(max_examples=80, **COMMON)
@given(kind=st.sampled_from(["volume", "scene"]),
       shears=st.sampled_from([None, "none", "-1 1"]),
       views=st.booleans(),
       flags=st.lists(st.sampled_from(sorted(_ALL_FLAGS)), max_size=3, unique=True))
def test_estimate_options_are_honoured_or_refused(option_inputs, kind, shears, views, flags):
    """Any combination of estimate's options on a volume of several frames or a light
    field of one frame, refocused or not: each option that applies is honoured (it is in
    the output's recorded settings with the value given), and one that does not apply to
    that input is refused with an error naming it, never accepted and ignored."""
    from gridflow.bench.cli import main
    from gridflow.io import load_estimate

    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "e.npz"
        # a small window for the small inputs; a --sigma or --window among the flags
        # comes later and overrides it
        args = ["estimate", str(option_inputs[kind]), "-o", str(out), "--no-progress",
                "--sigma", "2", "--window", "9"]
        if shears is not None:
            args += ["--shears", *shears.split()]
        if views:
            args += ["--views", "3"]
        for f in flags:
            args += [f, *_ALL_FLAGS[f][0]]
        # the oracle: what cannot apply to this input, stated from the options alone
        refocus = kind == "scene" and shears != "none"
        misplaced = set()
        if kind == "volume":
            misplaced |= {"--views"} if views else set()
            misplaced |= {"--shears"} if shears == "-1 1" else set()
        if refocus:
            misplaced |= set(flags) & set(_SINGLE_PASS_FLAGS)
        else:
            misplaced |= set(flags) & set(_REFOCUS_FLAGS)
            if kind == "scene":
                misplaced |= set(flags) & _NEEDS_FRAMES
        out_text, err_text = io.StringIO(), io.StringIO()
        with redirect_stdout(out_text), redirect_stderr(err_text):
            rc = main(args)
        cap = SimpleNamespace(out=out_text.getvalue(), err=err_text.getvalue())
        if misplaced:
            assert rc == 2, f"{args}: accepted although {sorted(misplaced)} cannot apply"
            names = {f for f in misplaced} | {_ALL_FLAGS[f][1] for f in misplaced
                                             if f in _ALL_FLAGS}
            assert any(n in cap.err for n in names), (args, cap.err)
            assert not out.exists()
            TRIED["estimate options: refused where they do not apply"] += 1
            return
        assert rc == 0, f"{args}: refused although every option applies: {cap.err}"
        _, _, meta = load_estimate(out)
        got = meta["settings"]
        for f in flags:
            _, key, value = _ALL_FLAGS[f]
            recorded = meta.get("model") if key == "model" else got.get(key)
            assert recorded == value, f"{args}: {f} given, {key} recorded as {recorded!r}"
        if views:
            assert ("3x3 views" in cap.out if not refocus else got["views"] == [3, 3]), \
                (args, cap.out, got)
        if shears == "-1 1":
            assert got["shears"] == [-1, 0, 1]
        TRIED["estimate options: accepted and honoured"] += 1
