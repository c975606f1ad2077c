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
import signal
import sys
import tomllib
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import pandas as pd

from gridflow.estimator import MODELS, EstimatorSettings, InputError, estimate_models
from gridflow.generators import SinusoidParams, add_noise, check_params, make_sinusoid

from gridflow.io import atomic_write
from gridflow.volume import physical_memory
from .metrics import evaluate
from .setups import get_setup

__all__ = ["SweepSpec", "Point", "run_point", "run_sweep", "SpecError", "SweepInterrupted",
           "COLUMNS", "shipped_specs", "resolve_spec"]

COLUMNS = ["sweep", "param", "value", "noise", "seed", "model", "quantity", "measure", "q",
           "q_rel", "q_abs", "n_pixels", "n_invalid", "generator", "estimator"]
QUANTITY_ORDER = ["Z", "Zx", "Zy", "Ux", "Uy", "Uz", "a1", "a2", "a1x", "a1y", "a2x", "a2y"]
_SWEEPABLE = {f.name for f in fields(SinusoidParams)} - {"grid", "spacing", "seed", "noise",
                                                           "texture"}
# generator parameters that are integers (sizes); spec values for them must be integral
_INTEGER = {f.name for f in fields(SinusoidParams) if f.type in ("int", int)}
# everything a row of the CSV depends on: the code of these modules (besides the spec and
# the library versions) keys a finished point, so a changed module is never mixed in
_ROW_SOURCES = ("gridflow.estimator", "gridflow.generators", "gridflow.volume", "gridflow.io",
                "gridflow.bench.sweep", "gridflow.bench.metrics", "gridflow.bench.setups")
_SECTION_KEYS = {"sweep": {"name", "models", "noise", "seeds", "setup"}, "base": None,
                 "estimator": None, "axis": {"param", "values"}}


class SpecError(ValueError):
    """A sweep spec that cannot run; raised before any work starts."""


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


class _Terminated(BaseException):
    """Raised in the main thread by the SIGTERM handler (a BaseException, like Ctrl-C)."""


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
    setup : str
        The named setup (:mod:`gridflow.bench.setups`) whose generator parameters,
        estimator settings and brightness reference the spec starts from; ``base`` and
        ``estimator`` override them.
    """

    name: str
    models: list[str]
    noise: list[float]
    seeds: list[int]
    base: dict = field(default_factory=dict)
    estimator: dict = field(default_factory=dict)
    axes: list[tuple[str, list[float]]] = field(default_factory=list)
    setup: str = "gridflow"

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
        """Build and validate a spec from parsed TOML; every key is used or refused."""
        if not isinstance(raw, dict):
            raise SpecError(f"{source}: a spec is a table of sections")
        unknown = set(raw) - set(_SECTION_KEYS)
        if unknown:
            raise SpecError(f"{source}: unknown section(s) {sorted(unknown)}; expected "
                            "[sweep], [base], [estimator], [[axis]]")
        sw = raw.get("sweep", {})
        for section in ("sweep", "base", "estimator"):
            if not isinstance(raw.get(section, {}), dict):
                raise SpecError(f"{source}: [{section}] must be a table")
        bad = set(sw) - _SECTION_KEYS["sweep"]
        if bad:
            raise SpecError(f"{source}: [sweep]: unknown key(s) {sorted(bad)}; expected "
                            f"{sorted(_SECTION_KEYS['sweep'])}")
        axes_raw = raw.get("axis", [])
        if not isinstance(axes_raw, list) or not all(isinstance(a, dict) for a in axes_raw):
            raise SpecError(f"{source}: [[axis]] must be an array of tables")
        axes = []
        for n, a in enumerate(axes_raw, 1):
            bad = set(a) - _SECTION_KEYS["axis"]
            if bad:
                raise SpecError(f"{source}: [[axis]] number {n}: unknown key(s) {sorted(bad)}; "
                                "expected 'param' and 'values'")
            axes.append((a.get("param"), a.get("values")))
        spec = cls(name=sw.get("name", "sweep"),
                   models=_list(sw.get("models", list(MODELS)), str, "[sweep] models", source),
                   noise=_list(sw.get("noise", [0.0]), float, "[sweep] noise", source),
                   seeds=_list(sw.get("seeds", [0]), int, "[sweep] seeds", source),
                   base=dict(raw.get("base", {})), estimator=dict(raw.get("estimator", {})),
                   axes=axes, setup=sw.get("setup", "gridflow"))
        spec.validate(source)
        return spec

    def validate(self, source: str = "spec") -> None:
        """Check everything that can be checked before running; raise :class:`SpecError`.

        Integral values of integer generator parameters (``height``, ``width``,
        ``frames``) are converted to ``int`` in place.
        """
        try:
            get_setup(self.setup)
        except ValueError as exc:
            raise SpecError(f"{source}: [sweep] setup: {exc}") from None
        if not isinstance(self.name, str) or not self.name.strip():
            raise SpecError(f"{source}: [sweep] name must be a non-empty string, got "
                            f"{self.name!r}")
        bad = [m for m in self.models if m not in MODELS]
        if bad or not self.models:
            raise SpecError(f"{source}: unknown or no model(s) {bad}; expected some of {MODELS}")
        for key, values in (("models", self.models), ("noise", self.noise),
                            ("seeds", self.seeds)):
            if len(set(values)) != len(values):
                raise SpecError(f"{source}: [sweep] {key} repeats a value: {values}")
        if not self.noise or any(not _real(n) or n < 0 for n in self.noise):
            raise SpecError(f"{source}: noise must be a non-empty list of values >= 0")
        if not self.seeds or any(not _integer(s) or s < 0 for s in self.seeds):
            raise SpecError(f"{source}: seeds must be a non-empty list of integers >= 0")
        if not self.axes:
            raise SpecError(f"{source}: no [[axis]] to sweep")
        swept = [p for p, _ in self.axes]
        for i, (param, values) in enumerate(self.axes):
            if param not in _SWEEPABLE:
                raise SpecError(f"{source}: unknown parameter {param!r}; sweepable: "
                                f"{sorted(_SWEEPABLE)}")
            if swept.count(param) > 1:
                raise SpecError(f"{source}: parameter {param!r} has more than one [[axis]]; "
                                "give it one axis with all its values")
            if not isinstance(values, list) or not values:
                raise SpecError(f"{source}: axis {param!r} has an empty or missing 'values' list")
            self.axes[i] = (param, [_value(param, v, f"axis {param!r}", source)
                                    for v in values])
            if len(set(self.axes[i][1])) != len(values):
                raise SpecError(f"{source}: axis {param!r} repeats values")
        for key in ("noise", "seed"):
            if key in self.base:
                raise SpecError(f"{source}: [base] {key} is set by [sweep] "
                                f"{'noise' if key == 'noise' else 'seeds'}; remove it from "
                                "[base]")
        overridden = sorted(set(self.base) & set(swept))
        if overridden:
            raise SpecError(f"{source}: [base] sets {overridden}, which an [[axis]] sweeps; "
                            "remove it from [base]")
        known = {f.name for f in fields(SinusoidParams)}
        unknown = sorted(set(self.base) - known)
        if unknown:
            raise SpecError(f"{source}: [base]: unknown sinusoid parameter(s) {unknown}")
        self.base = {k: _value(k, v, "[base]", source) for k, v in self.base.items()}
        try:
            base = self.base_params()
        except (TypeError, ValueError) as exc:
            raise SpecError(f"{source}: [base]: {exc}") from None
        try:
            EstimatorSettings(**self.estimator_settings())
        except (TypeError, InputError) as exc:
            raise SpecError(f"{source}: [estimator]: {exc}") from None
        for p in self.points():
            params = self.params(p, base)
            _check_size(params, f"{source}: {p.param} = {p.value}")
            try:
                check_params(params)
            except (TypeError, ValueError) as exc:
                raise SpecError(f"{source}: {p.param} = {p.value}: {exc}") from None

    def points(self) -> list[Point]:
        """All points in the canonical order of the output CSV."""
        return [Point(param, float(v), float(n), int(s))
                for param, values in self.axes for v in values
                for n in self.noise for s in self.seeds]

    def base_params(self) -> SinusoidParams:
        """Generator parameters common to all points: the setup's, then ``[base]``."""
        return SinusoidParams().replace(**{**get_setup(self.setup).base, **self.base})

    def estimator_settings(self) -> dict:
        """Estimator settings: the setup's, then ``[estimator]``."""
        return {**get_setup(self.setup).estimator, **self.estimator}

    def params(self, point: Point, base: SinusoidParams | None = None) -> SinusoidParams:
        base = base or self.base_params()
        value = int(point.value) if point.param in _INTEGER else point.value
        return base.replace(**{point.param: value, "noise": point.noise, "seed": point.seed})

    def as_dict(self) -> dict:
        """The spec as plain data (what the provenance sidecar and the resume key record)."""
        return {"name": self.name, "setup": self.setup, "models": list(self.models),
                "noise": list(self.noise),
                "seeds": list(self.seeds), "base": dict(self.base),
                "estimator": dict(self.estimator),
                "axes": [{"param": p, "values": list(v)} for p, v in self.axes]}


def _real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def _integer(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _list(values, kind, what: str, source: str) -> list:
    """A spec list of ``kind`` (str, float or int), or a SpecError naming the key."""
    if not isinstance(values, list):
        raise SpecError(f"{source}: {what} must be a list, got {values!r}")
    out = []
    for v in values:
        if kind is str and isinstance(v, str):
            out.append(v)
        elif kind is float and _real(v):
            out.append(float(v))
        elif kind is int and (_integer(v) or (_real(v) and float(v).is_integer())):
            out.append(int(v))
        else:
            raise SpecError(f"{source}: {what} must hold {kind.__name__} values, got {v!r}")
    return out


def _value(param: str, v, what: str, source: str):
    """A generator parameter's value from a spec: numbers only, integral for sizes."""
    if isinstance(v, list) and param in ("grid", "spacing"):
        return [_value(param + "[]", x, what, source) for x in v]
    if param == "texture":
        if not isinstance(v, str):
            raise SpecError(f"{source}: {what}: texture must be a string, got {v!r}")
        return v
    if not _real(v):
        raise SpecError(f"{source}: {what}: {param} must be a finite number, got {v!r}")
    if param in _INTEGER or param == "grid[]":
        if not float(v).is_integer():
            raise SpecError(f"{source}: {what}: {param} must be an integer, got {v!r}")
        return int(v)
    return float(v)


def _check_size(p: SinusoidParams, where: str) -> None:
    """Refuse a point whose volume would not fit in this machine's memory."""
    Sy, Sx = p.grid
    need = 8 * p.frames * Sy * Sx * p.height * p.width
    have = physical_memory()
    if have is not None and need > 0.25 * have:
        raise SpecError(f"{where}: the volume ({p.frames} x {Sy} x {Sx} x {p.height} x "
                        f"{p.width}) needs {need / 2**30:.1f} GiB, more than a quarter of "
                        f"this machine's {have / 2**30:.1f} GiB")


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
    """Generate one volume, estimate with every model, score every quantity.

    ``clean``: the point's noise-free rendering, if already made (its noise is then added
    by :func:`add_noise`, which gives the same volume as rendering with noise).

    Returns
    -------
    pandas.DataFrame
        Rows with the columns of :data:`COLUMNS`.
    """
    params = spec.params(point)
    if clean is None:
        sv = make_sinusoid(params)
    else:
        sv = add_noise(clean, params.noise, params.seed)
    res = estimate_models(sv.volume, sv.focal_length, sv.camera_spacing, models=spec.models,
                          principal_point=sv.principal_point, **spec.estimator_settings())
    truth = dict(sv.truth)
    if get_setup(spec.setup).brightness_reference == "global":
        # Eq. 22 against the swept brightness parameter's own value (the paper's reading
        # of Q_ref), not the local a + a_x X + a_y Y at each pixel
        fi = params.frame_interval
        truth["a1"] = np.full_like(truth["a1"], params.a1 * fi)
        truth["a2"] = np.full_like(truth["a2"], params.a2 * fi * fi)
    gen = _diff_json(params.as_dict(), SinusoidParams().as_dict())
    rows = []
    for model in spec.models:
        e = res[model]
        f = e.settings["filters"]
        # the settings the estimate reports beyond the spec's own: the model, the filters
        # chosen per axis (the spec's where it had the samples) and the backend that ran
        # (one of the same method's implementations) are not settings of the sweep
        est = _diff_json({k: v for k, v in e.settings.items() if k != "backend"},
                         {**EstimatorSettings().__dict__, "model": model, "filters_xy": f,
                          "filters_sx": f, "filters_sy": f, "filters_t": f})
        for r in evaluate(e.maps, truth, e.interior):
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


def _write_part(df: pd.DataFrame, part) -> None:
    with atomic_write(part, "w") as fh:
        df.to_csv(fh, index=False)


def _run_to_part(spec: SweepSpec, point: Point, part: str) -> str:
    _write_part(run_point(spec, point), part)
    return part


def run_group(spec: SweepSpec, points: list[Point]) -> list[pd.DataFrame]:
    """The points of one axis value (differing only in noise and seed): the noise-free
    volume is rendered once and each point's noise added to it."""
    clean = make_sinusoid(spec.params(points[0]).replace(noise=0.0, seed=0))
    return [run_point(spec, p, clean) for p in points]


def _run_group_to_parts(spec: SweepSpec, todo) -> list[str]:
    for df, (_, part) in zip(run_group(spec, [p for p, _ in todo]), todo):
        _write_part(df, part)
    return [part for _, part in todo]


def _groups(todo) -> list[list]:
    """``todo`` ((point, part) pairs) grouped by (param, value), in order."""
    groups: dict[tuple, list] = {}
    for p, part in todo:
        groups.setdefault((p.param, p.value), []).append((p, part))
    return list(groups.values())


def _worker_init(parent: int) -> None:
    """Start-up of a pool worker: Ctrl-C is the parent's to handle (it ends the workers),
    and a worker dies with its parent even when the parent is killed with SIGKILL."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        import ctypes

        PR_SET_PDEATHSIG = 1
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:       # the parent died before the line above took effect
        os._exit(1)


@contextmanager
def _signals_raise():
    """SIGTERM raises in the main thread like Ctrl-C, so both stop a sweep the same way."""
    def on_term(signum, frame):
        raise _Terminated()

    try:
        old = signal.signal(signal.SIGTERM, on_term)
    except ValueError:           # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


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
    parts_dir = output.parent / (output.name + ".parts")
    if parts_dir.exists() and not parts_dir.is_dir():
        raise SpecError(f"{parts_dir}: exists and is not a folder (the sweep keeps its "
                        "finished points there)")
    parts_dir.mkdir(parents=True, exist_ok=True)
    fp, versions = _code_fingerprint(), _versions()
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
    try:
        with _signals_raise():
            if executor is not None:
                _run_dask(executor, spec, todo, bar)
            elif workers == 1 or len(todo) <= 1:
                for group in _groups(todo):
                    _run_group_to_parts(spec, group)
                    bar.update(len(group))
            else:
                _run_pool(spec, todo, workers, bar)
    except (KeyboardInterrupt, _Terminated) as exc:
        bar.close()
        done = sum(Path(q).exists() for q in parts)
        name = "SIGTERM" if isinstance(exc, _Terminated) else "SIGINT"
        raise SweepInterrupted(name, done, len(parts), parts_dir) from None
    finally:
        bar.close()
    df = _order(pd.concat([pd.read_csv(p, keep_default_na=False, na_values=[""])
                           for p in parts], ignore_index=True), spec)
    with atomic_write(output, "w") as fh:
        df.to_csv(fh, index=False, float_format="%.7g")
    with atomic_write(sidecar, "w") as fh:
        json.dump(provenance(spec), fh, indent=1, sort_keys=True)
        fh.write("\n")
    if not keep_parts:
        shutil.rmtree(parts_dir, ignore_errors=True)
    return df


def _run_pool(spec: SweepSpec, todo, workers: int, bar) -> None:
    """The points in a local process pool; on an interrupt the workers are ended at once."""
    import multiprocessing as mp

    groups = _groups(todo)
    ex = ProcessPoolExecutor(max_workers=min(workers, len(groups)),
                             mp_context=mp.get_context("spawn"),
                             initializer=_worker_init, initargs=(os.getpid(),))
    try:
        # the workers start during submit, in this (the main) thread: the death signal of
        # _worker_init is tied to it
        with _single_threaded_blas():
            futs = {ex.submit(_run_group_to_parts, spec, g): len(g) for g in groups}
        for fut in as_completed(futs):
            fut.result()        # re-raise a worker's error here
            bar.update(futs[fut])
    except BaseException:
        # stop now: drop the queued points and end the running ones (their parts are
        # written atomically, so a killed point leaves nothing half-written)
        procs = list((ex._processes or {}).values())
        ex.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.join(timeout=5)
        raise
    ex.shutdown(wait=True)


def _run_dask(client, spec: SweepSpec, todo, bar) -> None:
    """The points on a dask cluster; each result comes back here and is written here."""
    from dask.distributed import as_completed as dask_completed

    futs = {client.submit(run_group, spec, [p for p, _ in g], pure=False): g
            for g in _groups(todo)}
    try:
        for fut in dask_completed(list(futs)):
            for df, (_, part) in zip(fut.result(), futs[fut]):
                _write_part(df, part)
            bar.update(len(futs[fut]))
    except BaseException:
        client.cancel(list(futs))
        raise


def provenance(spec: SweepSpec) -> dict:
    """What made a sweep CSV: the spec, the full defaults the CSV's JSON columns are
    relative to, the code fingerprint of every module a row depends on and the versions
    of Python and the libraries."""
    return {"spec": spec.as_dict(),
            "generator_defaults": SinusoidParams().as_dict(),
            "estimator_defaults": EstimatorSettings().__dict__,
            "code_fingerprint": _code_fingerprint(),
            "versions": _versions()}
