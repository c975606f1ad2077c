"""Depth from a static light field, step by step: what each step of the default adds.

    python -m gridflow.bench.lightfield_study                  # the tables
    python -m gridflow.bench.lightfield_study --write-doc bench/README.md   # ... into it
    python -m gridflow.bench.lightfield_study --hci SCENE      # also an HCI scene of yours

Each row adds one step to the one above it, up to the default of ``gridflow estimate``
on a light field of one frame: the estimator's single pass (the central 5 x 5 views,
the sinusoid defaults sigma 16 px / 65 taps); refocusing over the shears a coarse pass
estimates from the data, each pixel's estimate chosen among 1-D camera sub-grids
(segments of 5 views of the centre row and column) and shifted windows, sigma 1 px /
5 taps; where the data leave a region's shear open (every shear fits about as well, or
one two or more steps from the best as well as it), the shear of the confirmed coarse
disparity; the fill of the pixels left without an
estimate; a 3 x 3 median of the disparity.  Two last rows try the whole row and column
instead of segments (not in the default: worse between thin stripes) and the segments
estimated on their epipolar-plane images (``select="epi"``: no filtering across the
image rows, a window along the line; not the default: its confidence ranks its errors
less well).
Scenes: two synthetic
two-layer scenes of exact disparity (bands 10 px high with 12 px gaps, and thin stripes
with 8 px gaps, 9 x 9 views, 192^2, foreground and background 2 px per view apart),
crossing bars (the same layers, bars of 8 px with gaps of 4 along x in the left half and
along y in the right), a
smooth wall (43 % of the image, faintly shaded, at +1 px per view) and a textured plane
slanted from -3 to +2.4 px per view through it (9 x 9 views, 256^2, 8 bit, noise of 4
grey levels), a fine periodic grid (period 4 px, at -1.5 px per view, so that +2.5 fits it as
well but for a faint shading) behind a textured box at +2.5 (9 x 9 views, 192^2, 8 bit,
the same noise), the
POV-Ray cube as a 5 x 5 light field (-0.6 .. 3.0 px per view; rendered once into
``--cache``), and any HCI scene given.  Scores: the HCI benchmark's MSE x 100 and
BadPix(0.07) by its toolkit's rule (:func:`gridflow.metrics.hci_metrics`), the
share of scored pixels without a value, and the seconds of each estimate; for the
default and for the EPI segments, how well the confidence map ranks the errors, beside
the former confidence (:func:`confidence_ranking`).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from gridflow.bench.cube_experiment import RENDER_CACHE
from gridflow.metrics import hci_metrics
from gridflow.estimator import estimate
from gridflow.estimator.lightfield import estimate_refocused, estimate_shear_range

__all__ = ["STEPS", "DEFAULT_STEP", "RANKED_STEPS", "synthetic_scenes", "run_step",
           "confidence_ranking", "study", "tables", "main"]

# (label, how): None is the single pass; else estimate_refocused's keywords
STEPS = [
    ("single pass (5 x 5 views, sigma 16, 65 taps)", None),
    ("refocused, lines of 5 views, not filled", dict(fill=False, median=0, smooth=False)),
    ("+ coarse disparity where the data leave the shear open",
     dict(fill=False, median=0)),
    ("+ fill", dict(fill=True, median=0)),
    ("+ 3 x 3 median (the default)", dict(fill=True, median=3)),
    ("(not kept) the default with the whole centre row and column",
     dict(fill=True, median=3, whole_lines=True)),
    ("(not the default) EPI segments of 5 views (select=epi)",
     dict(fill=True, median=3, select="epi")),
]
# the step that is gridflow's default (its confidence map is ranked against the errors)
DEFAULT_STEP = STEPS[4][0]
# the steps whose confidence maps are ranked against the errors: the default and the EPI
# segments, the short name each has in that table
RANKED_STEPS = {DEFAULT_STEP: "default", STEPS[6][0]: "epi"}


def synthetic_scenes() -> dict:
    """``{name: (views (9, 9, S, S), disparity (S, S))}``: the two-layer scenes (S = 192),
    bars of 8 px with 4-px gaps along x in the left half and along y in the right
    (S = 192, the same layers), a smooth wall with a slanted textured plane through it
    (S = 256, 8-bit, sensor noise of 4 grey levels) and a periodic grid behind a box (S = 192, the same noise),
    where a shear four steps from the right one fits the grid as well."""
    from gridflow.generators.lightfield import (crossing_views, layered_views,
                                                periodic_views, smooth_wall_views)

    bands = [(y, y + 10) for y in range(20, 170, 22)]
    stripes = [(y, y + 8) for y in range(20, 172, 16)]
    return {"two layers": layered_views(n=9, size=192, d_fg=0.6, d_bg=-1.4, bands=bands,
                                        seed=3),
            "thin stripes": layered_views(n=9, size=192, d_fg=0.5, d_bg=-1.5,
                                          bands=stripes, seed=4),
            "crossing bars": crossing_views(n=9, size=192, bar=8, gap=4),
            "smooth wall": smooth_wall_views(n=9, size=256, shading=0.02, noise=4 / 255),
            "periodic grid": periodic_views(n=9, size=192, noise=4 / 255)}


def run_step(views: np.ndarray, how, shears) -> tuple[dict, float]:
    """The maps of one step (each shape (H, W); ``disparity`` among them) and its
    seconds."""
    t0 = time.perf_counter()
    if how is None:
        n = views.shape[0]
        c0 = max(0, (n - 5) // 2)
        sub = np.ascontiguousarray(views[c0:c0 + min(n, 5), c0:c0 + min(n, 5)])
        maps = estimate(sub[None], float(views.shape[-1]), (1.0, 1.0), model="bcc").maps
    else:
        how = dict(how)
        if how.pop("whole_lines", False):
            how["subgrid"] = views.shape[0]
        how.setdefault("select", "lines")
        maps = estimate_refocused(views, shears, **how).maps
    return maps, time.perf_counter() - t0


def confidence_ranking(maps: dict, truth: np.ndarray) -> dict:
    """How well a refocused estimate's ``confidence`` ranks its errors, beside the
    former confidence (``-log10`` of the model error relative to its median).

    Over the pixels with an estimate of their own (not filled) and a finite truth: the
    mean absolute error (px per view) of all of them and of the most confident half by
    each confidence, and Spearman's rank correlation of each confidence with the
    negative absolute error (1: the errors perfectly ranked, 0: not at all).

    Parameters
    ----------
    maps : dict of str to ndarray, each shape (H, W)
        ``disparity``, ``confidence``, ``model_error`` and ``filled`` of
        :func:`gridflow.estimator.lightfield.estimate_refocused`.
    truth : ndarray, shape (H, W)
        The true disparity.

    Returns
    -------
    dict
        ``n, mae_all, mae_half, mae_half_former, rho, rho_former``.
    """
    from scipy.stats import spearmanr

    own = np.isfinite(maps["disparity"]) & (maps["filled"] == 0) & np.isfinite(truth)
    err = np.abs(maps["disparity"] - truth)[own]
    err_model = maps["model_error"][own]
    with np.errstate(divide="ignore", invalid="ignore"):
        former = -np.log10(err_model / np.median(err_model))
    # a model error of 0 fits perfectly (+inf); NaN (round-off below 0) the least
    former = np.where(np.isnan(former), -np.inf, former)
    out = {"n": int(own.sum()), "mae_all": float(err.mean())}
    for key, conf in (("", maps["confidence"][own]), ("_former", former)):
        order = np.argsort(-conf, kind="stable")
        out["mae_half" + key] = float(err[order[:err.size // 2]].mean())
        out["rho" + key] = float(spearmanr(conf, -err).statistic)
    return out


def study(scenes: dict, progress=print) -> tuple[list[dict], list[dict]]:
    """The step-by-step table and the coarse ranges.

    Returns
    -------
    rows : list of dict
        One per scene and step: ``scene, step, mse_x100, badpix_007, no_value_pct,
        seconds``; the steps of :data:`RANKED_STEPS` also ``confidence``
        (:func:`confidence_ranking`).
    ranges : list of dict
        One per scene: ``scene, true_lo, true_hi`` (px per view), the coarse pass's
        ``lo, hi``, its level ``k`` and the ``shears`` it gives.
    """
    rows, ranges = [], []
    for name, (views, truth) in scenes.items():
        shears, info = estimate_shear_range(views)
        fin = truth[np.isfinite(truth)]
        ranges.append({"scene": name, "true_lo": float(fin.min()), "true_hi": float(fin.max()),
                       "lo": info["lo"], "hi": info["hi"], "k": info["k"],
                       "shears": (shears[0], shears[-1])})
        progress(f"{name}: {views.shape[0]}x{views.shape[1]} views of {views.shape[-1]}^2, "
                 f"true disparity {fin.min():.2f} .. {fin.max():.2f}, coarse pass "
                 f"{info['lo']:.2f} .. {info['hi']:.2f} (at 1/{info['k']} resolution) -> "
                 f"shears {shears[0]} .. {shears[-1]}")
        for label, how in STEPS:
            maps, secs = run_step(views, how, shears)
            m = hci_metrics(maps["disparity"], truth)
            row = {"scene": name, "step": label, "mse_x100": m["mse_x100"],
                   "badpix_007": m["badpix_007"],
                   "no_value_pct": 100.0 * m["n_nonfinite"] / max(m["n_pixels"], 1),
                   "seconds": secs}
            if label in RANKED_STEPS:
                row["confidence"] = confidence_ranking(maps, truth)
            rows.append(row)
    return rows, ranges


def tables(rows: list[dict], ranges: list[dict]) -> str:
    """The ranges and the step-by-step table, markdown.

    Parameters
    ----------
    rows, ranges : list of dict
        As :func:`study` returns them.

    Returns
    -------
    str
    """
    out = ["| scene | true disparity, px per view | coarse pass | at resolution | shears |",
           "|---|---|---|---|---|"]
    for r in ranges:
        out.append(f"| {r['scene']} | {r['true_lo']:.2f} … {r['true_hi']:.2f} | "
                   f"{r['lo']:.2f} … {r['hi']:.2f} | 1/{r['k']} | "
                   f"{r['shears'][0]} … {r['shears'][1]} |")
    out += ["", "| scene | step | MSE × 100 | BadPix(0.07) % | no value % | s |",
            "|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['scene']} | {r['step']} | {r['mse_x100']:.3f} | "
                   f"{r['badpix_007']:.2f} | {r['no_value_pct']:.2f} | {r['seconds']:.1f} |")
    out += ["", "| scene | step | pixels with an own estimate | mean abs. error, px | "
            "most confident half: confidence | former (model error) | Spearman: "
            "confidence | former |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        c = r.get("confidence")
        if c:
            out.append(f"| {r['scene']} | {RANKED_STEPS[r['step']]} | {c['n']} | "
                       f"{c['mae_all']:.3f} | "
                       f"{c['mae_half']:.4f} | {c['mae_half_former']:.4f} | "
                       f"{c['rho']:+.2f} | {c['rho_former']:+.2f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hci", nargs="*", default=[], help="HCI scene folders to add")
    ap.add_argument("--cache", default=RENDER_CACHE,
                    help=f"where the cube light field is rendered (default {RENDER_CACHE})")
    ap.add_argument("--no-cube", action="store_true", help="leave out the POV-Ray cube")
    ap.add_argument("--write-doc", default=None, metavar="MD",
                    help="rewrite the light-field block of this markdown file "
                         "(bench/README.md) with the tables; refused with --hci (an HCI "
                         "scene's numbers are not committed)")
    a = ap.parse_args(argv)
    if a.write_doc and a.hci:
        ap.error("--write-doc with --hci: the documentation holds no HCI scene's numbers")
    if a.write_doc:
        from gridflow.io import check_output

        check_output(a.write_doc, suffixes=(".md",), what="--write-doc")
    scenes = synthetic_scenes()
    if not a.no_cube:
        from gridflow.scenes.render import render_cube_lightfield

        print("rendering the cube light field (POV-Ray, once per cache) ...", flush=True)
        views, disp, _ = render_cube_lightfield(a.cache)
        scenes["cube"] = (views, disp)
    for path in a.hci:
        from gridflow.hci import load_hci

        data = load_hci(path)
        scenes[str(path)] = (data.volume[0], data.truth["disparity"])
    rows, ranges = study(scenes)
    text = tables(rows, ranges)
    print(text)
    if a.write_doc:
        from .markdown import rewrite_block

        import os

        cmd = f"python -m gridflow.bench.lightfield_study --write-doc {a.write_doc}"
        if a.no_cube:
            cmd += " --no-cube"
        rewrite_block(a.write_doc, "lightfield-study",
                      f"Generated by `{cmd}` (seconds: one run on a machine of "
                      f"{os.cpu_count()} cores):\n\n{text}")
        print(f"rewrote the lightfield-study block of {a.write_doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
