"""Camera-grid folders: reading and every kind of bad folder."""

import json
from functools import partial

import imageio.v3 as iio
import numpy as np
import pytest

from builders import noise_folder, noise_volume
from gridflow.loader import LoaderError, load_folder

# a folder of 16-bit noise (rounded), 12 x 10 px, naming the centre camera the reference:
# _make(folder, T=3, Sy=3, Sx=3, H=12, W=10, dtype=np.uint16, **manifest); Sy = Sx = 3 here
_make = partial(noise_folder, reference_camera=[1, 1])


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_png_folder_roundtrip(tmp_path, dtype):
    _make(tmp_path / "f", dtype=dtype)
    vol, scale = noise_volume(), np.iinfo(dtype).max
    d = load_folder(tmp_path / "f")
    assert d.volume.shape == (3, 3, 3, 12, 10)
    # quantisation: half a grey level
    assert np.max(np.abs(d.volume - vol)) <= 0.5 / scale + 1e-12
    assert d.focal_length == 500.0 and d.camera_spacing == (0.1, 0.2)
    assert d.principal_point == (4.5, 5.5)


def test_float_tiff_and_truth(tmp_path):
    f = tmp_path / "f"
    f.mkdir()
    vol = np.random.default_rng(1).random((3, 1, 3, 8, 9)).astype(np.float32)
    for t in range(3):
        for j in range(3):
            iio.imwrite(f / f"frame{t}_cam{j}_0.tif", vol[t, 0, j])
    (f / "truth").mkdir()
    np.save(f / "truth" / "Z.npy", np.full((8, 9), 42.0))
    (f / "grid.json").write_text(json.dumps({
        "focal_length": 100, "camera_spacing": [1, 0], "grid": [1, 3], "frames": 3,
        "pattern": "frame{t}_cam{sx}_{sy}.tif", "truth": {"Z": "truth/Z.npy"},
        "principal_point": [4.0, 3.5], "reference_frame": 1}))
    d = load_folder(f)
    np.testing.assert_array_equal(d.volume, vol.astype(np.float64))
    assert d.truth["Z"][0, 0] == 42.0 and d.principal_point == (4.0, 3.5)
    assert d.meta["ref_frame"] == 1


def _expect(folder, match):
    with pytest.raises(LoaderError, match=match):
        load_folder(folder)


def test_missing_image(tmp_path):
    _make(tmp_path / "f")
    (tmp_path / "f" / "t01_y1_x2.png").unlink()
    _expect(tmp_path / "f", r"1 image\(s\) .* missing, e.g. \['t01_y1_x2.png'\]")


def test_manifest_says_fewer_frames_than_files(tmp_path):
    _make(tmp_path / "f", T=3)
    m = json.loads((tmp_path / "f" / "grid.json").read_text())
    m["frames"] = 2
    (tmp_path / "f" / "grid.json").write_text(json.dumps(m))
    _expect(tmp_path / "f", r"outside the manifest's grid 3x3 x 2 frames, e.g. \['t02_y0_x0.png'")


def test_manifest_says_more_cameras_than_files(tmp_path):
    _make(tmp_path / "f", grid=[3, 5], reference_camera=[1, 2])
    _expect(tmp_path / "f", r"18 image\(s\) .* missing")


def test_mixed_sizes(tmp_path):
    _make(tmp_path / "f")
    iio.imwrite(tmp_path / "f" / "t02_y2_x2.png", np.zeros((12, 11), np.uint16))
    _expect(tmp_path / "f", r"t02_y2_x2.png: size \(12, 11\) differs")


def test_mixed_bit_depths(tmp_path):
    _make(tmp_path / "f")
    iio.imwrite(tmp_path / "f" / "t01_y0_x0.png", np.zeros((12, 10), np.uint8))
    _expect(tmp_path / "f", r"t01_y0_x0.png: pixel type uint8 differs .* \(uint16\)")


def test_unreadable_image(tmp_path):
    _make(tmp_path / "f")
    (tmp_path / "f" / "t00_y1_x1.png").write_bytes(b"not a png")
    _expect(tmp_path / "f", r"t00_y1_x1.png: unreadable image")


@pytest.mark.parametrize("content, match", [
    ("{not json", "not valid JSON"),
    ('{"focal_length": 1}', "missing key"),
    ('{"focal_length": 1, "camera_spacing": [1, 1], "grid": [3, 3], "frames": 2, '
     '"pattern": "img{t}.png"}', "must use the fields"),
    ('{"focal_length": -1, "camera_spacing": [1, 1], "grid": [3, 3], "frames": 2, '
     '"pattern": "{t}{sy}{sx}.png"}', "'focal_length' must be a positive number"),
])
def test_bad_manifest(tmp_path, content, match):
    (tmp_path / "grid.json").write_text(content)
    _expect(tmp_path, match)


def test_no_manifest_and_not_a_folder(tmp_path):
    _expect(tmp_path, "no grid.json")
    _expect(tmp_path / "absent", "not a folder")


def test_reference_camera_must_be_centre(tmp_path):
    _make(tmp_path / "f", reference_camera=[0, 0])
    _expect(tmp_path / "f", "not the centre camera")


def test_truth_of_wrong_shape(tmp_path):
    _make(tmp_path / "f", truth={"Z": "Z.npy"})
    np.save(tmp_path / "f" / "Z.npy", np.zeros((3, 3)))
    _expect(tmp_path / "f", r"Z.npy: truth map has shape \(3, 3\)")


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_non_finite_pixel_is_named_by_file(tmp_path, value):
    """A float image with a NaN or inf pixel: the error names the file and the pixel
    (was: an index into the whole volume, after loading all of it)."""
    f = tmp_path / "f"
    f.mkdir()
    vol = np.random.default_rng(2).random((3, 1, 3, 8, 9)).astype(np.float32)
    vol[1, 0, 2, 5, 4] = value
    for t in range(3):
        for j in range(3):
            iio.imwrite(f / f"frame{t}_cam{j}_0.tif", vol[t, 0, j])
    (f / "grid.json").write_text(json.dumps({
        "focal_length": 100, "camera_spacing": [1, 0], "grid": [1, 3], "frames": 3,
        "pattern": "frame{t}_cam{sx}_{sy}.tif"}))
    _expect(f, r"frame1_cam2_0\.tif: 1 non-finite pixel\(s\) \(NaN or inf\), the first at "
               r"\(y, x\) = \(5, 4\)")


def test_a_non_finite_volume_names_the_file(tmp_path, capsys):
    """A volume file with NaN values: the estimator's error names the file (a window
    that fits the 32-px image: a default window is refused first, for its size)."""
    from gridflow.bench.cli import main
    from gridflow.generators import make_sinusoid
    from gridflow.io import save_volume

    sv = make_sinusoid(height=32, width=32, frames=5, grid=(3, 3))
    sv.volume[2, 1, 1, 3, 3] = np.nan
    save_volume(tmp_path / "v.npz", sv)
    assert main(["estimate", str(tmp_path / "v.npz"), "-o", str(tmp_path / "e.npz"),
                 "--sigma", "2", "--window", "9"]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'v.npz'}: volume has 1 non-finite values" in err, err
    assert not (tmp_path / "e.npz").exists()


def test_a_folders_time_stamps_are_read_and_bad_ones_named(tmp_path):
    """grid.json's times_s: one finite, increasing number of seconds per frame; the source
    gives them as its time stamps (without them: the frame index times the interval)."""
    from gridflow.sources import open_source

    _make(tmp_path / "f", times_s=[0, 120, 7320])
    np.testing.assert_array_equal(open_source(tmp_path / "f").time_stamps(), [0, 120, 7320])
    _make(tmp_path / "g", frame_interval=60.0)
    np.testing.assert_array_equal(open_source(tmp_path / "g").time_stamps(), [0, 60, 120])
    for k, (times, text) in enumerate((([0, 120], "2 time stamps for 3 frames"),
                                       ([0, 120, 120], "frame 2 at 120 s is not after"),
                                       ([0, "x", 3], "must be numbers of seconds"))):
        _make(tmp_path / f"b{k}", times_s=times)
        _expect(tmp_path / f"b{k}", rf"grid.json: 'times_s': .*{text}")
