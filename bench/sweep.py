"""Running a sweep: every point of a spec (:mod:`gridflow.bench.spec`), resumable, into one
tidy CSV — the benchmark behind Figs. 3 and 4.

Every point is one volume, on which all models run with a shared structure tensor
(:func:`run_point`); the points of one axis value share their noise-free rendering
(:func:`run_group`).  Each point's rows are written atomically to a part file as soon as
it finishes, named by a key of everything that makes them (the whole spec, the point, the
code of every module a row depends on and the library versions), so that re-running an
interrupted sweep reuses exactly the finished, still valid points.  The final CSV is
assembled from the parts in a fixed order (so it does not depend on which point finished
first), written atomically, and the parts are removed.  Where the points run is an
:mod:`gridflow.pipeline.executors` choice.

Noise is seeded by the point's ``seed`` alone, so a point's result does not depend on the
order or the process it ran in.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from gridflow.estimator import DEFAULTS, estimate_models
from gridflow.estimator.models import TRANSLATION
from gridflow.generators import SinusoidParams, add_noise, make_sinusoid
from gridflow.io import atomic_write

from gridflow.pipeline.executors import Dask, InProcess, Pool, Terminated, signals_raise
from gridflow.metrics import evaluate
from .setups import get_setup
from .spec import Point, SpecError, SweepSpec

__all__ = ["run_point", "run_group", "run_sweep", "SweepInterrupted", "COLUMNS", "times_path",
           "provenance", "read_sweep_csv"]

COLUMNS = ["sweep", "param", "value", "noise", "seed", "method", "model", "motion",
           "quantity", "measure", "q", "q_rel", "q_abs", "n_pixels", "n_invalid", "generator",
           "estimator"]
# a point's part holds its wall times too; the sweep writes them apart (times_path), so
# that the CSV of scores is the same, to the byte, however often it is made
PART_COLUMNS = COLUMNS + ["seconds"]
TIME_COLUMNS = ["sweep", "param", "value", "noise", "seed", "method", "motion", "seconds"]
# the model and motion columns of a method other than the built-in estimator
NO_MODEL = "-"
QUANTITY_ORDER = ["Z", "Zx", "Zy", "Ux", "Uy", "Uz", "growth", "rotation", "Zx_t", "Zy_t",
                  "a1", "a2", "a1x", "a1y", "a2x", "a2y"]
# everything a row of the CSV depends on: the code of these modules (besides the spec and
# the library versions) keys a finished point, so a changed module is never mixed in
_ROW_SOURCES = ("gridflow.estimator", "gridflow.generators", "gridflow.volume", "gridflow.io",
                "gridflow.errors", "gridflow.bench.spec", "gridflow.bench.sweep",
                "gridflow.pipeline", "gridflow.pipeline.executors", "gridflow.metrics",
                "gridflow.bench.setups", "gridflow.bench.methods")


class SweepInterrupted(RuntimeError):
    """A sweep stopped by SIGINT or SIGTERM; the finished points are kept.

    Attributes
    ----------
    signal_name : str
    done, total : int
        Points finished (kept as parts) and points in the sweep.
    parts : pathlib.Path
        Folder of the finished parts; the same command finishes the sweep.
    """

    def __init__(self, signal_name: str, done: int, total: int, parts: Path):
        self.signal_name, self.done, self.total, self.parts = signal_name, done, total, parts
        super().__init__(f"interrupted by {signal_name}: {done} of {total} points finished and "
                         f"kept in {parts}/; run the same command again to finish the rest")


def _code_fingerprint() -> str:
    """Hash of the source of every module a row depends on (:data:`_ROW_SOURCES`): a part
    made by other code is never reused."""
    import importlib

    h = hashlib.sha1()
    for name in _ROW_SOURCES:
        mod = importlib.import_module(name)
        path = Path(mod.__file__)
        files = sorted(path.parent.glob("*.py")) if path.name == "__init__.py" else [path]
        for f in files:
            h.update(f.name.encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:12]


def _versions() -> dict:
    """Versions of Python and the libraries the numbers pass through."""
    import platform

    import numba
    import scipy

    from gridflow import __version__

    return {"python": platform.python_version(), "gridflow": __version__,
            "numpy": np.__version__, "scipy": scipy.__version__, "numba": numba.__version__,
            "pandas": pd.__version__}


def _point_key(spec: SweepSpec, point: Point, fingerprint: str, versions: dict) -> str:
    """Name of a point's part: everything that makes its rows (the whole spec, the point,
    the code and the library versions)."""
    blob = json.dumps({"point": point.__dict__, "spec": spec.as_dict(), "code": fingerprint,
                       "versions": versions}, sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()[:16]


def run_point(spec: SweepSpec, point: Point, clean=None) -> pd.DataFrame:
    """Generate one volume, run every method on it (the built-in estimator with every
    model and motion), score every quantity each returns.

    ``clean``: the point's noise-free rendering, if already made (its noise is then added
    by :func:`add_noise`, which gives the same volume as rendering with noise).

    Every method is scored by the same code (:func:`gridflow.metrics.evaluate`) over the
    same pixels: the built-in estimator's interior at the spec's settings (the pixels
    with a whole window), where the truth is given.  ``seconds`` is the wall time of the
    call that made the row (for the built-in estimator one call per motion, shared by
    its models, which share a structure tensor).

    Returns
    -------
    pandas.DataFrame
        Rows with the columns of :data:`PART_COLUMNS`.
    """
    from .methods import BUILTIN, resolve_methods, run_method

    params, sv, truth = point_data(spec, point, clean)
    gen = _diff_json(params.as_dict(), SinusoidParams().as_dict())
    key = {"sweep": spec.name, "param": point.param, "value": point.value,
           "noise": point.noise, "seed": point.seed}
    rows = []
    for method in resolve_methods(spec.methods, spec.method_cmds, spec.method_timeout):
        if method == BUILTIN:
            rows += _builtin_rows(spec, sv, truth, key, gen)
            continue
        maps, seconds = run_method(method, sv.volume, sv.focal_length, sv.camera_spacing,
                                   principal_point=sv.principal_point)
        scored = evaluate(maps, truth, scoring_region(spec, sv.volume.shape))
        if not scored:
            from .methods import MethodError

            raise MethodError(f"method {method.name}: returned none of the quantities this "
                              f"sweep has truth for (it returned {', '.join(maps)}; truth: "
                              f"{', '.join(truth)})")
        for r in scored:
            rows.append({**key, "method": method.name, "model": NO_MODEL,
                         "motion": NO_MODEL, **r, "generator": gen, "estimator": "{}",
                         "seconds": seconds})
    return pd.DataFrame(rows, columns=PART_COLUMNS)


def point_data(spec: SweepSpec, point: Point, clean=None):
    """A point's generator parameters, volume (:class:`gridflow.generators.SinusoidVolume`;
    from ``clean``, its noise-free rendering, where given) and the truth it is scored
    against (the volume's, but under a ``global`` brightness reference the swept
    parameter's own value)."""
    params = spec.params(point)
    if clean is None:
        sv = make_sinusoid(params)
    else:
        sv = add_noise(clean, params.noise, params.seed)
    truth = dict(sv.truth)
    if get_setup(spec.setup).brightness_reference == "global":
        # Eq. 22 against the swept brightness parameter's own value (the paper's reading
        # of Q_ref), not the local a + a_x X + a_y Y at each pixel
        fi = params.frame_interval
        truth["a1"] = np.full_like(truth["a1"], params.a1 * fi)
        truth["a2"] = np.full_like(truth["a2"], params.a2 * fi * fi)
    return params, sv, truth


def scoring_region(spec: SweepSpec, shape) -> np.ndarray:
    """The pixels every method other than the built-in estimator is scored over (shape
    (H, W) bool, for a volume of ``shape`` (..., H, W)): the built-in estimator's
    interior at the spec's settings, the pixels with a whole window."""
    from gridflow.estimator import window_halo
    from gridflow.estimator.settings import EstimatorSettings

    H, W = shape[-2:]
    halo = window_halo(EstimatorSettings(**spec.estimator_settings()))
    region = np.zeros((H, W), bool)
    region[halo:H - halo, halo:W - halo] = True
    return region


def times_path(output) -> Path:
    """Where a sweep writing ``output`` (``NAME.csv``) puts its wall times:
    ``NAME.times.csv``, a row per point, method and motion (:data:`TIME_COLUMNS`)."""
    output = Path(output)
    return output.with_name(output.stem + ".times.csv")


def _builtin_rows(spec: SweepSpec, sv, truth: dict, key: dict, gen: str) -> list[dict]:
    """The built-in estimator's rows of one point: every model with every motion."""
    import time

    res, seconds = {}, {}
    for motion in spec.motions:
        t0 = time.perf_counter()
        res[motion] = estimate_models(sv.volume, sv.focal_length, sv.camera_spacing,
                                      models=spec.models, principal_point=sv.principal_point,
                                      motion=motion, **spec.estimator_settings())
        seconds[motion] = time.perf_counter() - t0
    rows = []
    for motion in spec.motions:
        for model in spec.models:
            e = res[motion][model]
            f = e.settings["filters"]
            # the settings the estimate reports beyond the spec's own: the model and the
            # motion (columns of their own), the filters chosen per axis (the spec's
            # where it had the samples) and the backend that ran (one of the same
            # method's implementations) are not settings of the sweep
            est = _diff_json({k: v for k, v in e.settings.items() if k != "backend"},
                             {**DEFAULTS, "model": model, "motion": motion,
                              "filters_xy": f, "filters_sx": f, "filters_sy": f,
                              "filters_t": f})
            for r in evaluate(e.maps, truth, e.interior):
                rows.append({**key, "method": "gridflow", "model": model, "motion": motion,
                             **r, "generator": gen, "estimator": est,
                             "seconds": seconds[motion]})
    return rows


def _diff_json(values: dict, defaults: dict) -> str:
    """JSON of the entries that differ from the documented defaults (keeps the CSV small;
    the defaults themselves are recorded in the sweep's ``.json`` sidecar)."""
    diff = {k: (list(v) if isinstance(v, tuple) else v) for k, v in values.items()
            if k not in defaults or defaults[k] != v}
    return json.dumps(diff, sort_keys=True, separators=(",", ":"))


def _write_part(df: pd.DataFrame, part) -> None:
    with atomic_write(part, "w") as fh:
        df.to_csv(fh, index=False)


def run_group(spec: SweepSpec, points: list[Point]) -> list[pd.DataFrame]:
    """The points of one axis value (differing only in noise and seed): the noise-free
    volume is rendered once and each point's noise added to it."""
    clean = make_sinusoid(spec.params(points[0]).replace(noise=0.0, seed=0))
    return [run_point(spec, p, clean) for p in points]


def _run_group_to_parts(spec: SweepSpec, todo) -> list[str]:
    """:func:`run_group` on the points of ``todo`` ((point, part) pairs), each written to
    its part (where the workers share this process's disk)."""
    for df, (_, part) in zip(run_group(spec, [p for p, _ in todo]), todo):
        _write_part(df, part)
    return [part for _, part in todo]


def _groups(todo) -> list[list]:
    """``todo`` ((point, part) pairs) grouped by (param, value), in order."""
    groups: dict[tuple, list] = {}
    for p, part in todo:
        groups.setdefault((p.param, p.value), []).append((p, part))
    return list(groups.values())


def _order(df: pd.DataFrame, spec: SweepSpec) -> pd.DataFrame:
    pts = {(p.param, p.value, p.noise, p.seed): i for i, p in enumerate(spec.points())}
    methods = list(spec.methods) + list(spec.method_cmds)
    index = lambda seq, v: seq.index(v) if v in seq else -1  # noqa: E731
    key = df.apply(lambda r: (pts[(r.param, r.value, r.noise, r.seed)],
                              methods.index(r.method), index(spec.motions, r.motion),
                              index(spec.models, r.model),
                              QUANTITY_ORDER.index(r.quantity)
                              if r.quantity in QUANTITY_ORDER else 99), axis=1)
    return df.iloc[np.argsort(key.to_numpy(), kind="stable")].reset_index(drop=True)


def run_sweep(spec: SweepSpec, output, *, workers: int | None = None, progress: bool = True,
              executor=None, keep_parts: bool = False) -> pd.DataFrame:
    """Run every point of ``spec`` and write the tidy CSV ``output``.

    Parameters
    ----------
    spec : SweepSpec
    output : path
        CSV to write (atomically, at the end), with the provenance sidecar
        ``<output>.json``.  Finished points are kept meanwhile in ``<output>.parts/`` and
        reused if the sweep is run again after an interruption, as long as the spec, the
        code of every module a row depends on and the library versions are the same
        (they name the part); anything else is recomputed.
    workers : int, optional
        Processes on this machine (default: all cores).  1 runs in-process.
    progress : bool
        Show a progress bar (tqdm) on stderr.
    executor : dask.distributed.Client, optional
        Run the points there instead.  The results come back to this process, which
        alone writes the parts: the workers need no shared disk.
    keep_parts : bool
        Keep the part files after assembling.

    Returns
    -------
    pandas.DataFrame
        The rows written.

    Raises
    ------
    SweepInterrupted
        On SIGINT (Ctrl-C) or SIGTERM: running points are stopped within seconds, the
        finished ones are kept.
    """
    from tqdm import tqdm

    from gridflow.io import check_output

    output = check_output(output, suffixes=".csv", what="sweep output")
    sidecar = check_output(output.with_suffix(".json"), suffixes=".json",
                           what="sweep provenance")
    times_file = check_output(times_path(output), suffixes=".csv", what="sweep wall times")
    from .methods import resolve_methods

    # each method's code keys its points too: a resumed sweep never mixes two versions.
    # Resolved first: a method that does not load leaves nothing behind
    resolved = resolve_methods(spec.methods, spec.method_cmds, spec.method_timeout)
    parts_dir = output.parent / (output.name + ".parts")
    if parts_dir.exists() and not parts_dir.is_dir():
        raise SpecError(f"{parts_dir}: exists and is not a folder (the sweep keeps its "
                        "finished points there)")
    parts_dir.mkdir(parents=True, exist_ok=True)
    fp, versions = _code_fingerprint(), _versions()
    mv = {m.name: m.version for m in resolved if not isinstance(m, str)}
    if mv:
        versions = {**versions, "methods": mv}
    todo, parts = [], []
    for p in spec.points():
        part = str(parts_dir / f"{_point_key(spec, p, fp, versions)}.csv")
        parts.append(part)
        if not Path(part).exists():
            todo.append((p, part))
    stale = {f.name for f in parts_dir.glob("*.csv")} - {Path(q).name for q in parts}
    if stale and progress:
        print(f"sweep {spec.name}: {len(stale)} part(s) in {parts_dir} were made by another "
              "spec, code or library version; not reused", file=sys.stderr)
    bar = tqdm(total=len(parts), initial=len(parts) - len(todo), disable=not progress,
               desc=f"sweep {spec.name}", unit="pt")
    workers = workers or os.cpu_count() or 1
    if executor is not None:
        runner = Dask(executor)
    elif workers == 1 or len(todo) <= 1:
        runner = InProcess()
    else:
        runner = Pool(workers)

    def on_result(task, result):
        # where the workers share this disk they have written their parts; otherwise
        # the results came back and are written here
        group = task[1]
        if not runner.shared_disk:
            for df, (_, part) in zip(result, group):
                _write_part(df, part)
        bar.update(len(group))

    if runner.shared_disk:
        fn, tasks = _run_group_to_parts, [(spec, g) for g in _groups(todo)]
    else:
        fn, tasks = _dask_group, [(spec, g) for g in _groups(todo)]
    try:
        with signals_raise():
            runner.map(fn, tasks, on_result)
    except (KeyboardInterrupt, Terminated) as exc:
        bar.close()
        done = sum(Path(q).exists() for q in parts)
        name = "SIGTERM" if isinstance(exc, Terminated) else "SIGINT"
        raise SweepInterrupted(name, done, len(parts), parts_dir) from None
    finally:
        bar.close()
    df = _order(pd.concat([pd.read_csv(p, keep_default_na=False, na_values=[""])
                           for p in parts], ignore_index=True), spec)
    times = df[TIME_COLUMNS].drop_duplicates(ignore_index=True)
    df = df[COLUMNS]
    with atomic_write(output, "w") as fh:
        df.to_csv(fh, index=False, float_format="%.7g")
    with atomic_write(times_file, "w") as fh:
        times.to_csv(fh, index=False, float_format="%.4g")
    with atomic_write(sidecar, "w") as fh:
        json.dump(provenance(spec), fh, indent=1, sort_keys=True)
        fh.write("\n")
    if not keep_parts:
        shutil.rmtree(parts_dir, ignore_errors=True)
    return df


def _dask_group(spec: SweepSpec, todo) -> list[pd.DataFrame]:
    """:func:`run_group` on the points of ``todo`` ((point, part) pairs), for workers that
    do not share this disk: the rows come back."""
    return run_group(spec, [p for p, _ in todo])


def provenance(spec: SweepSpec) -> dict:
    """What made a sweep CSV: the spec, the full defaults the CSV's JSON columns are
    relative to, the code fingerprint of every module a row depends on and the versions
    of Python and the libraries."""
    return {"spec": spec.as_dict(),
            "generator_defaults": SinusoidParams().as_dict(),
            "estimator_defaults": dict(DEFAULTS),
            "code_fingerprint": _code_fingerprint(),
            "versions": _versions()}


def read_sweep_csv(path) -> pd.DataFrame:
    """A sweep CSV as a DataFrame, or a ValueError naming the file and what is wrong."""
    from gridflow.io import check_input_file

    check_input_file(path, "sweep CSV")
    try:
        df = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise SpecError(f"{path}: not a readable CSV ({exc})") from None
    need = {"param", "value", "model", "quantity", "noise", "q_rel", "q_abs"}
    missing = need - set(df)
    if "motion" not in df and not missing:
        # made before motion models existed: every row is the paper's translation
        df.insert(df.columns.get_loc("model") + 1, "motion", TRANSLATION.name)
    if "method" not in df and not missing:
        # made before other methods could run: every row is the built-in estimator's
        df.insert(df.columns.get_loc("model"), "method", "gridflow")
    if missing:
        raise SpecError(f"{path}: not a sweep CSV (missing columns {sorted(missing)})")
    for col in ("value", "noise", "q_rel", "q_abs"):
        if not pd.api.types.is_numeric_dtype(df[col]):
            raise SpecError(f"{path}: column {col!r} must hold numbers")
    return df
