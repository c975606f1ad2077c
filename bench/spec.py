"""Sweep specs: what a parameter sweep over sinusoid volumes runs, checked before it runs.

A spec (TOML; the shipped ones are ``bench/sweeps/*.toml``, found by name: ``paper``)
names the models, noise levels, seeds, base generator parameters, estimator settings and
one or more axes (a parameter and its values).  Every (axis, value, noise, seed) is a
:class:`Point`: one volume, on which all models run with a shared structure tensor.
:meth:`SweepSpec.validate` checks everything that can be checked without running:
unknown keys, repeated values, non-integral sizes, ``[base]`` settings the sweep itself
sets, estimator settings, and that every point's volume fits in memory.  Running a spec
is :mod:`gridflow.bench.sweep`'s business.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from gridflow.errors import GridflowError
from gridflow.estimator import DEFAULTS, MODELS, MOTIONS, EstimatorSettings, InputError
from gridflow.generators import SinusoidParams, check_params
from gridflow.volume import physical_memory

from .setups import get_setup

__all__ = ["SweepSpec", "Point", "SpecError", "shipped_specs", "resolve_spec", "SWEEPABLE"]

# (``spacing`` is swept as one number, the same along x and y)
_SWEEPABLE = {f.name for f in fields(SinusoidParams)} - {"grid", "seed", "noise", "texture"}
SWEEPABLE = tuple(sorted(_SWEEPABLE))
# generator parameters that are integers (sizes); spec values for them must be integral
_INTEGER = {f.name for f in fields(SinusoidParams) if f.type in ("int", int)}
_SECTION_KEYS = {"sweep": {"name", "models", "motions", "noise", "seeds", "setup", "methods",
                           "method_cmds", "method_timeout"},
                 "base": None,
                 "estimator": None, "axis": {"param", "values", "with"}}


class SpecError(GridflowError):
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
        Brightness models (:data:`gridflow.estimator.MODELS`).
    motions : list of str
        Motion models (:data:`gridflow.estimator.MOTIONS`); every brightness model runs
        with each, the models of one motion sharing a structure tensor.  Default the
        paper's ``translation``.
    noise : list of float
    seeds : list of int
    base : dict
        Generator parameters (``SinusoidParams`` fields) common to all points.
    estimator : dict
        Estimator settings (``EstimatorSettings`` fields).
    axes : list of (str, list of float)
        ``spacing`` is swept as one camera spacing for both axes.
    fixed : dict of str to dict
        Per swept parameter, generator parameters set on its axis only (``with`` in the
        ``[[axis]]`` table), e.g. a growth rate under which a brightness change is swept.
    setup : str
        The named setup (:mod:`gridflow.bench.setups`) whose generator parameters,
        estimator settings and brightness reference the spec starts from; ``base`` and
        ``estimator`` override them.
    methods : list of str
        What runs on each point (:mod:`gridflow.bench.methods`): ``"gridflow"`` (the
        built-in estimator: ``models`` x ``motions``; the default), ``MODULE:FUNCTION``
        or an entry point's name.
    method_cmds : list of str
        Programs run as methods (``'PROGRAM ARGS {input} {output}'``).
    method_timeout : float
        Seconds a program may take per point.
    """

    name: str
    models: list[str]
    noise: list[float]
    seeds: list[int]
    base: dict = field(default_factory=dict)
    estimator: dict = field(default_factory=dict)
    axes: list[tuple[str, list[float]]] = field(default_factory=list)
    setup: str = "gridflow"
    motions: list[str] = field(default_factory=lambda: [DEFAULTS["motion"]])
    fixed: dict = field(default_factory=dict)
    methods: list[str] = field(default_factory=lambda: ["gridflow"])
    method_cmds: list[str] = field(default_factory=list)
    method_timeout: float = 600.0

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
        axes, fixed = [], {}
        for n, a in enumerate(axes_raw, 1):
            bad = set(a) - _SECTION_KEYS["axis"]
            if bad:
                raise SpecError(f"{source}: [[axis]] number {n}: unknown key(s) {sorted(bad)}; "
                                "expected 'param', 'values' and optionally 'with'")
            axes.append((a.get("param"), a.get("values")))
            if "with" in a:
                fixed[a.get("param")] = a["with"]
        spec = cls(name=sw.get("name", "sweep"),
                   models=_list(sw.get("models", list(MODELS)), str, "[sweep] models", source),
                   noise=_list(sw.get("noise", [0.0]), float, "[sweep] noise", source),
                   seeds=_list(sw.get("seeds", [0]), int, "[sweep] seeds", source),
                   base=dict(raw.get("base", {})), estimator=dict(raw.get("estimator", {})),
                   axes=axes, setup=sw.get("setup", "gridflow"),
                   motions=_list(sw.get("motions", [DEFAULTS["motion"]]), str, "[sweep] motions",
                                 source), fixed=fixed,
                   methods=_list(sw.get("methods", ["gridflow"]), str, "[sweep] methods",
                                 source),
                   method_cmds=_list(sw.get("method_cmds", []), str, "[sweep] method_cmds",
                                     source) if sw.get("method_cmds") else [],
                   method_timeout=sw.get("method_timeout", 600.0))
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
        badm = [m for m in self.motions if m not in MOTIONS]
        if badm or not self.motions:
            raise SpecError(f"{source}: unknown or no motion model(s) {badm}; expected some "
                            f"of {MOTIONS}")
        if "motion" in self.estimator:
            raise SpecError(f"{source}: [estimator] motion: give the motion models as "
                            "[sweep] motions = [...] (every model runs with each)")
        if not self.methods and not self.method_cmds:
            raise SpecError(f"{source}: [sweep] methods: none given (\"gridflow\" is the "
                            "built-in estimator)")
        if any(not isinstance(m, str) or not m.strip() for m in self.methods + self.method_cmds):
            raise SpecError(f"{source}: [sweep] methods and method_cmds must be non-empty "
                            "strings")
        if not _real(self.method_timeout) or not self.method_timeout > 0 \
                or not np.isfinite(self.method_timeout):
            raise SpecError(f"{source}: [sweep] method_timeout must be a number of seconds "
                            f"> 0, got {self.method_timeout!r}")
        for key, values in (("models", self.models), ("motions", self.motions),
                            ("noise", self.noise), ("methods", self.methods),
                            ("method_cmds", self.method_cmds),
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
        for param, extra in list(self.fixed.items()):
            if not isinstance(extra, dict):
                raise SpecError(f"{source}: axis {param!r}: 'with' must be a table of "
                                f"generator parameters, got {extra!r}")
            bad = sorted(set(extra) - known) + sorted(set(extra) & {"noise", "seed", param})
            if bad:
                raise SpecError(f"{source}: axis {param!r}: 'with' may not set {bad} (unknown, "
                                "set by [sweep], or the swept parameter itself)")
            if param not in swept:
                raise SpecError(f"{source}: 'with' given for {param!r}, which no axis sweeps")
            self.fixed[param] = {k: _value(k, v, f"axis {param!r} with", source)
                                 for k, v in extra.items()}
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
        checked = set()
        for p in self.points():
            where = f"{source}: {p.param} = {p.value}"
            try:
                params = self.params(p, base)      # every point: its seed is checked here
            except (TypeError, ValueError) as exc:
                raise SpecError(f"{where}, noise {p.noise}, seed {p.seed}: {exc}") from None
            # the noise level and the seed do not enter the size, the geometry or the
            # brightness that _check_size and check_params test: once per swept value
            if (p.param, p.value) in checked:
                continue
            checked.add((p.param, p.value))
            _check_size(params, where)
            try:
                check_params(params)
            except (TypeError, ValueError) as exc:
                raise SpecError(f"{where}: {exc}") from None

    def points(self) -> list[Point]:
        """All points in the canonical order of the output CSV.  A noise-free point is
        run with the first seed only: the seed draws the noise, so every seed would
        render the same volume."""
        return [Point(param, float(v), float(n), int(s))
                for param, values in self.axes for v in values
                for n in self.noise for s in (self.seeds if n > 0 else self.seeds[:1])]

    def base_params(self) -> SinusoidParams:
        """Generator parameters common to all points: the setup's, then ``[base]``."""
        return SinusoidParams().replace(**{**get_setup(self.setup).base, **self.base})

    def estimator_settings(self) -> dict:
        """Estimator settings: the setup's, then ``[estimator]``."""
        return {**get_setup(self.setup).estimator, **self.estimator}

    def params(self, point: Point, base: SinusoidParams | None = None) -> SinusoidParams:
        base = base or self.base_params()
        value = int(point.value) if point.param in _INTEGER else point.value
        if point.param == "spacing":
            value = (value, value)
        extra = {k: tuple(v) if isinstance(v, list) else v
                 for k, v in self.fixed.get(point.param, {}).items()}
        return base.replace(**{**extra, point.param: value, "noise": point.noise,
                               "seed": point.seed})

    def as_dict(self) -> dict:
        """The spec as plain data (what the provenance sidecar and the resume key record)."""
        return {"name": self.name, "setup": self.setup, "models": list(self.models),
                "motions": list(self.motions), "noise": list(self.noise),
                "seeds": list(self.seeds), "base": dict(self.base),
                "estimator": dict(self.estimator),
                "axes": [{"param": p, "values": list(v),
                          **({"with": dict(self.fixed[p])} if self.fixed.get(p) else {})}
                         for p, v in self.axes],
                # the methods where they are not the built-in estimator's alone (a spec
                # of gridflow's models keeps the key and sidecar it always had)
                **({"methods": list(self.methods), "method_cmds": list(self.method_cmds),
                    "method_timeout": self.method_timeout}
                   if self.methods != ["gridflow"] or self.method_cmds else {})}


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
