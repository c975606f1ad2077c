"""The paper's figures, drawn from results (edge of the system: plotting only).

Fig. 2: first, reference and last central image of a sinusoid sequence (``a2 = -0.2,
a2x = -0.002``).  The brightness model is normalised at the centre frame, so the first and
last frames are darkened alike (``exp(-0.2 * 4^2) = 0.04``); the reference frame is shown
between them to make that visible.
Fig. 3: errors of ``a1`` and ``a2`` against each of ``a1, a1x, a2, a2x`` (HF and full).
Fig. 4: ``Q_rel(U_Z)`` against the same, three models, noise-free and sigma_n = 0.025.
Fig. 1 (the cube) is drawn by :mod:`gridflow.bench.cube_experiment`.
:func:`draw_figures` is what ``gridflow figures`` does.

Error measure per panel (Eq. 22): relative when the quantity is the swept parameter
itself, absolute for cross-talk (the swept parameter leaves the quantity's reference at 0
or makes it cross 0).  The x axes show ``|value|`` on a log scale; the value 0 of each
sweep is drawn as a dotted horizontal line at its error.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

__all__ = ["fig2", "fig3", "fig4", "fig_peers_depth", "draw_figures", "sinusoid_fig2", "save",
           "STYLE", "MODEL_STYLE", "PARAM_LABEL"]

STYLE = {"font.size": 8, "axes.titlesize": 8, "axes.labelsize": 8, "legend.fontsize": 7,
         "xtick.labelsize": 7, "ytick.labelsize": 7, "figure.dpi": 150, "savefig.dpi": 150,
         "axes.grid": True, "grid.alpha": 0.3}
MODEL_STYLE = {"bcc": dict(color="#d62728", marker="s", label="BCC"),
               "hf": dict(color="#1f77b4", marker="o", label="HF"),
               "full": dict(color="#2ca02c", marker="^", label="full")}
PARAM_LABEL = {"a1": r"$a_1$", "a1x": r"$a_{1,x}$", "a2": r"$a_2$", "a2x": r"$a_{2,x}$",
               "Uz": r"$U_Z$", "growth": "growth", "rotation": "rotation"}
PARAMS = ("a1", "a1x", "a2", "a2x")


def save(fig, out_dir, name: str) -> list[Path]:
    """Write ``name``.png and ``name``.pdf into ``out_dir``; returns the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for ext in ("png", "pdf"):
        p = out_dir / f"{name}.{ext}"
        # metadata without dates keeps the files identical from run to run
        meta = {"CreationDate": None} if ext == "pdf" else {"Software": None}
        fig.savefig(p, bbox_inches="tight", metadata=meta)
        paths.append(p)
    plt.close(fig)
    return paths


def _measure(quantity: str, param: str) -> str:
    return "q_rel" if quantity == param else "q_abs"


def _ylabel(quantity: str, measure: str) -> str:
    q = PARAM_LABEL.get(quantity, quantity)
    return (r"$Q_{rel}$" if measure == "q_rel" else r"$Q_{abs}$") + f" of {q}"


def _log_axes(ax) -> None:
    """Log-log axes, or a note where the sweep holds no positive value for this panel (a
    sweep need not cover every parameter)."""
    if not any(np.any(np.asarray(line.get_ydata(), float) > 0) for line in ax.get_lines()):
        ax.text(0.5, 0.5, "not in this sweep", transform=ax.transAxes, ha="center",
                va="center", color="0.5")
        return
    ax.set_xscale("log")
    ax.set_yscale("log")


def _panel(ax, df: pd.DataFrame, quantity: str, param: str, models, noise: float) -> None:
    measure = _measure(quantity, param)
    for model in models:
        d = df[(df.param == param) & (df.quantity == quantity) & (df.model == model)
               & (df.noise == noise)]
        if d.empty:
            continue
        d = d.groupby("value", as_index=False)[measure].mean()
        nz = d[d.value != 0]
        st = MODEL_STYLE[model]
        ax.plot(nz.value.abs(), nz[measure], ms=3, lw=1, **st)
        zero = d[d.value == 0][measure]
        if len(zero) and np.isfinite(zero.iloc[0]) and zero.iloc[0] > 0:
            ax.axhline(zero.iloc[0], color=st["color"], ls=":", lw=0.8)
    _log_axes(ax)
    sign = "-" if (df[df.param == param].value < 0).any() else ""
    ax.set_xlabel(f"{sign}{PARAM_LABEL[param]}" if sign else PARAM_LABEL[param])
    ax.set_ylabel(_ylabel(quantity, measure))


def fig3(df: pd.DataFrame, label: str = ""):
    """Errors of a1 (top) and a2 (bottom) against a1, a1x, a2, a2x; HF and full, noise-free."""
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(2, 4, figsize=(10, 4.6), constrained_layout=True)
        for row, q in enumerate(("a1", "a2")):
            for col, p in enumerate(PARAMS):
                _panel(axes[row, col], df, q, p, ("hf", "full"), 0.0)
        axes[0, 0].legend()
        fig.suptitle("Fig. 3: brightness parameters, noise-free (dotted: value at 0)"
                     + (f" [{label}]" if label else ""))
    return fig


def fig4(df: pd.DataFrame, noise: float = 0.025, label: str = ""):
    """Q_rel(U_Z) against a1, a1x, a2, a2x; three models; noise-free and noisy."""
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(2, 4, figsize=(10, 4.6), constrained_layout=True)
        for row, n in enumerate((0.0, noise)):
            for col, p in enumerate(PARAMS):
                ax = axes[row, col]
                for model in ("bcc", "hf", "full"):
                    d = df[(df.param == p) & (df.quantity == "Uz") & (df.model == model)
                           & (df.noise == n)].groupby("value", as_index=False)["q_rel"].mean()
                    nz = d[d.value != 0]
                    ax.plot(nz.value.abs(), nz.q_rel, ms=3, lw=1, **MODEL_STYLE[model])
                    zero = d[d.value == 0].q_rel
                    if len(zero):
                        ax.axhline(zero.iloc[0], color=MODEL_STYLE[model]["color"], ls=":", lw=0.8)
                _log_axes(ax)
                sign = "-" if (df[df.param == p].value < 0).any() else ""
                ax.set_xlabel(f"{sign}{PARAM_LABEL[p]}")
                ax.set_ylabel(r"$Q_{rel}$ of $U_Z$" + ("" if n == 0 else rf", $\sigma_n$={n}"))
        axes[0, 0].legend()
        fig.suptitle(r"Fig. 4: relative error of $U_Z$; top noise-free, bottom "
                     rf"$\sigma_n = {noise}$ (dotted: value at 0)" + (f" [{label}]" if label else ""))
    return fig


def fig2(frames: list[np.ndarray], titles: list[str], caption: str):
    """Central-camera images of a sequence, each on its own grey scale (the texture stays
    visible however dark a frame is), and their intensity along the middle row on one
    scale (the brightness change between the frames).

    Parameters
    ----------
    frames : list of ndarray, each shape (H, W)
    titles : list of str
    caption : str
    """
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(1, len(frames) + 1, figsize=(3 * len(frames) + 4.2, 3.3),
                                 constrained_layout=True,
                                 gridspec_kw={"width_ratios": [1] * len(frames) + [1.6]})
        row = frames[0].shape[0] // 2
        for ax, img, title in zip(axes, frames, titles):
            im = ax.imshow(img, cmap="gray", interpolation="nearest")
            ax.axhline(row, color="tab:orange", lw=0.8, ls="--")
            ax.set_title(title)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.grid(False)
            fig.colorbar(im, ax=ax, shrink=0.8, location="bottom", pad=0.02)
        prof = axes[-1]
        for img, title in zip(frames, titles):
            prof.plot(img[row], lw=1, label=title.split(",")[0])
        prof.set_xlabel("image column (middle row, dashed)")
        prof.set_ylabel("intensity")
        prof.legend(fontsize="small")
        prof.set_title("the brightness change")
        fig.suptitle(caption + "; each image on its own grey scale")
    return fig


def fig_peers_depth(truth: np.ndarray, results: list[dict], title: str):
    """Error maps side by side: the true disparity, then |estimate - truth| per method
    (one colour scale, 0-0.5 px; NaN estimates white, pixels without truth grey)."""
    import matplotlib.pyplot as plt

    n = len(results) + 1
    fig, axes = plt.subplots(1, n, figsize=(3.2 * n, 3.6), constrained_layout=True)
    im = axes[0].imshow(truth, cmap="viridis")
    axes[0].set_title("true disparity (px/view)", fontsize=9)
    fig.colorbar(im, ax=axes[0], shrink=0.8)
    cmap = plt.get_cmap("magma").copy()
    cmap.set_bad("white")
    for ax, r in zip(axes[1:], results):
        err = np.abs(r["disparity"] - truth)
        shown = np.where(np.isfinite(truth), err, np.nan)
        ax.imshow(np.where(np.isfinite(truth), 0.0, 1.0), cmap="Greys", vmin=0, vmax=4)
        im2 = ax.imshow(np.ma.masked_where(~np.isfinite(truth), shown), cmap=cmap, vmin=0,
                        vmax=0.5)
        ax.set_title(f"{r['method']}: BadPix(0.07) {r['badpix_007']:.1f} %\n"
                     f"MSE x 100 {r['mse_x100']:.3g}", fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im2, ax=list(axes[1:]), shrink=0.8, label="|error| (px per view)")
    fig.suptitle(title, fontsize=10)
    return fig


def fig_growth(df: pd.DataFrame, noise: float = 0.01, label: str = ""):
    """The growth sweep in the style of Fig. 4: Q_rel(U_Z) and Q_rel(growth) against the
    growth rate, and Q_rel(U_Z) and Q_rel(rotation) against the rotation rate; the three
    brightness models with the affine motion model (solid) and with the paper's
    translation model (dashed, U_Z only); top noise-free, bottom sigma_n = ``noise``."""
    panels = (("growth", "Uz"), ("growth", "growth"), ("rotation", "Uz"),
              ("rotation", "rotation"))
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(2, 4, figsize=(10, 4.8), constrained_layout=True)
        for row, n in enumerate((0.0, noise)):
            for col, (p, q) in enumerate(panels):
                ax = axes[row, col]
                for motion, ls in (("affine", "-"), ("translation", "--")):
                    for model in ("bcc", "hf", "full"):
                        d = df[(df.param == p) & (df.quantity == q) & (df.model == model)
                               & (df.noise == n) & (df.motion == motion)]
                        if d.empty:
                            continue
                        d = d.groupby("value", as_index=False)["q_rel"].mean()
                        nz = d[d.value != 0]
                        st = dict(MODEL_STYLE[model])
                        st["label"] = f"{st['label']}, {motion}"
                        ax.plot(nz.value.abs(), nz.q_rel, ms=3, lw=1, ls=ls, **st)
                _log_axes(ax)
                ax.set_xlabel(f"{p} rate per frame")
                ax.set_ylabel(rf"$Q_{{rel}}$ of {PARAM_LABEL.get(q, q)}"
                              + ("" if n == 0 else rf", $\sigma_n$={n}"))
        axes[0, 0].legend(fontsize=5)
        fig.suptitle("Growth: the affine motion model (solid) against the paper's "
                     "translation model (dashed); top noise-free, bottom "
                     rf"$\sigma_n = {noise}$" + (f" [{label}]" if label else ""))
    return fig


def sinusoid_fig2():
    """Fig. 2 of the paper from the generator: the first, reference and last central
    images of a sinusoid with ``a2 = -0.2, a2x = -0.002``."""
    from gridflow.generators import make_sinusoid

    sv = make_sinusoid(a2=-0.2, a2x=-0.002)
    c = sv.volume.shape[1] // 2, sv.volume.shape[2] // 2
    k = sv.params.ref_frame
    T = sv.volume.shape[0]
    frames = [sv.volume[i, c[0], c[1]] for i in (0, k, T - 1)]
    titles = [f"(a) first frame, t = {-k}", "reference frame, t = 0",
              f"(b) last frame, t = {T - 1 - k}"]
    return fig2(frames, titles, r"Fig. 2: $a_1 = a_{1,x} = 0$, $a_2 = -0.2$, "
                r"$a_{2,x} = -0.002$")


def draw_figures(out_dir, *, sweep: pd.DataFrame | None = None, fig2_too: bool = False,
                 suffix: str = "") -> list[Path]:
    """Figs. 3 and 4 from a sweep table (:func:`gridflow.bench.sweep.read_sweep_csv`)
    and/or Fig. 2, as ``fig3SUFFIX.png`` etc. in ``out_dir``; returns the paths written."""
    written = []
    if sweep is not None:
        label = (", ".join(f"sweep {n}" for n in sweep["sweep"].unique())
                 if "sweep" in sweep else "")
        if "motion" in sweep and (sweep.motion == "affine").any():
            # a growth sweep: its own figure
            written += save(fig_growth(sweep, label=label), out_dir, "fig_growth" + suffix)
        else:
            written += save(fig3(sweep, label), out_dir, "fig3" + suffix)
            written += save(fig4(sweep, label=label), out_dir, "fig4" + suffix)
    if fig2_too:
        written += save(sinusoid_fig2(), out_dir, "fig2")
    return written
