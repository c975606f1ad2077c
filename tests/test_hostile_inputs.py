"""Hostile inputs: malformed camera-grid folders and manifests (every key, FIFOs, links
out of the folder, ambiguous patterns), npz volumes and estimator settings are refused
naming the file, key or setting; the settings a manifest gives are honoured.

Every case must end in a clear error (exit 2 from the CLI, naming the file, key or
argument) or a correct result; none may crash, hang, exit 0 with garbage, or change a
file it was not asked to write.  The cases are counted (``builders.tried``) and the
count is printed in the pytest summary.
"""

from __future__ import annotations

import json
import os
import re
import threading
import time

import numpy as np
import pytest

from builders import PATTERN, cli_fails, sinusoid_folder, tried
from gridflow.bench.cli import main
from gridflow.estimator import EstimatorSettings, InputError, estimate
from gridflow.generators import make_sinusoid
from gridflow.loader import LoaderError, load_folder


# --- settings silently ignored or wrongly applied --------------------------------------------

def test_reference_frame_of_the_manifest_is_used(tmp_path, capsys):
    folder = sinusoid_folder(tmp_path / "f", T=7, reference_frame=2)
    assert main(["estimate", str(folder), "-o", str(tmp_path / "e.npz"), "--sigma", "2",
                 "--window", "9", "--model", "bcc"]) == 0
    meta = json.loads(str(np.load(tmp_path / "e.npz")["meta"]))
    assert meta["settings"]["ref_frame"] == 2
    # --ref-frame overrides the manifest
    assert main(["estimate", str(folder), "-o", str(tmp_path / "e3.npz"), "--sigma", "2",
                 "--window", "9", "--model", "bcc", "--ref-frame", "3"]) == 0
    assert json.loads(str(np.load(tmp_path / "e3.npz")["meta"]))["settings"]["ref_frame"] == 3
    tried("manifest setting honoured", 2)


@pytest.mark.parametrize("key, value, match", [
    ("reference_frame", 99, "'reference_frame' must be a frame index"),
    ("reference_frame", "x", "'reference_frame' must be a frame index"),
    ("reference_frame", 1.5, "'reference_frame' must be a frame index"),
    ("principal_point", [float("nan"), 3.0], "'principal_point' must be a list of 2 finite"),
    ("principal_point", [1.0], "'principal_point' must be a list of 2 finite"),
    ("focal_length", True, "'focal_length' must be a positive"),
    ("focal_length", float("inf"), "'focal_length' must be a positive"),
    ("camera_spacing", [0.1, -0.1], "'camera_spacing'"),
    ("grid", [2, 3], "even size"),
    ("grid", [3.0, 3], "'grid' must be [Sy, Sx]"),
    ("frames", 1e9, "'frames' must be an integer"),
    ("frames", 10 ** 9, "more than"),
    ("frames", 0, "'frames' must be an integer >= 1"),
    ("pattern", "{t}{sy}.png", "must use the fields"),
    ("pattern", "t{t:>1000000000}_{sy}_{sx}.png", "is not allowed"),
    ("pattern", "t{t!r}_{sy}_{sx}.png", "is not allowed"),
    ("pattern", "t{t.real}_{sy}_{sx}.png", "must use the fields"),
    ("pattern", "../t{t:02d}_y{sy}_x{sx}.png", "outside the folder"),
    ("pattern", "/tmp/t{t:02d}_y{sy}_x{sx}.png", "outside the folder"),
    ("pattern", 7, "'pattern' must be a file name pattern"),
    ("truth", {"Z": "../Z.npy"}, "outside the folder"),
    ("truth", {"Z": 3}, "'truth' must map"),
    ("truth", ["Z.npy"], "'truth' must map"),
    ("reference_camera", [0, 0], "not the centre camera"),
    ("units", 5, "'units' must be a str"),
    ("colour", "grey", "unknown key(s) ['colour']"),
])
def test_every_manifest_key_is_checked(tmp_path, key, value, match):
    folder = sinusoid_folder(tmp_path / "f", H=12, W=12, T=3)
    m = json.loads((folder / "grid.json").read_text())
    m[key] = value
    (folder / "grid.json").write_text(json.dumps(m))
    t0 = time.monotonic()
    with pytest.raises(LoaderError, match=re.escape(match)):
        load_folder(folder)
    assert time.monotonic() - t0 < 10          # no gigabyte allocation on the way
    assert str(folder / "grid.json") in _message(folder, load_folder)
    tried("malformed manifest key")


def _message(folder, fn) -> str:
    try:
        fn(folder)
    except LoaderError as exc:
        return str(exc)
    return ""


def test_ambiguous_pattern_is_refused(tmp_path):
    # 12 frames x 11 columns: "{t}{sx}_{sy}" names t=1, sx=10 and t=11, sx=0 alike
    folder = tmp_path / "f"
    folder.mkdir()
    (folder / "grid.json").write_text(json.dumps({
        "focal_length": 100.0, "camera_spacing": [0.1, 0.0], "grid": [1, 11], "frames": 12,
        "pattern": "{t}{sx}_{sy}.png"}))
    with pytest.raises(LoaderError, match="is ambiguous"):
        load_folder(folder)
    tried("ambiguous pattern")


def test_fifo_among_images_is_refused_without_blocking(tmp_path):
    folder = sinusoid_folder(tmp_path / "f", H=12, W=12, T=3)
    victim = folder / PATTERN.format(t=1, sy=1, sx=1)
    victim.unlink()
    os.mkfifo(victim)
    box = {}
    th = threading.Thread(target=lambda: box.setdefault("msg", _message(folder, load_folder)),
                          daemon=True)
    th.start()
    th.join(20)
    assert not th.is_alive(), "the loader blocked on a FIFO"
    assert "not regular files" in box["msg"]
    tried("FIFO image")


def test_truth_fifo_and_symlink_outside_are_refused(tmp_path):
    folder = sinusoid_folder(tmp_path / "f", H=12, W=12, T=3, truth={"Z": "Z.npy"})
    os.mkfifo(folder / "Z.npy")
    assert "not a regular file" in _message(folder, load_folder)
    (folder / "Z.npy").unlink()
    np.save(tmp_path / "outside.npy", np.zeros((12, 12)))
    (folder / "Z.npy").symlink_to(tmp_path / "outside.npy")
    assert "outside the folder" in _message(folder, load_folder)
    tried("truth path refused", 2)


@pytest.mark.parametrize("settings, match", [
    ({"band_rows": -5}, "band_rows"),
    ({"band_rows": 0}, "band_rows"),
    ({"band_rows": 2.5}, "band_rows"),
    ({"sigma": float("nan")}, "sigma"),
    ({"sigma": True}, "sigma"),
    ({"window": 9.0}, "window"),
    ({"temporal_radius": -1}, "temporal_radius"),
    ({"ref_frame": 1.5}, "ref_frame"),
    ({"slant_correction": "no"}, "slant_correction"),
    ({"method": None}, "method"),
])
def test_every_estimator_setting_is_checked(settings, match):
    with pytest.raises(InputError, match=match):
        EstimatorSettings(**settings)
    tried("malformed estimator setting")


def test_nan_principal_point_is_refused(tmp_path, small_volume, capsys):
    sv = make_sinusoid(height=40, width=40, frames=5, grid=(3, 3))
    with pytest.raises(InputError, match="principal_point"):
        estimate(sv.volume, sv.focal_length, sv.camera_spacing,
                 principal_point=(np.nan, 3.0), sigma=2.0, window=9)
    z = dict(np.load(small_volume))
    z["principal_point"] = np.array([np.nan, 1.0])
    np.savez(tmp_path / "pp.npz", **z)
    cli_fails(["estimate", tmp_path / "pp.npz", "-o", tmp_path / "e.npz"], capsys,
               "'principal_point' must be 2 finite numbers")
    assert not (tmp_path / "e.npz").exists()
    z = dict(np.load(small_volume))
    z["extra"] = np.zeros(3)
    np.savez(tmp_path / "extra.npz", **z)
    cli_fails(["estimate", tmp_path / "extra.npz", "-o", tmp_path / "e.npz"], capsys,
               "unknown array(s) ['extra']")
    tried("malformed npz volume", 3)
