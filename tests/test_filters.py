import numpy as np
import pytest

from gridflow.estimator.filters import FILTER_NAMES, get_filter_pair


@pytest.mark.parametrize("name", FILTER_NAMES)
def test_pair_normalisation(name):
    pair = get_filter_pair(name)
    k = np.arange(-pair.radius, pair.radius + 1)
    assert pair.prefilter.sum() == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(pair.prefilter, pair.prefilter[::-1], atol=1e-15)
    np.testing.assert_allclose(pair.derivative, -pair.derivative[::-1], atol=1e-15)
    # correlating the ramp f(k) = k gives exactly 1 (unit first moment)
    assert np.dot(pair.derivative, k) == pytest.approx(1.0, abs=1e-14)


def _exp_ratio(pair, a):
    k = np.arange(-pair.radius, pair.radius + 1)
    return np.dot(pair.derivative, np.exp(a * k)) / np.dot(pair.prefilter, np.exp(a * k))


@pytest.mark.parametrize("a", [0.1, 0.5, 1.0])
def test_matched5_is_exact_for_exponentials(a):
    # D(a)/P(a) - a = O(a^7) by construction; the a^7 coefficient gives ~2.5e-4 at a = 1.
    err = abs(_exp_ratio(get_filter_pair("matched5"), a) / a - 1)
    assert err < 3e-4 * a ** 6


def test_matched5_beats_fs5_on_exponentials():
    for a in (0.5, 1.0):
        m = abs(_exp_ratio(get_filter_pair("matched5"), a) / a - 1)
        fs = abs(_exp_ratio(get_filter_pair("fs5"), a) / a - 1)
        assert m < fs / 10


def test_matched5_derivative_of_prefilter_at_texture_frequency():
    # the sinusoid's 8-px wavelength: d(w) / (w p(w)) must be 1 to better than 1e-4
    pair = get_filter_pair("matched5")
    w = 2 * np.pi / 8
    k = np.arange(-2, 3)
    d = np.dot(pair.derivative, np.sin(w * k))
    p = np.dot(pair.prefilter, np.cos(w * k))
    assert abs(d / (w * p) - 1) < 1e-4


def test_unknown_filter():
    with pytest.raises(ValueError, match="unknown filter pair"):
        get_filter_pair("sobel")
