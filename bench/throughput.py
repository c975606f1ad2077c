"""Throughput benchmark: the fast estimator against an honest straightforward baseline.

    python -m gridflow.bench.throughput                 # all sections (about 12 minutes)
    python -m gridflow.bench.throughput --sections inprocess
    python -m gridflow.bench.throughput --sizes 256 512 --cli-size 512

The baseline is ``estimate(..., method="reference")``, the plain implementation: the same
camera/time and 5-tap spatial filtering, then for each of the ``n (n + 1) / 2`` tensor
entries the frames summed and one separable 65-tap correlation (``scipy.ndimage.
correlate1d``), then ``numpy.linalg.eigh`` on every pixel and the vectorised numpy
disentangling.  It shares no product, pass or solver with the fast path.

Sections (each prints its table):

``inprocess``
    Both paths on the same 5x5-camera, 9-frame sinusoid volume in this process, in
    ``--repeat`` rounds of one fast call and one baseline call (interleaved, so that both
    see the same machine: on a shared machine its speed drifts by 20 % and more): wall
    time (best of the rounds, the same statistic for both) and CPU time (user + system
    of this process over that call) of each, their ratios, the median of the rounds'
    own wall ratios beside them, and the largest difference between the answers.
``cli``
    ``gridflow estimate`` as a user runs it (a fresh process: start, imports, load,
    estimate, save) on a tiny volume (the fixed cost) and at ``--cli-size`` against the
    baseline in this process on the same volume.
``zoom``
    What the zoom-blur correction costs: the fast path with and without it
    (``zoom_correction``), interleaved, best wall and its CPU time of ``--repeat``
    rounds, on the same volume, one model at a time and the three together.
``stages``
    Where the default fast path's time goes, per model (the full model, and with the
    affine motion model), zoom-blur correction on: the wall time of each of its stages
    (the signals: camera/time sums and x/y filtering; the tensor: the products and their
    FFT smoothing; the null space: the per-pixel solver; the affine solve; the rest:
    disentangling, pooling, checks), measured around the backend's calls, in
    ``--repeat`` runs: each stage's share of the run's wall time and the spread over the
    runs.
``recording``
    A recording as a grower runs it: ``gridflow record`` (``--rec-frames`` frames of 5 x 5
    views at ``--size``, sensor noise 0.003), then ``gridflow estimate REC -o MAPS.zarr
    --every 1`` over ``--rec-steps`` steps, each motion model, ``--repeat`` times, each a
    fresh process on the default local scheduler: the run's own steps per second (as it
    prints them: over its run, the store's preparation included, the process's start-up
    and imports not), the process's wall
    and CPU time and its peak resident memory; then ``--rec-long`` steps from the same
    first step, and the rate of a long run: the steps beyond the first ``--rec-steps``
    over the difference of the two runs' times, in each round, the short run first (a
    run's first steps compute every frame of their windows, each later step one new
    frame: a grower's recording of 1440 steps should run at about this rate; a
    difference of two runs also takes in the machine's drift between them); and one
    step's window estimated by the baseline in this process, against which a long
    run's step (or, without long runs, the short run's) is set.
``scaling``
    The fast path alone at each of ``--sizes``, each in a fresh process: time, pixels per
    second over the *interior* (pixels with a full window: the border is 46 % of a 256^2
    image) and over the whole image, and peak resident memory (VmHWM, volume included).

Threads: the fast path runs its numba kernels on ``numba.get_num_threads()`` threads and
its FFTs with that many ``scipy.fft`` workers; the baseline's correlations and ``eigh`` are
single-threaded (``scipy.ndimage`` and numpy's batched LAPACK calls do not thread).  The
6 short signal filters, identical in both paths, run on a small thread pool.  The CPU
time beside each wall time shows what each path costs in total.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gridflow.estimator import MODELS, estimate
from gridflow.estimator.models import AFFINE, TRANSLATION
from gridflow.generators import make_sinusoid

SECTIONS = ("inprocess", "cli", "scaling", "zoom", "stages", "recording")


def _volume(size: int, dtype=np.float64):
    return make_sinusoid(height=size, width=size, a1=0.2, a1x=0.002, a2=-0.01,
                         noise=0.01, dtype=dtype)


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def _timed(fn, repeat: int):
    """Best wall time of ``repeat`` calls and the CPU time of that same call."""
    best, cpu, out = float("inf"), float("nan"), None
    for _ in range(repeat):
        c0, t0 = _cpu(), time.perf_counter()
        out = fn()
        dt, dc = time.perf_counter() - t0, _cpu() - c0
        if dt < best:
            best, cpu = dt, dc
    return best, cpu, out


def _threads() -> int:
    import numba

    return numba.get_num_threads()


def _max_rel_diff(a, b, truth, mask) -> float:
    return max(float(np.nanmax(np.abs(a[q][mask] - b[q][mask])
                               / np.maximum(np.abs(truth[q][mask]), 1e-3)))
               for q in ("Z", "Uz", "Zx"))


def inprocess(size: int, models, repeat: int, affine=("full",)) -> list[dict]:
    """``models`` with the translation model, and ``affine`` with the affine motion
    model (on the same volume; its answers are compared like the others')."""
    sv = _volume(size)
    # load (or compile) the numba kernels outside the timings
    estimate(sv.volume[..., :160, :160], sv.focal_length, sv.camera_spacing, model="full")
    rows = []
    cases = [(m, TRANSLATION) for m in models] + [(m, AFFINE) for m in affine]
    for model, motion in cases:
        run = lambda method: estimate(sv.volume, sv.focal_length, sv.camera_spacing,  # noqa: E731
                                      model=model, method=method, motion=motion.name)
        fast, base = [], []
        for _ in range(repeat):
            fast.append(_timed(lambda: run("fast"), 1))
            base.append(_timed(lambda: run("reference"), 1))
        fw, fc, ef = min(fast, key=lambda r: r[0])
        bw, bc, eb = min(base, key=lambda r: r[0])
        n_int = int(eb.interior.sum())
        rows.append(dict(model=model if motion is TRANSLATION else f"{model} ({motion.name})",
                         size=size, base_wall=bw, base_cpu=bc, fast_wall=fw,
                         fast_cpu=fc, wall_ratio=bw / fw, cpu_ratio=bc / fc,
                         round_ratio=float(np.median([b[0] / f[0] for f, b in zip(fast, base)])),
                         fast_interior_kpx_s=n_int / fw / 1e3,
                         max_rel_diff=_max_rel_diff(ef, eb, sv.truth, eb.interior)))
    return rows


def zoom(size: int, models, repeat: int) -> list[dict]:
    """The fast path with and without the zoom-blur correction, per model and for all
    models together (``estimate_models``), interleaved rounds."""
    from gridflow.estimator import estimate_models

    sv = _volume(size)
    estimate(sv.volume[..., :160, :160], sv.focal_length, sv.camera_spacing, model="full")
    rows = []
    for group in [(m,) for m in models] + [tuple(models)]:
        times = {True: [], False: []}
        for _ in range(repeat):
            for zc in (False, True):
                times[zc].append(_timed(lambda: estimate_models(
                    sv.volume, sv.focal_length, sv.camera_spacing, models=group,
                    zoom_correction=zc), 1))
        off, on = (min(times[z], key=lambda r: r[0]) for z in (False, True))
        rows.append(dict(models=",".join(group), off_wall=off[0], off_cpu=off[1],
                         on_wall=on[0], on_cpu=on[1], ratio=on[0] / off[0]))
    return rows


def stages(size: int, repeat: int) -> list[dict]:
    """Seconds in each stage of the default fast path (numba backend) per run, by timing
    the backend's ``signals``, ``tensor``, ``null_space`` and ``solve_affine`` calls."""
    from gridflow.estimator import backends

    sv = _volume(size)
    estimate(sv.volume[..., :160, :160], sv.focal_length, sv.camera_spacing, model="full")
    spent = {}
    cls = backends.NumbaBackend
    saved = {name: cls.__dict__.get(name)
             for name in ("signals", "tensor", "null_space", "null_space_parts")}

    def timed(name, fn):
        def wrapper(*args, **kw):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kw)
            finally:
                spent[name] = spent.get(name, 0.0) + time.perf_counter() - t0
        return wrapper

    def timed_parts(name, fn):
        # a generator: the time inside each of its steps, not between them
        def wrapper(*args, **kw):
            parts = timed(name, fn)(*args, **kw)
            while True:
                try:
                    part = timed(name, next)(parts)
                except StopIteration:
                    return
                yield part
        return wrapper

    rows = []
    init = cls.__init__

    def patched_init(self):
        init(self)
        self.solve_affine = timed("affine solve", self.solve_affine)
    try:
        for name in saved:
            wrap = timed_parts if name == "null_space_parts" else timed
            setattr(cls, name, wrap(name.replace("_parts", ""), getattr(cls, name)))
        cls.__init__ = patched_init
        for motion in (TRANSLATION.name, AFFINE.name):
            for run in range(repeat):
                spent.clear()
                t0 = time.perf_counter()
                estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="full",
                         motion=motion)
                wall = time.perf_counter() - t0
                parts = {"signals": spent.get("signals", 0.0),
                         "tensor": spent.get("tensor", 0.0),
                         "null space": spent.get("null_space", 0.0),
                         "affine solve": spent.get("affine solve", 0.0)}
                parts["rest"] = wall - sum(parts.values())
                rows.append(dict(motion=motion, run=run, wall=wall, **parts))
    finally:
        cls.__init__ = init
        for name, fn in saved.items():
            setattr(cls, name, fn)
    return rows


def _cli(args, env=None) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "gridflow.bench.cli", *args], check=True,
                   capture_output=True, text=True, env=env)
    return time.perf_counter() - t0


def cli(size: int, repeat: int) -> dict:
    from gridflow.io import save_volume

    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    with tempfile.TemporaryDirectory() as tmp:
        tiny = Path(tmp) / "tiny.npz"
        save_volume(tiny, make_sinusoid(height=24, width=24, frames=9))
        fixed = min(_cli(["estimate", str(tiny), "--sigma", "2", "--window", "9", "-o",
                          str(Path(tmp) / f"t{i}.npz")], env) for i in range(repeat))
        big = Path(tmp) / "big.npz"
        sv = _volume(size, dtype=np.float32)
        save_volume(big, sv)
        cli_s = min(_cli(["estimate", str(big), "-o", str(Path(tmp) / f"e{i}.npz")], env)
                    for i in range(repeat))
        bw, bc, _ = _timed(lambda: estimate(sv.volume, sv.focal_length, sv.camera_spacing,
                                            method="reference"), 1)
    return dict(size=size, fixed_s=fixed, cli_s=cli_s, base_wall=bw, base_cpu=bc,
                ratio=bw / cli_s)


def recording(size: int, frames: int, steps: int, repeat: int,
              long_steps: int | None = None) -> list[dict]:
    """``gridflow estimate REC --every 1`` per motion model: see the module docstring.
    Each round runs ``steps`` steps and, where ``long_steps`` is given, then
    ``long_steps`` from the same first step."""
    import re

    from gridflow.bench.series_bench import _gridflow
    from gridflow.estimator import temporal_reach
    from gridflow.estimator.settings import EstimatorSettings
    from gridflow.sources import open_source

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "rec.zarr"
        _gridflow("record", "--frames", frames, "--height", size, "--width", size,
                  "--noise", 0.003, "-o", rec, "--no-progress")
        src = open_source(rec)
        for motion in (TRANSLATION.name, AFFINE.name):
            reach = temporal_reach(EstimatorSettings(motion=motion))
            first = reach

            def run(n, name):
                out = Path(tmp) / name
                wall, cpu, peak, r = _gridflow(
                    "estimate", rec, "--every", 1, "--first", first, "--last", first + n - 1,
                    "--motion", motion, "-o", out, "--no-progress")
                m = re.search(r"(\d+) now in ([\d.]+) s, ([\d.]+) steps/s", r.stdout)
                if m is None or int(m.group(1)) != n:
                    raise RuntimeError(f"no rate of {n} steps in gridflow's report:\n"
                                       f"{r.stdout}")
                shutil.rmtree(out)
                # the run's seconds from its rate (printed to 3 decimals; its seconds to 1)
                rate = float(m.group(3))
                return dict(steps=n, run_s=n / rate, rate=rate, wall=wall, cpu=cpu,
                            peak_mb=peak / 2**20)
            runs, longs = [], []
            for i in range(repeat):
                runs.append(run(steps, f"{motion}{i}.zarr"))
                if long_steps:
                    longs.append(run(long_steps, f"{motion}{i}_long.zarr"))
            window = src.read(first - reach, first + reach + 1)
            g = src.geometry
            bw, bc, _ = _timed(lambda: estimate(window, g.focal_length, g.camera_spacing,
                                                motion=motion, method="reference"), 1)
            window = None                       # 890 MB at 512^2 (affine): not kept
            rows.append(dict(motion=motion, frames=2 * reach + 1, runs=runs, longs=longs,
                             base_wall=bw, base_cpu=bc))
    return rows


def _peak_rss_mb() -> float:
    """Peak resident set size of this process (VmHWM: unlike ru_maxrss it is not
    inherited across fork + exec from the parent)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc/self/status")


def _one_size(size: int) -> dict:
    """Run in a fresh process: estimate one float32 volume, report time and peak RSS."""
    sv = _volume(size, dtype=np.float32)
    estimate(sv.volume[..., :160, :160], sv.focal_length, sv.camera_spacing)   # load kernels
    rss_before = _peak_rss_mb()
    t0 = time.perf_counter()
    est = estimate(sv.volume, sv.focal_length, sv.camera_spacing, model="full")
    dt = time.perf_counter() - t0
    n_int = int(est.interior.sum())
    return {"size": size, "seconds": dt, "interior_px": n_int,
            "interior_kpx_s": n_int / dt / 1e3, "image_kpx_s": size * size / dt / 1e3,
            "volume_MB": sv.volume.nbytes / 2**20, "rss_before_MB": rss_before,
            "peak_rss_MB": _peak_rss_mb()}


def scaling(sizes) -> list[dict]:
    out = []
    for size in sizes:
        res = subprocess.run([sys.executable, "-m", "gridflow.bench.throughput", "--_one",
                              str(size)], capture_output=True, text=True, check=True,
                             env={**os.environ, "PYTHONWARNINGS": "ignore"})
        out.append(json.loads(res.stdout.strip().splitlines()[-1]))
        r = out[-1]
        print(f"| {size} | {r['seconds']:.2f} | {r['interior_px']} | "
              f"{r['interior_kpx_s']:.0f} | {r['image_kpx_s']:.0f} | {r['volume_MB']:.0f} | "
              f"{r['peak_rss_MB']:.0f} ({r['rss_before_MB']:.0f}) |", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    ap.add_argument("--size", type=int, default=512, help="in-process image size")
    ap.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    ap.add_argument("--affine", nargs="*", choices=MODELS, default=["full"],
                    help="models also run with the affine motion model (default full)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="rounds (in-process: one fast and one baseline call each) or CLI "
                         "repeats; the best is kept")
    ap.add_argument("--cli-size", type=int, default=1024)
    ap.add_argument("--sizes", type=int, nargs="*", default=[256, 512, 1024, 2048],
                    help="scaling table sizes")
    ap.add_argument("--rec-frames", type=int, default=42,
                    help="frames of the recording section's recording (default 42)")
    ap.add_argument("--rec-steps", type=int, default=8,
                    help="steps of each short recording run (default 8)")
    ap.add_argument("--rec-long", type=int, default=24,
                    help="steps of each long recording run (default 24; 0: none)")
    ap.add_argument("--_one", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if "recording" in a.sections:
        if a.rec_steps < 1 or a.rec_long < 0 or 0 < a.rec_long <= a.rec_steps:
            ap.error(f"--rec-steps must be at least 1 and --rec-long 0 or more than it, got "
                     f"{a.rec_steps} and {a.rec_long}")
        from gridflow.estimator import temporal_reach
        from gridflow.estimator.settings import EstimatorSettings

        need = max(a.rec_steps, a.rec_long) + 2 * temporal_reach(
            EstimatorSettings(motion=AFFINE.name))
        if need > a.rec_frames:
            ap.error(f"{max(a.rec_steps, a.rec_long)} steps under affine motion need "
                     f"{need} frames: --rec-frames {a.rec_frames} is too few")
    if a._one:
        print(json.dumps(_one_size(a._one)))
        return 0
    print(f"{os.cpu_count()} cores; fast path: {_threads()} numba threads and as many "
          "scipy.fft workers; baseline: single-threaded correlations and eigh")
    print("volume: 5x5 cameras, 9 frames, sinusoid a1 = 0.2, a1x = 0.002, a2 = -0.01, "
          "sigma_n = 0.01; window 65 taps, sigma 16")
    if "inprocess" in a.sections:
        print(f"\nin one process, {a.size}x{a.size} ({a.repeat} rounds of one fast and one "
              "baseline call; wall: best of the rounds, each path; CPU: user + system of "
              "that call; median round: the median of the rounds' own wall ratios)")
        print("| model | baseline wall s | baseline CPU s | fast wall s | fast CPU s | "
              "wall ratio | CPU ratio | median round | fast interior kpx/s | max rel diff |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for r in inprocess(a.size, a.models, a.repeat, a.affine):
            print(f"| {r['model']} | {r['base_wall']:.2f} | {r['base_cpu']:.2f} | "
                  f"{r['fast_wall']:.3f} | {r['fast_cpu']:.3f} | **{r['wall_ratio']:.1f}** | "
                  f"{r['cpu_ratio']:.1f} | {r['round_ratio']:.1f} | "
                  f"{r['fast_interior_kpx_s']:.0f} | {r['max_rel_diff']:.1e} |", flush=True)
    if "cli" in a.sections:
        r = cli(a.cli_size, a.repeat)
        print(f"\nthrough the CLI (`gridflow estimate`, a fresh process: start, imports, "
              f"load, estimate, save; best of {a.repeat}), full model")
        print("| what | seconds |")
        print("|---|---|")
        print(f"| fixed cost: 24x24 volume | {r['fixed_s']:.2f} |")
        print(f"| {r['size']}x{r['size']} float32 volume, CLI | {r['cli_s']:.2f} |")
        print(f"| {r['size']}x{r['size']}, baseline in this process (wall; CPU "
              f"{r['base_cpu']:.1f}) | {r['base_wall']:.2f} |")
        print(f"| ratio baseline / CLI | **{r['ratio']:.1f}** |", flush=True)
    if "zoom" in a.sections:
        print(f"\nthe zoom-blur correction's cost, fast path, {a.size}x{a.size} ({a.repeat} "
              "interleaved rounds; wall: best round, CPU: user + system of it)")
        print("| models | without: wall s | CPU s | with: wall s | CPU s | wall ratio |")
        print("|---|---|---|---|---|---|")
        for r in zoom(a.size, a.models, a.repeat):
            print(f"| {r['models']} | {r['off_wall']:.3f} | {r['off_cpu']:.3f} | "
                  f"{r['on_wall']:.3f} | {r['on_cpu']:.3f} | **{r['ratio']:.2f}** |", flush=True)
    if "stages" in a.sections:
        print(f"\nwhere the time goes, fast path, full model, zoom-blur correction on, "
              f"{a.size}x{a.size} ({a.repeat} runs; each stage: median seconds, its share "
              "of the median run, and the range over the runs)")
        print("| motion | run wall s | signals | tensor | null space | affine solve | rest |")
        print("|---|---|---|---|---|---|---|")
        rows = stages(a.size, a.repeat)
        for motion in (TRANSLATION.name, AFFINE.name):
            mine = [r for r in rows if r["motion"] == motion]
            wall = float(np.median([r["wall"] for r in mine]))
            cells = []
            for part in ("signals", "tensor", "null space", "affine solve", "rest"):
                v = [r[part] for r in mine]
                cells.append(f"{np.median(v):.3f} ({np.median(v) / wall:.0%}; "
                             f"{min(v):.3f}-{max(v):.3f})")
            w = [r["wall"] for r in mine]
            print(f"| {motion} | {wall:.3f} ({min(w):.3f}-{max(w):.3f}) | "
                  + " | ".join(cells) + " |", flush=True)
    if "recording" in a.sections:
        print(f"\na recording, {a.size}x{a.size} px, 5x5 views: `gridflow estimate REC -o "
              f"MAPS.zarr --every 1` over {a.rec_steps} steps, default local scheduler, "
              f"{a.repeat} fresh processes each (steps/s: the run's own, as it prints "
              "it; wall and CPU: the whole process; peak: its resident memory, VmHWM); "
              "baseline: one step's window by the reference in this process")
        n, m = a.rec_steps, a.rec_long
        if m:
            print(f"then the same from the same first step over {m} steps: a long run's rate "
                  f"is that of the steps beyond the first {n}, ({m} - {n}) steps over the "
                  "difference of the two runs' times (and CPU times), in each round: the "
                  "first steps also compute every frame of their windows, later ones one "
                  "frame each")
        print(f"| motion | window frames | {n} steps: steps/s (median; range) | s a step | "
              "process wall s | process CPU s | "
              + (f"beyond the first {n}: steps/s (median; range) | CPU s a step | " if m
                 else "")
              + "peak RSS MiB (max) | baseline s a window (CPU) | baseline / "
              + ("a long run's step |" if m else "step |"))
        print("|---|---|---|---|---|---|" + ("---|---|" if m else "") + "---|---|---|")
        for r in recording(a.size, a.rec_frames, n, a.repeat, m):
            rate = [x["rate"] for x in r["runs"]]
            med = float(np.median(rate))
            cells = ""
            if m:
                pairs = list(zip(r["runs"], r["longs"]))
                beyond = [(m - n) / (y["run_s"] - x["run_s"]) for x, y in pairs]
                cpu = [(y["cpu"] - x["cpu"]) / (m - n) for x, y in pairs]
                med = float(np.median(beyond))
                cells = (f"**{med:.3f}** ({min(beyond):.3f}-{max(beyond):.3f}) | "
                         f"{np.median(cpu):.2f} | ")
            peak = max(x["peak_mb"] for x in r["runs"] + r["longs"])
            print(f"| {r['motion']} | {r['frames']} | **{float(np.median(rate)):.3f}** "
                  f"({min(rate):.3f}-{max(rate):.3f}) | {1 / float(np.median(rate)):.2f} | "
                  f"{np.median([x['wall'] for x in r['runs']]):.1f} | "
                  f"{np.median([x['cpu'] for x in r['runs']]):.1f} | {cells}"
                  f"{peak:.0f} | {r['base_wall']:.1f} "
                  f"({r['base_cpu']:.1f}) | **{r['base_wall'] * med:.1f}** |", flush=True)
    if "scaling" in a.sections and a.sizes:
        print("\nscaling, fast path, full model, float32 volume, one fresh process per size")
        print("| size | seconds | interior px | interior kpx/s | image kpx/s | volume MB | "
              "peak RSS MB (before estimating) |")
        print("|---|---|---|---|---|---|---|")
        scaling(a.sizes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
