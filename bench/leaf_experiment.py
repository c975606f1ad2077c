"""The growing leaf (POV-Ray): growth maps under a moving spotlight, per region.

:func:`run_leaf_experiment` is what ``gridflow leaf`` does: render the leaf
(:class:`gridflow.scenes.LeafScene`, cached), estimate it with the translation and the
affine motion models (each with BCC, HF and the full brightness model), score each
region of the leaf (:data:`REGIONS`: its interior away from the edge, the edge, the
spotlight's border within the interior, the rest of the interior), draw the growth map
figure and write the table.

The per-pixel growth is a small difference of divergences (here 2e-3 per frame against
the image divergence 4.8e-3 that the approach at 1 mm per frame causes): its map is
noisy pixel by pixel, and the table gives medians beside means (a few pixels at the
edge and the spot's border dominate a mean).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from gridflow.estimator import MODELS, MOTIONS, estimate_models
from gridflow.estimator.models import AFFINE, TRANSLATION

from .cube_experiment import CUBE_SIGMA, CUBE_WINDOW

__all__ = ["run_leaf_experiment", "LeafReport", "leaf_regions", "leaf_table", "fig_leaf",
           "REGIONS"]

REGIONS = ("interior", "edge", "spot_border", "away")
COLUMNS = ["region", "motion", "model", "n_pixels", "n_valid", "median_growth",
           "truth_growth", "median_rel_growth", "q_abs_growth", "median_rel_Uz", "q_rel_Uz"]


def leaf_regions(truth: dict, scene) -> dict[str, np.ndarray]:
    """Masks, shape (H, W): ``interior`` (leaf pixels at least the truth's margin from its
    edge: the window's reach), ``edge`` (the other leaf pixels), ``spot_border`` (interior pixels between the
    spotlight's full-strength radius and its falloff at the reference frame, where the
    illumination varies across the surface), ``away`` (the rest of the interior)."""
    leaf = np.asarray(truth["leaf"], bool)
    inner = np.asarray(truth["interior"], bool)
    angle = truth["spot_angle"]
    with np.errstate(invalid="ignore"):
        border = inner & (angle >= scene.spot_radius_deg) & (angle <= scene.spot_falloff_deg)
    return {"interior": inner, "edge": leaf & ~inner, "spot_border": border,
            "away": inner & ~border}


def leaf_table(truth: dict, results: dict, masks: dict) -> pd.DataFrame:
    """Per region, motion and model: the median estimated growth against the truth, the
    median and mean absolute error of growth (relative, absolute) and of U_Z (relative)."""
    rows = []
    for (motion, model), e in results.items():
        for region in REGIONS:
            m = masks[region] & e.interior
            row = {"region": region, "motion": motion, "model": model,
                   "n_pixels": int(m.sum()),
                   "truth_growth": float(np.nanmedian(truth["growth"][m])) if m.any() else np.nan}
            # a method of the benchmark's interface may return either map alone: the
            # valid pixels are those with every map it returned of the two
            ok = m.copy()
            for q in ("Uz", "growth"):
                if q in e:
                    ok &= np.isfinite(e[q])
            row["n_valid"] = int(ok.sum())
            if "Uz" in e:
                uz_rel = np.abs(e["Uz"][ok] - truth["Uz"][ok]) / np.abs(truth["Uz"][ok])
                row.update(median_rel_Uz=float(np.median(uz_rel)) if ok.any() else np.nan,
                           q_rel_Uz=float(np.mean(uz_rel)) if ok.any() else np.nan)
            if "growth" in e:
                g, tg = e["growth"][ok], truth["growth"][ok]
                row.update(median_growth=float(np.median(g)) if ok.any() else np.nan,
                           median_rel_growth=float(np.median(np.abs(g - tg) / tg))
                           if ok.any() else np.nan,
                           q_abs_growth=float(np.mean(np.abs(g - tg))) if ok.any() else np.nan)
            rows.append(row)
    return pd.DataFrame(rows, columns=COLUMNS)


def fig_leaf(data, truth: dict, results: dict):
    """The reference image, the true growth, the affine full model's growth map and the
    translation full model's relative U_Z error, on the leaf."""
    import matplotlib.pyplot as plt

    from .figures import STYLE

    leaf = np.asarray(truth["leaf"], bool)
    Sy, Sx = data.volume.shape[1:3]
    img = data.volume[data.meta.get("ref_frame") or 0, Sy // 2, Sx // 2]
    aff = results[(AFFINE.name, "full")]
    tra = results[(TRANSLATION.name, "full")]
    g_true = float(np.nanmedian(truth["growth"]))
    with np.errstate(invalid="ignore", divide="ignore"):
        uz_err = np.abs(tra["Uz"] - truth["Uz"]) / np.abs(truth["Uz"])
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(1, 4, figsize=(10, 3.0), constrained_layout=True)
        axes[0].imshow(img, cmap="gray")
        axes[0].set_title("(a) centre camera, reference frame")
        inner = np.asarray(truth["interior"], bool)
        for ax, arr, title in ((axes[1], truth["growth"], "(b) true growth per frame"),
                               (axes[2], np.where(inner, aff["growth"], np.nan),
                                "(c) estimated growth (affine, full);\n"
                                "grey: the window crosses the leaf's edge")):
            if ax is axes[2]:
                ax.imshow(np.where(leaf & ~inner, 0.6, np.nan), cmap="gray", vmin=0, vmax=1)
            im = ax.imshow(arr, cmap="viridis", vmin=0.0, vmax=2.5 * g_true)
            ax.set_title(title)
        fig.colorbar(im, ax=axes[1:3], shrink=0.8, label="d ln(area)/dt per frame")
        im = axes[3].imshow(np.where(leaf, uz_err, np.nan), cmap="magma", vmin=0, vmax=1)
        axes[3].set_title("(d) translation model: |U_Z error| / |U_Z|")
        fig.colorbar(im, ax=axes[3], shrink=0.8)
        for ax in axes:
            ax.set_xticks([])
            ax.set_yticks([])
            ax.grid(False)
        fig.suptitle(f"A leaf growing at {g_true:g} per frame under a moving spotlight "
                     "(POV-Ray, 5 x 5 cameras, 9 frames)")
    return fig


@dataclass
class LeafReport:
    folder: Path
    seconds_render: float
    seconds_estimate: float
    table: pd.DataFrame
    written: list


def run_leaf_experiment(scene, cache, *, csv, fig_dir, sigma: float = CUBE_SIGMA,
                        window: int = CUBE_WINDOW, progress: bool = True, methods=(),
                        method_cmds=()) -> LeafReport:
    """Render ``scene`` into ``cache`` (or find it there), estimate with both motion
    models and every brightness model, score per region, write ``csv`` and
    ``fig_dir/fig_leaf.{png,pdf}``.  The window is the cube's (:data:`~gridflow.bench.
    cube_experiment.CUBE_SIGMA`, :data:`~gridflow.bench.cube_experiment.CUBE_WINDOW`); the
    outputs and the cache are checked before anything is rendered.

    ``methods``, ``method_cmds``: other methods (:mod:`gridflow.bench.methods`), run on
    the same volume and scored alike over the same pixels (the rows' ``motion`` is ``-``,
    ``model`` the method's name); not drawn in the figure."""
    from .methods import resolve_methods, run_method

    others = resolve_methods(methods, method_cmds)
    from gridflow.io import atomic_write, check_output
    from gridflow.loader import load_folder
    from gridflow.scenes.render import render_cube

    from . import figures as F

    check_output(csv, suffixes=".csv", what="--csv")
    check_output(fig_dir, suffixes=None, what="--fig-dir")
    check_output(cache, suffixes=None, what="--cache")
    t0 = time.perf_counter()
    folder = render_cube(scene, cache, progress=progress)
    data = load_folder(folder)
    t1 = time.perf_counter()
    from gridflow.scenes import leaf_truth

    # the interior: leaf pixels whose whole window (and filters) lies on the leaf
    truth = leaf_truth(scene, margin=window // 2 + 2)
    results = {}
    for motion in MOTIONS:
        res = estimate_models(data.volume, data.focal_length, data.camera_spacing,
                              principal_point=data.principal_point, motion=motion,
                              sigma=sigma, window=window, ref_frame=data.meta["ref_frame"],
                              models=MODELS)
        results.update({(motion, m): e for m, e in res.items()})
    t2 = time.perf_counter()
    scored = dict(results)
    if others:
        from gridflow.errors import UsageError
        from gridflow.estimator import Estimate

        T = data.volume.shape[0]
        if data.meta["ref_frame"] != (T - 1) // 2:
            raise UsageError(f"the leaf's reference frame is {data.meta['ref_frame']}; a "
                             f"method estimates the middle frame {(T - 1) // 2}")
        interior = next(iter(results.values())).interior
        for m in others:
            maps, _ = run_method(m, data.volume, data.focal_length, data.camera_spacing,
                                 principal_point=data.principal_point)
            scored[("-", m.name)] = Estimate(maps, m.name, interior, {})
    table = leaf_table(truth, scored, leaf_regions(truth, scene))
    with atomic_write(csv, "w") as fh:
        table.to_csv(fh, index=False, float_format="%.6g")
    written = [Path(csv)] + F.save(fig_leaf(data, truth, results), fig_dir, "fig_leaf")
    return LeafReport(folder, t1 - t0, t2 - t1, table, written)
