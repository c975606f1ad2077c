"""Shared builders of the test suite: camera-grid folders, sweep specs, recordings, runs that
must fail with a message, snapshots of what lies on disk, and the tally of inputs tried.

A plain module (no fixtures, no tests): test modules import it as ``from builders import
...`` (``pythonpath = ["tests"]`` in pyproject.toml).  One definition of each; a test
module that needs other data passes it, so that every test keeps its own data, seeds and
sizes.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np

# --- the tally of inputs tried (reported by conftest.pytest_terminal_summary) ----------------

TRIED: Counter = Counter()


def tried(kind: str, n: int = 1) -> None:
    """Count ``n`` inputs of ``kind`` tried: the property and hostile-input tests' tally."""
    TRIED[kind] += n


# --- what lies on disk, and command lines that must fail ----------------------------------------

def snapshot(folder: Path) -> dict:
    """Every file below ``folder`` with its bytes (FIFOs and folders by kind only)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        if p.is_fifo():
            out[rel] = "fifo"
        elif p.is_dir():
            out[rel] = "dir"
        else:
            out[rel] = p.read_bytes()
    return out


def cli_fails(args, capsys, match: str, code: int = 2) -> str:
    """Run ``gridflow ARGS`` in-process: it must exit ``code`` with ``match`` in its stderr
    (which is returned)."""
    from gridflow.bench.cli import main

    rc = main([str(a) for a in args])
    err = capsys.readouterr().err
    assert rc == code, err
    assert match in err, err
    return err


def refused(error, match: str, fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` must raise ``error`` with a message that ``match`` (a regular
    expression) finds; it is returned.  Any other outcome fails the test as a check: an
    acceptance, and another exception too (a bad value let through and failing later
    with a KeyError is the bug the refusal guards against, not an error of the test)."""
    import re

    import pytest

    try:
        fn(*args, **kwargs)
    except error as exc:
        assert re.search(match, str(exc)), f"refused for another reason: {exc}"
        return exc
    except Exception as exc:            # noqa: BLE001 - any other failure is the finding
        pytest.fail(f"not refused ({error.__name__}: {match!r}) but failed later: "
                    f"{type(exc).__name__}: {exc}")
    pytest.fail(f"accepted; expected {error.__name__}: {match!r}")


# --- camera-grid image folders -------------------------------------------------------------------

PATTERN = "t{t:02d}_y{sy}_x{sx}.png"


def _write_folder(folder: Path, images: np.ndarray, manifest: dict) -> Path:
    """``images`` (T, Sy, Sx, H, W), one file a view named by PATTERN, and ``grid.json``."""
    import imageio.v3 as iio

    folder.mkdir(exist_ok=True)
    T, Sy, Sx = images.shape[:3]
    for t in range(T):
        for i in range(Sy):
            for j in range(Sx):
                iio.imwrite(folder / PATTERN.format(t=t, sy=i, sx=j), images[t, i, j])
    (folder / "grid.json").write_text(json.dumps(manifest))
    return folder


def sinusoid_folder(folder: Path, T=5, Sy=3, Sx=3, H=40, W=40, **manifest) -> Path:
    """A textured camera-grid folder (a 16-bit rendering of a sinusoid volume) with the
    volume's geometry in its manifest; ``manifest`` adds or replaces keys."""
    from gridflow.generators import make_sinusoid

    sv = make_sinusoid(height=H, width=W, frames=T, grid=(Sy, Sx), offset=1.0, amplitude=0.5)
    v = sv.volume / sv.volume.max()
    m = {"focal_length": sv.focal_length, "camera_spacing": list(sv.camera_spacing),
         "grid": [Sy, Sx], "frames": T, "pattern": PATTERN}
    m.update(manifest)
    return _write_folder(folder, np.round(v * 65535).astype(np.uint16), m)


def noise_volume(T=3, Sy=3, Sx=3, H=12, W=10) -> np.ndarray:
    """The uniform noise in [0, 1) that ``noise_folder`` writes (seed 0)."""
    return np.random.default_rng(0).random((T, Sy, Sx, H, W))


def noise_folder(folder: Path, T=3, Sy=3, Sx=3, H=12, W=10, *, dtype=np.uint16,
                 rounded: bool = True, **manifest) -> Path:
    """A camera-grid folder of uniform noise (``noise_volume``) scaled to the full range of
    ``dtype``, rounded or (``rounded=False``) truncated; focal length 500, spacing (0.1,
    0.2); ``manifest`` adds or replaces keys."""
    scaled = noise_volume(T, Sy, Sx, H, W) * np.iinfo(dtype).max
    images = (np.round(scaled) if rounded else scaled).astype(dtype)
    m = {"focal_length": 500.0, "camera_spacing": [0.1, 0.2], "grid": [Sy, Sx], "frames": T,
         "pattern": PATTERN}
    m.update(manifest)
    return _write_folder(folder, images, m)


def small_volume(path: Path) -> Path:
    """A small sinusoid volume (48 x 48 px, 7 frames, 3 x 3 views, a1 = 0.1) saved as .npz."""
    from gridflow.generators import make_sinusoid
    from gridflow.io import save_volume

    save_volume(path, make_sinusoid(height=48, width=48, frames=7, grid=(3, 3), a1=0.1))
    return path


# --- sweep specs ---------------------------------------------------------------------------------

# a small spec that runs in seconds: one model, two points
SPEC_OK = {"sweep": {"name": "t", "models": ["full"], "noise": [0.0], "seeds": [0]},
           "base": {"height": 40, "width": 40, "frames": 5, "grid": [3, 3]},
           "estimator": {"sigma": 2.0, "window": 9},
           "axis": [{"param": "a1", "values": [0.0, 0.1]}]}


def spec_dict(raw: dict, /, *, replace: bool = False, **sections) -> dict:
    """A copy of the raw spec ``raw`` with ``sections`` changed: a table is merged into the
    table of that name (``replace=True``: put in its place), None removes the section, any
    other value is put in its place."""
    raw = json.loads(json.dumps(raw))
    for k, v in sections.items():
        if v is None:
            raw.pop(k)
        elif not replace and isinstance(v, dict) and isinstance(raw.get(k), dict):
            raw[k].update(v)
        else:
            raw[k] = v
    return raw


def sweep_spec(raw: dict, /, *, replace: bool = False, **sections):
    """``spec_dict`` read as a SweepSpec (its errors are the spec's own)."""
    from gridflow.bench.spec import SweepSpec

    return SweepSpec.from_dict(spec_dict(raw, replace=replace, **sections))


# --- recordings and map series -------------------------------------------------------------------

# the small growth recording: 64 x 64 px, 3 x 3 views
RECORDING = dict(frames=40, height=64, width=64, grid=(3, 3), growth=2e-3, rhythm=0.8,
                 period=60.0, illumination=0.3)


def record(path: Path, **over) -> Path:
    """``gridflow record -o PATH`` of RECORDING with ``over`` changed; it must succeed."""
    from gridflow.bench.cli import main

    args = ["record", "-o", str(path), "--no-progress"]
    for k, v in {**RECORDING, **over}.items():
        flag = "--" + k.replace("_", "-")
        args += [flag, *map(str, v)] if isinstance(v, tuple) else [flag, str(v)]
    assert main(args) == 0
    return path


def run_series(recording, output, *, every=1, settings=None, **options):
    """The pipeline into a map series, with the growth model unless settings say
    otherwise (the command line's ``estimate REC -o MAPS.zarr --motion affine``)."""
    from gridflow.pipeline import RunOptions, estimate

    settings = {"motion": "affine", **(settings or {})}
    return estimate(recording, output, RunOptions(settings=settings, every=every, **options))


def store_arrays(path: Path) -> dict:
    """Every array of a Zarr store, read whole."""
    import zarr

    g = zarr.open_group(str(path), mode="r")
    return {name: np.asarray(a[...]) for name, a in g.arrays()}


def same_arrays(a: dict, b: dict) -> bool:
    """The same names and the same arrays (NaN equal to NaN in float arrays)."""
    return a.keys() == b.keys() and all(
        np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f") for k in a)
