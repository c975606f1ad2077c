"""Growth maps on leaves that grow unevenly: gridflow beside the 2-D divergence plant labs use.

    python -m gridflow.bench.growth_maps                  # the table in bench/README.md
    python -m gridflow.bench.growth_maps --csv results/growth_maps.csv --seeds 0 1

A plane in the paper's geometry (``Z0 = 100``, ``f = 1000`` px, 5 x 5 cameras, spacing
0.05, 256^2 px, 17 frames) whose growth falls linearly along the leaf from 2e-3 per frame
at its base (left) to 2e-4 at its tip (right) (``make_sinusoid(growth_x=...)``: exact ray
casting), textured 0.5 +- 0.3 with sensor noise sigma_n = 0.003 (an SNR of about 50).
Five leaves: still, rising 0.5 % of its distance per frame, tilting 2e-3 rad per frame
(about the image's x axis), slanted (``Z_X = 0.3``), and growing 10 x slower.  Each is
estimated with the default command's settings (``gridflow estimate VOL.npz --motion
affine``: the full model, affine motion, pooled depth rates) and, for comparison, with
each pixel solved alone (``--growth-support 0``), and by the divergence of a 2-D optical
flow of the centre camera (OpenCV's Farneback and scikit-image's iterative Lucas-Kanade
between frames k-6 and k+6, the frames gridflow's window spans, the divergence averaged
over gridflow's window, a Gaussian of 16 px), the plant labs' method. Scores over the
estimate's interior: the per-pixel median relative error, and the growth profile along
the leaf (the median over rows per column) against the truth's: correlation and slope;
for gridflow, how its ``growth_sd`` describes the errors (the fractions within one and
two sd, and their rank correlation).  ``--method`` / ``--method-cmd`` put anyone's method
beside them (:mod:`gridflow.bench.methods`), scored alike.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

__all__ = ["LEAVES", "make_leaf", "score", "divergence_2d", "run", "main"]

_W = 256
_SPAN = _W * 100.0 / 1000.0                      # the image's width on the plane, world units
_BASE, _TIP = 2e-3, 2e-4                          # growth per frame at the left and right edge
_PEER_FRAMES = 6                                  # the peers' flow: frames k - 6 and k + 6

# name -> (parameters besides the uneven growth, growth scale)
LEAVES = {
    "still": ({}, 1.0),
    "rising": ({"U_Z": 0.5}, 1.0),
    "tilting": ({"G_ZY": 2e-3, "G_YZ": -2e-3}, 1.0),
    "slanted": ({"Z_X": 0.3}, 1.0),
    "slow": ({}, 0.1),
}


def make_leaf(name: str, noise: float = 0.003, seed: int = 0):
    """The leaf ``name`` of :data:`LEAVES` as a :class:`gridflow.generators.SyntheticVolume`
    (shape (17, 5, 5, 256, 256)); its growth at material ``Xm`` is ``g0 + b Xm``."""
    from gridflow.generators import make_sinusoid

    extra, scale = LEAVES[name]
    g0 = scale * (_BASE + _TIP) / 2.0
    b = scale * (_TIP - _BASE) / _SPAN
    p = dict(growth=g0, growth_x=b, U_Z=0.0, frames=17, height=_W, width=_W, offset=0.5,
             amplitude=0.3, wavelength_x=8.0, wavelength_y=12.0, noise=noise, seed=seed)
    p.update(extra)
    return make_sinusoid(**p)


def score(growth: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> dict:
    """Per-pixel median relative error and the profile's correlation and slope.

    Parameters
    ----------
    growth, truth : ndarray, shape (H, W)
        Estimated and true growth, per frame.
    mask : ndarray of bool, shape (H, W)
        Pixels scored (the estimate's interior).
    """
    ok = mask & np.isfinite(growth)
    if ok.sum() < 2:            # nothing (or one pixel) to score: no profile either
        return {"median_rel_error": np.nan, "profile_corr": np.nan, "profile_slope": np.nan,
                "coverage": float(ok.sum() / max(mask.sum(), 1))}
    rel = np.abs(growth - truth)[ok] / np.abs(truth[ok])
    cols = np.nonzero(ok.any(0))[0]
    est = np.array([np.median(growth[ok[:, c], c]) for c in cols])
    tru = np.array([np.median(truth[ok[:, c], c]) for c in cols])
    two = cols.size >= 2                  # a profile needs two columns
    return {"median_rel_error": float(np.median(rel)),
            "profile_corr": float(np.corrcoef(tru, est)[0, 1]) if two else np.nan,
            "profile_slope": float(np.polyfit(tru, est, 1)[0]) if two else np.nan,
            "coverage": float(ok.sum() / mask.sum())}


def uncertainty(growth, sd, truth, mask) -> dict:
    """How the estimate's own standard deviation ``sd`` (``growth_sd``) describes its
    errors: the fractions of pixels within one and two ``sd`` of the truth (68 % and 95 %
    for a calibrated Gaussian one) and the rank correlation of ``sd`` with the error."""
    from scipy.stats import spearmanr

    ok = mask & np.isfinite(growth) & np.isfinite(sd)
    if ok.sum() < 2:
        return {"within_1sd": np.nan, "within_2sd": np.nan, "rank_corr_sd_error": np.nan}
    err = np.abs(growth - truth)[ok]
    return {"within_1sd": float(np.mean(err <= sd[ok])),
            "within_2sd": float(np.mean(err <= 2 * sd[ok])),
            "rank_corr_sd_error": float(spearmanr(sd[ok], err)[0])}


def divergence_2d(flow: dict, sigma: float = 16.0) -> np.ndarray:
    """``d(flow_x)/dx + d(flow_y)/dy`` (central differences) averaged over a Gaussian of
    ``sigma`` px (gridflow's window), per frame: what a 2-D tool reports as growth."""
    from scipy.ndimage import gaussian_filter

    div = np.gradient(flow["flow_x"], axis=1) + np.gradient(flow["flow_y"], axis=0)
    return gaussian_filter(div, sigma, mode="nearest")


def run(seeds=(0, 1), noise: float = 0.003, leaves=tuple(LEAVES), progress=print,
        methods=(), method_cmds=()) -> list:
    """Rows ``dict(leaf, seed, method, median_rel_error, profile_corr, profile_slope,
    coverage, seconds)``.  ``methods`` and ``method_cmds`` (:mod:`gridflow.bench.methods`:
    ``MODULE:FUNCTION``, entry points, programs) run on the same volumes and are scored
    alike, on their ``growth`` map (and its ``growth_sd``, where they return one)."""
    from gridflow.estimator import estimate

    from .methods import MethodError, resolve_methods, run_method
    from .peers import flow_farneback, flow_ilk

    others = resolve_methods(methods, method_cmds)

    methods = {
        "gridflow (default)": lambda sv: estimate(
            sv.volume, sv.focal_length, sv.camera_spacing, motion="affine"),
        "gridflow per pixel": lambda sv: estimate(
            sv.volume, sv.focal_length, sv.camera_spacing, motion="affine",
            growth_support=0),
    }
    peers = {"2-D Farneback divergence": flow_farneback,
             "2-D Lucas-Kanade divergence": flow_ilk}
    rows = []
    for leaf in leaves:
        for seed in seeds:
            sv = make_leaf(leaf, noise, seed)
            k = sv.params.ref_frame
            truth = sv.truth["growth"]
            mask = None
            for name, fn in methods.items():
                t0 = time.perf_counter()
                e = fn(sv)
                secs = time.perf_counter() - t0
                mask = e.interior
                rows.append(dict(leaf=leaf, seed=seed, method=name, seconds=secs,
                                 **score(e["growth"], truth, mask),
                                 **uncertainty(e["growth"], e["growth_sd"], truth, mask)))
            for name, fn in peers.items():
                t0 = time.perf_counter()
                # the frames gridflow's window spans (k +- 6), the divergence over its
                # window: the peer sees the same data and support
                div = divergence_2d(fn(sv.volume, k, r=_PEER_FRAMES))
                secs = time.perf_counter() - t0
                # scored on gridflow's interior: the same pixels for every method
                rows.append(dict(leaf=leaf, seed=seed, method=name, seconds=secs,
                                 **score(div, truth, mask)))
            for m in others:
                maps, secs = run_method(m, sv.volume, sv.focal_length, sv.camera_spacing,
                                        principal_point=sv.principal_point)
                if "growth" not in maps:
                    raise MethodError(f"method {m.name}: returned no growth map (it "
                                      f"returned {', '.join(maps)})")
                extra = (uncertainty(maps["growth"], maps["growth_sd"], truth, mask)
                         if "growth_sd" in maps else {})
                rows.append(dict(leaf=leaf, seed=seed, method=m.name, seconds=secs,
                                 **score(maps["growth"], truth, mask), **extra))
            progress(f"  {leaf}, seed {seed}: done", flush=True)
    return rows


def table(rows) -> str:
    """The markdown table: per leaf and method, the mean over seeds (and the range of
    the per-pixel error)."""
    import pandas as pd

    df = pd.DataFrame(rows)
    out = ["| leaf | method | per-pixel median relative error (range over seeds) | "
           "profile correlation | profile slope | within 1 / 2 growth_sd (range) | "
           "rank corr. growth_sd vs error |",
           "|---|---|---|---|---|---|---|"]
    for (leaf, method), g in df.groupby(["leaf", "method"], sort=False):
        if g.within_1sd.notna().all():
            cal = (f"{g.within_1sd.mean():.2f} ({g.within_1sd.min():.2f}-"
                   f"{g.within_1sd.max():.2f}) / {g.within_2sd.mean():.2f}")
            rank = f"{g.rank_corr_sd_error.mean():.2f}"
        else:
            cal = rank = "-"
        out.append(f"| {leaf} | {method} | {g.median_rel_error.mean():.3f} "
                   f"({g.median_rel_error.min():.3f}-{g.median_rel_error.max():.3f}) | "
                   f"{g.profile_corr.mean():.3f} | {g.profile_slope.mean():.2f} | {cal} | "
                   f"{rank} |")
    return "\n".join(out)


def times_table(rows) -> str:
    """Wall seconds per estimate, per leaf and method (mean over seeds): printed and
    written apart from the scores, which must be the same to the byte on every machine."""
    import pandas as pd

    df = pd.DataFrame(rows)
    out = ["| leaf | method | s per estimate |", "|---|---|---|"]
    for (leaf, method), g in df.groupby(["leaf", "method"], sort=False):
        out.append(f"| {leaf} | {method} | {g.seconds.mean():.2f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--noise", type=float, default=0.003)
    ap.add_argument("--csv", default=None, help="also write the rows to this CSV")
    ap.add_argument("--method", dest="methods", action="append", default=[],
                    metavar="METHOD", help="also run this method (MODULE:FUNCTION or an "
                    "entry point of gridflow.methods; the README, 'Benchmark your own "
                    "method'), scored on its growth map; repeat for several")
    ap.add_argument("--method-cmd", dest="method_cmds", action="append", default=[],
                    metavar="CMD", help="also run this program ('PROG {input} {output}')")
    ap.add_argument("--leaves", nargs="+", choices=list(LEAVES), default=list(LEAVES))
    ap.add_argument("--write-doc", default=None, metavar="MD",
                    help="rewrite the growth-maps block of this markdown file "
                         "(bench/README.md) with the table")
    a = ap.parse_args(argv)
    print(f"growth maps: 5 leaves x {len(a.seeds)} noise draws (sigma_n = {a.noise}), "
          "256^2, 5 x 5 cameras, 17 frames; about 20 s a leaf ...", flush=True)
    rows = run(a.seeds, a.noise, leaves=tuple(a.leaves), methods=a.methods,
               method_cmds=a.method_cmds)
    print(table(rows))
    print(times_table(rows))
    if a.csv:
        from pathlib import Path

        import pandas as pd

        from gridflow.io import atomic_write

        df = pd.DataFrame(rows)
        # the wall times apart (NAME.times.csv, as the sweeps'): they change with the
        # machine and its load, the scores must not
        times = Path(a.csv).with_suffix(".times.csv")
        with atomic_write(a.csv, "w") as fh:
            df.drop(columns="seconds").to_csv(fh, index=False, float_format="%.6g")
        with atomic_write(times, "w") as fh:
            df[["leaf", "seed", "method", "seconds"]].to_csv(fh, index=False,
                                                             float_format="%.6g")
        print(f"wrote {a.csv} and {times}")
    if a.write_doc:
        from .markdown import rewrite_block

        cmd = ("python -m gridflow.bench.growth_maps --csv results/growth_maps.csv "
               f"--seeds {' '.join(map(str, a.seeds))} --noise {a.noise:g}")
        rewrite_block(a.write_doc, "growth-maps",
                      f"Generated by `{cmd}` (made by `make figures`):\n\n{table(rows)}")
        print(f"rewrote the growth-maps block of {a.write_doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
