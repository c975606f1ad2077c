"""The POV-Ray leaf that grows unevenly: gridflow's growth map and kymograph per region.

    python -m gridflow.bench.uneven_leaf                  # make figures runs this

A leaf of :class:`gridflow.scenes.UnevenLeafRecording` (a mesh of material points, its
texture on them) whose growth falls linearly along the leaf from 2e-3 per frame at its
base to 2e-4 at its tip, times a day/night rhythm of +-50 % over 40 frames (one frame
every 2 minutes), still, under a spotlight that swings across it; 5 x 5 cameras 0.4 mm
apart at 420 mm, 256^2 px, 25 frames.  It is rendered as a recording (``gridflow
record-leaf --tip-growth``, images cached), estimated with the default command for
growth (``gridflow estimate LEAF.zarr --motion affine``), with the leaf's mask
segmented from the images (``--mask auto``: each window uses only leaf pixels), and with
the mask and the growth defaults' alternatives (``--sigma 8 --window 33``;
``--temporal-radius 4``) on the same steps, and
scored per step against the truth of each frame, per region: the leaf's base, middle and tip thirds (by the material
distance from the base) on the pixels whose window lies on the leaf (farther than the
window's reach from its edge) and the band within that reach of the edge.  Writes the
table (``results/uneven_leaf.csv``) and ``fig_uneven_leaf``: the growth maps at the middle
step beside the truth, and the kymograph (the growth profile along the leaf's axis, the
image rows, against time) with the mask beside the true one.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

__all__ = ["scene", "REGIONS", "METHODS", "run", "region_masks", "score_step", "fig_uneven_leaf",
           "main"]

REGIONS = ("base", "middle", "tip", "inner", "edge_band")
# what is run: the label, the estimator settings beside --motion affine and the other
# options of gridflow estimate: the default, the mask, and with the mask the defaults'
# alternatives (a window of half the size; 4 frames either side instead of 6)
METHODS = {"default": ({}, {}), "mask auto": ({}, {"mask": "auto"}),
           "mask auto, sigma 8": ({"sigma": 8.0, "window": 33}, {"mask": "auto"}),
           "mask auto, temporal radius 4": ({"temporal_radius": 4}, {"mask": "auto"})}


def scene():
    """The leaf rendered here (the defaults of :class:`UnevenLeafRecording` but for 25
    frames and a rhythm of +-50 %)."""
    from gridflow.scenes import UnevenLeafRecording

    return UnevenLeafRecording(frames=25, rhythm=0.5, growth=2e-3, tip_growth=2e-4)



def region_masks(truth: dict, interior: np.ndarray, reach: float, length: float) -> dict:
    """Masks, shape (H, W), within the estimate's ``interior``: ``inner`` (leaf pixels at
    least ``reach`` px from its edge: the window lies on the leaf), its ``base``, ``middle``
    and ``tip`` thirds by the material distance ``W`` from the base (``length`` the leaf's),
    and ``edge_band`` (the leaf pixels nearer its edge than ``reach``)."""
    from scipy.ndimage import distance_transform_edt

    leaf = np.asarray(truth["leaf"], bool) & interior
    inner = leaf & (distance_transform_edt(truth["leaf"]) >= reach)
    s = np.where(leaf, truth["W"], np.nan) / length
    with np.errstate(invalid="ignore"):
        return {"base": inner & (s < 1 / 3), "middle": inner & (s >= 1 / 3) & (s < 2 / 3),
                "tip": inner & (s >= 2 / 3), "inner": inner, "edge_band": leaf & ~inner}


def _profile(growth, mask):
    """Per image row with pixels in ``mask``: the rows and the median of ``growth``."""
    rows = np.flatnonzero(mask.any(1))
    return rows, np.array([np.median(growth[r][mask[r]]) for r in rows])


def score_step(growth: np.ndarray, truth: dict, masks: dict) -> list[dict]:
    """Per region: pixels, the median estimate and truth, the per-pixel median relative
    error and Q_rel (Eq. 22); for ``inner`` also the profile along the rows against the
    truth's (correlation, slope; rows with at least 5 pixels)."""
    out = []
    for name in REGIONS:
        m = masks[name] & np.isfinite(growth)
        g, t = growth[m], truth["growth"][m]
        row = {"region": name, "n_pixels": int(m.sum()),
               "truth_median": float(np.median(t)) if m.any() else np.nan,
               "median": float(np.median(g)) if m.any() else np.nan,
               "median_rel_error": float(np.median(np.abs(g - t) / t)) if m.any() else np.nan,
               "q_rel": float(np.mean(np.abs(g - t)) / np.mean(np.abs(t))) if m.any() else np.nan,
               "profile_corr": np.nan, "profile_slope": np.nan}
        if name == "inner" and m.sum() > 10:
            m = m & (m.sum(axis=1) >= 5)[:, None]
            _, est = _profile(growth, m)
            _, tru = _profile(truth["growth"], m)
            row["profile_corr"] = float(np.corrcoef(tru, est)[0, 1])
            row["profile_slope"] = float(np.polyfit(tru, est, 1)[0])
        out.append(row)
    return out


def run(cache="work/cube", *, progress: bool = True):
    """Render (or find) the leaf, estimate it, score every step.

    Returns
    -------
    rows : list of dict
        Per step and region (:func:`score_step`), with ``step, frame``.
    snapshot : dict
        What the figure draws: the centre image, the truth and estimate at the middle
        step, and per method the kymographs (``est``, ``tru``: shape (steps, rows), per
        frame, NaN where a row has no estimate) at the steps' ``frames``.
    """
    from gridflow.estimator import DEFAULTS
    from gridflow.pipeline import RunOptions, estimate
    from gridflow.pipeline.growth import confident
    from gridflow.recording import MapStore
    from gridflow.scenes import uneven_leaf_truth
    from gridflow.sources import open_source

    from .recordings import make_leaf_recording

    sc = scene()
    reach = DEFAULTS["window"] // 2
    # the stores go beside the render cache (a fresh checkout has neither yet)
    Path(cache).parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="uneven-leaf-", dir=Path(cache).parent) as tmp:
        rec = Path(tmp) / "leaf.zarr"
        for line in make_leaf_recording(rec, sc, cache=cache, progress=progress):
            print(line, file=sys.stderr)
        rows, snap, seconds = [], {"growth": {}, "est": {}, "tru": {}}, {}
        truths = {}                     # per frame, shared by the methods
        for method, (settings, extra) in METHODS.items():
            maps = Path(tmp) / f"maps-{len(seconds)}.zarr"
            t0 = time.perf_counter()
            report = estimate(rec, maps, RunOptions(settings={"motion": "affine", **settings},
                                                    progress=progress, **extra))
            seconds[method] = time.perf_counter() - t0
            for line in report.lines:
                print(line, file=sys.stderr)
            store = MapStore.open(maps)
            g = store.group
            frames = store.frames()
            if method != "default":
                # the same steps for every method (a shorter temporal window has more)
                keep = np.isin(frames, snap["frames"])
                frames = frames[keep]
                steps = np.flatnonzero(keep)
            else:
                steps = np.arange(len(frames))
                snap["frames"] = np.asarray(frames)
            interior = np.asarray(g["interior"][:], bool)
            est_k, tru_k, middle = [], [], len(frames) // 2
            for i, k in zip(steps, frames):
                growth = np.asarray(g["growth"][i], np.float64)
                sd = np.asarray(g["growth_sd"][i], np.float64)
                if k not in truths:
                    truths[k] = uneven_leaf_truth(sc, margin=0.0, frame=int(k))
                truth = truths[k]
                masks = region_masks(truth, interior, reach, sc.leaf_length)
                # every pixel, and those gridflow growth keeps (confident: growth_sd at
                # most SD_LIMIT times the step's median)
                sure = confident(sd, interior & np.isfinite(growth))
                for pixels, m in (("all", growth), ("confident", np.where(sure, growth,
                                                                          np.nan))):
                    for r in score_step(m, truth, masks):
                        rows.append({"method": method, "pixels": pixels, "step": int(i),
                                     "frame": int(k), **r})
                # the kymograph over the leaf's pixels with an estimate
                on = np.asarray(truth["leaf"], bool) & interior & np.isfinite(growth)
                e_line = np.full(sc.height, np.nan)
                t_line = np.full(sc.height, np.nan)
                rr, e = _profile(growth, on)
                e_line[rr] = e
                t_line[rr] = _profile(truth["growth"], on)[1]
                est_k.append(e_line)
                tru_k.append(t_line)
                if k == snap["frames"][middle]:
                    if method == "default":
                        snap.update(image=open_source(rec).read(int(k), int(k) + 1)[0, 2, 2],
                                    truth=truth, masks=masks, frame=int(k))
                    snap["growth"][method] = growth
            snap["est"][method] = np.array(est_k)
            snap["tru"][method] = np.array(tru_k)
    snap.update(frame_interval=sc.frame_interval, seconds=seconds, scene=sc)
    return rows, snap


def fig_uneven_leaf(snap: dict):
    """The centre image, the true growth and gridflow's growth maps at the middle step
    (without and with the mask; % per hour), and the kymographs along the image rows with
    the mask and of the truth."""
    import matplotlib.pyplot as plt

    from .figures import STYLE

    per_hour = 100.0 * 3600.0 / snap["frame_interval"]
    truth = snap["truth"]
    leaf = np.asarray(truth["leaf"], bool)
    lo, hi = np.nanpercentile(truth["growth"], [0, 100]) * per_hour
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(1, 6, figsize=(17, 3.4), constrained_layout=True)
        axes[0].imshow(snap["image"], cmap="gray")
        axes[0].set_title(f"(a) centre camera, frame {snap['frame']}")
        maps = ((axes[1], truth["growth"], "(b) true growth"),
                (axes[2], snap["growth"]["default"], "(c) gridflow, default\n"
                 "(windows cross the edge)"),
                (axes[3], snap["growth"]["mask auto"], "(d) gridflow --mask auto"))
        for ax, arr, title in maps:
            ax.imshow(np.where(leaf & ~np.isfinite(arr), 0.6, np.nan), cmap="gray",
                      vmin=0, vmax=1)
            im = ax.imshow(np.where(leaf, arr, np.nan) * per_hour, cmap="viridis",
                           vmin=lo, vmax=hi)
            ax.set_title(title)
        fig.colorbar(im, ax=axes[1:4], shrink=0.8,
                     label="growth, % area per hour (grey: no estimate)")
        est, tru = snap["est"]["mask auto"], snap["tru"]["mask auto"]
        rows = np.flatnonzero(np.isfinite(tru).any(0))
        f0, f1 = snap["frames"][0], snap["frames"][-1]
        extent = (f0 - 0.5, f1 + 0.5, rows[-1] + 0.5, rows[0] - 0.5)
        for ax, arr, title in ((axes[4], est, "(e) kymograph, --mask auto"),
                               (axes[5], tru, "(f) kymograph, truth")):
            im = ax.imshow(arr[:, rows].T * per_hour, aspect="auto", extent=extent,
                           cmap="viridis", vmin=lo, vmax=hi, interpolation="nearest")
            ax.set_xlabel("frame (2 min each)")
            ax.set_ylabel("image row (base at the top)")
            ax.set_title(title)
        fig.colorbar(im, ax=axes[4:], shrink=0.8, label="median across the leaf, % per hour")
        for ax in axes[:4]:
            ax.set_xticks([])
            ax.set_yticks([])
            ax.grid(False)
        fig.suptitle("A leaf growing 10x faster at its base than at its tip, with a "
                     "day/night rhythm (POV-Ray, 5 x 5 cameras, 256^2 px)")
    return fig


def table(rows) -> str:
    """Markdown: per method and region, over the steps, the median truth, the median of
    the steps' per-pixel median relative errors and the worst step's; the profile's
    correlation and slope (inner pixels); and over the confident pixels only (those
    ``gridflow growth`` keeps) the share of the region's pixels kept and their error."""
    import pandas as pd

    from gridflow.pipeline.growth import SD_LIMIT

    df = pd.DataFrame(rows)
    out = ["| method | region | pixels per step | true growth, per frame | per-pixel median "
           "rel. error: median over steps (worst) | profile corr. / slope | confident "
           f"pixels (growth_sd <= {SD_LIMIT:g} x median): kept, error (worst) |",
           "|---|---|---|---|---|---|---|"]
    for method in METHODS:
        for name in REGIONS:
            sel = (df.method == method) & (df.region == name)
            d, c = df[sel & (df.pixels == "all")], df[sel & (df.pixels == "confident")]
            prof = (f"{d.profile_corr.median():.3f} / {d.profile_slope.median():.2f}"
                    if name == "inner" else "")
            kept = c.n_pixels.sum() / max(d.n_pixels.sum(), 1)
            out.append(f"| {method} | {name} | {d.n_pixels.median():.0f} | "
                       f"{d.truth_median.median():.3g} | {d.median_rel_error.median():.3f} "
                       f"({d.median_rel_error.max():.3f}) | {prof} | {kept:.0%}, "
                       f"{c.median_rel_error.median():.3f} ({c.median_rel_error.max():.3f}) |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="work/cube", help="render cache (default work/cube)")
    ap.add_argument("--csv", default="results/uneven_leaf.csv",
                    help="per step and region table (default results/uneven_leaf.csv)")
    ap.add_argument("--fig-dir", default="results/figures",
                    help="where fig_uneven_leaf.{png,pdf} go (default results/figures)")
    ap.add_argument("--write-doc", metavar="MD", help="rewrite the uneven-leaf block of "
                    "this markdown file (bench/README.md) with the table")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    from gridflow.io import atomic_write, check_output

    from . import figures as F

    check_output(a.csv, suffixes=".csv", what="--csv")
    check_output(a.fig_dir, suffixes=None, what="--fig-dir")
    print("the unevenly growing POV-Ray leaf: 25 frames of 5 x 5 views (625 renders, "
          "about 4 min on 2 cores unless cached), then two affine estimates of 9 steps "
          "...",
          file=sys.stderr, flush=True)
    rows, snap = run(a.cache, progress=not a.no_progress)
    import pandas as pd

    with atomic_write(a.csv, "w") as fh:
        pd.DataFrame(rows).to_csv(fh, index=False, float_format="%.6g")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        written = F.save(fig_uneven_leaf(snap), a.fig_dir, "fig_uneven_leaf")
    print(table(rows))
    took = ", ".join(f"{m} {t:.1f} s" for m, t in snap["seconds"].items())
    print(f"estimates: {took}; wrote {a.csv}, "
          + ", ".join(str(p) for p in written))
    if a.write_doc:
        from .markdown import rewrite_bench_block

        print(rewrite_bench_block(a.write_doc, "uneven-leaf", "uneven_leaf", table(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
