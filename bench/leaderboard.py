"""The leaderboard: per suite, the built-in models and the peers ranked, scored alike.

    python -m gridflow.bench.leaderboard                 # make figures runs this

Each suite is a shipped sweep spec (``bench/sweeps/leaderboard_*.toml``) whose methods are
gridflow (its models and motions) and the peers as methods of the benchmark's interface
(:mod:`gridflow.bench.peer_methods`); it runs as ``gridflow sweep`` runs it
(:func:`gridflow.bench.sweep.run_sweep`), so every entry is scored by the same code over
the same pixels.  An entry's score per quantity is the median over the suite's points of
Eq. 22 (``q``: the relative error where the truth keeps one sign, else the absolute
error), its worst point beside it; entries are ranked by the suite's main quantity.
Writes ``results/leaderboard.csv`` and ``fig_leaderboard.png``; the CSV and the figure
are the same, to the byte, on every run (no timings in them: each sweep's wall times
stay in the sweep's ``.times.csv``).  To put your method on it: ``gridflow sweep
leaderboard_growth -o mine.csv --method gridflow --method MODULE:FUNCTION``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["SUITES", "run", "ranking", "table", "main"]

# suite (a shipped spec) -> the quantity its entries are ranked by, and those shown
SUITES = {"leaderboard_depth": ("Z", ("Z", "Uz", "Ux")),
          "leaderboard_growth": ("growth", ("growth", "Uz", "Z"))}


def run(work=None, *, progress: bool = True):
    """Every suite's sweep (in ``work``, a temporary folder by default).

    Returns
    -------
    pandas.DataFrame
        The sweeps' rows (:data:`gridflow.bench.sweep.COLUMNS`), all suites.
    """
    import pandas as pd

    from .spec import SweepSpec
    from .sweep import run_sweep

    frames = []
    with tempfile.TemporaryDirectory(prefix="leaderboard-", dir=work) as tmp:
        for suite in SUITES:
            frames.append(run_sweep(SweepSpec.from_toml(suite), Path(tmp) / f"{suite}.csv",
                                    progress=progress))
    return pd.concat(frames, ignore_index=True)


def _entry(r) -> str:
    """An entry's name: gridflow's model and motion, or the method's function name."""
    if r.method == "gridflow":
        return f"gridflow {r.model}" + (f" ({r.motion})" if r.motion != "translation" else "")
    return str(r.method).rsplit(":", 1)[-1]


def ranking(rows):
    """Per suite, entry and shown quantity: the median and the worst ``q`` over the
    points, the rank by the suite's main quantity (1 the best: the lowest median, ties
    by the worst point; entries without it last).

    Returns
    -------
    pandas.DataFrame
        Columns ``suite, rank, entry, method, quantity, median_q, worst_q, measure,
        n_points``.
    """
    import pandas as pd

    df = rows.copy()
    df["entry"] = [_entry(r) for r in df.itertuples()]
    # two methods of one function name: their full names
    clash = df.groupby("entry").method.nunique()
    clash = set(clash[clash > 1].index)
    df["entry"] = [r.method if r.entry in clash else r.entry for r in df.itertuples()]
    # a point where a method gave no score counts as its worst: a method with values at
    # few points does not rank on those alone
    df["q"] = df["q"].fillna(np.inf)
    out = []
    for suite, (main, shown) in SUITES.items():
        d = df[(df.sweep == suite) & df.quantity.isin(shown)]
        g = d.groupby(["entry", "method", "quantity"], sort=False)
        s = g.agg(median_q=("q", "median"), worst_q=("q", "max"),
                  measure=("measure", "first"), n_points=("q", "size")).reset_index()
        # by the median, ties by the worst point, then by name
        key = s[s.quantity == main].set_index("entry")[["median_q", "worst_q"]]
        entries = sorted(s.entry.unique(), key=lambda e: (
            e not in key.index, *(key.loc[e] if e in key.index else (np.inf, np.inf)), e))
        rank = {e: i + 1 for i, e in enumerate(entries)}
        s["rank"] = s.entry.map(rank)
        s["suite"] = suite
        s["order"] = s.quantity.map({q: i for i, q in enumerate(shown)})
        out.append(s.sort_values(["rank", "order"]).drop(columns="order"))
    return pd.concat(out, ignore_index=True)[["suite", "rank", "entry", "method", "quantity",
                                              "median_q", "worst_q", "measure", "n_points"]]


def table(rank) -> str:
    """Markdown: per suite, the entries in rank order, each shown quantity's median Eq. 22
    over the points (the worst point's in brackets)."""
    out = []
    for suite, (main, shown) in SUITES.items():
        d = rank[rank.suite == suite]
        out += [f"**{suite}** (ranked by {main}; Eq. 22 median over "
                f"{int(d.n_points.max())} points, worst in brackets)", "",
                "| rank | entry | " + " | ".join(shown) + " |",
                "|---|---|" + "---|" * len(shown)]
        for (r, e), g in d.groupby(["rank", "entry"], sort=True):
            cells = []
            for q in shown:
                v = g[g.quantity == q]
                cells.append(f"{v.median_q.iloc[0]:.3g} ({v.worst_q.iloc[0]:.3g})"
                             if len(v) else "–")
            out.append(f"| {r} | {e} | " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def figure(rank):
    """One figure, a panel per suite: each entry's median Eq. 22 of the suite's main
    quantity (log scale), best at the top, the worst point as a tick."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(SUITES), figsize=(5.2 * len(SUITES), 3.2),
                             constrained_layout=True)
    for ax, (suite, (main, _)) in zip(np.atleast_1d(axes), SUITES.items()):
        d = rank[(rank.suite == suite) & (rank.quantity == main)].sort_values("rank")
        y = np.arange(len(d))[::-1]
        ax.barh(y, d.median_q, color=["tab:green" if m == "gridflow" else "tab:grey"
                                      for m in d.method])
        ax.plot(d.worst_q, y, "k|", ms=10, label="worst point")
        ax.set_yticks(y, d.entry, fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel(f"Eq. 22 of {main}, median over the points")
        ax.set_title(suite, fontsize=10)
        ax.legend(fontsize=7, loc="lower right")
    return fig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--csv", default="results/leaderboard.csv")
    ap.add_argument("--fig-dir", default="results/figures")
    ap.add_argument("--work", default=None, help="where the suites' sweeps run (default a "
                    "temporary folder)")
    ap.add_argument("--write-doc", metavar="MD", help="rewrite the leaderboard block of "
                    "this markdown file (bench/README.md)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    from gridflow.io import atomic_write, check_output

    check_output(a.csv, suffixes=".csv", what="--csv")
    check_output(a.fig_dir, suffixes=None, what="--fig-dir")
    print(f"the leaderboard: {len(SUITES)} suites, gridflow and the peers (about a minute "
          "on 2 cores) ...", file=sys.stderr, flush=True)
    rank = ranking(run(a.work, progress=not a.no_progress))
    with atomic_write(a.csv, "w") as fh:
        rank.to_csv(fh, index=False, float_format="%.6g")
    fig = figure(rank)
    Path(a.fig_dir).mkdir(parents=True, exist_ok=True)
    png = Path(a.fig_dir) / "fig_leaderboard.png"
    with atomic_write(png) as fh:
        # no software version in the file: the same bytes wherever it is made
        fig.savefig(fh, format="png", dpi=110, metadata={"Software": None})
    print(table(rank))
    print(f"wrote {a.csv}, {png}")
    if a.write_doc:
        from .markdown import rewrite_bench_block

        print(rewrite_bench_block(a.write_doc, "leaderboard", "leaderboard", table(rank)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
