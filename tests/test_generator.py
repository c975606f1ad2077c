"""The sinusoid generator against closed-form expectations (exact ray-plane geometry)."""

import numpy as np
import pytest

from gridflow.generators import SinusoidParams, add_noise, make_sinusoid

# Rendering is float64 throughout; these comparisons are exact up to roundoff of sin/exp
# of arguments <= ~1e3, i.e. ~1e-12.
EXACT = 1e-11


def test_shape_and_reference_image():
    sv = make_sinusoid(height=32, width=48, grid=(3, 5), frames=5)
    assert sv.volume.shape == (5, 3, 5, 32, 48)
    x = np.arange(48) - 23.5
    y = np.arange(32) - 15.5
    # fronto-parallel at t = 0, reference camera: wavelengths 8 and 80 px, amplitude 1
    expect = 0.5 * (np.sin(2 * np.pi * x / 8)[None, :] + np.sin(2 * np.pi * y / 80)[:, None])
    np.testing.assert_allclose(sv.volume[2, 1, 2], expect, atol=EXACT)


def test_disparity_between_cameras():
    # f ds / Z0 = 1000 * 0.2 / 100 = 2 px: camera +1 sees the reference image shifted by 2
    sv = make_sinusoid(height=16, width=40, grid=(3, 3), spacing=(0.2, 0.2), frames=3, U_Z=0)
    ref = sv.volume[1, 1, 1]
    np.testing.assert_allclose(sv.volume[1, 1, 2][:, :-2], ref[:, 2:], atol=EXACT)
    np.testing.assert_allclose(sv.volume[1, 2, 1][:-2, :], ref[2:, :], atol=EXACT)


def test_lateral_motion_is_a_shift():
    # U_X = Z0 / f = 0.1 world units per frame is exactly one pixel per frame
    sv = make_sinusoid(height=8, width=40, grid=(1, 3), frames=3, U_Z=0, U_X=0.1)
    np.testing.assert_allclose(sv.volume[2, 0, 1][:, 1:], sv.volume[1, 0, 1][:, :-1], atol=EXACT)


def test_divergence_from_U_Z():
    # approaching plane: the image point of a material point moves as x(t) = x0 Z0/(Z0 + U_Z t)
    sv = make_sinusoid(height=4, width=101, grid=(1, 3), frames=3, U_Z=-10.0, wavelength_x=8)
    # at t = +1, Z = 90; the pixel x = 45 sees X = 45*90/1000 = 4.05, seen at t=0 at x = 40.5
    x = np.arange(101) - 50.0
    X1 = x * 90.0 / 1000.0
    expect = 0.5 * (np.sin(2 * np.pi * X1 / 0.8)[None, :]
                        + np.sin(2 * np.pi * (np.arange(4) - 1.5) * 90 / 1000 / 8.0)[:, None])
    np.testing.assert_allclose(sv.volume[2, 0, 1], expect, atol=EXACT)


@pytest.mark.parametrize("kw", [dict(a1=0.3), dict(a2=-0.1), dict(a1x=0.2), dict(a2y=0.05)])
def test_brightness_change_is_exp_h(kw):
    p = SinusoidParams(height=16, width=24, grid=(1, 3), frames=5, U_Z=0, **kw)
    sv = make_sinusoid(p)
    x = (np.arange(24) - 11.5) * 0.1     # material X = x Z0 / f
    y = (np.arange(16) - 7.5) * 0.1
    X, Y = np.meshgrid(x, y)
    for k in range(5):
        t = k - 2
        h = (p.a1 + p.a1x * X + p.a1y * Y) * t + (p.a2 + p.a2x * X + p.a2y * Y) * t * t
        np.testing.assert_allclose(sv.volume[k, 0, 1], sv.volume[2, 0, 1] * np.exp(h),
                                   rtol=EXACT)


def test_truth_maps():
    sv = make_sinusoid(height=8, width=10, a1=0.2, a1x=0.05, a2=-0.1, a2y=0.01,
                       Z_X=0.3, frame_interval=2.0)
    x = np.arange(10) - 4.5
    Z = 100.0 / (1 - 0.3 * x / 1000)
    np.testing.assert_allclose(sv.truth["Z"][0], Z, rtol=1e-14)
    X = x * Z / 1000
    # per-frame units: a1 scales with the frame interval, a2 with its square
    np.testing.assert_allclose(sv.truth["a1"][0], (0.2 + 0.05 * X) * 2.0, rtol=1e-13)
    Y = (np.arange(8) - 3.5)[:, None] * Z / 1000          # material Y at each pixel
    np.testing.assert_allclose(sv.truth["a2"], (-0.1 + 0.01 * Y) * 2.0 ** 2, rtol=1e-13)
    assert sv.truth["a2y"][0, 0] == pytest.approx(0.01 * 4.0)
    assert sv.truth["Uz"][0, 0] == pytest.approx(0.2)
    assert sv.truth["a2x"][0, 0] == 0 and sv.truth["a1x"][0, 0] == pytest.approx(0.1)


def test_noise_is_seeded():
    a = make_sinusoid(height=16, width=16, grid=(3, 3), frames=3, noise=0.025, seed=3).volume
    b = make_sinusoid(height=16, width=16, grid=(3, 3), frames=3, noise=0.025, seed=3).volume
    c = make_sinusoid(height=16, width=16, grid=(3, 3), frames=3, noise=0.025, seed=4).volume
    clean = make_sinusoid(height=16, width=16, grid=(3, 3), frames=3).volume
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # 2304 samples: the sample std is within 5 standard errors (0.025 * 5/sqrt(2*2304))
    assert abs(np.std(a - clean) - 0.025) < 0.025 * 5 / np.sqrt(2 * a.size)


def test_float32_output():
    sv = make_sinusoid(height=8, width=8, grid=(3, 3), frames=3, dtype=np.float32)
    assert sv.volume.dtype == np.float32


@pytest.mark.parametrize("kw, match", [
    (dict(a1=100.0), "exponent"),
    (dict(a2x=10.0), "exponent"),
    (dict(Z_X=300.0), "edge-on"),
    (dict(noise=-1.0), "noise"),
    (dict(frames=0), "at least 1"),
    (dict(grid=(0, 5)), "grid"),
    (dict(Z0=float("nan")), "finite"),
    (dict(f=0.0), "positive"),
    # 2 pi f / (wavelength Z0) overflows to inf: the texture was NaN (test_properties'
    # example under a full run's xdist worker)
    (dict(wavelength_x=2.2250738585072014e-308), "wavelength_x .* too small"),
    (dict(wavelength_y=1e-307, f=1e5), "wavelength_y .* too small"),
])
def test_bad_parameters(kw, match):
    with pytest.raises(ValueError, match=match):
        make_sinusoid(height=16, width=16, **kw)


def test_unknown_parameter():
    with pytest.raises(ValueError, match="unknown sinusoid parameter"):
        SinusoidParams().replace(a3=1.0)


@pytest.mark.parametrize("noise, seed", [(0.025, 0), (0.1, 7), (0.0, 3)])
def test_add_noise_is_rendering_with_noise(noise, seed):
    clean = make_sinusoid(height=40, width=48, a1=0.2, a2x=-0.003)
    a = add_noise(clean, noise, seed)
    b = make_sinusoid(height=40, width=48, a1=0.2, a2x=-0.003, noise=noise, seed=seed)
    np.testing.assert_array_equal(a.volume, b.volume)
    assert a.params == b.params or noise == 0
    assert clean.params.noise == 0 and not np.shares_memory(a.volume, clean.volume) or noise == 0


def test_add_noise_refuses_what_it_cannot_reproduce():
    with pytest.raises(ValueError, match="noise-free"):
        add_noise(make_sinusoid(height=40, width=40, noise=0.01), 0.02, 0)
    with pytest.raises(ValueError, match="float64"):
        add_noise(make_sinusoid(height=40, width=40, dtype=np.float32), 0.02, 0)
