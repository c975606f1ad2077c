"""The POV-Ray cube end to end: render (small), load, estimate; ground truth checked
against what the images show.  Needs Debian's `povray` (.ci/run installs it)."""

import numpy as np
import pytest

from gridflow.bench.cli import main
from gridflow.bench.cube_experiment import (RIGHT_DEG, SCALE, angular_errors, cube_table,
                                            observation11, observation12, run_cube)
from gridflow.scenes import face_interior
from gridflow.io import load_estimate
from gridflow.loader import load_folder
from gridflow.scenes.render import PovrayMissing, povray_binary, render_cube
from gridflow.scenes import CubeScene, cube_truth


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """64x64, 3x3 cameras, 5 frames: the CI version of the scene."""
    root = tmp_path_factory.mktemp("cube")
    scene = CubeScene(width=64, height=64, grid=(3, 3), frames=5)
    return scene, render_cube(scene, root, progress=False)


def test_render_writes_a_loadable_grid(small):
    scene, folder = small
    d = load_folder(folder)
    assert d.volume.shape == (5, 3, 3, 64, 64)
    assert d.meta["pixel_type"] == "uint16"
    # linear 16-bit rendering of a lit texture: not black, not saturated
    assert 0.0 <= d.volume.min() and d.volume.max() < 1.0 and d.volume.mean() > 0.05
    assert set(d.truth) >= {"Z", "Zx", "Zy", "Uz", "face", "interior"}


def test_render_is_cached(small, tmp_path):
    scene, folder = small
    before = {p: p.stat().st_mtime_ns for p in folder.glob("*.png")}
    assert render_cube(scene, folder.parent, progress=False) == folder
    assert {p: p.stat().st_mtime_ns for p in folder.glob("*.png")} == before


def test_end_to_end_through_cli(small, tmp_path):
    _, folder = small
    out = tmp_path / "est.npz"
    assert main(["estimate", str(folder), "--model", "full", "--sigma", "4", "--window", "17",
                 "-o", str(out)]) == 0
    maps, interior, meta = load_estimate(out)
    assert meta["settings"]["ref_frame"] is None or meta["settings"]["ref_frame"] == 2
    assert np.isfinite(maps["Z"][interior]).mean() > 0.5


def test_cube_table_and_observation(small):
    _, folder = small
    d = load_folder(folder)
    res = run_cube(d, sigma=4.0, window=17)
    t = cube_table(d, res)
    assert list(t.face.unique()) == ["left", "right"]
    assert list(t.region.unique()) == ["interior", "edge", "ridge", "silhouette",
                                       "spot_border", "away"]
    assert len(t) == 2 * 6 * 3
    # the spotlight's border and the rest partition the interior, ridge and silhouette
    # the edge
    n = t.set_index(["face", "region", "model"]).n_pixels
    for face in ("left", "right"):
        for m in ("bcc", "hf", "full"):
            assert n[face, "interior", m] == n[face, "spot_border", m] + n[face, "away", m]
            assert n[face, "edge", m] == n[face, "ridge", m] + n[face, "silhouette", m]
            assert n[face, "ridge", m] > 0 and n[face, "silhouette", m] > 0
    assert ((t.shown_right >= 0) & (t.shown_right <= 1)).all()
    assert (t.median_angle_deg <= t.p90_angle_deg).all()
    checks = observation11(t) + observation12(t)
    assert {c["observation"] for c in checks} == {"11", "12"}
    assert all(isinstance(r["holds"], bool) for r in checks)
    assert {r["check"] for r in checks} >= {"HF high at the edge and the spot's border",
                                            "full high only at the edge"}


def test_spot_angle_geometry():
    """The spotlight points at the cube's centre, whose line of sight from the light
    crosses the visible surface: there the angle is ~0; the visible cube spans less than
    the falloff; off the cube it is NaN."""
    from gridflow.scenes import spot_angle

    scene = CubeScene()
    t = cube_truth(scene)
    a = spot_angle(scene, t["Z"], scene.ref_frame)
    on = t["face"] > 0
    assert np.isnan(a[~on]).all() and np.isfinite(a[on]).all()
    assert a[on].min() < 1.0 and a[on].max() < scene.spot_falloff_deg
    assert ((a[on] >= scene.spot_radius_deg)).mean() > 0.05     # a border exists


def test_analytic_truth_matches_the_images(tmp_path):
    """A static, evenly lit render: brightness constancy holds, so BCC's depth and slopes
    must match the ray-cast truth on the face interiors.  Measured at this size (192 px,
    sigma 6): median |Z/Z_true - 1| = 4.4e-4; median Z_X -1.78 on the left face (truth
    -1.732: the steep face is only ~40 px wide) and 0.575 on the right (truth 0.577);
    |median Z_Y| <= 0.006.  The bounds below leave 3-20x room for that, and a convention
    error lands far outside them: a focal length off by 2 or camera spacing in other
    units scales Z by >= 2; a flipped X axis flips the sign of Z_X; a flipped Y axis or a
    transposed grid moves the slope into Z_Y."""
    scene = CubeScene(width=192, height=192, grid=(3, 3), frames=5, static=True,
                      spotlight=False)
    d = load_folder(render_cube(scene, tmp_path, progress=False))
    e = run_cube(d, sigma=6.0, window=25)["bcc"]
    face = d.truth["face"]
    inner = face_interior(face, 12) & e.interior
    assert abs(np.nanmedian(e["Z"][inner] / d.truth["Z"][inner]) - 1) < 0.01
    for fid, zx in ((1, -np.sqrt(3)), (2, 1 / np.sqrt(3))):
        m = inner & (face == fid)
        assert m.sum() > 1000
        assert abs(np.nanmedian(e["Zx"][m]) - zx) < 0.1 * abs(zx)
        assert abs(np.nanmedian(e["Zy"][m])) < 0.05


def test_truth_geometry():
    t = cube_truth(CubeScene())
    for fid, zx in ((1, -np.sqrt(3)), (2, 1 / np.sqrt(3))):
        np.testing.assert_allclose(t["Zx"][t["face"] == fid], zx, rtol=1e-12)
    assert np.all(np.isnan(t["Z"][t["face"] == 0]))
    assert np.nanmin(t["Z"]) > 300 and np.all(t["Uz"][t["face"] > 0] == -2.0)


def test_missing_povray_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv("POVRAY", "no-such-povray-binary")
    with pytest.raises(PovrayMissing, match="apt-get install povray"):
        povray_binary()
    with pytest.raises(PovrayMissing):
        render_cube(CubeScene(width=16, height=16, grid=(3, 3), frames=3), tmp_path,
                    progress=False)


def test_angular_errors():
    """The 3-D angle and the angle as Fig. 1 draws it (lateral x SCALE), on vectors whose
    angles are known: a lateral error of tan(a) |U_Z| is a degrees in 3-D and
    atan(SCALE tan a) as drawn; an invalid estimate is NaN."""
    truth = {"Ux": np.zeros((1, 3)), "Uy": np.zeros((1, 3)), "Uz": np.full((1, 3), -2.0)}
    a = np.radians([0.1, 1.0, 10.0])
    est = {"Ux": 2 * np.tan(a)[None] * np.array([[1, 0, np.sqrt(0.5)]]),
           "Uy": 2 * np.tan(a)[None] * np.array([[0, 1, np.sqrt(0.5)]]),
           "Uz": np.full((1, 3), -2.0)}
    np.testing.assert_allclose(angular_errors(est, truth)[0], np.degrees(a), rtol=1e-9)
    np.testing.assert_allclose(angular_errors(est, truth, SCALE)[0],
                               np.degrees(np.arctan(SCALE * np.tan(a))), rtol=1e-9)
    est["Uz"] = np.array([[np.nan, 2.0, -2.0]])
    got = angular_errors(est, truth)[0]
    assert np.isnan(got[0]) and got[1] > 90


def test_observation12_reads_the_fraction_and_the_medians():
    """Observation 12 holds for a face exactly when the full model's drawn directions are
    right on at least 90 % of the interior and the other models' median angles are at
    least twice its own; each condition failing alone fails its check."""
    import pandas as pd

    def table(full_right, hf_angle):
        rows = [{"face": "left", "region": "interior", "model": m, "shown_right": r,
                 "median_angle_deg": ang}
                for m, r, ang in (("bcc", 0.0, 90.0), ("hf", 0.5, hf_angle),
                                  ("full", full_right, 1.0))]
        return pd.DataFrame(rows)

    def verdicts(t):
        return [c["holds"] for c in observation12(t)]

    assert verdicts(table(0.95, 3.0)) == [True, True]
    assert verdicts(table(0.85, 3.0)) == [False, True]
    assert verdicts(table(0.95, 1.5)) == [True, False]
    assert RIGHT_DEG == 22.5


def test_the_cube_experiment_takes_a_method(small, tmp_path, monkeypatch):
    """gridflow cube --method: a method's rows beside the models', scored by the same
    table code over the same pixels; the full model wrapped as a method gives the full
    model's rows, a method returning U_Z alone is scored on U_Z (the rest NaN)."""
    import pandas as pd

    scene, folder = small
    (tmp_path / "cubem.py").write_text(
        "from gridflow.estimator import estimate\n"
        "def full(volume, focal_length, camera_spacing, *, principal_point=None):\n"
        "    return dict(estimate(volume, focal_length, camera_spacing, sigma=4.0,\n"
        "                         window=17, principal_point=principal_point).maps)\n"
        "def uz(volume, focal_length, camera_spacing, *, principal_point=None):\n"
        "    return {'Uz': full(volume, focal_length, camera_spacing,\n"
        "                       principal_point=principal_point)['Uz']}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    csv = tmp_path / "cube.csv"
    assert main(["cube", "--size", "64", "--grid", "3", "--frames", "5", "--sigma", "4",
                 "--window", "17", "--cache", str(folder.parent), "--csv", str(csv),
                 "--fig-dir", str(tmp_path / "figs"), "--method", "cubem:full", "--method",
                 "cubem:uz", "--no-progress"]) == 0
    t = pd.read_csv(csv)
    key = ["face", "region"]
    full = t[t.model == "full"].set_index(key)
    wrapped = t[t.model == "cubem:full"].set_index(key)
    for col in ("q_rel_Uz", "q_abs_Ux", "q_rel_Z", "median_angle_deg", "n_valid"):
        np.testing.assert_allclose(wrapped[col], full.loc[wrapped.index, col], rtol=1e-12)
    only = t[t.model == "cubem:uz"].set_index(key)
    np.testing.assert_allclose(only.q_rel_Uz, full.loc[only.index, "q_rel_Uz"], rtol=1e-12)
    assert only.q_rel_Z.isna().all() and only.median_angle_deg.isna().all()


def test_the_cube_exported_and_scored_from_files_as_the_experiment_scores(small, tmp_path):
    """gridflow export cube: the rendered volume without truth, the truth apart with the
    pixels the experiment scores (the estimator's interior at its window); the full
    model's maps made from the file and scored by gridflow score give the experiment's
    own rows for the full model (cube_table over the same faces and regions)."""
    import json

    import pandas as pd

    from gridflow.bench.suites import export_suite, score_suite
    from gridflow.estimator import estimate

    scene, folder = small
    export_suite("cube", tmp_path / "s", progress=False, cache=folder.parent, scene=scene,
                 sigma=4.0, window=17)
    m = json.loads((tmp_path / "s" / "manifest.json").read_text())
    assert m["kind"] == "cube" and m["window"] == 17
    with np.load(tmp_path / "s" / "volumes" / "cube.npz") as z:
        assert not [k for k in z.files if k.startswith("truth")]
        e = estimate(z["volume"], float(z["focal_length"]), tuple(z["camera_spacing"]),
                     principal_point=tuple(z["principal_point"]), sigma=4.0, window=17)
    (tmp_path / "est").mkdir()
    np.savez(tmp_path / "est" / "cube.npz", **e.maps)
    score_suite(tmp_path / "s", tmp_path / "est", tmp_path / "c.csv", method="full")
    got = pd.read_csv(tmp_path / "c.csv")
    data = load_folder(folder)
    want = cube_table(data, run_cube(data, sigma=4.0, window=17, models=("full",)))
    assert list(got.columns) == list(want.columns) and len(got) == len(want)
    num = [c for c in want.columns if c not in ("face", "region", "model")]
    assert (got[["face", "region", "model"]].values == want[["face", "region", "model"]]
            .values).all()
    np.testing.assert_allclose(got[num].to_numpy(float), want[num].to_numpy(float),
                               rtol=1e-6)                   # the CSV keeps 7 digits
