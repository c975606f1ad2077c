"""Parameter sweeps over sinusoid volumes: the benchmark behind Figs. 3 and 4.

A sweep spec (TOML; the shipped ones are in ``bench/sweeps/``, found by name: ``paper``) names the models, noise levels,
seeds, base generator parameters, estimator settings and one or more axes (a parameter
and its values).  Every (axis, value, noise, seed) is a *point*: one volume, on which all
models run with a shared structure tensor.  Each point's rows are written atomically to a
part file as soon as it finishes; the final CSV is assembled from the parts in a fixed
order (so it does not depend on which point finished first), written atomically, and the
parts are removed.  Re-running an interrupted sweep reuses the finished parts.

Noise is seeded by the point's ``seed`` alone, so a point's result does not depend on the
order or the process it ran in.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tomllib
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import pandas as pd

from gridflow.estimator import MODELS, EstimatorSettings, estimate_models
from gridflow.generators import SinusoidParams, check_params, make_sinusoid

from gridflow.io import atomic_write
from .metrics import evaluate

__all__ = ["SweepSpec", "Point", "run_point", "run_sweep", "SpecError", "COLUMNS",
           "shipped_specs", "resolve_spec"]

COLUMNS = ["sweep", "param", "value", "noise", "seed", "model", "quantity", "measure", "q",
           "q_rel", "q_abs", "n_pixels", "n_invalid", "generator", "estimator"]
QUANTITY_ORDER = ["Z", "Zx", "Zy", "Ux", "Uy", "Uz", "a1", "a2", "a1x", "a1y", "a2x", "a2y"]
_SWEEPABLE = {f.name for f in fields(SinusoidParams)} - {"grid", "spacing", "seed", "noise"}
_SOURCES = ("estimator", "generators")


class SpecError(ValueError):
    """A sweep spec that cannot run; raised before any work starts."""


@dataclass(frozen=True)
class Point:
    """One volume of a sweep."""

    param: str
    value: float
    noise: float
    seed: int


@dataclass
class SweepSpec:
    """A parsed, validated sweep.

    Attributes
    ----------
    name : str
    models : list of str
    noise : list of float
    seeds : list of int
    base : dict
        Generator parameters (``SinusoidParams`` fields) common to all points.
    estimator : dict
        Estimator settings (``EstimatorSettings`` fields).
    axes : list of (str, list of float)
    """

    name: str
    models: list[str]
    noise: list[float]
    seeds: list[int]
    base: dict = field(default_factory=dict)
    estimator: dict = field(default_factory=dict)
    axes: list[tuple[str, list[float]]] = field(default_factory=list)

    @classmethod
    def from_toml(cls, path) -> "SweepSpec":
        """Read a spec from a TOML file, or a spec shipped with gridflow by its name
        (``"paper"``: see :func:`shipped_specs`)."""
        path = resolve_spec(path)
        try:
            raw = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise SpecError(f"{path}: no such sweep spec") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise SpecError(f"{path}: not valid TOML ({exc})") from None
        return cls.from_dict(raw, source=str(path))

    @classmethod
    def from_dict(cls, raw: dict, source: str = "spec") -> "SweepSpec":
        unknown = set(raw) - {"sweep", "base", "estimator", "axis"}
        if unknown:
            raise SpecError(f"{source}: unknown section(s) {sorted(unknown)}; expected "
                            "[sweep], [base], [estimator], [[axis]]")
        sw = raw.get("sweep", {})
        spec = cls(name=str(sw.get("name", "sweep")),
                   models=list(sw.get("models", list(MODELS))),
                   noise=[float(v) for v in sw.get("noise", [0.0])],
                   seeds=[int(v) for v in sw.get("seeds", [0])],
                   base=dict(raw.get("base", {})), estimator=dict(raw.get("estimator", {})),
                   axes=[(a.get("param"), a.get("values")) for a in raw.get("axis", [])])
        spec.validate(source)
        return spec

    def validate(self, source: str = "spec") -> None:
        """Check everything that can be checked before running; raise :class:`SpecError`."""
        bad = [m for m in self.models if m not in MODELS]
        if bad or not self.models:
            raise SpecError(f"{source}: unknown or no model(s) {bad}; expected some of {MODELS}")
        if not self.noise or any(not np.isfinite(n) or n < 0 for n in self.noise):
            raise SpecError(f"{source}: noise must be a non-empty list of values >= 0")
        if not self.seeds or any(s < 0 for s in self.seeds):
            raise SpecError(f"{source}: seeds must be a non-empty list of integers >= 0")
        if not self.axes:
            raise SpecError(f"{source}: no [[axis]] to sweep")
        for param, values in self.axes:
            if param not in _SWEEPABLE:
                raise SpecError(f"{source}: unknown parameter {param!r}; sweepable: "
                                f"{sorted(_SWEEPABLE)}")
            if not isinstance(values, list) or not values:
                raise SpecError(f"{source}: axis {param!r} has an empty or missing 'values' list")
            if len(set(values)) != len(values):
                raise SpecError(f"{source}: axis {param!r} repeats values")
        try:
            base = SinusoidParams().replace(**self.base)
        except (TypeError, ValueError) as exc:
            raise SpecError(f"{source}: [base]: {exc}") from None
        try:
            EstimatorSettings(**self.estimator)
        except TypeError as exc:
            raise SpecError(f"{source}: [estimator]: {exc}") from None
        for p in self.points():
            try:
                check_params(self.params(p, base))
            except (TypeError, ValueError) as exc:
                raise SpecError(f"{source}: {p.param} = {p.value}: {exc}") from None

    def points(self) -> list[Point]:
        """All points in the canonical order of the output CSV."""
        return [Point(param, float(v), float(n), int(s))
                for param, values in self.axes for v in values
                for n in self.noise for s in self.seeds]

    def params(self, point: Point, base: SinusoidParams | None = None) -> SinusoidParams:
        base = base or SinusoidParams().replace(**self.base)
        return base.replace(**{point.param: point.value, "noise": point.noise,
                               "seed": point.seed})


def shipped_specs() -> dict[str, Path]:
    """The sweep specs installed with gridflow (``bench/sweeps/*.toml``), by name."""
    from importlib.resources import files

    folder = files("gridflow.bench") / "sweeps"
    return {Path(f.name).stem: Path(str(f)) for f in folder.iterdir()
            if f.name.endswith(".toml")}


def resolve_spec(spec) -> Path:
    """The file of a sweep spec given as a path or as the name of a shipped spec.

    An existing file wins; a bare name (no folder, no ``.toml``) is looked up among
    :func:`shipped_specs`.

    Raises
    ------
    SpecError
        Neither a file nor a shipped spec's name.
    """
    path = Path(spec)
    if path.is_file():
        return path
    if path.suffix == "" and path.name == str(spec):
        shipped = shipped_specs()
        if str(spec) in shipped:
            return shipped[str(spec)]
        raise SpecError(f"{spec}: no such sweep spec file, and not the name of a shipped "
                        f"spec (shipped: {', '.join(sorted(shipped))})")
    raise SpecError(f"{spec}: no such sweep spec")


def _code_fingerprint() -> str:
    """Hash of the numerics' source: a part made by other code is not reused."""
    import importlib

    h = hashlib.sha1()
    for pkg in _SOURCES:
        folder = Path(importlib.import_module(f"gridflow.{pkg}").__file__).parent
        for f in sorted(folder.glob("*.py")):
            h.update(f.read_bytes())
    return h.hexdigest()[:12]


def _point_key(spec: SweepSpec, point: Point, fingerprint: str) -> str:
    blob = json.dumps({"point": point.__dict__, "base": spec.base, "est": spec.estimator,
                       "models": spec.models, "code": fingerprint}, sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()[:16]


def run_point(spec: SweepSpec, point: Point) -> pd.DataFrame:
    """Generate one volume, estimate with every model, score every quantity.

    Returns
    -------
    pandas.DataFrame
        Rows with the columns of :data:`COLUMNS`.
    """
    params = spec.params(point)
    sv = make_sinusoid(params)
    res = estimate_models(sv.volume, sv.focal_length, sv.camera_spacing, models=spec.models,
                          principal_point=sv.principal_point, **spec.estimator)
    gen = _diff_json(params.as_dict(), SinusoidParams().as_dict())
    rows = []
    for model in spec.models:
        e = res[model]
        f = e.settings["filters"]
        est = _diff_json(e.settings, {**EstimatorSettings().__dict__, "model": model,
                                      "filters_xy": f, "filters_sx": f, "filters_sy": f,
                                      "filters_t": f})
        for r in evaluate(e.maps, sv.truth, e.interior):
            rows.append({"sweep": spec.name, "param": point.param, "value": point.value,
                         "noise": point.noise, "seed": point.seed, "model": model, **r,
                         "generator": gen, "estimator": est})
    df = pd.DataFrame(rows)
    return df[COLUMNS]


def _diff_json(values: dict, defaults: dict) -> str:
    """JSON of the entries that differ from the documented defaults (keeps the CSV small;
    the defaults themselves are recorded in the sweep's ``.json`` sidecar)."""
    diff = {k: (list(v) if isinstance(v, tuple) else v) for k, v in values.items()
            if k not in defaults or defaults[k] != v}
    return json.dumps(diff, sort_keys=True, separators=(",", ":"))


def _run_to_part(spec: SweepSpec, point: Point, part: str) -> str:
    df = run_point(spec, point)
    with atomic_write(part, "w") as fh:
        df.to_csv(fh, index=False)
    return part


@contextmanager
def _single_threaded_blas():
    """Worker processes share the cores: one BLAS thread each avoids oversubscription."""
    keys = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
    old = {k: os.environ.get(k) for k in keys}
    os.environ.update({k: "1" for k in keys})
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _order(df: pd.DataFrame, spec: SweepSpec) -> pd.DataFrame:
    pts = {(p.param, p.value, p.noise, p.seed): i for i, p in enumerate(spec.points())}
    key = df.apply(lambda r: (pts[(r.param, r.value, r.noise, r.seed)],
                              spec.models.index(r.model),
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
        CSV to write (atomically, at the end).  Finished points are kept meanwhile in
        ``<output>.parts/`` and reused if the sweep is run again after an interruption.
    workers : int, optional
        Processes on this machine (default: all cores).  1 runs in-process.
    progress : bool
        Show a progress bar (tqdm) on stderr.
    executor : concurrent.futures.Executor-like, optional
        Run the points there instead (e.g. a ``dask.distributed.Client``); it must
        offer ``submit`` and futures usable with ``as_completed``.
    keep_parts : bool
        Keep the part files after assembling.

    Returns
    -------
    pandas.DataFrame
        The rows written.
    """
    from tqdm import tqdm

    output = Path(output)
    parts_dir = output.parent / (output.name + ".parts")
    parts_dir.mkdir(parents=True, exist_ok=True)
    fp = _code_fingerprint()
    todo, parts = [], []
    for p in spec.points():
        part = str(parts_dir / f"{_point_key(spec, p, fp)}.csv")
        parts.append(part)
        if not Path(part).exists():
            todo.append((p, part))
    bar = tqdm(total=len(parts), initial=len(parts) - len(todo), disable=not progress,
               desc=f"sweep {spec.name}", unit="pt")
    workers = workers or os.cpu_count() or 1
    try:
        if executor is not None:
            futs = [executor.submit(_run_to_part, spec, p, part) for p, part in todo]
            _drain(futs, bar, executor)
        elif workers == 1 or len(todo) <= 1:
            for p, part in todo:
                _run_to_part(spec, p, part)
                bar.update()
        else:
            import multiprocessing as mp

            with _single_threaded_blas(), ProcessPoolExecutor(
                    max_workers=min(workers, len(todo)), mp_context=mp.get_context("spawn")) as ex:
                futs = [ex.submit(_run_to_part, spec, p, part) for p, part in todo]
                _drain(futs, bar)
    finally:
        bar.close()
    df = _order(pd.concat([pd.read_csv(p, keep_default_na=False, na_values=[""])
                           for p in parts], ignore_index=True), spec)
    with atomic_write(output, "w") as fh:
        df.to_csv(fh, index=False, float_format="%.7g")
    with atomic_write(output.with_suffix(".json"), "w") as fh:
        json.dump(provenance(spec), fh, indent=1, sort_keys=True)
        fh.write("\n")
    if not keep_parts:
        shutil.rmtree(parts_dir, ignore_errors=True)
    return df


def provenance(spec: SweepSpec) -> dict:
    """What made a sweep CSV: the spec, the full defaults the CSV's JSON columns are
    relative to, the numerics' code fingerprint and library versions."""
    import scipy

    return {"spec": {"name": spec.name, "models": spec.models, "noise": spec.noise,
                     "seeds": spec.seeds, "base": spec.base, "estimator": spec.estimator,
                     "axes": [{"param": p, "values": v} for p, v in spec.axes]},
            "generator_defaults": SinusoidParams().as_dict(),
            "estimator_defaults": EstimatorSettings().__dict__,
            "code_fingerprint": _code_fingerprint(),
            "versions": {"numpy": np.__version__, "scipy": scipy.__version__,
                         "pandas": pd.__version__}}


def _drain(futs, bar, executor=None) -> None:
    if executor is not None and hasattr(executor, "gather"):
        from dask.distributed import as_completed as dask_completed

        for fut in dask_completed(futs):
            fut.result()
            bar.update()
        return
    for fut in as_completed(futs):
        fut.result()        # re-raise a worker's error here
        bar.update()
