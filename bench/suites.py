"""Data for those who do not call Python: a sweep's volumes exported as interchange files,
and a folder of estimates scored into the sweep's table.

``gridflow export SUITE DIR`` (:func:`export_suite`) writes every point of the sweep spec
``SUITE`` (a shipped spec's name or a TOML file) as::

    DIR/manifest.json            the suite: name, spec, gridflow's version and the code
                                 fingerprint, and per item its id, point, generator
                                 parameters and the SHA-256 of its files
    DIR/volumes/ID.npz           the interchange volume (no truth arrays)
    DIR/truth/ID.npz             the truth maps and ``region``, the pixels scored

A method run outside gridflow writes ``ESTIMATES/ID.npz`` (its maps under gridflow's
quantity names, :mod:`gridflow.bench.methods`) for every volume; ``gridflow score DIR
ESTIMATES`` (:func:`score_suite`) scores them with the code that scores the sweeps, into a
CSV of the sweep's columns (:data:`gridflow.bench.sweep.COLUMNS`), so that the claims and
figures read it as they read a sweep.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from gridflow.errors import GridflowError, UsageError

__all__ = ["export_suite", "score_suite", "SUITE_FORMAT"]

# the layout's version: a reader refuses a manifest of another
SUITE_FORMAT = 1


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


def export_suite(suite, folder, *, progress: bool = True) -> list[str]:
    """Write every point of the sweep spec ``suite`` into ``folder`` (see the module
    docstring); the folder must not exist or be empty.  Returns the report's lines."""
    from tqdm import tqdm

    from gridflow import __version__
    from gridflow.io import atomic_write, save_volume
    from gridflow.volume import GridVolume

    from .spec import SweepSpec
    from .sweep import _code_fingerprint, point_data, scoring_region

    spec = SweepSpec.from_toml(suite)
    folder = Path(folder)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise UsageError(f"{folder}: exists and is not an empty folder (export writes a "
                         "suite into a new one)")
    (folder / "volumes").mkdir(parents=True, exist_ok=True)
    (folder / "truth").mkdir(exist_ok=True)
    items = []
    for point in tqdm(spec.points(), desc=f"export {spec.name}", unit="volume",
                      disable=not progress):
        params, sv, truth = point_data(spec, point)
        iid = _item_id(point)
        vol, tru = folder / "volumes" / f"{iid}.npz", folder / "truth" / f"{iid}.npz"
        save_volume(vol, GridVolume(sv.volume, sv.focal_length, sv.camera_spacing,
                                    sv.principal_point, {}, {}), compress=True)
        with atomic_write(tru) as fh:
            np.savez_compressed(fh, region=scoring_region(spec, sv.volume.shape),
                                **{k: np.asarray(v, float) for k, v in truth.items()})
        items.append({"id": iid, "point": point.__dict__, "params": params.as_dict(),
                      "volume": f"volumes/{iid}.npz", "truth": f"truth/{iid}.npz",
                      "sha256": {"volume": _sha256(vol), "truth": _sha256(tru)}})
    manifest = {"format": SUITE_FORMAT, "suite": spec.name, "spec": spec.as_dict(),
                "gridflow": __version__, "code_fingerprint": _code_fingerprint(),
                "items": items}
    with atomic_write(folder / "manifest.json", "w") as fh:
        json.dump(manifest, fh, indent=1, sort_keys=True)
        fh.write("\n")
    return [f"wrote {len(items)} volumes of suite {spec.name} to {folder}/volumes, their "
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
    need = {"id", "point", "params", "truth", "sha256"}
    for n, it in enumerate(m["items"] if isinstance(m["items"], list) else [None]):
        if not isinstance(it, dict) or need - set(it) or not isinstance(it["sha256"], dict):
            raise UsageError(f"{path}: item {n} is not an item of a suite (it needs "
                             f"{', '.join(sorted(need))})")
    return m


def score_suite(folder, estimates, output, *, method: str | None = None) -> list[str]:
    """Score ``estimates/ID.npz`` for every item of the suite in ``folder`` against its
    truth (Eq. 22 and the others, :func:`gridflow.metrics.evaluate`, over the item's
    ``region``) into the CSV ``output`` (the sweep's columns; ``method`` names the
    estimates, default the folder's name).  Every item must have its estimate; a truth
    file that does not match its checksum is refused.  Returns the report's lines."""
    import pandas as pd

    from gridflow.io import atomic_write, check_output, load_npz_maps
    from gridflow.metrics import evaluate

    from .methods import QUANTITIES
    from .sweep import COLUMNS, NO_MODEL, _diff_json

    from gridflow.generators import SinusoidParams

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
    rows = []
    for it in m["items"]:
        tpath = folder / it["truth"]
        if _sha256(tpath) != it["sha256"]["truth"]:
            raise UsageError(f"{tpath}: does not match the checksum in the manifest")
        truth = load_npz_maps(tpath)
        region = truth.pop("region").astype(bool)
        epath = estimates / f"{it['id']}.npz"
        # gridflow's own estimate files hold their interior too
        maps = {k: v for k, v in load_npz_maps(epath).items() if k != "interior"}
        unknown = [k for k in maps if k not in QUANTITIES]
        if unknown:
            raise UsageError(f"{epath}: maps under names gridflow does not score: "
                             f"{', '.join(unknown)}")
        bad = {k: v.shape for k, v in maps.items() if v.shape != region.shape}
        if bad:
            raise UsageError(f"{epath}: maps of shape {bad}, expected {region.shape}")
        odd = {k: str(v.dtype) for k, v in maps.items() if v.dtype.kind not in "iuf"}
        if odd:
            raise UsageError(f"{epath}: maps that are not real numbers: {odd}")
        p = it["point"]
        gen = _diff_json(it["params"], json.loads(json.dumps(SinusoidParams().as_dict())))
        for r in evaluate({k: np.asarray(v, float) for k, v in maps.items()}, truth, region):
            rows.append({"sweep": m["suite"], "param": p["param"], "value": p["value"],
                         "noise": p["noise"], "seed": p["seed"], "method": name,
                         "model": NO_MODEL, "motion": NO_MODEL, **r, "generator": gen,
                         "estimator": "{}"})
    if not rows:
        raise GridflowError(f"{estimates}: no estimate shares a quantity with the truth")
    df = pd.DataFrame(rows, columns=COLUMNS)
    with atomic_write(out, "w") as fh:
        df.to_csv(fh, index=False, float_format="%.7g")
    return [f"scored {len(m['items'])} estimates of {name} on suite {m['suite']}: "
            f"{len(df)} rows; wrote {out}"]
