"""Affine surface motion: the generator's deforming planes and ``motion="affine"``.

The generator's truths are checked against the deformation itself, by finite
differences of tracked material vectors (independent of the closed forms it uses); the
estimator against those truths on exact renderings in the paper's geometry (Z0 = 100,
f = 1000 px, 5 x 5 cameras 0.05 apart, 9 frames, U_Z = 0.1, 192^2).  Bounds: 3x the
errors measured at 586d64e (``MEASURED``; deterministic noise-free renderings), each also
under the goal the growth issue sets where it sets one (2 % for growth, U_Z, rotation;
1e-3 for U_Z and 2e-5 for |growth| on a translating plane).
"""

from __future__ import annotations

import numpy as np
import pytest

from builders import refused
from gridflow.metrics import evaluate
from gridflow.estimator import InputError, estimate, estimate_models
from gridflow.generators import SinusoidParams, make_sinusoid
from gridflow.generators.sinusoid import velocity_gradient

MARGIN = 3.0
CASES = {
    "growth": dict(growth=1e-3),
    "growth slope brightness": dict(growth=1e-3, Z_X=0.4, a1=0.05, a1x=0.002),
    "rotation": dict(rotation=2e-3),
    "all together": dict(growth=1e-3, rotation=2e-3, U_X=0.02, U_Y=-0.01),
    "translation only": dict(),
    "tilting": dict(G_XZ=1e-3, G_ZX=-1e-3),
    "anisotropic": dict(G_XX=1e-3),
    "shear": dict(G_XY=1e-3),
}
MEASURED = {
    ("growth", "bcc"): {"Ux": ("abs", 8.9e-07), "Uy": ("abs", 7.9e-07), "Uz": ("rel", 0.00029), "growth": ("rel", 0.00053), "rotation": ("abs", 4.4e-07), "Zx_t": ("abs", 1.8e-07), "Zy_t": ("abs", 2.4e-09)},
    ("growth", "full"): {"Ux": ("abs", 8.9e-07), "Uy": ("abs", 1.2e-06), "Uz": ("rel", 0.00029), "growth": ("rel", 0.0072), "rotation": ("abs", 2.5e-07), "Zx_t": ("abs", 1.3e-07), "Zy_t": ("abs", 3.3e-08)},
    ("growth slope brightness", "full"): {"Ux": ("abs", 1.3e-05), "Uy": ("abs", 1.2e-06), "Uz": ("rel", 0.00023), "growth": ("rel", 0.0072), "rotation": ("abs", 2.9e-07), "Zx_t": ("abs", 2.4e-06), "Zy_t": ("abs", 6e-07)},
    ("rotation", "bcc"): {"Ux": ("abs", 1.5e-06), "Uy": ("abs", 1.1e-06), "Uz": ("rel", 0.00049), "growth": ("abs", 1e-06), "rotation": ("rel", 0.00058), "Zx_t": ("abs", 2.5e-06), "Zy_t": ("abs", 5e-07)},
    ("rotation", "full"): {"Ux": ("abs", 1.6e-06), "Uy": ("abs", 3e-06), "Uz": ("rel", 0.0005), "growth": ("abs", 1.9e-05), "rotation": ("rel", 0.00032), "Zx_t": ("abs", 1.7e-06), "Zy_t": ("abs", 4.1e-06)},
    ("all together", "bcc"): {"Ux": ("rel", 5e-05), "Uy": ("abs", 7.7e-07), "Uz": ("rel", 0.00028), "growth": ("rel", 0.00065), "rotation": ("rel", 0.00021), "Zx_t": ("abs", 1.3e-05), "Zy_t": ("abs", 1.2e-06)},
    ("all together", "full"): {"Ux": ("rel", 5.2e-05), "Uy": ("abs", 1.1e-06), "Uz": ("rel", 0.00029), "growth": ("rel", 0.0053), "rotation": ("rel", 0.00014), "Zx_t": ("abs", 8.7e-06), "Zy_t": ("abs", 8e-06)},
    ("translation only", "bcc"): {"Ux": ("abs", 1.5e-06), "Uy": ("abs", 1.3e-06), "Uz": ("rel", 0.0005), "growth": ("abs", 1.1e-06), "rotation": ("abs", 1.2e-06), "Zx_t": ("abs", 7e-07), "Zy_t": ("abs", 8e-09)},
    ("translation only", "full"): {"Ux": ("abs", 1.5e-06), "Uy": ("abs", 3e-06), "Uz": ("rel", 0.0005), "growth": ("abs", 1.9e-05), "rotation": ("abs", 6.5e-07), "Zx_t": ("abs", 5.3e-07), "Zy_t": ("abs", 1.3e-07)},
    ("tilting", "bcc"): {"Ux": ("abs", 2e-05), "Uy": ("abs", 1.5e-06), "Uz": ("rel", 0.0005), "growth": ("abs", 1.3e-06), "rotation": ("abs", 2.1e-06), "Zx_t": ("rel", 0.0011), "Zy_t": ("abs", 8.3e-09)},
    ("tilting", "full"): {"Ux": ("abs", 2e-05), "Uy": ("abs", 3e-06), "Uz": ("rel", 0.0005), "growth": ("abs", 1.9e-05), "rotation": ("abs", 1.9e-06), "Zx_t": ("rel", 0.00098), "Zy_t": ("abs", 1.4e-07)},
    ("anisotropic", "bcc"): {"Ux": ("abs", 2.3e-07), "Uy": ("abs", 9e-08), "Uz": ("rel", 7.5e-05), "growth": ("rel", 0.00044), "rotation": ("abs", 2.8e-07), "Zx_t": ("abs", 7.9e-12), "Zy_t": ("abs", 4.4e-09)},
    ("anisotropic", "full"): {"Ux": ("abs", 2.3e-07), "Uy": ("abs", 7.8e-07), "Uz": ("rel", 7.5e-05), "growth": ("rel", 0.005), "rotation": ("abs", 1.7e-07), "Zx_t": ("abs", 4.7e-11), "Zy_t": ("abs", 2.7e-09)},
    ("shear", "bcc"): {"Ux": ("abs", 1.5e-06), "Uy": ("abs", 1.3e-06), "Uz": ("rel", 0.0005), "growth": ("abs", 1.1e-06), "rotation": ("rel", 0.0023), "Zx_t": ("abs", 1.2e-06), "Zy_t": ("abs", 1.8e-07)},
    ("shear", "full"): {"Ux": ("abs", 1.6e-06), "Uy": ("abs", 3e-06), "Uz": ("rel", 0.0005), "growth": ("abs", 1.9e-05), "rotation": ("rel", 0.0013), "Zx_t": ("abs", 8.4e-07), "Zy_t": ("abs", 1.1e-06)},
}
# the translation model on the same volumes, measured: Q_rel(U_Z) 0.50 under growth (and
# with slope and brightness change), 0.98 under anisotropic growth, 0.031 when the plane
# tilts; 2.7e-4 under rotation about the normal (which does not change the divergence)
TRANSLATION_UZ = {"growth": 0.5, "growth slope brightness": 0.5, "all together": 0.5,
                  "anisotropic": 0.98, "tilting": 0.031}


# --- the generator's truths, against the deformation itself ----------------------------------

def _deformed(p: SinusoidParams, t: float):
    """The plane's tangents e1 = (1, 0, Z_X), e2 = (0, 1, Z_Y) carried by I + G t."""
    A = np.eye(3) + velocity_gradient(p) * t
    return A @ np.array([1.0, 0.0, p.Z_X]), A @ np.array([0.0, 1.0, p.Z_Y])


@pytest.mark.parametrize("kw", [dict(growth=2e-3), dict(rotation=3e-3, Z_X=0.4, Z_Y=-0.2),
                                dict(G_XY=1e-3, G_YX=-2e-3, G_XZ=1e-3, Z_X=0.3),
                                dict(growth=1e-3, rotation=-1e-3, G_ZY=2e-3, Z_Y=0.5)])
def test_generator_truths_are_the_deformation_rates(kw):
    """growth = d ln(area)/dt of the parallelogram the tangents span; rotation = the
    mean rate at which in-plane directions turn about the normal; Z_x's rate = that of
    -N_x / N_z of the carried plane; all by central differences (h = 1e-3 time units,
    truncation ~h^2 |G|^3: far below 1e-9 here)."""
    p = SinusoidParams(frame_interval=2.0, **kw)
    truth = make_sinusoid(p.replace(height=20, width=20)).truth
    h = 1e-3
    (a1, a2), (b1, b2) = _deformed(p, h), _deformed(p, -h)
    area = lambda u, v: np.linalg.norm(np.cross(u, v))  # noqa: E731
    growth = (np.log(area(a1, a2)) - np.log(area(b1, b2))) / (2 * h)
    np.testing.assert_allclose(truth["growth"], growth * 2.0, rtol=1e-6, atol=1e-12)

    # each material direction of the plane turns about the normal at a rate ω_n plus
    # the symmetric part's, which varies as cos/sin 2θ and averages out over a half turn
    e1, e2 = _deformed(p, 0.0)
    n0 = np.cross(e1, e2) / np.linalg.norm(np.cross(e1, e2))
    t1 = e1 / np.linalg.norm(e1)
    t2 = np.cross(n0, t1)
    G = velocity_gradient(p)
    rates = []
    for th in np.linspace(0, np.pi, 64, endpoint=False):
        d = np.cos(th) * t1 + np.sin(th) * t2
        dp, dm = (np.eye(3) + G * h) @ d, (np.eye(3) - G * h) @ d
        rates.append(np.arctan2(np.cross(dm, dp) @ n0, dm @ dp) / (2 * h))
    np.testing.assert_allclose(truth["rotation"], np.mean(rates) * 2.0, rtol=1e-5,
                               atol=1e-11)

    def slope(t):
        u, v = _deformed(p, t)
        N = np.cross(u, v)
        return -N[0] / N[2], -N[1] / N[2]

    (zxp, zyp), (zxm, zym) = slope(h), slope(-h)
    np.testing.assert_allclose(truth["Zx_t"], (zxp - zxm) / (2 * h) * 2.0, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(truth["Zy_t"], (zyp - zym) / (2 * h) * 2.0, rtol=1e-6, atol=1e-12)


def test_a_translating_plane_renders_as_before():
    """The deformation path is taken only where a gradient is set; a plane that only
    translates keeps the paper's closed form, and a vanishing gradient agrees with it to
    roundoff."""
    a = make_sinusoid(height=40, width=40, U_X=0.03, Z_X=0.2)
    b = make_sinusoid(height=40, width=40, U_X=0.03, Z_X=0.2, G_XX=1e-15)
    assert not a.params.deforms and b.params.deforms
    np.testing.assert_allclose(b.volume, a.volume, rtol=0, atol=1e-10)


# --- the estimator ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def affine_results():
    out = {}
    for name, kw in CASES.items():
        sv = make_sinusoid(**kw)
        models = ("full",) if name == "growth slope brightness" else ("bcc", "full")
        res = estimate_models(sv.volume, sv.focal_length, sv.camera_spacing, models=models,
                              motion="affine")
        for m, e in res.items():
            out[(name, m)] = {r["quantity"]: r for r in evaluate(e.maps, sv.truth, e.interior)}
    return out


@pytest.mark.parametrize("case, model", sorted(MEASURED))
def test_affine_motion_against_exact_truth(affine_results, case, model):
    rows = affine_results[(case, model)]
    bad = []
    for q, (measure, value) in MEASURED[(case, model)].items():
        r = rows[q]
        assert r["measure"] == measure and r["n_invalid"] == 0, (case, model, q)
        if not r["q"] <= MARGIN * value:
            bad.append(f"{q}: {r['q']:.3g} > {MARGIN:g} x measured {value:.2g}")
    assert not bad, f"{case}, {model}: " + "; ".join(bad)


def test_the_growth_issue_goals(affine_results):
    """The goals as the issue states them (each bound above is inside them)."""
    r = affine_results
    for case in ("growth", "growth slope brightness", "all together"):
        assert r[(case, "full")]["growth"]["q_rel"] <= 0.02
        assert r[(case, "full")]["Uz"]["q_rel"] <= 0.02
    assert r[("rotation", "full")]["rotation"]["q_rel"] <= 0.02
    assert r[("translation only", "full")]["Uz"]["q_rel"] <= 1e-3
    assert r[("translation only", "full")]["growth"]["q_abs"] <= 2e-5


@pytest.mark.parametrize("case", sorted(TRANSLATION_UZ))
def test_the_translation_model_reads_growth_as_divergence(case):
    """Outlook of the paper: deformation corrupts the translation model's U_Z."""
    sv = make_sinusoid(**CASES[case])
    e = estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="full")
    (uz,) = [r for r in evaluate(e.maps, sv.truth, e.interior) if r["quantity"] == "Uz"]
    assert uz["q_rel"] == pytest.approx(TRANSLATION_UZ[case], rel=0.05)


def test_affine_fast_path_agrees_with_reference():
    """Fast (numba) against reference (LAPACK) on a growing, rotating, slanted plane at
    160^2, against each quantity's scale here (Z 100, U_Z 0.1, the rates 1e-3): measured
    6.4e-13 (Z), 7.8e-11 (U_Z), 2.2e-10 (growth), 7.2e-11 (rotation), 1.1e-9 (Z_x's rate);
    asked: 1e-8."""
    sv = make_sinusoid(growth=1e-3, rotation=1e-3, U_X=0.02, Z_X=0.2, Z_Y=-0.1, height=160,
                       width=160)
    a = estimate(sv.volume, sv.focal_length, sv.camera_spacing, motion="affine")
    b = estimate(sv.volume, sv.focal_length, sv.camera_spacing, motion="affine",
                 method="reference")
    assert a.settings["backend"] == "numba"
    for q, scale in (("Z", 100.0), ("Uz", 0.1), ("growth", 1e-3), ("rotation", 1e-3),
                     ("Zx_t", 1e-3)):
        assert np.nanmax(np.abs(a[q] - b[q])) <= 1e-8 * scale, q


@pytest.mark.parametrize("grid", [(1, 5), (3, 3)])
def test_affine_on_small_and_one_dimensional_grids(grid):
    """A row of 5 cameras, or 3 x 3: measured Q_rel(growth) 0.71 % / 0.87 %, Q_rel(U_Z)
    2.9e-4 / 1.5e-4 (growth 1e-3 and rotation 1e-3 per frame, full model); asked 3x."""
    sv = make_sinusoid(growth=1e-3, rotation=1e-3, grid=grid)
    e = estimate(sv.volume, sv.focal_length, sv.camera_spacing, motion="affine")
    r = {x["quantity"]: x for x in evaluate(e.maps, sv.truth, e.interior)}
    want = {(1, 5): (0.0071, 2.9e-4), (3, 3): (0.0087, 1.5e-4)}[grid]
    assert r["growth"]["q_rel"] <= MARGIN * want[0]
    assert r["Uz"]["q_rel"] <= MARGIN * want[1]


def test_affine_needs_time():
    sv = make_sinusoid(height=40, width=40, frames=1)
    refused(InputError, "motion 'affine' needs a time axis", estimate, sv.volume,
            sv.focal_length, sv.camera_spacing, model="bcc", sigma=2.0, window=9,
            motion="affine")
    sv = make_sinusoid(height=40, width=40, frames=3)
    with pytest.raises(InputError, match="too few frames"):
        estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="bcc", sigma=2.0,
                 window=9, motion="affine")
    with pytest.raises(InputError, match="motion must be one of"):
        estimate(sv.volume, sv.focal_length, sv.camera_spacing, motion="rigid")


# --- the error estimates ---------------------------------------------------------------------

def _white_over_correlated(settings: dict, frames: int) -> float:
    """How much the error estimate would overstate if the prefiltered noise had no
    correlation at all: sqrt(N_white / N_eff), derived here independently of the
    driver's code: the variance of a weighted sum of samples correlated as the
    prefilter's normalised autocorrelation R is ``w^T T(R) w`` (T Toeplitz), per axis
    (the Gaussian window in x and y, ``frames`` uniform weights in time)."""
    from scipy.linalg import toeplitz

    from gridflow.estimator.filters import get_filter_pair
    from gridflow.estimator.tensor import gaussian_moment_kernels

    p = get_filter_pair("matched5").prefilter
    R = np.correlate(p, p, mode="full")[p.size - 1:] / (p @ p)        # lags 0, 1, ...

    def ratio(w):
        col = np.zeros(w.size)
        col[:min(R.size, w.size)] = R[:w.size]
        return (w @ toeplitz(col) @ w) / (w @ w)

    w = gaussian_moment_kernels(settings["sigma"], settings["window"])[0]
    return float(np.sqrt(ratio(w) ** 2 * ratio(np.full(frames, 1.0 / frames))))


@pytest.mark.parametrize("grid", [(5, 5), (1, 5)])
def test_error_estimates_bound_the_scatter(grid):
    """``Uz_err``, ``growth_err``, ``rotation_err`` against the actual scatter of the
    errors (1.4826 MAD over the interior) under sigma_n = 0.01, growth 1e-3/frame.

    The estimate takes the prefiltered noise as fully correlated over the prefilter's
    reach (its largest possible correlation, the prefilter's autocorrelation being
    non-negative), so to first order it cannot fall below the scatter: lower bound 1.  Had
    the noise no correlation, it would overstate by ``_white_over_correlated`` (4.9 for
    the default window and 9 frames): the upper bound.  Measured at this commit on 160^2
    sinusoids: ratios 1.6-3.0 over seeds, noise 0.003-0.03, windows sigma 8-24, 13
    frames, slopes, rotation, brightness change, spacing 0.1 and a 1-D grid; 3.8 at growth
    1e-2, where the model's own misfit adds to the residual.

    They are the errors of each pixel solved alone (``growth_support=0``); the pooled
    solution's are smaller (``test_pooling.py``) and not estimated yet."""
    settings = dict(sigma=16.0, window=65, growth_support=0)
    sv = make_sinusoid(growth=1e-3, noise=0.01, grid=grid, height=160, width=160)
    e = estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="full",
                 motion="affine", **settings)
    upper = _white_over_correlated(settings, sv.volume.shape[0])
    assert 4.0 < upper < 6.0                          # the bound is a real margin
    for q in ("Uz", "growth", "rotation"):
        err = (e[q] - sv.truth[q])[e.interior]
        scatter = 1.4826 * np.median(np.abs(err - np.median(err)))
        ratio = np.median(e[q + "_err"][e.interior]) / scatter
        assert 1.0 < ratio < upper, (q, ratio, upper)


def test_rate_coefficients_are_the_rates_linear_map():
    """The outputs and their error estimates come from the growth's, rotation's and slope
    rates' coefficients in theta (solve_affine: one solve with M^T); they must be the
    linear map :func:`_surface_rates` applies (checked on random motions and slopes, to
    rounding)."""
    from gridflow.estimator.disentangle import _rate_coefficients, _surface_rates

    rng = np.random.default_rng(5)
    Zx, Zy = rng.normal(0, 0.8, 50), rng.normal(0, 0.8, 50)
    theta = rng.normal(size=(9, 50))
    rates = _surface_rates(theta, Zx, Zy)
    coef = _rate_coefficients(Zx, Zy)
    for q in ("growth", "rotation", "Zx_t", "Zy_t"):
        np.testing.assert_allclose(np.einsum("nj,jn->n", coef[q], theta), rates[q],
                                   rtol=1e-12, atol=1e-12)


def test_the_affine_system_is_affine_observations_of_each_unit_motion():
    """The numba solve's 9 x 9 system (estimator._affine._system, written out entry by
    entry) is, column j, :func:`affine_observations` of the unit motion e_j: the same
    values exactly, on random pixels, with exact zeros among the slopes and the pixel
    coordinates (a wrong sign or a swapped slope in one entry fails it)."""
    from gridflow.estimator._affine import _system
    from gridflow.estimator.disentangle import affine_observations

    rng = np.random.default_rng(12)
    N = 400
    Z, Zx, Zy = rng.uniform(50, 150, N), rng.normal(0, 0.5, N), rng.normal(0, 0.5, N)
    x0, y0 = rng.uniform(-256, 256, N), rng.uniform(-256, 256, N)
    Zx[:60], Zy[40:100], x0[80:140], y0[120:180] = 0.0, -0.0, 0.0, 0.0
    M = np.empty((N, 9, 9))
    for i in range(N):
        _system.py_func(Z[i], Zx[i], Zy[i], x0[i], y0[i], 1000.0, M[i])
    for j in range(9):
        theta = np.zeros((9, N))
        theta[j] = 1.0
        want = affine_observations(theta, Z, Zx, Zy, x0, y0, 1000.0)
        np.testing.assert_array_equal(M[:, :, j], want.T, err_msg=f"column {j}")


def test_affine_kernel_is_the_numpy_solve():
    """The numba backend's per-pixel solve (:mod:`estimator._affine`) against
    :func:`solve_affine` (numpy, LAPACK ``gesv``) on random systems with slopes up to
    about 1.5 and pixels across a 512^2 image: every output, the errors and the growth's
    sensitivity.  Both are LU with partial pivoting, summed in other orders: backward
    stable, each within about kappa eps of the exact solution, kappa the system's
    condition number (here at most 1.7e3, median 1.1e3): asked 2 kappa_max eps, 1e-12 of
    each output's scale; measured <= 1.1e-15.  A non-finite input gives NaN in both; an
    exactly singular system (a zero pivot) is refused by the kernel's LU."""
    from gridflow.estimator._affine import solve_affine_kernel
    from gridflow.estimator.disentangle import solve_affine

    rng = np.random.default_rng(11)
    N = 4000
    Z, Zx, Zy = rng.uniform(50, 150, N), rng.normal(0, 0.5, N), rng.normal(0, 0.5, N)
    x0, y0 = rng.uniform(-256, 256, N), rng.uniform(-256, 256, N)
    scale = np.array([1, 1, 1e-2, 1e-2, 1e-2, 1e-2, 1e-4, 1e-4, 1e-4])[:, None]
    obs = rng.normal(size=(9, N)) * scale
    var = rng.uniform(0, 1, (N, 9)) * scale.T ** 2
    obs[3, 5], Z[7], Zy[9] = np.nan, np.inf, np.nan
    a = solve_affine_kernel(obs, Z, Zx, Zy, x0, y0, 1000.0, var, sensitivity=True)
    b = solve_affine(obs, Z, Zx, Zy, x0, y0, 1000.0, var, sensitivity=True)
    assert set(a) == set(b)
    for q in b:
        assert np.array_equal(np.isnan(a[q]), np.isnan(b[q])), q
        assert np.isnan(b[q][[5, 7, 9]]).all(), q
        ok = np.isfinite(b[q])
        assert np.abs(a[q][ok] - b[q][ok]).max() <= 1e-12 * np.abs(b[q][ok]).max(), q
    from gridflow.estimator._affine import _lu_solve_transposed

    M = np.eye(9)
    M[4, 4] = 0.0
    assert not _lu_solve_transposed(M, np.ones((9, 7)), np.empty((9, 7)), np.empty((9, 9)))
    assert _lu_solve_transposed(np.eye(9), np.ones((9, 7)), np.empty((9, 7)),
                                np.empty((9, 9)))
