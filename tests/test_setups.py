"""Named setups and the choices they select: texture, combination rule, brightness
reference (bench/setups.py)."""

import numpy as np
import pytest

from gridflow.bench.setups import SETUPS, get_setup
from gridflow.bench.spec import SpecError, SweepSpec
from gridflow.bench.sweep import run_point
from gridflow.estimator.models import get_model
from gridflow.estimator.disentangle import disentangle
from gridflow.generators import SinusoidParams, make_sinusoid

SMALL = {"height": 48, "width": 48, "frames": 7, "grid": [3, 3]}


def test_product_texture():
    p = dict(height=40, width=40, frames=3, grid=(1, 3), U_Z=0.0)
    prod = make_sinusoid(texture="product", amplitude=1.0, **p).volume
    summ = make_sinusoid(texture="sum", amplitude=1.0, **p).volume
    # sin * sin spans [-1, 1]; the sum's half-amplitude terms too, but differently
    assert -1.0 <= prod.min() < -0.9 and 0.9 < prod.max() <= 1.0
    assert not np.allclose(prod, summ)
    # a product vanishes along the zero lines of either factor: some rows are ~0
    ref = prod[1, 0, 1]
    assert np.min(np.abs(ref).max(axis=1)) < 0.2
    with pytest.raises(ValueError, match="texture must be one of"):
        SinusoidParams(texture="checkerboard")


def test_mean_combination_is_the_plain_average():
    """With combine="mean" the two estimates of v are averaged with equal weights, so Z is
    -f over the mean of the two disparities (Sec. 3, step 4)."""
    model = get_model("full", 2)
    rng = np.random.default_rng(3)
    N, n = 50, model.n
    P = rng.normal(size=(N, n, 3))
    g = rng.uniform(0.5, 2.0, size=(N, n))
    x0, y0 = rng.normal(size=N), rng.normal(size=N)
    f, ds = 1000.0, (0.05, 0.08)
    out = disentangle(P, g, model, x0, y0, f, ds, combine="mean")
    v = (P[:, model.index("Ix"), 0] / ds[0] + P[:, model.index("Iy"), 1] / ds[1]) / 2
    np.testing.assert_allclose(out["Z"], -f / v, rtol=1e-12)
    weighted = disentangle(P, g, model, x0, y0, f, ds)
    assert not np.allclose(weighted["Z"], out["Z"])


def test_setups_are_complete_and_valid():
    assert set(SETUPS) == {"gridflow", "paper"}
    assert get_setup("gridflow").base == {} and get_setup("gridflow").estimator == {}
    for name in SETUPS:
        spec = SweepSpec.from_dict({"sweep": {"setup": name},
                                    "axis": [{"param": "a1", "values": [0.1]}]})
        spec.base_params()
    with pytest.raises(ValueError, match="unknown setup"):
        get_setup("pape")
    with pytest.raises(SpecError, match="setup"):
        SweepSpec.from_dict({"sweep": {"setup": "pape"}, "axis": [{"param": "a1",
                                                                     "values": [0.1]}]})


def test_spec_values_override_the_setup():
    spec = SweepSpec.from_dict({"sweep": {"setup": "paper"},
                                "base": {"height": 48, "amplitude": 0.7},
                                "estimator": {"temporal_radius": 2},
                                "axis": [{"param": "a1", "values": [0.1]}]})
    p = spec.base_params()
    assert p.texture == "product" and p.amplitude == 0.7 and p.height == 48
    assert p.width == 160 and p.spacing == (0.1, 0.1)
    s = spec.estimator_settings()
    assert s == {"temporal_radius": 2, "combine": "mean", "zoom_correction": False}


def _a1_error(setup, a1x):
    spec = SweepSpec.from_dict({"sweep": {"setup": setup, "models": ["full"]},
                                "base": dict(SMALL),
                                "estimator": {"sigma": 4.0, "window": 17},
                                "axis": [{"param": "a1x", "values": [a1x]}]})
    df = run_point(spec, spec.points()[0])
    return float(df[df.quantity == "a1"].q.iloc[0])


def test_global_brightness_reference():
    """Against the local truth a1 + a1x X the full model's a1 is nearly right; against the
    global a1 = 0 (the paper's Q_ref) its error is the local value |a1x X| itself.  The
    5-tap filters and the 17-tap window leave interior columns 10..37 of 48, |x| = 0.5 ..
    13.5 px around the centre 23.5, mean 7.0 px = 0.70 world units at Z0 / f = 0.1: the
    global error is a1x * 0.70 = 7.0e-3, give or take the local error (4.1e-4 measured
    with the gridflow setup, 6 %; the bound allows 10 %)."""
    a1x = 0.01
    local, glob = _a1_error("gridflow", a1x), _a1_error("paper", a1x)
    assert abs(glob - a1x * 0.70) < 0.1 * a1x * 0.70
    assert glob > 10 * local


def _uz(combine, model, a1, noise):
    spec = SweepSpec.from_dict({"sweep": {"setup": "paper", "models": [model],
                                          "noise": [noise]},
                                "estimator": {"combine": combine},
                                "axis": [{"param": "a1", "values": [a1]}]})
    df = run_point(spec, spec.points()[0])
    return float(df[df.quantity == "Uz"].q_rel.iloc[0])


@pytest.mark.slow
def test_the_combination_rule_decides_observations_7_and_10():
    """docs/reproduction.md: under the paper setup, plain averaging lets noise lift the
    full model's small-a1 U_Z error to the paper's "nearly 0.1" and BCC break down at
    a1 = 0.01; inverse-variance weights keep the first near 0.014 and BCC below 0.1
    (measured: 0.058 vs 0.014, and 0.58 vs 0.009)."""
    assert 0.05 <= _uz("mean", "full", 0.01, 0.025) <= 0.2
    assert _uz("inverse_variance", "full", 0.01, 0.025) < 0.03
    assert _uz("mean", "bcc", 0.01, 0.0) > 0.1
    assert _uz("inverse_variance", "bcc", 0.01, 0.0) < 0.1
