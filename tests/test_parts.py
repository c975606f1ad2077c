"""The estimator's parts and the benchmark layer's seams: the Estimate mapping, the choice
of backend, one worker environment, cache detection, the choices defined once, and user
errors told apart from bugs."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest

from gridflow.estimator import COMBINE, FILTER_NAMES, METHODS, MODELS, estimate
from gridflow.generators import make_sinusoid

ROOT = Path(__file__).resolve().parent.parent


def test_estimate_is_a_mapping_with_a_short_repr():
    sv = make_sinusoid(height=64, width=64, a1=0.1)
    e = estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="hf", sigma=4.0,
                 window=17)
    assert list(e) == ["Z", "Zx", "Zy", "disparity", "Ux", "Uy", "Uz", "a1", "a2",
                       "model_error"]
    assert len(e) == 10 and "a1" in e and "a1x" not in e
    assert e["Uz"] is e.maps["Uz"] and dict(e.items()).keys() == e.maps.keys()
    with pytest.raises(KeyError, match="'a1x': this estimate holds Z, Zx"):
        e["a1x"]
    text = repr(e)
    assert text.startswith("<Estimate model hf, motion translation, 64x64, valid 100.0 % of ")
    assert "array" not in text and len(text) < 200, text
    assert e == e and e != estimate(sv.volume, sv.focal_length, sv.camera_spacing,
                                    model="hf", sigma=4.0, window=17)


def test_an_estimate_names_both_axes_of_its_model():
    """``Estimate.model`` the brightness model, ``Estimate.motion`` the motion model
    (read-only; ``settings["motion"]`` kept too); a map without a motion model (a
    refocused light field) has none, and its repr says nothing of one."""
    from gridflow.estimator import Estimate

    sv = make_sinusoid(height=40, width=40, frames=5, grid=(3, 3), growth=1e-3)
    for motion in ("translation", "affine"):
        e = estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="bcc", sigma=2.0,
                     window=9, motion=motion)
        assert (e.model, e.motion, e.settings["motion"]) == ("bcc", motion, motion)
        assert repr(e).startswith(f"<Estimate model bcc, motion {motion}, 40x40")
        with pytest.raises(AttributeError):
            e.motion = "translation"
    lf = Estimate({"disparity": np.zeros((4, 4))}, "bcc", np.ones((4, 4), bool), {"sigma": 2})
    assert lf.motion is None and repr(lf).startswith("<Estimate model bcc, 4x4")
    assert Estimate({}, "bcc", np.ones((4, 4), bool), {"motion": "translation"},
                    motion="affine").motion == "affine"


def test_each_axis_of_a_model_is_one_registered_object():
    """The registries, written out: each motion model's rows, outputs, the rows a 1-D
    grid drops and whether it needs a time axis; each brightness model's; the names the
    rest of gridflow reads are theirs, in order."""
    from gridflow.estimator import MOTIONS
    from gridflow.estimator.models import (AFFINE, BRIGHTNESS_MODELS, MOTION_MODELS,
                                           TRANSLATION)

    paper = ("Ix", "Iy", "IxDx", "IxDy", "IyDx", "IyDy", "Isx", "Isy", "It")
    assert MOTIONS == ("translation", "affine") and MODELS == ("bcc", "hf", "full")
    assert MOTION_MODELS == {"translation": TRANSLATION, "affine": AFFINE}
    assert TRANSLATION.rows == paper
    assert TRANSLATION.outputs == ("Ux", "Uy", "Uz")
    assert TRANSLATION.rows_dropped_1d == ("IyDx", "Isy") and not TRANSLATION.needs_time
    assert AFFINE.rows == paper + ("tIx", "tIy", "tIxDx", "tIxDy", "tIyDx", "tIyDy")
    assert AFFINE.outputs == ("Ux", "Uy", "Uz", "growth", "rotation", "Zx_t", "Zy_t",
                              "Uz_err", "growth_err", "rotation_err", "pooled", "growth_sd")
    assert AFFINE.rows_dropped_1d == ("Isy",) and AFFINE.needs_time
    assert (TRANSLATION.temporal_radius, AFFINE.temporal_radius) == (2, 6)
    assert AFFINE.pools_rates and not TRANSLATION.pools_rates
    want = {"bcc": ((), (), False),
            "hf": (("I", "tI"), ("a1", "a2"), True),
            "full": (("I", "IDx", "IDy", "tI", "tIDx", "tIDy"),
                     ("a1", "a2", "a1x", "a1y", "a2x", "a2y"), True)}
    assert {n: (b.rows, b.outputs, b.needs_time) for n, b in BRIGHTNESS_MODELS.items()} == want
    assert all(b.name == n for n, b in BRIGHTNESS_MODELS.items())
    assert all(m.name == n for n, m in MOTION_MODELS.items())


@pytest.mark.parametrize("grid_dims", [1, 2])
def test_a_model_carries_both_axes(grid_dims):
    """get_model combines the two objects: the motion's rows then the brightness model's,
    less the rows a 1-D grid drops (I_y Δx only under translation) or a static light
    field (I_t); the outputs in that order too; the static rule is the axes' needs_time."""
    from gridflow.estimator.models import AFFINE, BRIGHTNESS_MODELS, TRANSLATION, get_model

    full = BRIGHTNESS_MODELS["full"]
    for motion in (TRANSLATION, AFFINE):
        m = get_model("full", grid_dims, motion=motion.name)
        assert m.brightness is full and m.motion is motion and m.name == "full"
        assert m.needs_time
        dropped = motion.rows_dropped_1d if grid_dims == 1 else ()
        assert m.rows == tuple(r for r in motion.rows + full.rows if r not in dropped)
        assert m.outputs == ("Z", "Zx", "Zy", "disparity") + motion.outputs + full.outputs
    t1 = get_model("bcc", 1)
    assert "IyDx" not in t1.rows and "IyDx" in get_model("bcc", 1, motion="affine").rows
    assert not t1.needs_time and get_model("bcc", motion=AFFINE).needs_time
    static = get_model("bcc", grid_dims, static=True)
    assert "It" not in static.rows and static.outputs == ("Z", "Zx", "Zy", "disparity")
    with pytest.raises(ValueError, match="models \\['hf'\\] need a time axis"):
        get_model("hf", grid_dims, static=True)
    with pytest.raises(ValueError, match="motion 'affine' needs a time axis"):
        get_model("bcc", grid_dims, static=True, motion="affine")
    with pytest.raises(ValueError, match="unknown motion model 'rigid'"):
        get_model("bcc", grid_dims, motion="rigid")
    with pytest.raises(ValueError, match="unknown model 'cc'"):
        get_model("cc", grid_dims)


def test_every_motion_model_has_its_disentangling():
    from gridflow.estimator import disentangle as D
    from gridflow.estimator.models import AFFINE, MOTION_MODELS, TRANSLATION

    assert set(D._DISENTANGLING) == set(MOTION_MODELS.values())
    assert D._DISENTANGLING[TRANSLATION] is D._translation
    assert D._DISENTANGLING[AFFINE] is D._affine


def test_a_new_motion_model_is_one_object_and_one_registered_function(monkeypatch):
    """What docs/architecture.md says a new motion model takes: a MotionModel object and
    a function registered for it; get_model and disentangle need nothing else.  Here a
    model of the paper's rows that gives only the lateral velocity, on one pixel."""
    from gridflow.estimator import disentangle as D
    from gridflow.estimator.models import TRANSLATION, MotionModel, get_model

    lateral = MotionModel("lateral", TRANSLATION.rows, ("Ux", "Uy"),
                          TRANSLATION.rows_dropped_1d)
    model = get_model("hf", 2, motion=lateral)
    assert model.motion is lateral and model.rows == TRANSLATION.rows + ("I", "tI")
    assert model.outputs == ("Z", "Zx", "Zy", "disparity", "Ux", "Uy", "a1", "a2")
    rng = np.random.default_rng(0)
    P, g = rng.standard_normal((1, model.n, 3)), rng.uniform(0.5, 2.0, (1, model.n))
    args = (P, g, model, np.array([3.0]), np.array([-2.0]), 1000.0, (0.05, 0.05))
    with pytest.raises(LookupError, match="'lateral' has no disentangling"):
        D.disentangle(*args)
    monkeypatch.setitem(D._DISENTANGLING, lateral, None)     # removed again after the test

    @D.disentangles(lateral)
    def _lateral(P, g, model, plane, *rest):
        out = D._translation(P, g, model, plane, *rest)
        return {"Ux": out["Ux"], "Uy": out["Uy"]}

    out = D.disentangle(*args)
    assert tuple(out) == model.outputs
    paper = D.disentangle(P, g, get_model("hf", 2), *args[3:])
    for q in model.outputs:
        assert np.array_equal(out[q], paper[q]), q


@pytest.mark.parametrize("method, size, backend", [("fast", 127, "fft"), ("fast", 128, "numba"),
                                                   ("grouped", 128, "grouped"),
                                                   ("reference", 40, "reference")])
def test_the_backend_is_chosen_in_one_place_and_recorded(method, size, backend):
    """``fast`` runs on numba from 128 x 128 pixels on (the threshold of
    estimator.backends, written here), on numpy.fft and LAPACK below; the estimate says
    which ran."""
    from gridflow.estimator.backends import select_backend

    shape = (5, 3, 3, size, 128)
    assert select_backend(method, shape).name == backend
    sv = make_sinusoid(height=size, width=128, frames=5, grid=(3, 3))
    e = estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="bcc", sigma=2.0,
                 window=9, method=method)
    assert e.settings["backend"] == backend


def _threads_seen(_):
    """A pool task: the worker's thread settings as the estimator would see them."""
    import numba

    from gridflow.estimator.backends import thread_count

    return ({k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                            "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")},
            numba.get_num_threads(), thread_count())


def test_pool_workers_share_the_cores():
    """Each of two pool workers gets cores // 2 threads for BLAS, numba and (numba's count)
    scipy.fft; before, numba and scipy.fft took every core in every worker."""
    from gridflow.pipeline.executors import Pool

    want = max(1, (os.cpu_count() or 1) // 2)
    before = dict(os.environ)
    seen = []
    Pool(2).map(_threads_seen, [(i,) for i in range(4)], lambda t, r: seen.append(r))
    assert len(seen) == 4
    for env, numba_threads, estimator_threads in seen:
        assert set(env.values()) == {str(want)}, env
        assert numba_threads == want and estimator_threads == want
    assert dict(os.environ) == before          # this process's environment is restored


def test_every_cached_kernel_is_found_without_a_list():
    """jit.py finds the kernels by their type: as many as the kernel modules declare
    with cache=True (counted here in their source); after make's warm-up all are cached
    for this CPU."""
    from gridflow.estimator import _affine, _kernels, _solver, jit

    declared = sum(len(re.findall(r"@njit\([^)]*cache=True", (ROOT / "estimator" / f).read_text()))
                   for f in ("_kernels.py", "_solver.py", "_affine.py"))
    assert len(jit.cached_kernels((_kernels, _solver, _affine))) == declared >= 11
    sv = make_sinusoid(height=128, width=128, frames=5, grid=(3, 3))
    estimate(sv.volume, sv.focal_length, sv.camera_spacing, sigma=2.0, window=9)
    estimate(sv.volume.astype(np.float32), sv.focal_length, sv.camera_spacing, sigma=2.0,
             window=9)
    estimate(sv.volume, sv.focal_length, sv.camera_spacing, sigma=2.0, window=9,
             motion="affine")
    assert jit.kernels_cached((_kernels, _solver, _affine))


def _subparser(parser, command):
    return next(a for a in parser._actions if a.dest == "command").choices[command]


def _choices(parser, command, dest):
    sub = _subparser(parser, command)
    return tuple(next(a for a in sub._actions if a.dest == dest).choices)


def test_the_cli_takes_its_choices_from_the_library():
    from gridflow.bench import claims
    from gridflow.bench.cli import build_parser
    from gridflow.estimator.lightfield import SELECT_DEFAULTS, SELECTS

    ap = build_parser()
    # --method takes an implementation or another method (gridflow.bench.methods): its
    # help names every implementation, and estimator_settings passes those through
    from gridflow.bench.cli._common import estimator_settings

    help_text = next(a.help for a in _subparser(ap, "estimate")._actions
                     if "--method" in a.option_strings)
    assert all(m in help_text for m in METHODS)
    a = ap.parse_args(["estimate", "x.npz", "-o", "y.npz", "--method", METHODS[-1]])
    assert estimator_settings(a)["method"] == METHODS[-1]
    a = ap.parse_args(["estimate", "x.npz", "-o", "y.npz", "--method", "mod:fn"])
    assert "method" not in estimator_settings(a)
    assert _choices(ap, "estimate", "combine") == COMBINE
    assert _choices(ap, "estimate", "filters") == FILTER_NAMES
    assert _choices(ap, "estimate", "select") == SELECTS
    assert set(SELECTS) == set(SELECT_DEFAULTS)
    assert claims.NEEDS["7"][1] == MODELS


def test_the_figures_style_every_model():
    from gridflow.bench import figures

    assert set(figures.MODEL_STYLE) == set(figures._LINE) == set(MODELS)


def test_user_errors_exit_2_and_bugs_keep_their_traceback(tmp_path, monkeypatch, capsys):
    import gridflow.pipeline as pipeline
    from gridflow.bench import cli
    from gridflow.errors import UsageError

    sv = make_sinusoid(height=40, width=40, frames=5, grid=(3, 3))
    from gridflow.io import save_volume

    save_volume(tmp_path / "v.npz", sv)
    args = ["estimate", str(tmp_path / "v.npz"), "-o", str(tmp_path / "e.npz")]

    def usage(*a, **k):
        raise UsageError("--this and --that exclude each other")

    monkeypatch.setattr(pipeline, "estimate", usage, raising=False)
    assert cli.main(args) == 2
    assert "gridflow estimate: error: --this and --that" in capsys.readouterr().err
    for bug in (TypeError("unsupported operand"), RuntimeError("state"), KeyError("x")):
        def broken(*a, _bug=bug, **k):
            raise _bug

        monkeypatch.setattr(pipeline, "estimate", broken, raising=False)
        with pytest.raises(type(bug)):
            cli.main(args)
