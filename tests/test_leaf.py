"""The POV-Ray leaf: its truth matches its images, and the affine motion model measures
its growth where the translation model mistakes it for motion in depth."""

from __future__ import annotations

import numpy as np
import pytest

from gridflow.estimator import estimate_models
from gridflow.loader import load_folder
from gridflow.scenes import LeafScene, leaf_truth, render_cube

SMALL = LeafScene(width=160, height=160, grid=(3, 3), frames=5, growth=4e-3)


@pytest.fixture(scope="module")
def leaf_folder(tmp_path_factory):
    return render_cube(SMALL, tmp_path_factory.mktemp("leaf"), progress=False)


@pytest.fixture(scope="module")
def leaf(leaf_folder):
    return load_folder(leaf_folder), leaf_truth(SMALL, margin=14)


def test_truth_mask_matches_the_image(leaf):
    """The leaf's pixels by ray casting against the rendered reference image (the dark
    texture end is 0.05, the background 0): measured 99.96 % agree (a few edge pixels)."""
    data, truth = leaf
    img = data.volume[SMALL.ref_frame, 1, 1]
    assert ((img > 0.01) == truth["leaf"]).mean() >= 0.999
    assert data.truth["growth"][truth["leaf"]] == pytest.approx(4e-3)


def test_affine_model_measures_the_leafs_growth(leaf):
    """Over the interior (the window on the leaf), full model, sigma 5, each pixel solved
    alone (growth_support=0): measured median relative U_Z error 0.083 (affine) against
    0.81 (translation), median growth 4.61e-3 for a true 4e-3 (15 %) when this test was
    written (4.79e-3, 20 %, now).  Asked: affine U_Z below 3x its measured error,
    translation above 0.5, the median growth within 3x the first measured deviation
    (45 %).

    With the pooled default the U_Z error falls (measured 0.030; asked: the same bound),
    but the growth does not improve on this leaf of 5 frames and 3 x 3 cameras: the
    per-pixel tilt rate is biased (Z_y,t 5.5e-3 where the truth is 0) and pooling carries
    the bias everywhere (median growth 5.69e-3, +42 %; docs/model.md, *Pooled depth
    rates*); asked: within the same 45 %, so that a worse pooling fails here."""
    data, truth = leaf
    out = {}
    for motion, extra in (("translation", {}), ("affine", {"growth_support": 0}),
                          ("pooled", {})):
        e = estimate_models(data.volume, data.focal_length, data.camera_spacing,
                            motion="translation" if motion == "translation" else "affine",
                            sigma=5.0, window=21, models=("full",),
                            ref_frame=SMALL.ref_frame, **extra)["full"]
        m = truth["interior"] & e.interior
        out[motion] = (np.median(np.abs(e["Uz"][m] - truth["Uz"][m]) / np.abs(truth["Uz"][m])),
                       np.median(e["growth"][m]) if "growth" in e else None)
    assert out["affine"][0] <= 3 * 0.083 and out["pooled"][0] <= 3 * 0.083
    assert out["translation"][0] >= 0.5
    assert abs(out["affine"][1] - 4e-3) <= 0.45 * 4e-3
    assert abs(out["pooled"][1] - 4e-3) <= 0.45 * 4e-3


def test_the_leaf_exported_and_scored_from_files_as_the_experiment_scores(leaf_folder,
                                                                          tmp_path):
    """gridflow export leaf: the rendered volume without truth, the experiment's truth
    apart (its interior: leaf pixels the window's reach from the edge) with the pixels it
    scores; the affine full model's maps made from the file and scored by gridflow score
    give the experiment's table for them (leaf_table over its regions and the
    estimator's interior)."""
    import pandas as pd

    from gridflow.bench.leaf_experiment import leaf_regions, leaf_table
    from gridflow.bench.suites import export_suite, score_suite
    from gridflow.estimator import estimate

    export_suite("leaf", tmp_path / "s", progress=False, cache=leaf_folder.parent,
                 scene=SMALL, sigma=5.0, window=21)
    with np.load(tmp_path / "s" / "volumes" / "leaf.npz") as z:
        assert not [k for k in z.files if k.startswith("truth")]
        e = estimate(z["volume"], float(z["focal_length"]), tuple(z["camera_spacing"]),
                     principal_point=tuple(z["principal_point"]), sigma=5.0, window=21,
                     motion="affine")
    (tmp_path / "est").mkdir()
    np.savez(tmp_path / "est" / "leaf.npz", Uz=e["Uz"], growth=e["growth"])
    score_suite(tmp_path / "s", tmp_path / "est", tmp_path / "l.csv", method="mine")
    got = pd.read_csv(tmp_path / "l.csv")
    truth = leaf_truth(SMALL, margin=21 // 2 + 2)
    want = leaf_table(truth, {("-", "mine"): e}, leaf_regions(truth, SMALL))
    assert list(got.columns) == list(want.columns) and len(got) == len(want) == 4
    assert (got.region == want.region).all() and (got.model == "mine").all()
    num = [c for c in want.columns if c not in ("region", "motion", "model")]
    np.testing.assert_allclose(got[num].to_numpy(float), want[num].to_numpy(float),
                               rtol=1e-6)                   # the CSV keeps 7 digits


# --- the leaf as a recording (issue 25) ----------------------------------------------------

from gridflow.scenes import LeafRecording  # noqa: E402

# 160 px as SMALL; the default day of 40 frames, of which the 12 frames here see a rising rate
REC = LeafRecording(width=160, height=160, grid=(3, 3), frames=12, growth=4e-3, margin=12.0)


def test_leaf_recording_truth_is_its_geometrys_motion():
    """Each frame's truth is the motion of the leaf as the scene draws it: a material point
    p (found from the truth's depth at a pixel) moves along X(t) = A(t) p + b(t), the
    transform POV-Ray is given; its central difference (error O(h^2), ~1e-9 here) equals
    the truth's (U_X, U_Y, U_Z) there, and the growth truth is 2 s'/s of the scale."""
    h = 1e-4
    for k in (0, 3, 7):
        t = REC.truth_at(k)
        assert np.isfinite(t["growth"]).any()
        rate = (np.log(REC.scale(k + h)) - np.log(REC.scale(k - h))) / h
        assert np.nanmax(np.abs(t["growth"] / rate - 1)) < 1e-6
        A, b = REC.transform(float(k))
        for y, x in ((80, 80), (50, 85), (100, 70)):
            assert np.isfinite(t["Z"][y, x]), (k, y, x)
            r = np.array([(x - 79.5) / REC.f, (y - 79.5) / REC.f, 1.0])
            p = np.linalg.solve(A, r * t["Z"][y, x] - b)
            moved = [REC.transform(k + d) for d in (h, -h)]
            V = ((moved[0][0] @ p + moved[0][1]) - (moved[1][0] @ p + moved[1][1])) / (2 * h)
            U = np.array([t["Ux"][y, x], t["Uy"][y, x], t["Uz"][y, x]])
            assert np.abs(V - U).max() <= 1e-6 * np.abs(V).max(), (k, V, U)
    # the day/night rhythm: the rate spans growth (1 -+ rhythm) over a day
    g = [REC.growth_rate(s) for s in np.arange(0, REC.period, 0.01)]
    assert max(g) == pytest.approx(4e-3 * 1.8, rel=1e-4)
    assert min(g) == pytest.approx(4e-3 * 0.2, rel=1e-3)


@pytest.fixture(scope="module")
def leaf_recording(tmp_path_factory):
    from gridflow.bench.recordings import make_leaf_recording

    root = tmp_path_factory.mktemp("leafrec")
    make_leaf_recording(root / "leaf.zarr", REC, cache=root / "cache")
    return root / "leaf.zarr"


def test_leaf_recording_images_match_the_truth_per_frame(leaf_recording):
    """Frame by frame, the leaf's pixels in the rendered centre view (the texture's dark end
    is 0.05, the background 0) are where the truth's depth is finite (measured 99.96 % of
    the pixels agree at the first and the last frame, as for SMALL), and the leaf's area
    grows between them (6846 to 7287 pixels measured)."""
    from gridflow.sources import open_source

    rec = open_source(leaf_recording)
    assert sorted(rec.truth_names) == sorted(("Z", "Ux", "Uy", "Uz", "growth"))
    assert rec.frame_interval == REC.frame_interval
    areas = []
    for k in (0, REC.frames - 1):
        img = rec.read(k, k + 1)[0, 1, 1]
        leaf = np.isfinite(rec.truth(k)["Z"])
        assert ((img > 0.01) == leaf).mean() >= 0.999, k
        areas.append(leaf.sum())
    assert areas[1] > areas[0]


def test_leaf_recording_growth_series_against_its_truth(leaf_recording, tmp_path):
    """gridflow estimate on the leaf recording, then each step's median growth over the leaf
    (where the truth is given; the median, as gridflow growth reports it, since a few
    pixels where the estimate breaks down move the mean) against the truth of its frame.

    Measured: within 2-7.5 % at every step (the mean: 2-12 %).  Asked: within 20 %, the single-volume leaf's
    measured deviation at this size and window (15 %, median growth, test above) plus the
    bias of a rate that changes inside the temporal window (1/2 g'' times the window's
    variance in time, at most 4 frames^2: 2 g0 m w^2 / g_min = 2 % with the default day of
    40 frames)."""
    from gridflow.bench.cli import main
    from gridflow.pipeline import growth_table

    out = tmp_path / "maps.zarr"
    assert main(["estimate", str(leaf_recording), "-o", str(out), "--sigma", "5",
                 "--window", "21", "--motion", "affine", "--temporal-radius", "2",
                 "--no-progress"]) == 0
    table = growth_table(out, leaf_recording)
    assert list(table.frame) == [4, 5, 6, 7]
    assert (table.n_pixels > 3000).all()
    rel = (table["median"] / table["truth"] - 1).abs()
    assert rel.max() < 0.20, table[["frame", "median", "truth"]]


def test_record_leaf_refuses_an_output_it_cannot_write(tmp_path, capsys):
    """A recording is a new Zarr store: another suffix, or a store that exists, is refused
    before anything is rendered."""
    from gridflow.bench.cli import main

    assert main(["record-leaf", "-o", str(tmp_path / "leaf.npz"), "--no-progress"]) == 2
    assert "a recording is a Zarr store" in capsys.readouterr().err
    (tmp_path / "leaf.zarr").mkdir()
    assert main(["record-leaf", "-o", str(tmp_path / "leaf.zarr"), "--no-progress"]) == 2
    assert "exists" in capsys.readouterr().err
    assert not (tmp_path / "work").exists()


# --- the leaf growing unevenly (issue 36) --------------------------------------------------

from scipy.ndimage import map_coordinates  # noqa: E402

from gridflow.scenes import UnevenLeafRecording, uneven_leaf_truth  # noqa: E402

UNEVEN = UnevenLeafRecording(width=160, height=160, grid=(1, 1), frames=12, growth=4e-3,
                             tip_growth=4e-4, margin=12.0)


def _material(scene, truth, t):
    """Each pixel's material point ``(U, W)`` from the truth's depth at frame ``t``."""
    H = scene.height
    x = np.arange(H) - (H - 1) / 2
    X, Y = np.meshgrid(x, x)
    P = np.stack([X / scene.f, Y / scene.f, np.ones_like(X)], -1) * truth["Z"][..., None]
    local = (P - scene.base(t)) @ scene.rotation()
    return scene.undeform(local[..., 0], local[..., 1], t)


def _at(scene, U, W, t):
    return scene.point(*scene.deform(U, W, t), t)


def test_uneven_leaf_truth_is_its_geometrys_motion():
    """Per frame, the truth is the motion of the material points as the mesh places them:
    the velocity is the central difference of their positions (error O(h^2), ~1e-10
    here), the growth the rate of a small material cross's area (diagonals of 1e-2 mm
    centred on the point, 1e-2 frames either side: at most 3.4e-7 relative from the truth
    over the points and frames below, asked 3e-6; a corner triangle of 1e-3 mm and 1e-3
    frames, as before, was 1e-5 off, half of it from the rate's gradient across the
    triangle and half from roundoff, and failed on another machine), the rotation the
    turn of a material segment about the normal; the base grows about 10x faster than
    the tip, and deform and undeform are inverse."""
    h, d = 1e-3, 1e-3
    for k in (0, 5, 11):
        tr = uneven_leaf_truth(UNEVEN, 12, k)
        U, W = _material(UNEVEN, tr, float(k))
        back = UNEVEN.deform(*UNEVEN.undeform(*UNEVEN.deform(U, W, k), k), k)
        assert np.nanmax(np.abs(back[1] - UNEVEN.deform(U, W, k)[1])) < 1e-9
        n = UNEVEN.rotation()[:, 2]
        for y, x in ((80, 80), (40, 85), (120, 70), (80, 60)):
            assert tr["leaf"][y, x], (k, y, x)
            u, w = U[y, x], W[y, x]
            V = (_at(UNEVEN, u, w, k + h) - _at(UNEVEN, u, w, k - h)) / (2 * h)
            T = np.array([tr["Ux"][y, x], tr["Uy"][y, x], tr["Uz"][y, x]])
            assert np.abs(V - T).max() <= 1e-7 * np.abs(T).max() + 1e-12, (k, V, T)

            def area(t, s=1e-2):
                a, b = _at(UNEVEN, u - s / 2, w, t), _at(UNEVEN, u + s / 2, w, t)
                c, e = _at(UNEVEN, u, w - s / 2, t), _at(UNEVEN, u, w + s / 2, t)
                return np.linalg.norm(np.cross(b - a, e - c))
            ha = 1e-2
            rate = (np.log(area(k + ha)) - np.log(area(k - ha))) / (2 * ha)
            assert rate == pytest.approx(tr["growth"][y, x], rel=3e-6), (k, y, x)

            def angle(t):                      # a material segment's direction about n
                a, b = _at(UNEVEN, u, w, t), _at(UNEVEN, u, w + d, t)
                e = (b - a) / np.linalg.norm(b - a)
                e1 = UNEVEN.rotation()[:, 0]
                return np.arctan2(np.cross(e1, e) @ n, e1 @ e)
            turn_w = (angle(k + h) - angle(k - h)) / (2 * h)

            def angle_u(t):
                a, b = _at(UNEVEN, u, w, t), _at(UNEVEN, u + d, w, t)
                e = (b - a) / np.linalg.norm(b - a)
                e1 = UNEVEN.rotation()[:, 0]
                return np.arctan2(np.cross(e1, e) @ n, e1 @ e)
            turn_u = (angle_u(k + h) - angle_u(k - h)) / (2 * h)
            # rotation = the mean turn of two orthogonal material segments (the strain's
            # symmetric part turns them oppositely); the segments along u and w are
            # orthogonal up to the shear, O(1e-4), so compared to 1e-3 of the rate scale
            assert 0.5 * (turn_u + turn_w) == pytest.approx(tr["rotation"][y, x],
                                                            abs=1e-3 * 4e-3), (k, y, x)
    # the pixels span the leaf from base to tip (the last pixel 0.94 of the way: measured
    # ratio 9.4 of the 10 between the material rates at the ends)
    g = uneven_leaf_truth(UNEVEN, 12, 0)["growth"]
    assert np.nanmax(g) / np.nanmin(g) >= 8


@pytest.fixture(scope="module")
def uneven_images(tmp_path_factory):
    from gridflow.loader import open_folder

    folder = render_cube(UNEVEN, tmp_path_factory.mktemp("uneven"), progress=False)
    return open_folder(folder)


def test_uneven_leaf_images_move_with_its_material_points(uneven_images):
    """The rendered centre view against the truth: the leaf's pixels are where the truth
    puts the leaf (measured 99.99 % agree at the first and last frame), and the texture
    moves with the material points: the last frame, sampled where the exact map carries
    each interior pixel of the first, correlates with the first at 0.9986 (measured;
    lighting changes and cubic interpolation take the rest), against 0.983 for a uniform
    growth at the leaf's mean rate and 0.83 without motion.  Asked: the exact map leaves
    at most a quarter of the uniform map's residual 1 - r, and r >= 0.995."""
    img0 = uneven_images.read(0, 1)[0, 0, 0]
    img1 = uneven_images.read(11, 12)[0, 0, 0]
    for k, img in ((0, img0), (11, img1)):
        assert ((img > 0.01) == uneven_leaf_truth(UNEVEN, 12, k)["leaf"]).mean() >= 0.999
    tr = uneven_leaf_truth(UNEVEN, 12, 0)
    m = tr["interior"]

    def warped(scene):
        U, W = _material(scene, tr, 0.0)
        Q = _at(scene, U, W, 11.0)
        c = (scene.height - 1) / 2
        px, py = scene.f * Q[..., 0] / Q[..., 2] + c, scene.f * Q[..., 1] / Q[..., 2] + c
        return map_coordinates(img1, [np.nan_to_num(py), np.nan_to_num(px)], order=3)

    r = lambda a: np.corrcoef(img0[m], a[m])[0, 1]  # noqa: E731
    uniform = UnevenLeafRecording(width=160, height=160, grid=(1, 1), frames=12,
                                  growth=2.2e-3, tip_growth=2.2e-3)
    exact, flat = r(warped(UNEVEN)), r(warped(uniform))
    assert exact >= 0.995
    assert 1 - exact <= 0.25 * (1 - flat), (exact, flat)
