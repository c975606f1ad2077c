"""What a grower reads from a map series: the growth per leaf and step (median, mean,
spread, pixels used) and, with a recording that has growth truth, its error; the growth
maps at chosen frames, the growth against time and the kymograph as figures.  Each is
over the pixels the estimator is confident of (:func:`confident`).
:func:`growth_report` is what ``gridflow growth`` does.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gridflow.errors import UsageError

__all__ = ["growth_table", "growth_profiles", "draw_growth", "draw_kymograph",
           "growth_report", "GrowthReport", "confident", "leaves", "SD_LIMIT"]


# a pixel whose growth_sd exceeds this many times the step's median growth_sd is left out
# of the report's statistics, profiles and maps (gridflow growth --sd-limit)
SD_LIMIT = 3.0
# connected parts of the maps smaller than this fraction of the largest are not leaves
MIN_LEAF_FRACTION = 0.05


def confident(sd: np.ndarray, where: np.ndarray, limit: float = SD_LIMIT) -> np.ndarray:
    """The pixels of ``where`` (bool, shape (H, W)) whose standard deviation ``sd`` (shape
    (H, W)) is at most ``limit`` times its median over ``where``: the few pixels the
    estimator itself finds far less certain than the rest of the leaf (its edge,
    texture-poor spots) are left out.  ``limit`` 0 (or infinite) keeps every pixel of
    ``where``; so does a map series without ``growth_sd``."""
    if not limit or not np.isfinite(limit) or sd is None:
        return where
    ok = where & np.isfinite(sd)
    if not ok.any():
        return where
    return ok & (sd <= limit * np.median(sd[ok]))


def leaves(maps, quantity: str = "growth"):
    """The leaves of a map series: the connected parts (8-neighbours) of the interior's
    pixels that have a value in any done step, numbered 1, 2, ... in the order of their
    first pixel (row by row); parts smaller than :data:`MIN_LEAF_FRACTION` of the largest
    are left out (label 0).  Without a mask the interior is one leaf.

    Returns
    -------
    labels : ndarray of int, shape (H, W)
    n_fragments : int
        The small parts left out.
    """
    from scipy import ndimage

    store = _open_maps(maps, quantity)
    seen = np.zeros(store.group["interior"].shape, dtype=bool)
    for i in np.flatnonzero(store.done()):
        seen |= np.isfinite(store.read(quantity, i))
    seen &= np.asarray(store.read("interior"), dtype=bool)
    labels, n = ndimage.label(seen, structure=np.ones((3, 3)))
    if n == 0:
        return labels, 0
    size = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    big = np.flatnonzero(size >= MIN_LEAF_FRACTION * size.max()) + 1
    renumber = np.zeros(n + 1, dtype=int)
    renumber[big] = np.arange(1, big.size + 1)
    return renumber[labels], int(n - big.size)


def growth_table(maps, truth=None, *, quantity: str = "growth", sd_limit: float = SD_LIMIT,
                 labels: np.ndarray | None = None):
    """Per leaf and step of the map series ``maps``: the mean, median, 10th and 90th
    percentile of ``quantity`` over the leaf's confident pixels, and with a recording
    ``truth`` that has it, the truth's mean and Q_rel (Eq. 22); with a truth, every column
    is over the pixels where the truth is given (a scene's truth is NaN off the object).
    Steps not done are left out.

    A leaf is a connected part of the maps (:func:`leaves`; one, the whole interior,
    without a mask); its confident pixels are those whose ``growth_sd`` is at most
    ``sd_limit`` times the step's median over the leaf (:func:`confident`; 0 keeps all).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W), optional
        The leaves (:func:`leaves`, computed when not given).

    Returns
    -------
    pandas.DataFrame
        Columns ``leaf, step, frame, time_s, mean, median, median_per_hour, p10, p90,
        n_pixels, n_uncertain`` (and ``truth, q_rel``); growth per frame, and the median
        per hour from each step's frame interval where the store knows it (the source's
        time stamps or its frame interval; NaN otherwise); ``n_pixels`` the pixels used,
        ``n_uncertain`` those left out for their ``growth_sd``.  A PlantCV-style
        observations table.
    """
    import pandas as pd

    from gridflow.metrics import q_rel
    from gridflow.sources import open_source

    store = _open_maps(maps, quantity)
    rec = open_source(truth) if truth is not None else None
    if rec is not None and quantity not in rec.truth_names:
        raise UsageError(f"{truth}: holds no {quantity!r} truth (it has "
                         f"{', '.join(rec.truth_names) or 'none'})")
    frames, done = store.frames(), store.done()
    interior = np.asarray(store.read("interior"), dtype=bool)
    if rec is not None:
        _check_truth(maps, store, truth, rec, interior.shape, frames)
    if labels is None:
        labels = leaves(maps, quantity)[0]
    has_sd = "growth_sd" in store.quantities
    times, intervals = store.step_times()
    rows = []
    for i in np.flatnonzero(done):
        m = np.asarray(store.read(quantity, i), dtype=np.float64)
        sd = np.asarray(store.read("growth_sd", i), dtype=np.float64) if has_sd else None
        t = rec.truth(int(frames[i]), names=(quantity,))[quantity] if rec is not None else None
        for leaf in range(1, int(labels.max()) + 1):
            where = (labels == leaf) & np.isfinite(m)
            if t is not None:
                # where the truth is given (a scene's truth is NaN off the object and near
                # its edge): the statistics and Q_rel over the same pixels
                where &= np.isfinite(t)
            kept = confident(sd, where, sd_limit)
            v = m[kept]
            row = {"leaf": leaf, "step": int(i), "frame": int(frames[i]),
                   "time_s": float(times[i]) if times is not None else np.nan,
                   "mean": float(v.mean()) if v.size else np.nan,
                   "median": float(np.median(v)) if v.size else np.nan,
                   "median_per_hour": (float(np.median(v)) * 3600.0 / intervals[i]
                                       if v.size and intervals is not None else np.nan),
                   "p10": float(np.percentile(v, 10)) if v.size else np.nan,
                   "p90": float(np.percentile(v, 90)) if v.size else np.nan,
                   "n_pixels": int(v.size), "n_uncertain": int(where.sum() - v.size)}
            if t is not None:
                row["truth"] = float(t[kept].mean()) if kept.any() else np.nan
                row["q_rel"] = q_rel(m, t, kept)
            rows.append(row)
    if not rows:
        raise UsageError(f"{maps}: no step is done yet" if not done.any() else
                         f"{maps}: no pixel of the interior has a {quantity} value")
    return pd.DataFrame(rows)


def _open_maps(maps, quantity: str):
    """The map series ``maps``, refused by name without ``quantity`` maps."""
    from gridflow.recording import MapStore

    store = MapStore.open(maps)
    if quantity not in store.quantities:
        raise UsageError(f"{maps}: holds no {quantity!r} maps (it has "
                         f"{', '.join(store.quantities)}); growth needs --motion affine")
    # a done step whose chunk is gone would read as NaN: an empty row, not an error
    store.check_done()
    return store


def growth_profiles(maps, *, axis: str = "x", quantity: str = "growth",
                    sd_limit: float = SD_LIMIT):
    """The growth profile along the leaf per step: at each position along ``axis`` (image
    columns for ``"x"``, rows for ``"y"``), the median of ``quantity`` across the other
    axis over the interior's confident pixels (:func:`confident`, over all leaves), and
    the pixels it used.  A grower's kymograph is this table as an image
    (:func:`draw_kymograph`).

    Returns
    -------
    pandas.DataFrame
        Columns ``step, frame, time_s, position_px, median, per_hour, n_pixels``;
        ``median`` per frame, ``per_hour`` per hour from each step's frame interval
        where the store knows it (NaN otherwise).  Positions without interior pixels are left out.
    """
    import pandas as pd

    if axis not in ("x", "y"):
        raise UsageError(f"--axis must be x or y, got {axis!r}")
    store = _open_maps(maps, quantity)
    frames, done = store.frames(), store.done()
    interior = np.asarray(store.read("interior"), dtype=bool)
    has_sd = "growth_sd" in store.quantities
    times, intervals = store.step_times()
    across = 0 if axis == "x" else 1          # the axis the median runs across
    rows = []
    for i in np.flatnonzero(done):
        m = np.asarray(store.read(quantity, i), dtype=np.float64)
        sd = np.asarray(store.read("growth_sd", i), dtype=np.float64) if has_sd else None
        m = np.where(confident(sd, interior & np.isfinite(m), sd_limit), m, np.nan)
        n = np.isfinite(m).sum(axis=across)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)       # all-NaN positions
            med = np.nanmedian(m, axis=across)
        for pos in np.flatnonzero(n > 0):
            rows.append({"step": int(i), "frame": int(frames[i]),
                         "time_s": float(times[i]) if times is not None else np.nan,
                         "position_px": int(pos), "median": float(med[pos]),
                         "per_hour": (float(med[pos] * 3600.0 / intervals[i])
                                      if intervals is not None else np.nan),
                         "n_pixels": int(n[pos])})
    if not rows:
        raise UsageError(f"{maps}: no step is done yet")
    return pd.DataFrame(rows)


def draw_kymograph(profiles, path, *, axis: str = "x", title: str = "") -> Path:
    """The growth profile along the leaf against time as an image (a kymograph), on a
    colour scale from the 2nd to the 98th percentile (a few pixels where the estimate
    breaks down do not set it), in % area per hour where the frame interval is known,
    else per frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gridflow.io import atomic_write

    hourly = profiles["per_hour"].notna().all()
    col = "per_hour" if hourly else "median"
    grid = profiles.pivot(index="frame", columns="position_px", values=col) * 100.0
    v = grid.to_numpy()
    lo, hi = np.nanpercentile(v, 2), np.nanpercentile(v, 98)
    times = (profiles.groupby("frame")["time_s"].first() / 3600.0) if hourly else None
    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
    extent = [grid.columns.min() - 0.5, grid.columns.max() + 0.5,
              (times.iloc[-1] if hourly else grid.index.max()),
              (times.iloc[0] if hourly else grid.index.min())]
    with warnings.catch_warnings():
        # one step: a kymograph one row high (matplotlib widens its limits, and warns)
        warnings.simplefilter("ignore", UserWarning)
        im = ax.imshow(v, aspect="auto", extent=extent, vmin=lo, vmax=hi, cmap="viridis",
                       interpolation="nearest")
    ax.set_xlabel(f"position along the image {axis}, px")
    ax.set_ylabel("time, h" if hourly else "frame")
    fig.colorbar(im, ax=ax, label="growth, % area per " + ("hour" if hourly else "frame")
                 + " (median across the leaf)")
    ax.set_title(title or "Growth along the leaf over time", fontsize=10)
    path = Path(path)
    with atomic_write(path) as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
    return path


def _made_from(maps) -> list:
    """The input the map series records, where it still exists (read-only; a store that
    does not open is left to :func:`growth_table` to refuse)."""
    from gridflow.recording import MapStore

    try:
        made = MapStore.open(maps).attrs["gridflow"].get("input")
    except Exception:       # noqa: BLE001 - growth_table names what is wrong with it
        return []
    return [made] if made and Path(made).exists() else []


def _check_truth(maps, store, truth, rec, shape, frames) -> None:
    """Refuse a truth that cannot be the maps' input: another image size, too few frames,
    or another recording than the one the store records (its path)."""
    if tuple(rec.shape[3:]) != tuple(shape):
        raise UsageError(f"--truth {truth}: images of {rec.shape[4]}x{rec.shape[3]} px, the "
                         f"maps of {maps} are {shape[1]}x{shape[0]}")
    if rec.truth_frame is not None or int(np.max(frames)) >= rec.frames:
        held = "one frame" if rec.truth_frame is not None else f"{rec.frames} frames"
        raise UsageError(f"--truth {truth}: holds truth of {held}; the maps' steps reach "
                         f"frame {int(np.max(frames))} (a recording with truth per frame)")
    made_from = store.attrs["gridflow"].get("input")
    if made_from and Path(made_from).resolve() != Path(truth).resolve():
        raise UsageError(f"--truth {truth}: {maps} was estimated from {made_from}; score it "
                         "against that recording's truth")


def scale_bar_length(depth: float, focal_length: float, width_px: int) -> tuple[float, float]:
    """A scale bar for an image ``width_px`` wide of a surface at ``depth`` (world units)
    seen with ``focal_length`` px: ``(length in world units, in px)``, a round length (1,
    2 or 5 times a power of ten) near a fifth of the image's width there."""
    per_px = depth / focal_length
    target = width_px * per_px / 5.0
    p = 10.0 ** np.floor(np.log10(target))
    length = max(m * p for m in (1.0, 2.0, 5.0) if m * p <= target)
    return float(length), float(length / per_px)


def _scale_bar(ax, store, step: int, where) -> None:
    """A scale bar on a growth map, at the median depth of the step's pixels ``where``
    (none where the series holds no depth)."""
    if "Z" not in store.quantities or not where.any():
        return
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    g = store.attrs["gridflow"]
    Z = float(np.nanmedian(np.asarray(store.read("Z", step), dtype=float)[where]))
    if not (np.isfinite(Z) and Z > 0):
        return
    length, px = scale_bar_length(Z, g["focal_length"], where.shape[1])
    units = (g.get("geometry") or {}).get("units") or "world units"
    ax.add_artist(AnchoredSizeBar(ax.transData, px, f"{length:g} {units}", "lower left",
                                  pad=0.3, frameon=False, size_vertical=1.5, color="k",
                                  fontproperties={"size": 7}))


def draw_growth(maps, table, fig_dir, *, times=None, quantity: str = "growth",
                sd_limit: float = SD_LIMIT) -> list[Path]:
    """The growth maps at chosen frames (a strip on one colour scale; the pixels
    :func:`confident` leaves out blank) and each leaf's growth against time (``table``
    from :func:`growth_table`): its median (robust to the few pixels where the estimate
    breaks down, which move the mean), the mean, the 10-90 % spread and the truth where
    known.

    Returns the files written (``growth_maps.png``, ``growth_series.png``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gridflow.io import atomic_write
    from gridflow.recording import MapStore

    store = MapStore.open(maps)
    fig_dir = Path(fig_dir)
    fig_dir.mkdir(parents=True, exist_ok=True)
    frames = sorted(set(table["frame"]))
    if times:
        missing = [t for t in times if t not in frames]
        if missing:
            raise UsageError(f"--times {missing}: no finished step at those frames (steps at "
                             f"{frames[0]}, {frames[1] if len(frames) > 1 else ''} ... "
                             f"{frames[-1]})")
        chosen = list(times)
    else:
        chosen = [frames[int(round(j))] for j in np.linspace(0, len(frames) - 1,
                                                             min(6, len(frames)))]
    interior = np.asarray(store.read("interior"), dtype=bool)
    per_frame = 100.0          # shown in % per frame
    imgs = []
    steps = [int(table.loc[table["frame"] == f, "step"].iloc[0]) for f in chosen]
    has_sd = "growth_sd" in store.quantities
    for i in steps:
        m = np.asarray(store.read(quantity, i), dtype=float) * per_frame
        sd = np.asarray(store.read("growth_sd", i), dtype=float) if has_sd else None
        imgs.append(np.where(confident(sd, interior & np.isfinite(m), sd_limit), m, np.nan))
    # a colour scale from the 2nd to the 98th percentile: the few pixels where the
    # estimate breaks down (texture-poor spots, the leaf's edge) do not set it
    lo = np.nanpercentile(np.concatenate([m[np.isfinite(m)] for m in imgs]), 2)
    hi = np.nanpercentile(np.concatenate([m[np.isfinite(m)] for m in imgs]), 98)
    timed = table["time_s"].notna().all()
    hours = dict(zip(table["frame"], table["time_s"] / 3600.0))
    label = (lambda f: f"frame {f} ({hours[f]:.1f} h)") if timed else (lambda f: f"frame {f}")
    fig, axes = plt.subplots(1, len(chosen), figsize=(2.6 * len(chosen) + 0.8, 3.0),
                             squeeze=False, constrained_layout=True)
    for ax, f, i, m in zip(axes[0], chosen, steps, imgs):
        im = ax.imshow(m, vmin=lo, vmax=hi, cmap="viridis")
        ax.set_title(label(f), fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        _scale_bar(ax, store, i, interior & np.isfinite(m))
    fig.colorbar(im, ax=axes[0], shrink=0.85, label="growth, % area per frame")
    fig.suptitle(f"Growth maps ({maps})", fontsize=10)
    out1 = fig_dir / "growth_maps.png"
    with atomic_write(out1) as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 3.6), constrained_layout=True)
    several = table["leaf"].nunique() > 1
    for n, (leaf, rows) in enumerate(table.groupby("leaf")):
        x = rows["time_s"] / 3600 if timed else rows["frame"]
        colour = plt.get_cmap("tab10")((n + 2) % 10)
        name = f"leaf {leaf}, " if several else ""
        ax.fill_between(x, rows["p10"] * per_frame, rows["p90"] * per_frame, alpha=0.3,
                        color=colour, label=f"{name}10-90 % of the pixels")
        ax.plot(x, rows["median"] * per_frame, color=colour, lw=1.5,
                label=f"{name}median, estimated")
        ax.plot(x, rows["mean"] * per_frame, color=colour, lw=0.8, ls=":",
                label=f"{name}mean, estimated")
        if "truth" in rows:
            ax.plot(x, rows["truth"] * per_frame, "k--", lw=1.0,
                    label="truth" if n == 0 else None)
    ax.set_xlabel("time, h" if timed else "frame")
    ax.set_ylabel("growth, % area per frame")
    ax.legend(fontsize=8, loc="best")
    ax.set_title("Growth over the leaf" + ("ves" if several else "") + " (confident pixels)",
                 fontsize=10)
    out2 = fig_dir / "growth_series.png"
    with atomic_write(out2) as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
    return [out1, out2]


@dataclass
class GrowthReport:
    """What :func:`growth_report` found and wrote.

    Attributes
    ----------
    table : pandas.DataFrame
        :func:`growth_table`.
    written : list of Path
        The figures (and the CSV) written.
    lines : list of str
        The report as text: the table, Q_rel against the truth where given, the files.
    """

    table: object
    written: list = field(default_factory=list)
    lines: list = field(default_factory=list)


def growth_report(maps, truth=None, *, fig_dir="growth", csv=None,
                  times=None, profile_csv=None, axis: str = "x",
                  sd_limit: float = SD_LIMIT) -> GrowthReport:
    """The growth of the map series ``maps`` per leaf and step (:func:`growth_table`,
    against the recording ``truth`` where given), drawn into ``fig_dir``
    (:func:`draw_growth`, the maps at ``times``) and, with ``csv``, the table written
    there.  The outputs are checked before anything is read or written; a grower reads
    the median (the mean is moved by the few pixels where the estimate breaks down).  The
    growth profile along the image ``axis`` per step (:func:`growth_profiles`) is drawn as
    a kymograph (``growth_kymograph.png``) and, with ``profile_csv``, written there.
    Everything is over the confident pixels (:func:`confident`, ``sd_limit``)."""
    from gridflow.io import atomic_write, check_output

    # the inputs: the maps, the truth, and the recording the maps were made from
    inputs = [maps] + ([truth] if truth else []) + _made_from(maps)
    if csv:
        check_output(csv, suffixes=".csv", inputs=inputs, what="--csv")
    if profile_csv:
        check_output(profile_csv, suffixes=".csv", inputs=inputs, what="--profile-csv")
    check_output(fig_dir, suffixes=None, inputs=inputs, what="--fig-dir")
    if sd_limit is None or not (sd_limit >= 0):
        raise UsageError(f"--sd-limit must be a number >= 0 (0 keeps every pixel), got "
                         f"{sd_limit}")
    labels, fragments = leaves(maps)
    table = growth_table(maps, truth, sd_limit=sd_limit, labels=labels)
    profiles = growth_profiles(maps, axis=axis, sd_limit=sd_limit)
    written = draw_growth(maps, table, fig_dir, times=times, sd_limit=sd_limit)
    written.append(draw_kymograph(profiles, Path(fig_dir) / "growth_kymograph.png",
                                  axis=axis, title=f"Growth along the leaf ({maps})"))
    if profile_csv:
        with atomic_write(profile_csv, "w") as fh:
            profiles.to_csv(fh, index=False, float_format="%.6g")
        written.append(Path(profile_csv))
    several = table["leaf"].nunique() > 1
    cols = (["leaf"] if several else []) + ["frame", "median", "mean", "p10", "p90",
                                            "n_pixels"] + (["truth", "q_rel"] if truth else [])
    lines = [table[cols].to_string(index=False, float_format=lambda v: f"{v:.3g}")]
    from gridflow.recording import MapStore

    done = MapStore.open(maps).done()
    if not done.all():
        # a series still being written (or cut short): the steps not done are not in the
        # table, and that is said
        lines.append(f"{int(done.sum())} of {done.size} steps done; the others are not in "
                     "the table (run the same gridflow estimate to finish them)")
    n_kept, n_out = table["n_pixels"].sum(), table["n_uncertain"].sum()
    lines.append(
        f"{table['leaf'].nunique()} leaf part(s) of the maps"
        + (f" ({fragments} fragment(s) under {MIN_LEAF_FRACTION:.0%} of the largest left "
           "out)" if fragments else "")
        + (f"; {n_out / max(n_kept + n_out, 1):.1%} of the pixels left out as uncertain "
           f"(growth_sd over {sd_limit:g} x the step's median; --sd-limit 0 keeps all)"
           if sd_limit else "; every pixel kept (--sd-limit 0)"))
    if truth:
        lines.append(f"Q_rel(growth) over the steps: median {table['q_rel'].median():.3g}, "
                     f"max {table['q_rel'].max():.3g}; correlation with the truth: of the "
                     f"median {table['median'].corr(table['truth']):.4f}, of the mean "
                     f"{table['mean'].corr(table['truth']):.4f}")
    if csv:
        with atomic_write(csv, "w") as fh:
            table.to_csv(fh, index=False, float_format="%.6g")
        written.append(Path(csv))
    lines += [f"wrote {f}" for f in written]
    return GrowthReport(table, written, lines)
