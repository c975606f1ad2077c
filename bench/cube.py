"""The cube experiment (Sec. 4.2): per-face error table and Fig. 1.

``run_cube`` estimates the three models on a rendered camera-grid folder and scores each
visible face's interior (away from edges) with Eq. 22: Q_rel(U_Z), Q_abs(U_X), Q_abs(U_Y),
Q_rel(Z), Q_abs(Z_X), Q_abs(Z_Y), plus the median model error.  ``fig1`` draws the paper's
Fig. 1 from the same estimates.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from gridflow.estimator import estimate_models
from gridflow.scenes import FACE_NAMES, face_interior

from .metrics import q_abs, q_rel

__all__ = ["run_cube", "cube_table", "fig1", "observation11", "face_interior"]

COLUMNS = ["face", "model", "n_pixels", "n_valid", "q_rel_Uz", "q_abs_Ux", "q_abs_Uy",
           "q_rel_Z", "q_abs_Zx", "q_abs_Zy", "median_model_error", "median_rel_Uz",
           "median_abs_Zx"]


def run_cube(data, **settings):
    """Estimate all three models on ``data`` (a GridVolume with cube truth)."""
    ref = data.meta.get("ref_frame")
    if ref is not None and "ref_frame" not in settings:
        settings["ref_frame"] = ref
    return estimate_models(data.volume, data.focal_length, data.camera_spacing,
                           principal_point=data.principal_point, **settings)


def cube_table(data, results, margin: float | None = None) -> pd.DataFrame:
    """One row per (visible face, model), over the face interior (``margin`` pixels from
    the edges; default the window's radius, so that the whole neighbourhood lies on the
    face) and the estimator's interior."""
    face = data.truth["face"].astype(int)
    if margin is None:
        margin = next(iter(results.values())).settings["window"] // 2
    inner = face_interior(face, margin)
    rows = []
    for fid, fname in FACE_NAMES.items():
        for model, e in results.items():
            mask = inner & (face == fid) & e.interior
            m = e.maps
            ok = mask & np.isfinite(m["Z"])
            t = data.truth
            rows.append({
                "face": fname, "model": model, "n_pixels": int(mask.sum()),
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


def observation11(table: pd.DataFrame) -> list[dict]:
    """Observation 11 per face: model error BCC > HF > full; the full model's U_Z and
    lateral-motion errors below both other models'."""
    out = []
    for face, d in table.groupby("face", sort=False):
        v = d.set_index("model")
        err = v["median_model_error"]
        lat = v["q_abs_Ux"] + v["q_abs_Uy"]
        checks = {
            "model error BCC > HF > full": bool(err["bcc"] > err["hf"] > err["full"]),
            "U_Z error of full lowest": bool(v.q_rel_Uz["full"] < min(v.q_rel_Uz["bcc"],
                                                                      v.q_rel_Uz["hf"])),
            "lateral error of full lowest": bool(lat["full"] < min(lat["bcc"], lat["hf"])),
        }
        for name, ok in checks.items():
            out.append({"face": face, "check": name, "holds": ok})
    return out


def fig1(data, results, step: int = 12, scale: float = 135.0):
    """The paper's Fig. 1 as a 2 x 4 grid of panels.

    (a, e) first and last central images; (b-d) model error of BCC, HF, full (log colour)
    over the contrast-reduced central image; (f-h) estimated motion vectors, drawn as the
    3-D vector (scale U_X, scale U_Y, U_Z) in a cabinet projection (U_Z along the
    diagonal), so the truth (0, 0, U_Z < 0) is the same arrow everywhere and any lateral
    error bends it.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from .figures import STYLE

    T, Sy, Sx = data.volume.shape[:3]
    centre = data.volume[:, (Sy - 1) // 2, (Sx - 1) // 2]
    ref = centre[data.meta.get("ref_frame") or (T - 1) // 2]
    lo, hi = np.percentile(centre, [0.5, 99.5])
    faint = 0.35 + 0.3 * (ref - lo) / max(hi - lo, 1e-12)      # contrast-reduced
    errs = np.concatenate([e["model_error"][np.isfinite(e["model_error"])].ravel()
                           for e in results.values()])
    errs = errs[errs > 0]
    norm = LogNorm(*np.percentile(errs, [2, 98])) if errs.size else None
    names = {"bcc": "no change (BCC)", "hf": "constant change (HF)",
             "full": "spatially varying (full)"}
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(2, 4, figsize=(11, 5.8), constrained_layout=True)
        for a, img, title in ((ax[0, 0], centre[0], "(a) first image"),
                              (ax[1, 0], centre[-1], "(e) last image")):
            a.imshow(img, cmap="gray", vmin=lo, vmax=hi)
            a.set_title(title)
        H, W = ref.shape
        yy, xx = np.mgrid[step // 2:H:step, step // 2:W:step]
        c45 = 0.5 * np.sqrt(0.5)
        for col, (model, e) in enumerate(results.items(), start=1):
            a = ax[0, col]
            a.imshow(faint, cmap="gray", vmin=0, vmax=1)
            im = a.imshow(np.ma.masked_invalid(e["model_error"]), cmap="inferno", norm=norm,
                          alpha=0.75)
            a.set_title(f"({'bcd'[col - 1]}) model error, {names[model]}")
            b = ax[1, col]
            b.imshow(faint, cmap="gray", vmin=0, vmax=1)
            ux, uy, uz = (e[q][yy, xx] for q in ("Ux", "Uy", "Uz"))
            dx = scale * ux + c45 * uz
            dy = scale * uy + c45 * uz
            on_cube = data.truth["face"][yy, xx] > 0
            ok = np.isfinite(dx) & np.isfinite(dy) & on_cube
            # the true vector is drawn one grid step long; longer ones are clipped at two
            unit = abs(c45 * np.nanmedian(data.truth["Uz"])) * np.sqrt(2) / step
            length = np.hypot(dx, dy) / unit
            clip = np.where(length > 2 * step, 2 * step / np.maximum(length, 1e-12), 1.0)
            b.quiver(xx[ok], yy[ok], (dx * clip)[ok], (dy * clip)[ok], angles="xy",
                     scale_units="xy", scale=unit, width=0.004, color="#00c0ff")
            b.set_title(f"({'fgh'[col - 1]}) motion, {model.upper() if model != 'full' else 'full'}"
                        f" ($U_X, U_Y$ x{scale:g}; clipped at 2 steps)")
        for a in ax.ravel():
            a.set_xticks([])
            a.set_yticks([])
            a.grid(False)
        if norm is not None:
            fig.colorbar(im, ax=ax[0, 1:], shrink=0.8, label="model error (3rd smallest eigenvalue)")
        fig.suptitle("Fig. 1: cube moving towards the cameras under a spotlight moving right "
                     "to left")
    return fig
