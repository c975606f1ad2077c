"""Where a run's estimates go: an ``.npz`` per model (one step) or a Zarr map series per
model (any number of steps, row bands, resumable).  Both take the same ``{model:
Estimate}`` of a step (:mod:`gridflow.pipeline.run`); the sink is chosen by the output's
suffix (:func:`sink_for`).

A map series is keyed on what its maps depend on and nothing else: the input's identity,
the strategy and its settings, the model, the steps, the row bands, the estimator's own
code (:func:`code_key`: its modules' syntax trees without docstrings, and this package's
step code) and the format version.  Editing the benchmark, or a docstring, never makes a
half-finished store "another run's".
"""

from __future__ import annotations

import ast
import hashlib
import json
from dataclasses import asdict
from functools import lru_cache
from pathlib import Path

import numpy as np

from gridflow.errors import UsageError

__all__ = ["NpzSink", "MapSeriesSink", "sink_for", "model_outputs", "code_key",
           "SINK_SUFFIXES"]

SINK_SUFFIXES = (".npz", ".zarr")


def model_outputs(output, models) -> dict[str, Path]:
    """One model: OUTPUT itself; several: OUTPUT with _MODEL before the suffix."""
    out = Path(output)
    if len(models) == 1:
        return {models[0]: out}
    return {m: out.with_name(f"{out.stem}_{m}{out.suffix}") for m in models}


def _module_tree_hash(path: Path) -> str:
    """A module's syntax tree without docstrings: comments and docstrings may change
    without changing the key."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(body, list) and body and isinstance(body[0], ast.Expr)
                and isinstance(getattr(body[0], "value", None), ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return hashlib.sha1(ast.dump(tree, include_attributes=False).encode()).hexdigest()


@lru_cache(maxsize=1)
def code_key() -> str:
    """The code a step's maps depend on: the estimator's modules, this package's step
    code (strategies, the step itself) and the format modules that read the frames, as
    syntax trees without docstrings; and the numerical libraries' versions."""
    import importlib.metadata as md

    import gridflow
    import gridflow.estimator as est

    base, here = Path(gridflow.__file__).parent, Path(__file__).parent
    files = sorted(Path(est.__file__).parent.glob("*.py"))
    files += [here / "strategies.py", here / "run.py"]
    files += [base / f"{m}.py" for m in ("volume", "sources", "loader", "hci", "io",
                                         "recording")]
    h = hashlib.sha1()
    for f in files:
        h.update(f.name.encode() + b"\0" + _module_tree_hash(f).encode())
    versions = {}
    for lib in ("numpy", "scipy", "numba"):
        try:
            versions[lib] = md.version(lib)
        except md.PackageNotFoundError:
            versions[lib] = None
    return json.dumps({"code": h.hexdigest()[:16], "versions": versions}, sort_keys=True)


class NpzSink:
    """One ``.npz`` estimate per model (:func:`gridflow.io.save_estimates`), all written
    at once at the end (all or none), for a run of one step."""

    kind = "npz"
    max_steps = 1
    damaged = ()             # (array, step) of done steps that lost a chunk: none here

    def __init__(self, output, models, inputs=()):
        from gridflow.io import check_output

        self.output = Path(output)
        self.outputs = model_outputs(output, models)
        for p in self.outputs.values():
            check_output(p, suffixes=".npz", inputs=inputs, what="-o")
        self.ests = None
        self._bands = {}

    def prepare(self, plan) -> None:
        """Nothing to make: the files are written whole at the end."""
        self._nbands = len(plan.bands)
        self._geometry = plan.source.geometry

    def todo(self, plan) -> tuple[list, list, int]:
        return [(i, b) for i in range(len(plan.frames)) for b in range(len(plan.bands))], [], 0

    def write(self, i: int, b: int, ests: dict, stamp: int = 0) -> None:
        """Band ``b`` of the step (the image's bands are joined top to bottom)."""
        from gridflow.estimator import Estimate

        self._bands[b] = ests
        if len(self._bands) == self._nbands:
            parts = [self._bands[k] for k in sorted(self._bands)]
            if len(parts) == 1:
                self.ests = parts[0]
                return
            first = parts[0]
            self.ests = {m: Estimate({q: np.concatenate([p[m][q] for p in parts])
                                      for q in first[m]}, first[m].model,
                                     np.concatenate([p[m].interior for p in parts]),
                                     first[m].settings) for m in first}

    def close(self) -> list[str]:
        """Write the estimates; one line per file."""
        from gridflow.io import save_estimates

        if self.ests is None:
            return []
        from gridflow.estimator import Estimate

        # the unit of each map, stored with them (meta's settings.units)
        self.ests = {m: Estimate(e.maps, e.model, e.interior,
                                 {**e.settings, "units": _units(list(e.maps), self._geometry)})
                     for m, e in self.ests.items()}
        save_estimates({self.outputs[m]: est for m, est in self.ests.items()})
        lines = []
        for m, est in self.ests.items():
            if "shear" in est:
                continue                 # a refocused light field reports itself
            n_ok = int(np.isfinite(est["Z"][est.interior]).sum())
            lines.append(f"wrote {self.outputs[m]}: model {m}, motion "
                         f"{est.settings.get('motion', 'translation')}, {n_ok}/"
                         f"{int(est.interior.sum())} interior pixels valid")
        return lines


class MapSeriesSink:
    """A map series per model (:class:`gridflow.recording.MapStore`): the estimate at
    every chosen frame, in row bands, written by whichever process estimated it; made
    anew, or reopened when it holds the same run (:func:`code_key` and the plan)."""

    kind = "zarr"
    max_steps = None

    def __init__(self, output, models, inputs=()):
        from gridflow.io import check_output

        self.output = Path(output)
        self.outputs = model_outputs(output, models)
        for p in self.outputs.values():
            check_output(p, suffixes=None, inputs=inputs, what="-o")
        self.inputs = list(inputs)
        self.stores = {}
        self.keys = {}
        self.damaged = []    # (array, step) of done steps that lost a chunk (todo)

    def prepare(self, plan) -> None:
        """Make or reopen each model's store, keyed on the run."""
        from gridflow.recording import MAPS_VERSION, MapStore

        source = plan.source
        frames = list(plan.frames)
        band_rows = plan.bands[0][1] - plan.bands[0][0]
        quantities = plan.strategy.quantities(source.shape)
        for m, path in self.outputs.items():
            blob = json.dumps({"input": source.identity(), "strategy": _describe(plan.strategy),
                               "model": m, "frames": frames, "code": code_key(),
                               "band_rows": band_rows, "format": MAPS_VERSION},
                              sort_keys=True, default=str)
            key = hashlib.sha1(blob.encode()).hexdigest()[:16]
            g = source.geometry
            attrs = {"gridflow": {"input": str(Path(source.path).resolve()), "model": m,
                                  "strategy": _describe(plan.strategy),
                                  "settings": getattr(plan.strategy, "settings", {}),
                                  "reach": plan.reach, "border": plan.strategy.border,
                                  "geometry": g.as_dict(),
                                  "focal_length": g.focal_length,
                                  "camera_spacing": list(g.camera_spacing),
                                  "frame_interval": g.frame_interval,
                                  "units": _units(quantities[m], g)}}
            store = MapStore.reopen_or_refuse(path, key, inputs=self.inputs)
            if store is None:
                store = MapStore.create(path, key=key, frames=frames, shape=source.shape[3:],
                                        quantities=quantities[m],
                                        frame_interval=g.frame_interval, attrs=attrs,
                                        band_rows=band_rows, times=plan.times,
                                        intervals=plan.intervals)
            self.stores[m] = store
            self.keys[m] = key

    def todo(self, plan) -> tuple[list, list, int]:
        """The (step, band) pairs to estimate: not done in every model's store, or done
        from frames that changed since (their stamp); the steps redone for that reason;
        the steps done whole and kept."""
        done = np.all([s.band_done() for s in self.stores.values()], axis=0)
        # a done band that lost a chunk (deleted, a disk's damage) is done again, and said
        missing = [m for s in self.stores.values() for m in s.missing_chunks()]
        self.damaged = sorted({(q, i) for q, i, _ in missing}, key=lambda x: x[1])
        for _, i, b in missing:
            done[i, b] = False
        stamps = next(iter(self.stores.values())).stamps()
        changed = [i for i in np.flatnonzero(done.any(axis=1))
                   if (plan.stamp(i) != stamps[i][done[i]]).any()]
        redo = set(changed)
        todo = [(i, b) for i in range(len(plan.frames)) for b in range(len(plan.bands))
                if not done[i, b] or i in redo]
        kept = int(sum(done[i].all() for i in range(len(plan.frames)) if i not in redo))
        return todo, changed, kept

    def write(self, i: int, b: int, ests: dict, stamp: int = 0) -> None:
        """Band ``b`` of step ``i``: ``ests`` hold that band's rows only."""
        for m, store in self.stores.items():
            est = ests[m]
            interior = est.interior
            if est.settings.get("masked"):
                # the series' interior is the same for every step (a step may come
                # first): free of the image border's effects; each step's mask (its
                # object) shows as NaN in its maps
                r0, r1 = store.bands()[b]
                H, W = store.group["interior"].shape
                k = store.attrs["gridflow"]["border"]
                rows = np.arange(r0, r1)[:, None]
                cols = np.arange(W)[None, :]
                interior = ((rows >= k) & (rows < H - k) & (cols >= k) & (cols < W - k))
            store.write_band(i, b, {q: est[q] for q in store.quantities}, interior, stamp)

    def done_steps(self) -> int:
        return int(np.min([s.done().sum() for s in self.stores.values()]))

    def close(self) -> list[str]:
        return []

    def spec(self) -> dict:
        """What a worker needs to reopen the stores (paths and keys): :meth:`reopen`."""
        return {"outputs": {m: str(p.resolve()) for m, p in self.outputs.items()},
                "keys": dict(self.keys)}

    @classmethod
    def reopen(cls, spec: dict) -> "MapSeriesSink":
        """The sink of :meth:`spec` on a worker: its stores opened for writing, each
        checked to hold this run."""
        from gridflow.recording import MapStore

        sink = cls.__new__(cls)
        sink.outputs = {m: Path(p) for m, p in spec["outputs"].items()}
        sink.output = next(iter(sink.outputs.values()))
        sink.inputs, sink.keys, sink.damaged = [], dict(spec["keys"]), []
        sink.stores = {m: MapStore.reopen(p, sink.keys[m]) for m, p in sink.outputs.items()}
        return sink


def _describe(strategy) -> dict:
    d = {"name": strategy.name, **asdict(strategy)}
    if isinstance(d.get("mask"), np.ndarray):
        # a mask file by its content: another mask is another store
        d["mask"] = "mask sha1 " + hashlib.sha1(np.packbits(d["mask"]).tobytes()).hexdigest()
    return d


def _units(quantities, g) -> dict:
    """The unit of each map, stored with the maps (attributes of the store)."""
    length = g.units
    per = "frame"
    known = {"Z": length, "Zx": "1", "Zy": "1", "disparity": "px per camera step",
             "Ux": f"{length} per {per}", "Uy": f"{length} per {per}",
             "Uz": f"{length} per {per}", "Uz_err": f"{length} per {per}",
             "growth": f"1 per {per} (d ln(area)/dt)", "growth_err": f"1 per {per}",
             "rotation": f"rad per {per}", "rotation_err": f"rad per {per}",
             "growth_sd": f"1 per {per}", "pooled": "1 (pooled rates used)",
             "Zx_t": f"1 per {per}", "Zy_t": f"1 per {per}", "a1": f"1 per {per}",
             "a2": f"1 per {per}^2", "a1x": f"1 per {per} per {length}",
             "a1y": f"1 per {per} per {length}", "a2x": f"1 per {per}^2 per {length}",
             "a2y": f"1 per {per}^2 per {length}", "model_error": "intensity^2",
             "confidence": "1", "shear": "px per camera step", "filled": "1"}
    return {q: known.get(q, "") for q in quantities}


def sink_for(output, models, inputs=()):
    """The sink an output's suffix names: ``.npz`` (:class:`NpzSink`) or ``.zarr``
    (:class:`MapSeriesSink`)."""
    suffix = Path(output).suffix.lower()
    if suffix == ".npz":
        return NpzSink(output, models, inputs)
    if suffix == ".zarr":
        return MapSeriesSink(output, models, inputs)
    raise UsageError(f"-o {output}: expected an estimate .npz (one step) or a map series "
                     ".zarr (a step at every K-th frame)")
