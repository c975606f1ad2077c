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

from gridflow.estimator import MODELS  # noqa: E402
from gridflow.estimator.models import AFFINE, TRANSLATION  # noqa: E402

from .labels import is_growth_sweep, setup_label  # noqa: E402

__all__ = ["fig2", "fig3", "fig4", "fig_peers_depth", "draw_figures", "figures_from_csv",
           "sinusoid_fig2", "save",
           "setup_label",
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


# Fig. 4's y range: errors above TOP are drawn at the top edge (BCC's broken values reach
# 1e10 and would squash the 1e-3 .. 1e-1 band where the paper's statements live)
TOP = 10.0
BREAK_LEVEL = 0.1          # bench.claims.BREAK: "breaks down" (the dashed grey line)
# the paper's breakdown positions of BCC (observation 9), marked on their axes
PAPER_MARKS = {"a2": 0.1, "a2x": 0.02}
# HF's line is drawn dashed with open markers: it often lies exactly under full's
_LINE = {"bcc": {}, "hf": dict(ls="--", mfc="none", ms=5), "full": {}}


def _curve_stats(df: pd.DataFrame, measure: str) -> pd.DataFrame:
    """Mean, min and max of ``measure`` over the seeds of each value."""
    g = df.groupby("value")[measure]
    return pd.DataFrame({"mean": g.mean(), "lo": g.min(), "hi": g.max(),
                         "n": g.count()}).reset_index()


def _draw(ax, d: pd.DataFrame, measure: str, model: str, clip: float | None = None):
    """One model's curve: the mean over seeds, their range shaded where there are
    several, the value at 0 as a dotted line; values above ``clip`` at ``clip``."""
    st = dict(MODEL_STYLE[model], **_LINE[model])
    c = _curve_stats(d, measure)
    nz = c[c.value != 0]
    y = nz["mean"].to_numpy()
    if clip is not None:
        y = np.minimum(y, clip)
    ax.plot(nz.value.abs(), y, ms=st.pop("ms", 3), lw=1, **st)
    if (nz.n > 1).any():
        lo, hi = nz.lo.to_numpy(), nz.hi.to_numpy()
        if clip is not None:
            lo, hi = np.minimum(lo, clip), np.minimum(hi, clip)
        ax.fill_between(nz.value.abs(), lo, hi, color=MODEL_STYLE[model]["color"],
                        alpha=0.2, lw=0)
    zero = c[c.value == 0]["mean"]
    if len(zero) and np.isfinite(zero.iloc[0]) and zero.iloc[0] > 0:
        ax.axhline(min(zero.iloc[0], clip or np.inf), color=MODEL_STYLE[model]["color"],
                   ls=":", lw=0.8)


def _panel(ax, df: pd.DataFrame, quantity: str, param: str, models, noise: float) -> None:
    measure = _measure(quantity, param)
    for model in models:
        d = df[(df.param == param) & (df.quantity == quantity) & (df.model == model)
               & (df.noise == noise)]
        if d.empty:
            continue
        _draw(ax, d, measure, model)
    _log_axes(ax)
    _min_span(ax, 100.0)
    sign = "-" if (df[df.param == param].value < 0).any() else ""
    ax.set_xlabel(f"{sign}{PARAM_LABEL[param]}" if sign else PARAM_LABEL[param])
    ax.set_ylabel(_ylabel(quantity, measure))


def _min_span(ax, factor: float) -> None:
    """Widen a log y-axis to span at least ``factor`` (autoscaling a nearly flat curve
    to 1.15 .. 1.62e-4 makes "almost independent" look like strong dependence)."""
    if ax.get_yscale() != "log":
        return
    lo, hi = ax.get_ylim()
    if hi / lo < factor:
        mid = np.sqrt(lo * hi)
        ax.set_ylim(mid / np.sqrt(factor), mid * np.sqrt(factor))


def _file_label(label: str) -> str:
    """``setup_label`` as part of a file name: letters, digits and '_' only."""
    import re

    return re.sub(r"[^A-Za-z0-9]+", "_", label).strip("_")


def fig3(df: pd.DataFrame, label: str = ""):
    """Errors of a1 (top) and a2 (bottom) against a1, a1x, a2, a2x; HF and full, noise-free.
    Every panel spans at least two decades; the 0.5 % of observation 1 is marked."""
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(2, 4, figsize=(10, 4.6), constrained_layout=True)
        for row, q in enumerate(("a1", "a2")):
            for col, p in enumerate(PARAMS):
                _panel(axes[row, col], df, q, p, ("hf", "full"), 0.0)
        axes[0, 0].axhline(0.005, color="0.4", ls="--", lw=0.8, label="0.5 % (obs. 1)")
        axes[0, 0].legend()
        fig.suptitle("Fig. 3: brightness parameters, noise-free (dotted: value at 0; HF "
                     "dashed, open markers)" + (f" [{label}]" if label else ""))
    return fig


def fig4(df: pd.DataFrame, noise: float = 0.025, label: str = ""):
    """Q_rel(U_Z) against a1, a1x, a2, a2x; three models; noise-free and noisy on the same
    y range per column (values above ``TOP`` at the top edge), the noisy curves the mean
    over their seeds with the range shaded; the breakdown level 0.1 and the paper's BCC
    breakdowns (|a2| ~ 0.1, |a2x| ~ 0.02) marked."""
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(2, 4, figsize=(10, 4.8), constrained_layout=True,
                                 sharey="col")
        for row, n in enumerate((0.0, noise)):
            for col, p in enumerate(PARAMS):
                ax = axes[row, col]
                for model in MODELS:
                    d = df[(df.param == p) & (df.quantity == "Uz") & (df.model == model)
                           & (df.noise == n)]
                    if not d.empty:
                        _draw(ax, d, "q_rel", model, clip=TOP)
                _log_axes(ax)
                ax.axhline(BREAK_LEVEL, color="0.4", ls="--", lw=0.8)
                if p in PAPER_MARKS:
                    ax.axvline(PAPER_MARKS[p], color="0.4", ls="-.", lw=0.8)
                sign = "-" if (df[df.param == p].value < 0).any() else ""
                ax.set_xlabel(f"{sign}{PARAM_LABEL[p]}")
                ax.set_ylabel(r"$Q_{rel}$ of $U_Z$" + ("" if n == 0 else rf", $\sigma_n$={n}"))
        for ax in axes[0]:
            if ax.get_yscale() == "log":
                ax.set_ylim(max(ax.get_ylim()[0], 1e-8), TOP * 1.5)
        axes[0, 0].legend()
        seeds = df[df.noise == noise].groupby(["param", "value", "model", "quantity"]).size()
        nseeds = int(seeds.min()) if len(seeds) else 0
        fig.suptitle(r"Fig. 4: relative error of $U_Z$; top noise-free, bottom "
                     rf"$\sigma_n = {noise}$ (mean of {nseeds} seeds, range shaded); dotted: "
                     r"value at 0; dashed grey: breakdown level 0.1; dash-dot: the paper's "
                     rf"BCC breakdown; above {TOP:g} drawn at the top"
                     + (f" [{label}]" if label else ""), fontsize=7)
    return fig


def fig2(frames: list[np.ndarray], titles: list[str], caption: str):
    """Central-camera images of a sequence on one grey scale (so that the dimming between
    them shows as it is), and their intensity along the middle row (the first frame
    dashed, the last dotted with markers: they darken alike and would hide each other).

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
        lo = min(float(np.min(f)) for f in frames)
        hi = max(float(np.max(f)) for f in frames)
        for ax, img, title in zip(axes, frames, titles):
            im = ax.imshow(img, cmap="gray", interpolation="nearest", vmin=lo, vmax=hi)
            ax.axhline(row, color="tab:orange", lw=0.8, ls="--")
            ax.set_title(f"{title}\nrange {np.min(img):.2g} .. {np.max(img):.2g}")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.grid(False)
        fig.colorbar(im, ax=list(axes[:len(frames)]), shrink=0.8, location="bottom",
                     pad=0.02, label="intensity (one scale for all the images)")
        prof = axes[-1]
        styles = [dict(ls="--", lw=1.4), dict(ls="-", lw=1.0),
                  dict(ls=":", lw=1.0, marker="o", ms=2, markevery=6)]
        for i, (img, title) in enumerate(zip(frames, titles)):
            st = styles[i] if len(frames) == 3 else {}
            prof.plot(img[row], label=title.split(",")[0], **st)
        prof.set_xlabel("image column (middle row, dashed)")
        prof.set_ylabel("intensity")
        prof.legend(fontsize="small")
        prof.set_title("the brightness change")
        fig.suptitle(caption)
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
                for motion, ls in ((AFFINE.name, "-"), (TRANSLATION.name, "--")):
                    for model in MODELS:
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
    and/or Fig. 2, in ``out_dir``; returns the paths written.

    Figs. 3 and 4 are named after the setup the sweep ran under (``fig3_gridflow_setup.png``,
    ``fig3_paper_setup.png``), then ``suffix``; a growth sweep's figure is
    ``fig_growthSUFFIX.png``."""
    written = []
    if sweep is not None:
        names = [f"sweep {n}" for n in sweep["sweep"].unique()] if "sweep" in sweep else []
        label = ", ".join(names + [setup_label(sweep)])
        if is_growth_sweep(sweep):
            # a growth sweep: its own figure
            written += save(fig_growth(sweep, label=label), out_dir, "fig_growth" + suffix)
        else:
            setup = "_" + _file_label(setup_label(sweep))
            written += save(fig3(sweep, label), out_dir, "fig3" + setup + suffix)
            written += save(fig4(sweep, label=label), out_dir, "fig4" + setup + suffix)
    if fig2_too:
        written += save(sinusoid_fig2(), out_dir, "fig2")
    return written


def figures_from_csv(out_dir, *, sweep_csv=None, fig2: bool = False,
                     suffix: str = "") -> list[Path]:
    """What ``gridflow figures`` does: :func:`draw_figures` from the sweep CSV
    ``sweep_csv`` and/or Fig. 2, into ``out_dir`` (checked first); returns the paths
    written."""
    from gridflow.errors import UsageError
    from gridflow.io import check_output

    from .sweep import read_sweep_csv

    out = check_output(out_dir, suffixes=None, what="--out")
    if not all(c.isalnum() or c in "_.-" for c in suffix):
        raise UsageError(f"--suffix {suffix!r}: use letters, digits, '_', '.' and '-' only")
    if not (sweep_csv or fig2):
        raise UsageError("nothing to draw: give --sweep CSV (Figs. 3, 4) and/or --fig2")
    df = read_sweep_csv(sweep_csv) if sweep_csv else None
    return draw_figures(out, sweep=df, fig2_too=fig2, suffix=suffix)
