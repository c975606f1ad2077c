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
    from gridflow.estimator import _kernels, _solver, jit

    declared = sum(len(re.findall(r"@njit\([^)]*cache=True", (ROOT / "estimator" / f).read_text()))
                   for f in ("_kernels.py", "_solver.py"))
    assert len(jit.cached_kernels((_kernels, _solver))) == declared >= 10
    sv = make_sinusoid(height=128, width=128, frames=5, grid=(3, 3))
    estimate(sv.volume, sv.focal_length, sv.camera_spacing, sigma=2.0, window=9)
    estimate(sv.volume.astype(np.float32), sv.focal_length, sv.camera_spacing, sigma=2.0,
             window=9)
    assert jit.kernels_cached((_kernels, _solver))


def _choices(parser, command, dest):
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    return tuple(next(a for a in sub._actions if a.dest == dest).choices)


def test_the_cli_takes_its_choices_from_the_library():
    from gridflow.bench import claims
    from gridflow.bench.cli import build_parser
    from gridflow.estimator.lightfield import SELECT_DEFAULTS, SELECTS

    ap = build_parser()
    assert _choices(ap, "estimate", "method") == METHODS
    assert _choices(ap, "estimate", "combine") == COMBINE
    assert _choices(ap, "estimate", "filters") == FILTER_NAMES
    assert _choices(ap, "estimate", "select") == SELECTS
    assert set(SELECTS) == set(SELECT_DEFAULTS)
    assert claims.NEEDS["7"][1] == MODELS


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
