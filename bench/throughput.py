"""Throughput benchmark: the fast estimator against the straightforward baseline.

    python -m gridflow.bench.throughput                  # 512x512, three models, + scaling table
    python -m gridflow.bench.throughput --sizes 256 512  # a shorter scaling table

The baseline is ``estimate(..., method="reference")``: the structure tensor entry by entry
with separable 65-tap Gaussian correlations (scipy.ndimage), then ``numpy.linalg.eigh`` on
every pixel.  Both run in this process on the same 5x5-camera, 9-frame sinusoid volume.
Pixels per second count all H*W pixels of the reference image.  Peak memory is what
tracemalloc sees (numpy arrays and Python objects) during one call; the scaling table runs
each size in a fresh process and reports its peak resident set size (volume included).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
import tracemalloc

import numpy as np

from gridflow.estimator import estimate
from gridflow.generators import make_sinusoid


def _volume(size: int, dtype=np.float64):
    return make_sinusoid(height=size, width=size, a1=0.2, a1x=0.002, a2=-0.01,
                         noise=0.01, dtype=dtype)


def _timed(fn, repeat: int, memory: bool = True):
    """Best wall time of ``repeat`` calls, then (untimed: tracing slows numpy down) the
    tracemalloc peak of one more call."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    peak = 0
    if memory:
        tracemalloc.start()
        fn()
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return best, peak, out


def compare(size: int, models, repeat: int, baseline: bool = True) -> list[dict]:
    sv = _volume(size)
    px = size * size
    # compile the numba kernels outside the timings (cached on disk after the first run)
    estimate(sv.volume[..., :80, :80], sv.focal_length, sv.camera_spacing, model="full")
    rows = []
    for model in models:
        kw = dict(model=model)
        t_fast, m_fast, e_fast = _timed(lambda: estimate(sv.volume, sv.focal_length,
                                                         sv.camera_spacing, **kw), repeat)
        row = {"model": model, "size": size, "fast_s": t_fast, "fast_px_s": px / t_fast,
               "fast_peak_MB": m_fast / 2**20}
        if baseline:
            t_base, m_base, e_base = _timed(lambda: estimate(
                sv.volume, sv.focal_length, sv.camera_spacing, method="reference", **kw), 1)
            m = e_base.interior
            diff = max(float(np.nanmax(np.abs(e_fast[q][m] - e_base[q][m])
                                       / np.maximum(np.abs(sv.truth[q][m]), 1e-3)))
                       for q in ("Z", "Uz", "Zx"))
            row.update(base_s=t_base, base_px_s=px / t_base, base_peak_MB=m_base / 2**20,
                       ratio=t_base / t_fast, max_rel_diff=diff)
        rows.append(row)
    return rows


def _peak_rss_mb() -> float:
    """Peak resident set size of this process (VmHWM; unlike ru_maxrss it is not
    inherited across fork + exec from the parent)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _one_size(size: int) -> dict:
    """Run in a fresh process: estimate one float32 volume, report time and peak RSS."""
    sv = _volume(size, dtype=np.float32)
    estimate(sv.volume[..., :80, :80], sv.focal_length, sv.camera_spacing)   # compile
    rss_before = _peak_rss_mb()
    t0 = time.perf_counter()
    estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="full")
    dt = time.perf_counter() - t0
    return {"size": size, "seconds": dt, "px_s": size * size / dt,
            "volume_MB": sv.volume.nbytes / 2**20, "rss_before_MB": rss_before,
            "peak_rss_MB": _peak_rss_mb()}


def scaling(sizes) -> list[dict]:
    out = []
    for size in sizes:
        res = subprocess.run([sys.executable, "-m", "gridflow.bench.throughput", "--_one", str(size)],
                             capture_output=True, text=True, check=True,
                             env={**os.environ, "PYTHONWARNINGS": "ignore"})
        out.append(json.loads(res.stdout.strip().splitlines()[-1]))
        r = out[-1]
        print(f"  {size:>5} px  {r['seconds']:7.2f} s  {r['px_s'] / 1e3:8.1f} kpx/s  "
              f"volume {r['volume_MB']:7.0f} MB  peak RSS {r['peak_rss_MB']:7.0f} MB "
              f"(before estimating {r['rss_before_MB']:.0f} MB)", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--models", nargs="+", default=["bcc", "hf", "full"])
    ap.add_argument("--repeat", type=int, default=3, help="fast-path repeats (best kept)")
    ap.add_argument("--sizes", type=int, nargs="*", default=[256, 512, 1024, 2048],
                    help="scaling table sizes (empty: skip)")
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--_one", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a._one:
        print(json.dumps(_one_size(a._one)))
        return 0
    print(f"throughput on {a.size}x{a.size}, 5x5 cameras, 9 frames, {os.cpu_count()} cores")
    print(f"{'model':<6}{'baseline s':>11}{'fast s':>9}{'base kpx/s':>12}{'fast kpx/s':>12}"
          f"{'ratio':>8}{'base MB':>9}{'fast MB':>9}{'max rel diff':>14}")
    for r in compare(a.size, a.models, a.repeat, baseline=not a.no_baseline):
        if "ratio" in r:
            print(f"{r['model']:<6}{r['base_s']:>11.2f}{r['fast_s']:>9.2f}"
                  f"{r['base_px_s'] / 1e3:>12.1f}{r['fast_px_s'] / 1e3:>12.1f}{r['ratio']:>8.1f}"
                  f"{r['base_peak_MB']:>9.0f}{r['fast_peak_MB']:>9.0f}{r['max_rel_diff']:>14.1e}")
        else:
            print(f"{r['model']:<6}{'-':>11}{r['fast_s']:>9.2f}{'-':>12}"
                  f"{r['fast_px_s'] / 1e3:>12.1f}")
    if a.sizes:
        print("scaling (full model, float32 volume, one fresh process per size):")
        scaling(a.sizes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
