"""Long recordings, measured: a synthetic growth recording processed out of core.

    python -m gridflow.bench.series_bench                       # all (about 40 min on 2 cores)
    python -m gridflow.bench.series_bench --frames 60 --size 256 --compare-steps 8   # quick
    python -m gridflow.bench.series_bench --part leaf         # the POV-Ray leaf (about 15 min)
    python -m gridflow.bench.series_bench --part bands        # row bands (about 10 min)

Every run is a fresh ``gridflow`` process (as a user runs it), so its peak resident memory
(``ru_maxrss`` of the child: the recording's window, the estimator and the interpreter) is
its own.  Prints, in order:

1. **The recording**: ``gridflow record`` (``--frames`` time instances of 5 x 5 views of
   ``--size``\\ :sup:`2` px, the default rhythm), its time and size on disk.
2. **Bounded memory**: the whole series (every frame) of that recording and of one a
   quarter as long, with the default local scheduler: steps, wall and CPU time, steps per
   second, peak RSS.  The peak does not grow with the number of time instances.
3. **Where it runs**: the same ``--compare-steps`` steps with 1 and 2 local steps at once
   (threads; numba threads 2 and 1 each) and on a 2-worker ``dask.distributed``
   LocalCluster (``--connect``; single-threaded worker processes), wall time, steps per
   second, and whether each store equals the first array for array.
4. **Resume**: the same steps killed with SIGKILL half-way, then the same command: the
   steps skipped, and whether the store equals the uninterrupted one.
5. **Growth against truth**: ``gridflow growth --truth`` on the whole series: Q_rel per
   step (median, 90th percentile, max) and the correlation of the mean growth with the
   truth over time (the rhythm).
6. **The POV-Ray leaf as a recording** (``--part leaf``, or with ``all``): ``gridflow
   record-leaf`` (``--leaf-frames`` frames of 5 x 5 views of 256\\ :sup:`2` px, the
   default day of 40 frames and swinging spotlight), the whole series at the leaf
   experiment's window (sigma 8, 33 taps), and per step the median and the mean growth
   over the leaf against the truth: their relative errors (median, max over the steps),
   their correlation with the truth over time, and the per-pixel Q_rel.
7. **Row bands** (``--part bands``, or with ``all``): 4 steps of a 16-frame recording of
   ``--bands-size``\\ :sup:`2` px, whole (default budget) and under a ``--memory`` budget
   of a third of one step's modelled need (so cut into row bands), one task at a time:
   wall and CPU time, peak RSS, the bands, and the largest difference between the stores.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _gridflow(*args, **kw) -> tuple[float, float, int, subprocess.CompletedProcess]:
    """Run ``gridflow ARGS`` in a fresh process: (wall s, CPU s, peak RSS bytes, result)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    # the peak of this one child: run it under a wrapper that reports its own
    code = ("import resource, sys, runpy; sys.argv = ['gridflow'] + sys.argv[1:]\n"
            "try:\n    runpy.run_module('gridflow.bench.cli', run_name='__main__')\n"
            "except SystemExit as e:\n    code = e.code\nelse:\n    code = 0\n"
            # VmHWM, not ru_maxrss: the latter is inherited across fork + exec from the
            # parent (a benchmark that held gigabytes would show them as the child's)
            "peak = [l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM:')]\n"
            "sys.stderr.write(f'\\nPEAK_RSS_KB {peak[0]}\\n'); sys.exit(code)")
    r = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True,
                       text=True, **kw)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    peak = 0
    for line in r.stderr.splitlines():
        if line.startswith("PEAK_RSS_KB"):
            peak = int(line.split()[1]) * 1024
    if r.returncode != 0:
        raise RuntimeError(f"gridflow {' '.join(map(str, args))} failed:\n{r.stderr[-3000:]}")
    return wall, cpu, peak, r


def _arrays(path: Path) -> dict:
    import zarr

    g = zarr.open_group(str(path), mode="r")
    return {n: np.asarray(a[...]) for n, a in g.arrays()}


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f") for k in a)


def _du(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=200, help="time instances (default 200)")
    ap.add_argument("--size", type=int, default=512, help="image width = height (default 512)")
    ap.add_argument("--compare-steps", type=int, default=24,
                    help="steps of the scheduler and resume comparisons (default 24)")
    ap.add_argument("--work", default=None, help="folder for the stores (default a temporary "
                    "one, removed afterwards)")
    ap.add_argument("--part", choices=("all", "synthetic", "leaf", "bands"), default="all",
                    help="the synthetic recording (1-5), the POV-Ray leaf (6), row bands "
                         "(7), or all")
    ap.add_argument("--leaf-frames", type=int, default=60,
                    help="time instances of the leaf recording (default 60)")
    ap.add_argument("--bands-size", type=int, default=1024,
                    help="image width = height of the row-band comparison (default 1024)")
    a = ap.parse_args(argv)
    work = Path(a.work or tempfile.mkdtemp(prefix="gridflow-series-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"gridflow series benchmark: {os.cpu_count()} cores; stores in {work}", flush=True)
    try:
        if a.part in ("all", "synthetic"):
            _run(a, work)
        if a.part in ("all", "leaf"):
            _leaf(a, work)
        if a.part in ("all", "bands"):
            _bands(a, work)
    finally:
        if a.work is None:
            shutil.rmtree(work, ignore_errors=True)
    return 0


def _run(a, work: Path) -> None:
    size = ["--height", a.size, "--width", a.size]
    # 1. the recordings
    rec = work / "rec.zarr"
    short = work / "rec_short.zarr"
    print("\n1. the recording (gridflow record)")
    for path, frames in ((rec, a.frames), (short, max(12, a.frames // 4))):
        wall, cpu, peak, _ = _gridflow("record", "-o", path, "--frames", frames, *size,
                                       "--no-progress")
        print(f"   {path.name}: {frames} frames of 5x5 views of {a.size}x{a.size} px, "
              f"{_du(path) / 2**30:.2f} GiB on disk, rendered in {wall:.1f} s wall "
              f"({cpu:.1f} s CPU), peak RSS {peak / 2**20:.0f} MiB", flush=True)

    # 2. bounded memory: the whole series of each
    print("\n2. the whole series, default local scheduler (every frame)")
    print(f"   {'recording':<16}{'frames':>7}{'steps':>7}{'wall s':>9}{'CPU s':>9}"
          f"{'steps/s':>9}{'peak RSS MiB':>14}")
    for path, frames in ((short, max(12, a.frames // 4)), (rec, a.frames)):
        out = work / f"maps_{path.stem}.zarr"
        wall, cpu, peak, r = _gridflow("estimate", path, "-o", out, "--motion", "affine", "--no-progress")
        from gridflow.recording import MapStore

        steps = int(MapStore.open(out).done().sum())
        print(f"   {path.name:<16}{frames:>7}{steps:>7}{wall:>9.1f}{cpu:>9.1f}"
              f"{steps / wall:>9.3f}{peak / 2**20:>14.0f}", flush=True)

    # 3. where it runs: the same steps three ways
    first = 4
    last = first + a.compare_steps - 1
    span = ["--first", first, "--last", last, "--no-progress"]
    print(f"\n3. the same {a.compare_steps} steps (frames {first}..{last}), three ways")
    print(f"   {'where':<52}{'wall s':>9}{'CPU s':>9}{'steps/s':>9}  same store")
    ref = None
    from dask.distributed import LocalCluster

    from gridflow.pipeline.executors import worker_env

    runs = [("local threads: 1 step at once, 2 numba threads", ["--workers", "1"]),
            ("local threads: 2 steps at once, 1 numba thread each", ["--workers", "2"])]
    results = []
    for label, extra in runs:
        out = work / f"cmp_{len(results)}.zarr"
        wall, cpu, _, _ = _gridflow("estimate", rec, "-o", out, "--motion", "affine", *span, *extra)
        results.append((label, out, wall, cpu))
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0", env=worker_env(1)) as cluster:
        out = work / "cmp_cluster.zarr"
        wall, cpu, _, _ = _gridflow("estimate", rec, "-o", out, "--motion", "affine", *span, "--connect",
                                    cluster.scheduler_address)
        results.append(("dask.distributed LocalCluster, 2 workers x 1 thread", out, wall,
                        cpu))
    for label, out, wall, cpu in results:
        arrays = _arrays(out)
        ref = arrays if ref is None else ref
        note = "" if "LocalCluster" not in label else " (CPU: the client only)"
        print(f"   {label:<52}{wall:>9.1f}{cpu:>9.1f}{a.compare_steps / wall:>9.3f}  "
              f"{'yes' if _same(ref, arrays) else 'NO'}{note}", flush=True)

    # 4. resume after SIGKILL
    print("\n4. SIGKILL half-way, then the same command")
    out = work / "killed.zarr"
    cmd = [sys.executable, "-m", "gridflow.bench.cli", "estimate", str(rec), "-o", str(out),
           "--motion", "affine",
           *map(str, span), "--workers", "1"]
    whole_wall = results[0][2]
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(0.5 * whole_wall)
    p.send_signal(signal.SIGKILL)
    p.wait()
    from gridflow.recording import MapStore

    done = int(MapStore.open(out).done().sum())
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    again = time.perf_counter() - t0
    print(f"   killed after {0.5 * whole_wall:.1f} s with {done} of {a.compare_steps} steps "
          f"done; the rerun (exit {r.returncode}) took {again:.1f} s; its report: "
          f"{r.stdout.strip().splitlines()[-1] if r.stdout.strip() else r.stderr[-300:]}")
    print(f"   store equal to the uninterrupted run's: "
          f"{'yes' if _same(ref, _arrays(out)) else 'NO'}", flush=True)

    # 5. growth against truth
    print("\n5. growth against truth (gridflow growth --truth), the whole series")
    maps = work / f"maps_{rec.stem}.zarr"
    _, _, _, r = _gridflow("growth", maps, "--truth", rec, "--fig-dir", work / "figs",
                           "--csv", work / "growth.csv")
    import pandas as pd

    t = pd.read_csv(work / "growth.csv")
    print(f"   {len(t)} steps: Q_rel(growth) median {t['q_rel'].median():.4f}, 90th "
          f"percentile {t['q_rel'].quantile(0.9):.4f}, max {t['q_rel'].max():.4f}; "
          f"correlation of the mean with the truth {t['mean'].corr(t['truth']):.5f}; mean "
          f"growth over the run {t['mean'].mean():.3e} (truth {t['truth'].mean():.3e}) per "
          f"frame; figures in {work / 'figs'}", flush=True)


def _leaf(a, work: Path) -> None:
    import pandas as pd

    from gridflow.bench.cube_experiment import CUBE_SIGMA, CUBE_WINDOW

    print("\n6. the POV-Ray leaf as a recording (gridflow record-leaf)")
    rec = work / "leaf.zarr"
    wall, cpu, peak, _ = _gridflow("record-leaf", "-o", rec, "--frames", a.leaf_frames,
                                   "--cache", work / "render", "--no-progress")
    print(f"   {rec.name}: {a.leaf_frames} frames of 5x5 views of 256x256 px "
          f"({25 * a.leaf_frames} POV-Ray images), {_du(rec) / 2**30:.2f} GiB in Zarr, "
          f"{wall:.1f} s wall, {cpu:.1f} s CPU, peak RSS {peak / 2**20:.0f} MiB",
          flush=True)
    maps = work / "maps_leaf.zarr"
    wall, cpu, peak, _ = _gridflow("estimate", rec, "-o", maps, "--motion", "affine", "--sigma",
                                   f"{CUBE_SIGMA:g}", "--window", CUBE_WINDOW, "--no-progress")
    from gridflow.recording import MapStore

    steps = int(MapStore.open(maps).done().sum())
    print(f"   the whole series (sigma {CUBE_SIGMA:g}, {CUBE_WINDOW} taps, full model, affine "
          f"motion): {steps} steps "
          f"in {wall:.1f} s wall, {cpu:.1f} s CPU, {steps / wall:.3f} steps/s, peak RSS "
          f"{peak / 2**20:.0f} MiB", flush=True)
    _gridflow("growth", maps, "--truth", rec, "--fig-dir", work / "figs_leaf",
                           "--csv", work / "growth_leaf.csv")
    t = pd.read_csv(work / "growth_leaf.csv")
    for stat in ("median", "mean"):
        rel = (t[stat] / t["truth"] - 1).abs()
        print(f"   {len(t)} steps, truth {t['truth'].min():.2e} .. {t['truth'].max():.2e} per "
              f"frame: the {stat} growth over the leaf within {100 * rel.median():.1f} % of "
              f"the truth (median over the steps), {100 * rel.max():.1f} % at worst; "
              f"correlation with the truth over time {t[stat].corr(t['truth']):.4f}",
              flush=True)
    print(f"   per pixel Q_rel median {t['q_rel'].median():.2f}; figures in "
          f"{work / 'figs_leaf'}")
    print("   step  frame    median      mean     truth")
    for row in t.iloc[::max(1, len(t) // 12)].itertuples():
        print(f"   {row.step:>4}{row.frame:>7}{row.median:>10.2e}{row.mean:>10.2e}"
              f"{row.truth:>10.2e}")


def _bands(a, work: Path) -> None:
    from gridflow.estimator import temporal_reach
    from gridflow.pipeline.run import step_memory
    from gridflow.pipeline.strategies import SinglePass
    from gridflow.recording import MapStore
    from gridflow.sources import open_source

    size = a.bands_size
    print(f"\n7. row bands: the same steps whole and under a budget a step does not fit "
          f"({size}^2 px)")
    rec = work / "rec_bands.zarr"
    # translation: the affine model's pooled rates reach farther than a band of a 1024^2
    # image could save (band_halo), so it is estimated in whole steps only
    _gridflow("record", "-o", rec, "--frames", 16, "--height", size, "--width", size,
              "--no-progress")
    strategy = SinglePass(("full",), {"motion": "translation"})
    frames = 2 * temporal_reach(strategy.estimator_settings) + 1
    need = step_memory(open_source(rec).shape, frames, itemsize=4, strategy=strategy)
    budget = need / 3 / 2**30
    span = ["--first", 4, "--last", 7, "--workers", 1, "--no-progress"]
    print(f"   one step ({frames} frames of 5x5 views of {size}^2 px, float32, translation) needs "
          f"{need / 2**30:.2f} GiB by the planner's model; the banded run's budget "
          f"(--memory) is a third: {budget:.2f} GiB")
    print(f"   {'run (4 steps, one task at a time)':<38}{'wall s':>9}{'CPU s':>9}"
          f"{'peak RSS MiB':>14}  bands")
    stores = {}
    for label, extra in (("whole steps", []), ("row bands (--memory)", ["--memory", budget])):
        out = work / f"bands_{len(stores)}.zarr"
        wall, cpu, peak, _ = _gridflow("estimate", rec, "-o", out, "--motion", "translation",
                                       *span, *extra)
        st = MapStore.open(out)
        stores[label] = _arrays(out)
        print(f"   {label:<38}{wall:>9.1f}{cpu:>9.1f}{peak / 2**20:>14.0f}  "
              f"{len(st.bands())} of {st.band_rows} rows", flush=True)
    x, y = stores.values()
    worst = max((float(np.nanmax(np.abs(x[q] - y[q]) / np.nanmax(np.abs(x[q])))), q)
                for q in st.quantities if np.isfinite(x[q]).any())
    print(f"   largest difference between the stores: {worst[0]:.1e} of the quantity's "
          f"largest value ({worst[1]}); interior the same: "
          f"{np.array_equal(x['interior'], y['interior'])}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
