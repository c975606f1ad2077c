"""Data for those who do not call Python: a suite's volumes exported as interchange files,
and a folder of estimates scored into the suite's own table.

``gridflow export SUITE DIR`` (:func:`export_suite`) writes a suite: a sweep spec (a
shipped spec's name or a TOML file: every point of the sweep) or one of the experiments
:data:`EXPERIMENTS` (``cube``: the POV-Ray cube of Fig. 1; ``leaf``: the growing POV-Ray
leaf; ``growth_maps``: the unevenly growing leaves of the growth study, five leaves times
two noise draws), as::

    DIR/manifest.json            the suite: name, kind, spec or experiment options,
                                 gridflow's version and the code fingerprint, and per item
                                 its id, parameters and the SHA-256 of its files
    DIR/volumes/ID.npz           the interchange volume (no truth arrays)
    DIR/truth/ID.npz             the truth maps and ``region``, the pixels scored (the
                                 built-in estimator's interior at the suite's settings)

A method run outside gridflow writes ``ESTIMATES/ID.npz`` (its maps under gridflow's
quantity names, :mod:`gridflow.bench.methods`) for every volume; ``gridflow score DIR
ESTIMATES`` (:func:`score_suite`) scores them with the code that scores the suite in
gridflow: a sweep into a CSV of the sweep's columns (:data:`gridflow.bench.sweep.COLUMNS`),
so that the claims and figures read it as they read a sweep; the cube into ``cube.csv``'s
per-face table, the leaf into ``leaf.csv``'s per-region table, the growth leaves into
``growth_maps.csv``'s rows.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from gridflow.errors import GridflowError, UsageError

__all__ = ["export_suite", "score_suite", "SUITE_FORMAT", "EXPERIMENTS"]

# the layout's version: a reader refuses a manifest of another
SUITE_FORMAT = 1

# the experiments a suite may name besides the sweep specs
EXPERIMENTS = ("cube", "leaf", "growth_maps")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _item_id(point) -> str:
    # repr: every digit, so that two values never share a file
    return (f"{point.param}={point.value!r}_noise={point.noise!r}_seed={point.seed}"
            .replace("/", "_"))


def _interior(shape, sigma: float, window: int) -> np.ndarray:
    """The built-in estimator's interior at ``sigma``/``window`` (shape (H, W) bool): the
    pixels with a whole window, over which every method of an experiment is scored."""
    from gridflow.estimator import window_halo
    from gridflow.estimator.settings import EstimatorSettings

    H, W = shape[-2:]
    halo = window_halo(EstimatorSettings(sigma=sigma, window=window))
    region = np.zeros((H, W), bool)
    region[halo:H - halo, halo:W - halo] = True
    return region


# --- the suites' items: (id, parameters, GridVolume, truth with its region) -------------

def _bare(v):
    """``v`` (anything with a volume and a camera geometry) as the interchange volume: no
    truth, no metadata."""
    from gridflow.volume import GridVolume

    return GridVolume(v.volume, v.focal_length, v.camera_spacing, v.principal_point, {}, {})


def _sweep_suite(suite, options):
    from .spec import SweepSpec
    from .sweep import point_data, scoring_region

    spec = SweepSpec.from_toml(suite)

    def make(point):
        params, sv, truth = point_data(spec, point)
        truth = {k: np.asarray(v, float) for k, v in truth.items()}
        truth["region"] = scoring_region(spec, sv.volume.shape)
        return {"point": point.__dict__, "params": params.as_dict()}, _bare(sv), truth

    return (spec.name, {"spec": spec.as_dict()},
            [(_item_id(p), lambda p=p: make(p)) for p in spec.points()])


def _rendered_suite(name, default_scene, options, truth_of):
    """A POV-Ray experiment (``cube``, ``leaf``) as a suite of one item: its scene
    (``options["scene"]``, default ``default_scene``) rendered into the cache (or found
    there), its truth ``truth_of(data, scene, window)`` and the pixels it scores."""
    from gridflow.loader import load_folder
    from gridflow.scenes.render import RENDER_CACHE, render_cube

    from .cube_experiment import CUBE_SIGMA, CUBE_WINDOW

    scene = options.get("scene") or default_scene
    sigma = float(options.get("sigma", CUBE_SIGMA))
    window = int(options.get("window", CUBE_WINDOW))

    def make():
        data = load_folder(render_cube(scene, options.get("cache") or RENDER_CACHE,
                                       progress=options.get("progress", True)))
        T = data.volume.shape[0]
        if data.meta["ref_frame"] != (T - 1) // 2:
            raise UsageError(f"the {name}'s reference frame is {data.meta['ref_frame']}; a "
                             f"method estimates the middle frame {(T - 1) // 2}")
        truth = {k: np.asarray(v, float) for k, v in truth_of(data, scene, window).items()}
        truth["region"] = _interior(data.volume.shape, sigma, window)
        return {"scene": scene.as_dict()}, _bare(data), truth

    return name, {"sigma": sigma, "window": window, "scene": scene.as_dict()}, [(name, make)]


def _cube_suite(suite, options):
    from gridflow.scenes import CubeScene

    return _rendered_suite("cube", CubeScene(), options, lambda data, scene, w: data.truth)


def _leaf_suite(suite, options):
    from gridflow.scenes import LeafScene, leaf_truth

    # the experiment's truth: its interior is the leaf pixels whose window lies on it
    return _rendered_suite("leaf", LeafScene(), options,
                           lambda data, scene, w: leaf_truth(scene, margin=w // 2 + 2))


def _growth_suite(suite, options):
    from gridflow.estimator import DEFAULTS

    from .growth_maps import LEAVES, make_leaf

    seeds = tuple(options.get("seeds", (0, 1)))
    noise = float(options.get("noise", 0.003))
    leaves = tuple(options.get("leaves", LEAVES))

    def make(leaf, seed):
        sv = make_leaf(leaf, noise, seed)
        truth = {k: np.asarray(v, float) for k, v in sv.truth.items()}
        # the growth study scores every method over the default estimate's interior
        truth["region"] = _interior(sv.volume.shape, DEFAULTS["sigma"], DEFAULTS["window"])
        return {"leaf": leaf, "seed": seed, "noise": noise}, _bare(sv), truth

    return ("growth_maps", {"noise": noise, "seeds": list(seeds), "leaves": list(leaves)},
            [(f"{leaf}_seed={seed}", lambda a=leaf, b=seed: make(a, b))
             for leaf in leaves for seed in seeds])


_SUITES = {"cube": _cube_suite, "leaf": _leaf_suite, "growth_maps": _growth_suite}
# the settings each kind of suite takes (export_suite's **options)
_OPTIONS = {"sweep": set(), "cube": {"cache", "scene", "sigma", "window"},
            "leaf": {"cache", "scene", "sigma", "window"},
            "growth_maps": {"seeds", "noise", "leaves"}}
# what a manifest's items and truth files hold, per kind (beyond id, truth, sha256, region)
_ITEM_KEYS = {"sweep": {"point", "params"}, "cube": {"scene"}, "leaf": {"scene"},
              "growth_maps": {"leaf", "seed"}}
_TRUTH_KEYS = {"sweep": set(), "cube": {"face", "Z", "Zx", "Zy", "Ux", "Uy", "Uz"},
               "leaf": {"leaf", "interior", "spot_angle", "growth", "Uz"},
               "growth_maps": {"growth"}}


def export_suite(suite, folder, *, progress: bool = True, only: str | None = None,
                 **options) -> list[str]:
    """Write the suite ``suite`` into ``folder`` (see the module docstring).

    Parameters
    ----------
    suite : str or path
        A sweep spec (a shipped spec's name or a TOML file) or one of :data:`EXPERIMENTS`.
    folder : path
        A new (or empty) folder; the suite is written into a temporary folder beside it
        and renamed into place when whole, so that an interrupted export leaves none.
    only : str, optional
        A shell pattern on the items' ids (``'still_*'``): export those alone.
    **options
        The experiments' settings: ``cache`` (the render cache of ``cube`` and ``leaf``),
        ``scene`` (their :class:`~gridflow.scenes.CubeScene` or
        :class:`~gridflow.scenes.LeafScene`), ``sigma``, ``window``; ``seeds``, ``noise``,
        ``leaves`` of ``growth_maps``.

    Returns the report's lines.
    """
    from tqdm import tqdm

    from gridflow import __version__
    from gridflow.io import folder_beside, save_volume

    from .sweep import _code_fingerprint

    folder = Path(folder)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise UsageError(f"{folder}: exists and is not an empty folder (export writes a "
                         "suite into a new one)")
    if folder.resolve() == Path.cwd():
        raise UsageError(f"{folder}: the current folder; export writes a suite into a new "
                         "one (a name such as suite/)")
    kind = suite if str(suite) in _SUITES else "sweep"
    make = _SUITES.get(str(suite), _sweep_suite)
    odd = sorted(set(options) - _OPTIONS[kind])
    if odd:
        raise UsageError(f"{', '.join(odd)}: not a setting of suite {suite} (it takes "
                         f"{', '.join(sorted(_OPTIONS[kind])) or 'none'})")
    name, settings, every = make(suite, dict(options, progress=progress))
    items = [(iid, f) for iid, f in every if only is None or fnmatch.fnmatchcase(iid, only)]
    if not items:
        raise UsageError(f"--only {only!r}: matches none of the ids of suite {name}'s "
                         f"{len(every)} items (e.g. {every[0][0]})")
    target = folder.resolve()
    with folder_beside(target) as tmp:
        (tmp / "volumes").mkdir()
        (tmp / "truth").mkdir()
        entries = []
        for iid, item in tqdm(items, desc=f"export {name}", unit="volume",
                              disable=not progress):
            params, vol, truth = item()
            vpath, tpath = tmp / "volumes" / f"{iid}.npz", tmp / "truth" / f"{iid}.npz"
            save_volume(vpath, vol, compress=True)
            np.savez_compressed(tpath, **truth)      # in the temporary folder: whole or gone
            entries.append({"id": iid, **params, "volume": f"volumes/{iid}.npz",
                            "truth": f"truth/{iid}.npz",
                            "sha256": {"volume": _sha256(vpath), "truth": _sha256(tpath)}})
        manifest = {"format": SUITE_FORMAT, "suite": name, "kind": kind, **settings,
                    "only": only, "gridflow": __version__,
                    "code_fingerprint": _code_fingerprint(), "items": entries}
        with open(tmp / "manifest.json", "w") as fh:
            json.dump(manifest, fh, indent=1, sort_keys=True)
            fh.write("\n")
        if target.exists():
            target.rmdir()          # empty (checked above)
        os.replace(tmp, target)
    return [f"wrote {len(entries)} volume(s) of suite {name} to {folder}/volumes, their "
            f"truth to {folder}/truth and {folder}/manifest.json; run a method on every "
            f"volume into ESTIMATES/ID.npz, then: gridflow score {folder} ESTIMATES"]


def _manifest(folder: Path) -> dict:
    path = folder / "manifest.json"
    try:
        m = json.loads(path.read_text())
    except FileNotFoundError:
        raise UsageError(f"{folder}: no manifest.json (a suite written by gridflow "
                         "export)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(m, dict) or m.get("format") != SUITE_FORMAT or "items" not in m:
        raise UsageError(f"{path}: not a gridflow suite manifest of format {SUITE_FORMAT}")
    kind = m.setdefault("kind", "sweep")
    if kind != "sweep" and kind not in _SUITES:
        raise UsageError(f"{path}: a suite of unknown kind {kind!r} (gridflow scores "
                         f"sweeps and {', '.join(EXPERIMENTS)})")
    top = {"suite"} | ({"window"} if kind == "cube" else set())
    if top - set(m):
        raise UsageError(f"{path}: a {kind} suite's manifest needs "
                         f"{', '.join(sorted(top - set(m)))}")
    need = {"id", "truth", "sha256"} | _ITEM_KEYS[kind]
    items = m["items"] if isinstance(m["items"], list) else [None]
    for n, it in enumerate(items):
        if (not isinstance(it, dict) or need - set(it) or not isinstance(it["sha256"], dict)
                or "truth" not in it["sha256"]):
            raise UsageError(f"{path}: item {n} is not an item of a {kind} suite (it needs "
                             f"{', '.join(sorted(need))}, and sha256.truth)")
    if not items:
        raise UsageError(f"{path}: the manifest lists no items")
    return m


def _read_estimate(epath: Path, shape) -> dict:
    """A method's maps from ``epath``, checked as :func:`~gridflow.bench.methods.run_method`
    checks a method's return: known names, the images' shape, real numbers."""
    from gridflow.io import load_npz_maps

    from .methods import QUANTITIES

    # gridflow's own estimate files hold their interior too
    maps = {k: v for k, v in load_npz_maps(epath).items() if k != "interior"}
    if not maps:
        raise UsageError(f"{epath}: holds no maps (expected maps under gridflow's quantity "
                         "names)")
    unknown = [k for k in maps if k not in QUANTITIES]
    if unknown:
        raise UsageError(f"{epath}: maps under names gridflow does not score: "
                         f"{', '.join(unknown)}")
    bad = {k: v.shape for k, v in maps.items() if v.shape != tuple(shape)}
    if bad:
        raise UsageError(f"{epath}: maps of shape {bad}, expected {tuple(shape)}")
    odd = {k: str(v.dtype) for k, v in maps.items() if v.dtype.kind not in "iuf"}
    if odd:
        raise UsageError(f"{epath}: maps that are not real numbers: {odd}")
    return {k: np.asarray(v, float) for k, v in maps.items()}


def _scene(cls, d: dict):
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def _score_sweep(m, it, truth, region, maps, name) -> "list[dict]":
    from gridflow.generators import SinusoidParams
    from gridflow.metrics import evaluate

    from .sweep import NO_MODEL, _diff_json

    p = it["point"]
    gen = _diff_json(it["params"], json.loads(json.dumps(SinusoidParams().as_dict())))
    return [{"sweep": m["suite"], "param": p["param"], "value": p["value"],
             "noise": p["noise"], "seed": p["seed"], "method": name, "model": NO_MODEL,
             "motion": NO_MODEL, **r, "generator": gen, "estimator": "{}"}
            for r in evaluate(maps, truth, region)]


def _score_cube(m, it, truth, region, maps, name):
    from types import SimpleNamespace

    from gridflow.estimator import Estimate

    from .cube_experiment import cube_table

    # the experiment's table code: its regions from the truth's faces and the scene
    data = SimpleNamespace(truth=truth, meta={"source": {"scene": it["scene"]}})
    t = cube_table(data, {name: Estimate(maps, name, region, {})},
                   margin=int(m["window"]) // 2)
    return t.to_dict("records")


def _score_leaf(m, it, truth, region, maps, name):
    from gridflow.estimator import Estimate
    from gridflow.scenes import LeafScene

    from .leaf_experiment import leaf_regions, leaf_table

    truth = dict(truth, leaf=truth["leaf"].astype(bool), interior=truth["interior"].astype(bool))
    t = leaf_table(truth, {("-", name): Estimate(maps, name, region, {})},
                   leaf_regions(truth, _scene(LeafScene, it["scene"])))
    return t.to_dict("records")


def _score_growth(m, it, truth, region, maps, name):
    from .growth_maps import score, uncertainty
    from .methods import MethodError

    if "growth" not in maps:
        raise MethodError(f"{name}: its estimate of {it['id']} holds no growth map (it "
                          f"holds {', '.join(maps) or 'nothing'})")
    extra = (uncertainty(maps["growth"], maps["growth_sd"], truth["growth"], region)
             if "growth_sd" in maps else {})
    return [dict(leaf=it["leaf"], seed=it["seed"], method=name,
                 **score(maps["growth"], truth["growth"], region), **extra)]


def _columns(kind):
    if kind == "sweep":
        from .sweep import COLUMNS
        return COLUMNS
    if kind == "cube":
        from .cube_experiment import COLUMNS
        return COLUMNS
    if kind == "leaf":
        from .leaf_experiment import COLUMNS
        return COLUMNS
    return ["leaf", "seed", "method", "median_rel_error", "profile_corr", "profile_slope",
            "coverage", "within_1sd", "within_2sd", "rank_corr_sd_error"]


_SCORERS = {"sweep": _score_sweep, "cube": _score_cube, "leaf": _score_leaf,
            "growth_maps": _score_growth}


def score_suite(folder, estimates, output, *, method: str | None = None) -> list[str]:
    """Score ``estimates/ID.npz`` for every item of the suite in ``folder`` against its
    truth into the CSV ``output``, with the code that scores the suite in gridflow: a
    sweep's Eq. 22 and the others (:func:`gridflow.metrics.evaluate`, over the item's
    ``region``) in the sweep's columns; the cube's, the leaf's and the growth leaves'
    tables (see the module docstring).  ``method`` names the estimates (default the
    folder's name).  Every item must have its estimate; a truth file that does not match
    its checksum is refused.  Returns the report's lines."""
    import pandas as pd

    from gridflow.io import atomic_write, check_output, load_npz_maps

    folder, estimates = Path(folder), Path(estimates)
    out = check_output(output, suffixes=".csv", inputs=[folder, estimates], what="-o")
    m = _manifest(folder)
    if not estimates.is_dir():
        raise UsageError(f"{estimates}: no such folder of estimates (ESTIMATES/ID.npz for "
                         f"every volume of {folder})")
    name = method or estimates.resolve().name
    missing = [it["id"] for it in m["items"] if not (estimates / f"{it['id']}.npz").is_file()]
    if missing:
        raise UsageError(f"{estimates}: {len(missing)} of {len(m['items'])} estimates "
                         f"missing, e.g. {missing[0]}.npz")
    scorer = _SCORERS[m["kind"]]
    rows = []
    for it in m["items"]:
        tpath = folder / it["truth"]
        if _sha256(tpath) != it["sha256"]["truth"]:
            raise UsageError(f"{tpath}: does not match the checksum in the manifest")
        truth = load_npz_maps(tpath)
        lacking = sorted(({"region"} | _TRUTH_KEYS[m["kind"]]) - set(truth))
        if lacking:
            raise UsageError(f"{tpath}: a truth file of a {m['kind']} suite without "
                             f"{', '.join(lacking)}")
        region = truth.pop("region").astype(bool)
        maps = _read_estimate(estimates / f"{it['id']}.npz", region.shape)
        rows += scorer(m, it, truth, region, maps, name)
    if not rows:
        raise GridflowError(f"{estimates}: no estimate shares a quantity with the truth")
    df = pd.DataFrame(rows, columns=_columns(m["kind"]))
    with atomic_write(out, "w") as fh:
        df.to_csv(fh, index=False, float_format="%.7g")
    return [f"scored {len(m['items'])} estimates of {name} on suite {m['suite']}: "
            f"{len(df)} rows; wrote {out}"]
