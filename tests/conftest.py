"""Shared fixtures: volumes and estimates are cached per session, since every check on
the default sinusoid reads the same estimates.  The builders themselves (folders, specs,
recordings, runs) are in ``builders.py``."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

import builders
from gridflow.estimator import estimate_models
from gridflow.generators import make_sinusoid
from gridflow.metrics import evaluate


def _key(kw: dict) -> tuple:
    return tuple(sorted((k, tuple(v) if isinstance(v, (list, tuple)) else v)
                        for k, v in kw.items()))


@lru_cache(maxsize=32)
def _estimates_and_scores(key: tuple):
    kw = dict(key)
    est_kw = {k[4:]: v for k, v in kw.items() if k.startswith("est_")}
    gen_kw = {k: v for k, v in kw.items() if not k.startswith("est_")}
    sv = make_sinusoid(**gen_kw)
    res = estimate_models(sv.volume, sv.focal_length, sv.camera_spacing, **est_kw)
    scores = {m: {r["quantity"]: r for r in evaluate(e.maps, sv.truth, e.interior)}
              for m, e in res.items()}
    return sv, res, scores


@pytest.fixture(scope="session")
def run():
    """``run(**params)`` -> (volume, {model: Estimate}, {model: {quantity: Eq.22 row}})."""
    return lambda **kw: _estimates_and_scores(_key(kw))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="module")
def small_volume(tmp_path_factory):
    """``builders.small_volume``: 48 x 48 px, 7 frames, 3 x 3 views, a1 = 0.1 (.npz)."""
    return builders.small_volume(tmp_path_factory.mktemp("vol") / "v.npz")


def pytest_sessionfinish(session):
    """Under pytest-xdist a worker hands its tally to the controller (``workeroutput``)."""
    out = getattr(session.config, "workeroutput", None)
    if out is not None:
        out["tried"] = dict(builders.TRIED)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """The controller adds each worker's tally to its own (pytest-xdist's hook)."""
    builders.TRIED.update(getattr(node, "workeroutput", {}).get("tried", {}))


def pytest_terminal_summary(terminalreporter):
    """Report how many inputs the property and hostile-input tests tried (their
    ``builders.tried`` tally), and what became of them."""
    counts = builders.TRIED
    if counts:
        terminalreporter.write_sep("-", "property and hostile-input tests: inputs tried")
        for key in sorted(counts):
            terminalreporter.write_line(f"{counts[key]:6d}  {key}")
        terminalreporter.write_line(f"{sum(counts.values()):6d}  in all; none crashed, hung or "
                                    "wrote a file it should not (a failure would be reported "
                                    "above)")
