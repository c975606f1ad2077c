"""Shared fixtures: volumes and estimates are cached per session, since every check on
the default sinusoid reads the same estimates."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from gridflow.estimator import estimate_models
from gridflow.generators import make_sinusoid
from gridflow.metrics import evaluate


def _key(kw: dict) -> tuple:
    return tuple(sorted((k, tuple(v) if isinstance(v, (list, tuple)) else v)
                        for k, v in kw.items()))


@lru_cache(maxsize=32)
def _run(key: tuple):
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
    return lambda **kw: _run(_key(kw))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def pytest_terminal_summary(terminalreporter):
    """Report how many inputs the property and hostile-input tests tried, and what became
    of them."""
    import sys

    counts = {}
    for name, m in list(sys.modules.items()):
        if name.endswith(("test_properties", "test_hostile")) and getattr(m, "TRIED", None):
            counts.update(m.TRIED)
    if counts:
        terminalreporter.write_sep("-", "property and hostile-input tests: inputs tried")
        for key in sorted(counts):
            terminalreporter.write_line(f"{counts[key]:6d}  {key}")
        terminalreporter.write_line(f"{sum(counts.values()):6d}  in all; none crashed, hung or "
                                    "wrote a file it should not (a failure would be reported "
                                    "above)")
