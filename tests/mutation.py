"""Mutation testing with hand-written mutants: plausible one-line bugs, each applied alone
to a copy of the package, with the tests that should catch it.

    .venv/bin/python tests/mutation.py            # every mutant (make mutants)
    .venv/bin/python tests/mutation.py --list     # what they are
    .venv/bin/python tests/mutation.py -k claims  # those whose id contains "claims"

Each mutant names the file, the exact text it replaces (found exactly once, or the
mutant is reported as stale, so the list cannot rot silently) and the tests that should
catch it; none of them is the stored-curve comparison
(``tests/test_baseline.py::test_reduced_sweep_matches_stored_curves``), so the kill rate
printed is that of correctness tests alone.  A mutant is

* ``killed`` when one of its tests fails on an assertion (``assert``, ``pytest.raises``
  not raising, ``pytest.approx``);
* ``crashed`` when they fail only by an exception in the code under test (a bug found,
  but by luck, not by a check);
* ``survived`` when they all pass.

How: the package is mirrored under ``$TMPDIR/gridflow-mutants/`` as a tree of links to
the repository's files (the layout of the ``package-dir`` mapping), the mutated file is
written in place of its link, and pytest runs from the repository's root with that tree
first on ``PYTHONPATH`` (no folder of the repository is named ``gridflow``, so nothing
shadows it).  The tree's path stays the same from mutant to mutant, so numba's cache of
the unmutated kernels is reused; a mutant of a kernel module compiles (about 40 s).
The repository itself is never written to.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TREE = Path(tempfile.gettempdir()) / "gridflow-mutants"
# repository folder -> folder in the installed namespace (pyproject.toml, package-dir)
LAYOUT = {"base": "gridflow", "estimator": "gridflow/estimator",
          "generators": "gridflow/generators", "scenes": "gridflow/scenes",
          "pipeline": "gridflow/pipeline",
          "bench": "gridflow/bench", "bench/cli": "gridflow/bench/cli",
          "bench/sweeps": "gridflow/bench/sweeps"}


@dataclass(frozen=True)
class Mutant:
    id: str
    file: str              # repository path
    old: str
    new: str
    tests: tuple[str, ...]
    what: str


T = "tests/"
TRUTH = T + "test_truth.py"
MUTANTS = [
    # --- estimator -------------------------------------------------------------------------
    Mutant("disentangle-weight-ds", "estimator/disentangle.py",
           "        wy = dsy ** 2 / norm2[:, 1]", "        wy = dsx ** 2 / norm2[:, 1]",
           (TRUTH + "::test_the_two_estimates_are_weighted_by_their_variances",
            TRUTH + "::test_unequal_spacing_with_noise"),
           "the y-estimate's weight with ds_x instead of ds_y"),
    Mutant("disentangle-a2-factor", "estimator/disentangle.py",
           '        out["a2"] = -ct[:, i("tI")] / 2.0', '        out["a2"] = -ct[:, i("tI")]',
           (TRUTH,), "a2 without the factor 1/2 of row 13 (2 b2 dt)"),
    Mutant("models-row13-t2", "estimator/models.py",
           '"tI": ("I", 1, ""),', '"tI": ("I", 2, ""),', (TRUTH,),
           "row 13 computed as I t^2"),
    Mutant("disentangle-slant-sign", "estimator/disentangle.py",
           "            uz_x = uz_x - zx * p1 / v", "            uz_x = uz_x + zx * p1 / v",
           (TRUTH,), "the slant correction's sign in x"),
    Mutant("disentangle-per-axis-slopes", "estimator/disentangle.py",
           "        Zx = zx * Z / den\n        Zy = zy * Z / den",
           "        Zx = zx * Z / (1.0 + zx * x0 * Z / f)\n"
           "        Zy = zy * Z / (1.0 + zy * y0 * Z / f)",
           (T + "test_estimator_accuracy.py::test_slopes_exact_for_a_plane_slanted_both_ways",),
           "the slopes inverted per axis (the paper's Eq. 16)"),
    Mutant("disentangle-ux-x0", "estimator/disentangle.py",
           "    ux, uy = p1 - x0 * uz, p2 - y0 * uz",
           "    ux, uy = p1 - y0 * uz, p2 - x0 * uz", (TRUTH,),
           "x0 and y0 swapped in the translation"),
    Mutant("disentangle-uz-sign", "estimator/disentangle.py",
           '"Uz": -Z * uz}', '"Uz": Z * uz}', (TRUTH,), "U_Z's sign"),
    Mutant("disentangle-a1x-coupling", "estimator/disentangle.py",
           '            out[a + "x"] = -((f - Zx * x0) * bx - Zx * y0 * by) / Z',
           '            out[a + "x"] = -((f - Zx * x0) * bx) / Z',
           (T + "test_estimator_accuracy.py::test_slopes_exact_for_a_plane_slanted_both_ways",),
           "a1x without the y-coupling of Eq. 20 inverted exactly"),
    Mutant("disentangle-disparity-sign", "estimator/disentangle.py",
           "    disparity = -v * spacing[0]", "    disparity = v * spacing[0]", (TRUTH,),
           "disparity with gridflow's sign, not the HCI benchmark's"),
    Mutant("nullspace-rank-test", "estimator/nullspace.py",
           "(lam[..., k] > RANK_TOL * tr)", "(lam[..., k - 1] > RANK_TOL * tr)",
           (TRUTH + "::test_every_quantity_against_exact_truth",),
           "the texture check on the k-th eigenvalue instead of the (k+1)-th"),
    Mutant("nullspace-weights", "estimator/nullspace.py",
           "    g[:, q] = np.diagonal(np.linalg.inv(Jq), axis1=-2, axis2=-1)",
           "    g[:, q] = 1.0 / np.diagonal(Jq, axis1=-2, axis2=-1)",
           (T + "test_nullspace.py",),
           "the weights from J_qq's diagonal instead of its inverse's"),
    Mutant("signals-taps-by-blas", "estimator/signals.py",
           '    out = {"p": _taps_sum(plan.taps["p"], cams["pp"]),',
           '    out = {"p": np.tensordot(plan.taps["p"], cams["pp"], axes=1),',
           (T + "test_reproducible.py::test_estimates_do_not_depend_on_threads_or_cpu_kernels",),
           "the prefiltered camera/time signal by a BLAS product (rounded by the CPU)"),
    Mutant("spectral-combine-once", "estimator/spectral.py",
           "acc[e] = cmul2(FP, KY[py], KX[px], float(mult), acc[e])",
           "acc[e] = cmul2(FP, KY[py], KX[px], 1.0, acc[e])",
           (T + "test_estimator_properties.py::test_fast_path_agrees_with_reference",),
           "a term that comes twice in a zoom-corrected entry summed once"),
    Mutant("spectral-batch-order", "estimator/spectral.py",
           "            before[v].add(u)", "            pass",
           (T + "test_estimator_properties.py::"
                "test_the_products_in_batches_are_the_products_one_by_one",),
           "the products batched by pair without keeping the summed planes' order "
           "(other bits)"),
    Mutant("spectral-lean-order", "estimator/spectral.py",
           "            return opens - closes, g[0], rank[g]",
           "            return rank[g]",
           (T + "test_estimator_properties.py::"
                "test_the_products_in_batches_are_the_products_one_by_one",),
           "the products in the groups' order, many summed planes open at once (memory)"),
    Mutant("lightfield-no-rival", "estimator/lightfield.py",
           "    own = data & ((spread < _OPEN_DECADES) | (rival < _OPEN_DECADES))",
           "    own = data & (spread < _OPEN_DECADES)",
           (T + "test_lightfield.py::"
                "test_a_far_shear_that_ties_the_best_by_noise_leaves_the_shear_open",),
           "a far shear that ties the best one by noise does not leave the shear open"),
    Mutant("kept-signals-unscaled", "estimator/backends.py",
           "coefs * (a.scale * b.scale), frames(a), frames(b), shape, out)",
           "coefs, frames(a), frames(b), shape, out)",
           (T + "test_estimator_properties.py::"
                "test_a_volume_given_frame_by_frame_gives_the_maps_of_its_array",),
           "a recording's kept signals multiplied without the window's intensity scale"),
    Mutant("kept-span-unsigned", "base/recording.py",
           "        full = (key, span, sources)",
           "        full = (key, span, ())",
           (T + "test_series.py::"
                "test_a_value_of_several_frames_is_kept_until_one_of_them_is_rewritten",),
           "a frame's kept signals kept after another frame they were filtered from "
           "changed on disk"),
    Mutant("kept-signals-scaled-key", "estimator/driver.py",
           "signals = _kept_signals(vol, unit, plan.frames, factor, backend)",
           "signals = _kept_signals(vol, splan, plan.frames, factor, backend)",
           (T + "test_estimator_properties.py::"
                "test_a_volume_given_frame_by_frame_gives_the_maps_of_its_array",),
           "a recording's kept signals keyed by the window's scale (filtered again when "
           "it changes)"),
    Mutant("planner-kept-despite-mask", "estimator/driver.py",
           '    if masked or not getattr(backend_class(method, shape), "frame_stacks", False):',
           '    if not getattr(backend_class(method, shape), "frame_stacks", False):',
           (T + "test_estimator_properties.py::"
                "test_the_planners_rule_for_kept_signals_is_the_estimators",),
           "the planner counting a masked step's signals as kept"),
    Mutant("planner-framed-window", "pipeline/run.py",
           "    window = frame if kept else window_frames * Sy * Sx * r * W * itemsize",
           "    window = window_frames * Sy * Sx * r * W * itemsize",
           (T + "test_docs.py::test_the_readmes_planner_numbers_are_the_planners",),
           "a step with its frames kept planned as if it read its window"),
    Mutant("signals-time-derivative", "estimator/signals.py",
           '        taps["d"] = along_t(time.derivative)', '        taps["d"] = along_t(time.prefilter)',
           (TRUTH,), "I_t filtered with the temporal prefilter"),
    Mutant("signals-camera-y", "estimator/signals.py",
           '        combos["pd"] = scale * weights(yd, xs)', '        combos["pd"] = scale * weights(ys, xd)',
           (TRUTH,), "I_sy taken along the camera x axis"),
    Mutant("tensor-moment-sign", "estimator/tensor.py",
           "    return np.stack([w, w * delta, w * delta ** 2])",
           "    return np.stack([w, -w * delta, w * delta ** 2])", (TRUTH,),
           "the first moment kernel w(Δ) Δ reversed"),
    Mutant("spectral-kernel-flip", "estimator/spectral.py",
           "    kx[:, :2 * R + 1] = kernels[:, ::-1]", "    kx[:, :2 * R + 1] = kernels",
           (TRUTH + "::test_every_quantity_against_exact_truth",),
           "the FFT's x kernels not flipped (convolution for correlation)"),
    Mutant("filters-matched3", "estimator/filters.py",
           '        return _from_half("matched3", 2 / 3, [1 / 6], [1 / 2])',
           '        return _from_half("matched3", 2 / 3, [1 / 6], [1 / 3])',
           (T + "test_estimator_accuracy.py::test_three_by_three_grid_five_frames",
            T + "test_filters.py"), "the 3-tap derivative's taps scaled wrong"),
    Mutant("solver-p-tolerance", "estimator/_solver.py", "_P_TOL = 1e-11", "_P_TOL = 1e-6",
           (T + "test_estimator_properties.py::test_fast_path_agrees_with_reference",),
           "the lane solver's stopping tolerance loosened 10^5 x"),
    Mutant("solver-shift", "estimator/_solver.py", "_SHIFT = RIDGE", "_SHIFT = RIDGE * 1e4",
           (T + "test_estimator_properties.py::test_fast_path_agrees_with_reference",),
           "the inverse iteration's shift no longer the reference's ridge"),
    Mutant("kernels-edge-clamp", "estimator/_kernels.py",
           "                yy = min(max(y + j - ry, 0), h - 1)",
           "                yy = min(max(y + j - ry, 0), h - 2)",
           (T + "test_estimator_properties.py::test_fast_spatial_filter_matches_numpy",),
           "the y filter's edge clamped one row early"),
    Mutant("kernels-product", "estimator/_kernels.py",
           "                            out[k, y, x] += c * fa[y, x] * fb[y, x]",
           "                            out[k, y, x] += c * fa[y, x] * fa[y, x]",
           (T + "test_estimator_properties.py::test_fast_path_agrees_with_reference",),
           "the FFT tensor's product of a signal with itself"),
    Mutant("driver-principal-point", "estimator/driver.py",
           "        x0 = (xx - plan.cx).ravel().astype(float)",
           "        x0 = (xx - plan.cy).ravel().astype(float)", (TRUTH,),
           "x measured from the principal point's y"),
    Mutant("driver-temporal-radius", "estimator/driver.py",
           "    R_t = (min(MOTION_MODELS[s.motion].temporal_radius, reach - time.radius)",
           "    R_t = (min(MOTION_MODELS[s.motion].temporal_radius - 1, reach - time.radius)",
           (T + "test_boundaries.py::test_temporal_radius_and_reference_frame_at_the_limit",
            T + "test_pooling.py::test_pooled_growth_is_exact_on_noise_free_uneven_growth"),
           "the default temporal window one frame short of the motion model's (±1 instead of "
           "up to ±2 under translation, ±5 instead of ±6 under affine motion)"),
    Mutant("driver-interior", "estimator/driver.py",
           "    interior[halo:H - halo, halo:W - halo] = True",
           "    interior[halo - 1:H - halo, halo:W - halo] = True",
           (T + "test_estimator_properties.py::test_border_is_nan_interior_is_not",
            T + "test_boundaries.py::test_image_size_at_the_limit"),
           "the interior mask one row too tall (a border row counted as free of it)"),
    Mutant("affine-rotation-sign", "estimator/disentangle.py",
           "    rotation = 0.5 * ((t2 * L(t1)).sum(0) - (t1 * L(t2)).sum(0))",
           "    rotation = 0.5 * ((t2 * L(t1)).sum(0) + (t1 * L(t2)).sum(0))",
           (T + "test_affine.py",), "the rotation from the symmetric part"),
    Mutant("affine-vt", "estimator/disentangle.py",
           "    vt = (da * x0 + db * y0) / c - v * dc / c",
           "    vt = (da * x0 + db * y0) / c + v * dc / c", (T + "test_affine.py",),
           "the disparity's rate with the plane offset's term of the wrong sign"),
    Mutant("affine-row-t2", "estimator/models.py", '"tIx": ("x", 1, ""),',
           '"tIx": ("x", 2, ""),', (T + "test_affine.py",),
           "the disparity-rate row computed as I_x t^2"),
    Mutant("models-needs-time", "estimator/models.py",
           "    return any(ROWS[r][1] > 0 for r in rows)",
           "    return any(ROWS[r][1] > 1 for r in rows)",
           (T + "test_affine.py::test_affine_needs_time",
            T + "test_parts.py::test_a_model_carries_both_axes"),
           "no model needing a time axis (the rows with a factor t overlooked)"),
    Mutant("affine-err-white", "estimator/driver.py",
           "        R = [math.fsum(p[i] * p[i + d] for i in range(len(p) - d)) / pp\n"
           "             for d in range(len(p))]",
           "        R = [1.0] + [0.0] * (len(p) - 1)",
           (T + "test_affine.py::test_error_estimates_bound_the_scatter",),
           "the error estimates with the prefiltered noise taken as uncorrelated"),
    Mutant("affine-system-entry", "estimator/_affine.py",
           "    M[7, 4] = -b / c - a * dc / cc", "    M[7, 4] = -a / c - a * dc / cc",
           (T + "test_affine.py::test_the_affine_system_is_affine_observations_of_each_unit_motion",
            T + "test_affine.py::test_affine_kernel_is_the_numpy_solve"),
           "a slope swapped in one entry of the written-out system"),
    Mutant("affine-err-rotation-coef", "estimator/disentangle.py",
           "        [zero] + [0.5 * ((d * t1).sum(0) * t2 - (d * t2).sum(0) * t1) for d in dual])",
           "        [zero] + [0.5 * ((d * t1).sum(0) * t2 + (d * t2).sum(0) * t1) for d in dual])",
           (T + "test_affine.py::test_rate_coefficients_are_the_rates_linear_map",),
           "the rotation error carried through the symmetric part's coefficients"),
    Mutant("render-deformation-half", "generators/sinusoid.py",
           "    Z, Xm, Ym = _intersect_mapped(p, np.eye(3) + G * t, x,",
           "    Z, Xm, Ym = _intersect_mapped(p, np.eye(3) + G * t * 0.5, x,", (T + "test_affine.py",),
           "the rendered deformation at half the rate the truth says"),
    Mutant("truth-growth-trace", "generators/sinusoid.py",
           "    growth = float(np.trace((np.eye(3) - np.outer(n, n)) @ G))",
           "    growth = float(np.trace(G))",
           (T + "test_affine.py::test_generator_truths_are_the_deformation_rates",),
           "growth as the volume divergence, not the surface's"),
    Mutant("claims-growth-stable", "bench/claims.py", "Part(\"affine model stable\", bool((af < STABLE).all()), core=True)]\n    where = f\"from {param}",
           "Part(\"affine model stable\", bool((af < BREAK).all()), core=True)]\n    where = f\"from {param}",
           (T + "test_claims.py",), "the affine model's U_Z \"stable\" up to the breakdown level"),
    # --- generators ------------------------------------------------------------------------
    Mutant("truth-a2-per-frame", "generators/sinusoid.py",
           '"a2": (p.a2 + p.a2x * Xm + p.a2y * Ym) * dt * dt,',
           '"a2": (p.a2 + p.a2x * Xm + p.a2y * Ym) * dt,',
           (TRUTH + "::test_frame_interval_scales_the_truths_not_the_volume",),
           "the a2 truth per frame instead of per frame^2"),
    Mutant("truth-ux-interval", "generators/sinusoid.py",
           '"Ux": V[0] * dt, "Uy"', '"Ux": V[0], "Uy"',
           (TRUTH + "::test_frame_interval_scales_the_truths_not_the_volume",),
           "the U_X truth not converted to per frame"),
    Mutant("truth-a1y", "generators/sinusoid.py",
           '"a1y": const(p.a1y * dt),', '"a1y": const(p.a1x * dt),',
           (TRUTH,), "the a1y truth from a1x"),
    Mutant("render-a1y", "generators/sinusoid.py",
           "p.a1y * Ym) * t\n                     + (p.a2 + p.a2x * Xm + p.a2y * Ym) * t * t)\n"
           "                img = texture(",
           "p.a1y * Xm) * t\n                     + (p.a2 + p.a2x * Xm + p.a2y * Ym) * t * t)\n"
           "                img = texture(", (TRUTH,),
           "the rendering's a1y term along X"),
    Mutant("render-uy-sign", "generators/sinusoid.py",
           "p.Z_Y * (sy - p.U_Y * t)", "p.Z_Y * (sy + p.U_Y * t)", (TRUTH,),
           "the ray-plane intersection's lateral motion in y with the wrong sign"),
    Mutant("noise-seed", "generators/sinusoid.py",
           "    rng = np.random.default_rng(q.seed)", "    rng = np.random.default_rng(q.seed + 1)",
           (T + "test_generator.py::test_add_noise_is_rendering_with_noise",),
           "add_noise drawing other numbers than the rendering"),
    # --- metrics ---------------------------------------------------------------------------
    Mutant("metrics-negative-reference", "base/metrics.py",
           "        use_rel = bool(np.all(r > 0) or np.all(r < 0))",
           "        use_rel = bool(np.all(r > 0))",
           (T + "test_metrics.py", TRUTH + "::test_every_quantity_against_exact_truth"),
           "the relative measure for all-positive references only"),
    Mutant("metrics-q-rel-denominator", "base/metrics.py",
           "    return float(np.mean(np.abs(e - r) / np.abs(r)))",
           "    return float(np.mean(np.abs(e - r) / np.abs(e)))", (T + "test_metrics.py",),
           "Q_rel divided by the estimate"),
    Mutant("metrics-invalid-count", "base/metrics.py",
           "        n_inv = int(np.count_nonzero(~np.isfinite(np.asarray(est)[m])))",
           "        n_inv = int(np.count_nonzero(np.isnan(np.asarray(est)[m])))",
           (T + "test_metrics.py",), "infinite estimates not counted as invalid"),
    Mutant("metrics-hci-mse", "base/metrics.py",
           '    out = {"mse_x100": float(100.0 * np.mean(err[ok] ** 2))',
           '    out = {"mse_x100": float(100.0 * np.mean(err[ok]))', (T + "test_metrics.py",),
           "the HCI MSE as a mean absolute error"),
    Mutant("metrics-hci-badpix-nonfinite", "base/metrics.py",
           "        out[key] = (float(100.0 * np.mean(ok & (err > tau))) if g.size else",
           "        out[key] = (float(100.0 * np.mean(err[ok] > tau)) if g.size else",
           (T + "test_metrics.py", T + "test_lightfield.py"),
           "pixels without a value left out of BadPix's count instead of counted as not bad"),
    # --- light fields ----------------------------------------------------------------------
    Mutant("lightfield-range-floor", "estimator/lightfield.py",
           "    shears = tuple(range(int(np.floor(lo)), int(np.ceil(hi)) + 1))",
           "    shears = tuple(range(int(np.round(lo)), int(np.round(hi)) + 1))",
           (T + "test_lightfield.py",), "the estimated range rounded instead of covered"),
    Mutant("lightfield-median-off", "estimator/lightfield.py",
           "    if median > 1 and np.isfinite(disp).any():",
           "    if median > 99 and np.isfinite(disp).any():", (T + "test_lightfield.py",),
           "the default median never applied"),
    Mutant("lightfield-fill-border", "estimator/lightfield.py",
           "    rest = ~(valid | conv)",
           "    rest = np.zeros_like(valid)", (T + "test_lightfield.py",),
           "holes beyond the fill's Gaussian and the border left without a value"),
    Mutant("lightfield-check-shears", "estimator/lightfield.py",
           "    if max(abs(lo), abs(hi)) > reach:",
           "    if max(abs(lo), abs(hi)) > 100 * reach:", (T + "test_lightfield.py",),
           "shears beyond the image accepted"),
    # --- claims ----------------------------------------------------------------------------
    Mutant("claims-break", "bench/claims.py", "BREAK = 0.1", "BREAK = 0.3",
           (T + "test_claims.py",), "the breakdown level raised to 0.3"),
    Mutant("claims-stable", "bench/claims.py", "STABLE = 0.01", "STABLE = 0.02",
           (T + "test_claims.py",), "\"stable\" at 2 %"),
    Mutant("claims-ratio", "bench/claims.py", "RATIO = 10.0", "RATIO = 5.0",
           (T + "test_claims.py",), "a breakdown at 5x the full model's error"),
    Mutant("claims-factor", "bench/claims.py", "FACTOR = 2.0", "FACTOR = 3.0",
           (T + "test_claims.py",), "\"similar\" within a factor 3"),
    Mutant("claims-identical", "bench/claims.py", "IDENTICAL = 1.5", "IDENTICAL = 2.0",
           (T + "test_claims.py",), "\"almost identical\" within a factor 2"),
    Mutant("claims-orders", "bench/claims.py", "ORDERS = (10.0, 10 ** 2.5)",
           "ORDERS = (10.0, 10 ** 3)", (T + "test_claims.py",),
           "\"1 to 2 orders\" up to 3 orders"),
    Mutant("claims-slope", "bench/claims.py", "SLOPE = (0.8, 1.2)", "SLOPE = (0.5, 1.5)",
           (T + "test_claims.py",), "\"linear\" for slopes 0.5-1.5"),
    Mutant("claims-leak", "bench/claims.py", "LEAK = 0.01", "LEAK = 0.02",
           (T + "test_claims.py",), "\"almost independent\" at 2 %"),
    Mutant("claims-obs1-level", "bench/claims.py", "bool(len(mid) and (mid < 0.0025).all()),",
           "bool(len(mid) and (mid < 0.005).all()),", (T + "test_claims.py",),
           "observation 1's \"well below 0.5 %\" read as below 0.5 %"),
    Mutant("claims-obs10-small", "bench/claims.py", "(f0[sel] < STABLE / 2).all()",
           "(f0[sel] < STABLE).all()", (T + "test_claims.py",),
           "observation 10's \"well below 0.01\" read as below 0.01"),
    # --- loader ----------------------------------------------------------------------------
    Mutant("loader-reference-frame", "base/loader.py",
           "    if rf is not None and not (_is_int(rf) and 0 <= rf < frames):",
           "    if rf is not None and not (_is_int(rf) and 0 <= rf <= frames):",
           (T + "test_boundaries.py",), "reference_frame == frames accepted"),
    Mutant("loader-frames", "base/loader.py", "    if not (_is_int(frames) and frames >= 1):",
           "    if not (_is_int(frames) and frames >= 0):", (T + "test_boundaries.py",),
           "a manifest of 0 frames accepted"),
    Mutant("loader-focal-length", "base/loader.py", "    if not (_is_number(f) and f > 0):",
           "    if not (_is_number(f) and f >= 0):", (T + "test_boundaries.py",),
           "a focal length of 0 accepted"),
    Mutant("loader-spacing", "base/loader.py",
           "    if ds[0] <= 0 or (sy > 1 and ds[1] <= 0) or ds[1] < 0:",
           "    if ds[0] < 0 or (sy > 1 and ds[1] <= 0) or ds[1] < 0:",
           (T + "test_boundaries.py",), "ds_x = 0 accepted"),
    Mutant("loader-memory", "base/loader.py", "    if have is not None and need > 0.8 * have:",
           "    if have is not None and need > 0.9 * have:", (T + "test_boundaries.py",),
           "the memory limit at 0.9 of physical memory"),
    Mutant("loader-image-count", "base/loader.py", "    if sy * sx * frames > MAX_IMAGES:",
           "    if sy * sx * frames >= MAX_IMAGES:", (T + "test_boundaries.py",),
           "MAX_IMAGES itself refused"),
    Mutant("loader-16bit-scale", "base/loader.py",
           "        out = np.asarray(img, np.float64) / 65535.0",
           "        out = np.asarray(img, np.float64) / 65536.0",
           (T + "test_loader.py::test_png_folder_roundtrip",), "16-bit images scaled by 2^16"),
    Mutant("loader-principal-point", "base/loader.py",
           "else (pp[0], pp[1])", "else (pp[1], pp[0])",
           (T + "test_loader.py::test_float_tiff_and_truth",),
           "the manifest's principal point read as (cy, cx)"),
    # the recording paths' review (issue 38)
    Mutant("recording-chunk-present", "base/recording.py",
           '                if not (self.path / "volume" / key).is_file():',
           '                if False:',
           (T + "test_recording_review.py::test_a_missing_frame_chunk_is_refused_whatever_the_fill_value",),
           "a missing frame chunk read as the fill value"),
    Mutant("geometry-focal-range", "base/volume.py",
           "    if not (np.isfinite(f) and 0 < f <= MAX_FOCAL_PX):",
           "    if not (np.isfinite(f) and 0 < f):",
           (T + "test_recording_review.py::test_a_geometry_out_of_range_is_refused_where_it_is_read",),
           "no upper bound on the focal length"),
    Mutant("maps-done-chunks", "base/recording.py",
           "                if not (self.path / q / \"c\" / str(i) / str(b) / \"0\").is_file():",
           "                if False:",
           (T + "test_recording_review.py::test_a_done_step_that_lost_a_chunk_is_estimated_again",),
           "a done step's lost map chunk not noticed"),
    Mutant("maps-made-in-place", "base/recording.py",
           "            cls._make(tmp, key=key,",
           "            cls._make(path, key=key,",
           (T + "test_recording_review.py::test_a_map_series_cut_short_while_it_is_made_leaves_no_store",),
           "the map series made in place: a cut leaves a store without its key"),
    Mutant("suites-interior", "bench/suites.py",
           "    region[halo:H - halo, halo:W - halo] = True",
           "    region[halo + 1:H - halo, halo:W - halo] = True",
           (T + "test_methods.py::test_the_growth_leaves_exported_and_scored_from_files_as_the_study_scores",),
           "an exported suite scored over other pixels than the experiment's"),
]


def _tree_path(repo_file: Path) -> Path:
    rel = repo_file.relative_to(ROOT)
    return TREE / LAYOUT[str(rel.parent)] / rel.name


def build_tree() -> None:
    """The package as links to the repository's files (kept between runs: numba's cache
    lives in its __pycache__ folders)."""
    for folder in LAYOUT:
        for f in sorted((ROOT / folder).iterdir()):
            if f.is_file() and f.suffix in (".py", ".toml"):
                dest = _tree_path(f)
                dest.parent.mkdir(parents=True, exist_ok=True)
                if dest.is_symlink() and dest.resolve() == f.resolve():
                    continue
                if dest.exists() or dest.is_symlink():
                    dest.unlink()
                dest.symlink_to(f)


# A pytest plugin, loaded into each run from the tree: it records why each test failed
# (an assertion, pytest.raises not raising, or another exception) into a JSON file.
_PLUGIN = '''
import json, os
import pytest

_FAILED = []


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    if rep.failed and call.excinfo is not None:
        e = call.excinfo
        kind = "assert" if e.errisinstance((AssertionError, pytest.fail.Exception)) else "crash"
        first = (str(e.value).splitlines() or [""])[0][:120]
        _FAILED.append([item.nodeid, kind, e.typename, first])


def pytest_sessionfinish(session):
    with open(os.environ["GRIDFLOW_MUTATION_REPORT"], "w") as fh:
        json.dump(_FAILED, fh)
'''


def _run_tests(tests, timeout: float) -> tuple[str, list[str], float]:
    """Run ``tests`` against the tree: ("pass" | "assert" | "crash", failures, seconds)."""
    report = TREE / "report.json"
    report.unlink(missing_ok=True)
    (TREE / "_mutation_plugin.py").write_text(_PLUGIN)
    env = {**os.environ, "PYTHONPATH": str(TREE), "PYTHONDONTWRITEBYTECODE": "1",
           "GRIDFLOW_MUTATION_REPORT": str(report)}
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider",
                            "-p", "_mutation_plugin", *tests], cwd=ROOT, env=env,
                           timeout=timeout, capture_output=True, text=True)
    except subprocess.TimeoutExpired:
        return "crash", [f"timed out after {timeout:g} s"], time.perf_counter() - t0
    seconds = time.perf_counter() - t0
    if not report.exists():
        return "crash", ["pytest wrote no report: " + (r.stdout + r.stderr)[-300:]], seconds
    failed = json.loads(report.read_text())
    if not failed and r.returncode != 0:
        return "crash", [f"pytest exited {r.returncode}: " + r.stdout[-300:]], seconds
    if not failed:
        return "pass", [], seconds
    kinds = {k for _, k, _, _ in failed}
    lines = [f"{test.split('::')[-1]}: {typ}: {msg}" for test, _, typ, msg in failed]
    return ("assert" if "assert" in kinds else "crash"), lines, seconds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-k", default="", help="only the mutants whose id contains this")
    ap.add_argument("--list", action="store_true", help="list the mutants and stop")
    ap.add_argument("--timeout", type=float, default=900, help="seconds per mutant's tests")
    a = ap.parse_args(argv)
    chosen = [m for m in MUTANTS if a.k in m.id]
    if a.list:
        for m in chosen:
            print(f"{m.id:32} {m.file:26} {m.what}")
        return 0
    stale = [m.id for m in chosen if (ROOT / m.file).read_text().count(m.old) != 1]
    if stale:
        print(f"stale mutants (their text is not found exactly once): {stale}", file=sys.stderr)
        return 2
    if TREE.exists() and not (TREE / "gridflow").is_dir():
        shutil.rmtree(TREE)
    build_tree()
    check = subprocess.run([sys.executable, "-c", "import gridflow; print(gridflow.__file__)"],
                           cwd=ROOT, env={**os.environ, "PYTHONPATH": str(TREE)},
                           capture_output=True, text=True)
    if not check.stdout.startswith(str(TREE)):
        print(f"the mutant tree is not what Python imports: {check.stdout}{check.stderr}",
              file=sys.stderr)
        return 2
    union = sorted({t for m in chosen for t in m.tests})
    print(f"{len(chosen)} mutants; first the unmutated run of their tests ({len(union)}) ...",
          flush=True)
    status, failures, secs = _run_tests(union, a.timeout * 2)
    if status != "pass":
        print("the tests fail without a mutant:\n  " + "\n  ".join(failures), file=sys.stderr)
        return 2
    print(f"unmutated: pass ({secs:.0f} s)\n", flush=True)
    results = []
    for m in chosen:
        src = ROOT / m.file
        dest = _tree_path(src)
        dest.unlink()
        dest.write_text(src.read_text().replace(m.old, m.new))
        try:
            status, failures, secs = _run_tests(m.tests, a.timeout)
        finally:
            dest.unlink()
            dest.symlink_to(src)
        verdict = {"pass": "SURVIVED", "assert": "killed", "crash": "crashed"}[status]
        results.append((m, verdict))
        print(f"{verdict:8} {m.id:32} {secs:5.0f} s  {m.what}", flush=True)
        for f in failures[:1]:
            print(f"{'':8} {f}", flush=True)
    killed = sum(v == "killed" for _, v in results)
    crashed = sum(v == "crashed" for _, v in results)
    print(f"\n{killed} of {len(results)} killed by an assertion ({100 * killed / len(results):.0f} %), "
          f"{crashed} only by a crash, {len(results) - killed - crashed} survived")
    for m, v in results:
        if v != "killed":
            print(f"  {v}: {m.id} ({m.file}): {m.what}; tests {', '.join(m.tests)}")
    return 0 if killed == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
