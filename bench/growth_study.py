"""What camera grid a growth experiment needs: the affine motion model under noise.

    python -m gridflow.bench.growth_study             # the table in bench/README.md
    python -m gridflow.bench.growth_study --seeds 0 1 2 --noise 0.01

A plane in the paper's geometry (Z0 = 100, f = 1000 px, 5 x 5 cameras, U_Z = 0.1, 192^2)
growing at 1e-3 per frame, with sigma_n = 0.01 on the unit-contrast sinusoid texture, is
estimated with the full model and affine motion for each camera spacing, window and
temporal window; the table gives Q_rel(growth) and Q_rel(U_Z) (mean and spread over the
noise seeds).  The growth is told from depth motion only by the disparity's change in
time, ``v_t ds t``, so it gains from a wider camera spacing (while the disparity stays
within the derivative filters' reach, about 1 px per camera step), a longer temporal
window and a larger window.  Each pixel is solved alone (``growth_support=0``): the
study is of what one pixel's data can tell; pooling the depth rates over the leaf
(the default, ``bench/growth_maps.py``) adds to any grid.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from gridflow.metrics import evaluate
from gridflow.estimator import estimate
from gridflow.generators import make_sinusoid

__all__ = ["study", "main"]


def study(spacings, windows, temporal, noise: float, seeds, growth: float = 1e-3):
    """Rows ``(spacing, sigma, taps, frames, temporal_radius, growth mean, growth std,
    U_Z mean, U_Z std, seconds)``."""
    rows = []
    for ds in spacings:
        for sigma, taps in windows:
            for frames, radius in temporal:
                g, u = [], []
                t0 = time.perf_counter()
                for seed in seeds:
                    sv = make_sinusoid(growth=growth, spacing=(ds, ds), frames=frames,
                                       noise=noise, seed=seed)
                    e = estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="full",
                                 motion="affine", sigma=sigma, window=taps,
                                 temporal_radius=radius, growth_support=0)
                    r = {x["quantity"]: x for x in evaluate(e.maps, sv.truth, e.interior)}
                    g.append(r["growth"]["q_rel"])
                    u.append(r["Uz"]["q_rel"])
                rows.append((ds, sigma, taps, frames, radius, np.mean(g), np.std(g),
                             np.mean(u), np.std(u), (time.perf_counter() - t0) / len(seeds)))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--spacings", type=float, nargs="+", default=[0.05, 0.1])
    a = ap.parse_args(argv)
    windows = [(8.0, 33), (16.0, 65), (24.0, 97)]
    temporal = [(9, 2), (13, 4)]
    print(f"growth 1e-3 per frame, sigma_n = {a.noise}, seeds {a.seeds}; full model, affine "
          "motion; disparity per camera step = 10 x spacing px")
    print("| spacing | sigma px (taps) | frames (temporal radius) | Q_rel(growth) | "
          "Q_rel(U_Z) | s per estimate |")
    print("|---|---|---|---|---|---|")
    for ds, sigma, taps, frames, radius, gm, gs, um, us, secs in study(
            a.spacings, windows, temporal, a.noise, a.seeds):
        print(f"| {ds:g} | {sigma:g} ({taps}) | {frames} ({radius}) | {gm:.3f} ± {gs:.3f} | "
              f"{um:.4f} ± {us:.4f} | {secs:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
