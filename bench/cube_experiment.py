"""The cube experiment (Sec. 4.2): per-face error table, observation 11 and Fig. 1.

:func:`run_cube_experiment` is what ``gridflow cube`` does: render the scene (cached),
estimate the three models (:func:`run_cube`), score each visible face's interior (away
from edges) and its regions with Eq. 22 (:func:`cube_table`: Q_rel(U_Z), Q_abs(U_X),
Q_abs(U_Y), Q_rel(Z), Q_abs(Z_X), Q_abs(Z_Y), the median model error), check observation
11 (:func:`observation11`), draw Fig. 1 (:func:`fig1`) and write the table, the figure
and the documentation's cube section.  (The scene itself, its truth and its rendering
are :mod:`gridflow.scenes`.)
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from gridflow.estimator import estimate_models
from gridflow.scenes import FACE_NAMES, CubeScene, face_interior, spot_angle

from .metrics import q_abs, q_rel

__all__ = ["run_cube_experiment", "CubeReport", "run_cube", "cube_table", "fig1",
           "observation11", "regions", "cube_markdown"]

COLUMNS = ["face", "region", "model", "n_pixels", "n_valid", "q_rel_Uz", "q_abs_Ux", "q_abs_Uy",
           "q_rel_Z", "q_abs_Zx", "q_abs_Zy", "median_model_error", "median_rel_Uz",
           "median_abs_Zx"]


def run_cube(data, **settings):
    """Estimate all three models on ``data`` (a GridVolume with cube truth)."""
    ref = data.meta.get("ref_frame")
    if ref is not None and "ref_frame" not in settings:
        settings["ref_frame"] = ref
    return estimate_models(data.volume, data.focal_length, data.camera_spacing,
                           principal_point=data.principal_point, **settings)


REGIONS = ("interior", "edge", "spot_border", "away")


def regions(data, margin: float) -> dict[str, np.ndarray]:
    """Pixel masks, shape (H, W), of the regions the paper's Fig. 1 speaks of.

    ``interior``: the faces' pixels at least ``margin`` from another face or the
    background (the whole window lies on one face); ``edge``: cube pixels closer than that
    to an edge of the cube; ``spot_border``: interior pixels in the spotlight's border at
    the reference frame (between its full-strength radius and its falloff, where the
    illumination varies across the surface); ``away``: the rest of the interior.
    """
    face = data.truth["face"].astype(int)
    inner = face_interior(face, margin)
    out = {"interior": inner, "edge": (face > 0) & ~inner}
    src = (data.meta.get("source") or {}).get("scene")
    if src is not None:
        scene = CubeScene(**{k: tuple(v) if isinstance(v, list) else v
                             for k, v in src.items()})
        theta = spot_angle(scene, data.truth["Z"], scene.ref_frame)
        border = inner & (theta >= scene.spot_radius_deg) & (theta <= scene.spot_falloff_deg)
        out["spot_border"] = border
        out["away"] = inner & ~border
    return out


def cube_table(data, results, margin: float | None = None) -> pd.DataFrame:
    """One row per (visible face, region, model): Eq. 22 and medians over the region
    (:func:`regions`; ``margin`` default the window's radius) and the estimator's
    interior."""
    face = data.truth["face"].astype(int)
    if margin is None:
        margin = next(iter(results.values())).settings["window"] // 2
    masks = regions(data, margin)
    rows = []
    for (fid, fname), region in ((f, r) for f in FACE_NAMES.items() for r in REGIONS
                                 if r in masks):
        for model, e in results.items():
            mask = masks[region] & (face == fid) & e.interior
            m = e.maps
            ok = mask & np.isfinite(m["Z"])
            t = data.truth
            rows.append({
                "face": fname, "region": region, "model": model,
                "n_pixels": int(mask.sum()),
                "n_valid": int(ok.sum()),
                "q_rel_Uz": q_rel(m["Uz"], t["Uz"], mask),
                "q_abs_Ux": q_abs(m["Ux"], t["Ux"], mask),
                "q_abs_Uy": q_abs(m["Uy"], t["Uy"], mask),
                "q_rel_Z": q_rel(m["Z"], t["Z"], mask),
                "q_abs_Zx": q_abs(m["Zx"], t["Zx"], mask),
                "q_abs_Zy": q_abs(m["Zy"], t["Zy"], mask),
                "median_model_error": float(np.nanmedian(m["model_error"][ok]))
                if ok.any() else float("nan"),
                # beyond Eq. 22: medians, insensitive to the pixels whose window still
                # reaches across the cube's edge
                "median_rel_Uz": float(np.median(np.abs(m["Uz"][ok] / t["Uz"][ok] - 1)))
                if ok.any() else float("nan"),
                "median_abs_Zx": float(np.median(np.abs(m["Zx"][ok] - t["Zx"][ok])))
                if ok.any() else float("nan"),
            })
    return pd.DataFrame(rows, columns=COLUMNS)


def cube_markdown(table: pd.DataFrame, checks: list[dict], source: str) -> str:
    """The cube's per-face, per-region table and observation 11's checks, as markdown."""
    cols = ["face", "region", "model", "n_pixels", "q_rel_Uz", "q_abs_Ux", "q_abs_Uy",
            "q_abs_Zx", "median_model_error", "median_rel_Uz"]
    lines = [f"Made by `gridflow cube` from {source} (`results/cube.csv`).", "",
             "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in table[cols].itertuples(index=False):
        lines.append("| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v)
                                        for v in r) + " |")
    lines += ["", "| face | observation 11: check | verdict |", "|---|---|---|"]
    lines += [f"| {c['face']} | {c['check']} | **{'holds' if c['holds'] else 'does not hold'}** |"
              for c in checks]
    return "\n".join(lines)


def observation11(table: pd.DataFrame) -> list[dict]:
    """Observation 11 per face: over the face interior, model error BCC > HF > full and the
    full model's U_Z and lateral-motion errors below both other models'; HF's model error
    high at the cube's edge and the spotlight's border (at least twice its value away from
    both), the full model's high only at the edge (at least twice there, less than twice
    at the spotlight's border)."""
    out = []
    for face, d in table.groupby("face", sort=False):
        by = {r: g.set_index("model") for r, g in d.groupby("region")}
        v = by["interior"]
        err = v["median_model_error"]
        lat = v["q_abs_Ux"] + v["q_abs_Uy"]
        checks = {
            "model error BCC > HF > full": bool(err["bcc"] > err["hf"] > err["full"]),
            "U_Z error of full lowest": bool(v.q_rel_Uz["full"] < min(v.q_rel_Uz["bcc"],
                                                                      v.q_rel_Uz["hf"])),
            "lateral error of full lowest": bool(lat["full"] < min(lat["bcc"], lat["hf"])),
        }
        if {"edge", "spot_border", "away"} <= set(by):
            me = {r: by[r]["median_model_error"] for r in ("edge", "spot_border", "away")}
            checks["HF high at the edge and the spot's border"] = bool(
                me["edge"]["hf"] >= 2 * me["away"]["hf"]
                and me["spot_border"]["hf"] >= 2 * me["away"]["hf"])
            checks["full high only at the edge"] = bool(
                me["edge"]["full"] >= 2 * me["away"]["full"]
                and me["spot_border"]["full"] < 2 * me["away"]["full"])
        for name, ok in checks.items():
            out.append({"face": face, "check": name, "holds": ok})
    return out


def fig1(data, results, step: int = 12, scale: float = 135.0, margin: float | None = None):
    """The paper's Fig. 1, readable without the text, as a 3 x 4 grid of panels.

    Top: first and last central images, the regions the paper speaks of (cube edge,
    spotlight border, the rest), and the ratio of HF's to the full model's model error.
    Middle: the model error of BCC, HF and full, each on its own log colour range (their
    levels differ by orders of magnitude; the ratio panel compares HF and full directly).
    Bottom: the estimated motion of each model as the 3-D vector (scale U_X, scale U_Y,
    U_Z) in a cabinet projection (U_Z along the diagonal), over the true vector (0, 0,
    U_Z < 0) drawn in orange at the same points: any lateral error bends the blue arrow
    away from the orange one.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap, LogNorm

    from .figures import STYLE

    T, Sy, Sx = data.volume.shape[:3]
    centre = data.volume[:, (Sy - 1) // 2, (Sx - 1) // 2]
    ref = centre[data.meta.get("ref_frame") or (T - 1) // 2]
    lo, hi = np.percentile(centre, [0.5, 99.5])
    faint = 0.35 + 0.3 * (ref - lo) / max(hi - lo, 1e-12)      # contrast-reduced
    if margin is None:
        margin = next(iter(results.values())).settings["window"] // 2
    masks = regions(data, margin)
    names = {"bcc": "BCC (no change)", "hf": "HF (constant change)",
             "full": "full (spatially varying)"}
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(3, 4, figsize=(12.5, 9.6), constrained_layout=True)
        for a, img, title in ((ax[0, 0], centre[0], "(a) first image"),
                              (ax[0, 1], centre[-1], "(e) last image")):
            a.imshow(img, cmap="gray", vmin=lo, vmax=hi)
            a.set_title(title)
        # the regions of the text
        reg = np.full(ref.shape, np.nan)
        reg[masks["edge"]] = 0
        if "spot_border" in masks:
            reg[masks["away"]] = 1
            reg[masks["spot_border"]] = 2
        a = ax[0, 2]
        a.imshow(faint, cmap="gray", vmin=0, vmax=1)
        cmap = ListedColormap(["#d62728", "#7f7f7f", "#1f77b4"])
        a.imshow(np.ma.masked_invalid(reg), cmap=cmap, vmin=-0.5, vmax=2.5, alpha=0.55,
                 interpolation="nearest")
        for colour, label in zip(cmap.colors, ("cube edge", "elsewhere", "spotlight border")):
            a.plot([], [], "s", color=colour, label=label)
        a.legend(loc="lower left", fontsize="x-small", framealpha=0.8)
        a.set_title("regions (reference frame)")
        # HF / full model error
        a = ax[0, 3]
        ratio = results["hf"]["model_error"] / results["full"]["model_error"]
        ok = np.isfinite(ratio) & (ratio > 0)
        a.imshow(faint, cmap="gray", vmin=0, vmax=1)
        if ok.any():
            rn = LogNorm(*np.percentile(ratio[ok], [2, 98]))
            im = a.imshow(np.ma.masked_where(~ok, ratio), cmap="viridis", norm=rn, alpha=0.85)
            cb = fig.colorbar(im, ax=a, shrink=0.8, location="bottom", pad=0.02,
                              label="HF / full model error")
            from matplotlib.ticker import NullFormatter

            cb.ax.xaxis.set_minor_formatter(NullFormatter())
        a.set_title("HF vs full")
        for col, (model, e) in enumerate(results.items()):
            a = ax[1, col]
            a.imshow(faint, cmap="gray", vmin=0, vmax=1)
            err = e["model_error"]
            good = np.isfinite(err) & (err > 0)
            if good.any():
                norm = LogNorm(*np.percentile(err[good], [2, 98]))
                im = a.imshow(np.ma.masked_where(~good, err), cmap="inferno", norm=norm,
                              alpha=0.8)
                fig.colorbar(im, ax=a, shrink=0.8, location="bottom", pad=0.02,
                             label="model error")
            a.set_title(f"({'bcd'[col]}) model error, {names[model]}")
        ax[1, 3].axis("off")
        ax[1, 3].text(0, 0.5, "Model error: the largest of the\nthree smallest eigenvalues of J,"
                      "\neach panel on its own log range.\n\nMotion (bottom): blue the estimate,"
                      f"\norange the truth; U_X, U_Y scaled\nx{scale:g} against U_Z, arrows longer"
                      "\nthan two grid steps clipped.", va="center", fontsize="small")
        H, W = ref.shape
        yy, xx = np.mgrid[step // 2:H:step, step // 2:W:step]
        c45 = 0.5 * np.sqrt(0.5)
        on_cube = data.truth["face"][yy, xx] > 0
        tz = data.truth["Uz"][yy, xx]
        unit = abs(c45 * np.nanmedian(data.truth["Uz"])) * np.sqrt(2) / step
        for col, (model, e) in enumerate(results.items()):
            b = ax[2, col]
            b.imshow(faint, cmap="gray", vmin=0, vmax=1)
            ux, uy, uz = (e[q][yy, xx] for q in ("Ux", "Uy", "Uz"))
            dx = scale * ux + c45 * uz
            dy = scale * uy + c45 * uz
            ok = np.isfinite(dx) & np.isfinite(dy) & on_cube
            # the true vector is drawn one grid step long; longer ones are clipped at two
            length = np.hypot(dx, dy) / unit
            clip = np.where(length > 2 * step, 2 * step / np.maximum(length, 1e-12), 1.0)
            t_ok = on_cube & np.isfinite(tz)
            b.quiver(xx[t_ok], yy[t_ok], (c45 * tz)[t_ok], (c45 * tz)[t_ok], angles="xy",
                     scale_units="xy", scale=unit, width=0.006, color="#ff9f1c",
                     label="truth")
            b.quiver(xx[ok], yy[ok], (dx * clip)[ok], (dy * clip)[ok], angles="xy",
                     scale_units="xy", scale=unit, width=0.004, color="#00a0ff",
                     label="estimate")
            b.set_title(f"({'fgh'[col]}) motion, {names[model].split(' ')[0]}")
            if col == 0:
                b.legend(loc="lower left", fontsize="x-small", framealpha=0.8)
        ax[2, 3].axis("off")
        for a in ax.ravel():
            a.set_xticks([])
            a.set_yticks([])
            a.grid(False)
        fig.suptitle("Fig. 1: a cube moving towards the cameras under a spotlight moving "
                     "right to left")
    return fig


@dataclass
class CubeReport:
    """What :func:`run_cube_experiment` did.

    Attributes
    ----------
    folder : Path
        The rendered camera-grid folder (the render cache).
    rendered, render_seconds
        Images rendered for the scene and their time (from its manifest).
    seconds_render, seconds_estimate : float
        This run's time for rendering (or finding the cache) and estimating.
    table : pandas.DataFrame
        :func:`cube_table`.
    checks : list of dict
        :func:`observation11`.
    written : list of Path
    """

    folder: Path
    rendered: object
    render_seconds: object
    seconds_render: float
    seconds_estimate: float
    table: pd.DataFrame
    checks: list
    written: list


def run_cube_experiment(scene: CubeScene, cache, *, csv, fig_dir, doc=None,
                        sigma: float = 8.0, window: int = 33,
                        progress: bool = True) -> CubeReport:
    """Render ``scene`` into ``cache`` (or find it there), estimate, score, draw, write.

    Parameters
    ----------
    scene : CubeScene
    cache : path
        Render cache (``work/cube``).
    csv : path
        The per-face table (``results/cube.csv``), written atomically.
    fig_dir : path
        Where ``fig1.png`` and ``fig1.pdf`` go.
    doc : path, optional
        A markdown file whose ``cube`` block is rewritten (``docs/reproduction.md``).
    sigma, window
        The estimator's window (the 55-px left face of a 256-px image needs a smaller one
        than the sinusoid's 16).
    progress : bool
        The render's progress bar.
    """
    from gridflow.io import atomic_write
    from gridflow.loader import load_folder
    from gridflow.scenes.render import render_cube

    from . import figures as F
    from .markdown import rewrite_block

    t0 = time.perf_counter()
    folder = render_cube(scene, cache, progress=progress)
    data = load_folder(folder)
    src = data.meta.get("source") or {}
    t1 = time.perf_counter()
    results = run_cube(data, sigma=sigma, window=window)
    t2 = time.perf_counter()
    table = cube_table(data, results)
    checks = observation11(table)
    with atomic_write(csv, "w") as fh:
        table.to_csv(fh, index=False, float_format="%.6g")
    written = [Path(csv)]
    if doc:
        written.append(rewrite_block(doc, "cube", cube_markdown(
            table, checks, f"the scene `{folder.name}`, sigma {sigma:g}, {window} taps")))
    written += F.save(fig1(data, results), fig_dir, "fig1")
    return CubeReport(folder, src.get("rendered"), src.get("render_seconds"), t1 - t0,
                      t2 - t1, table, checks, written)
