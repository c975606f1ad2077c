"""Eq. 22 and the HCI scores on arrays whose answers are known by hand."""

from __future__ import annotations

import numpy as np
import pytest

from gridflow.metrics import evaluate, hci_metrics, q_abs, q_rel


def _one(est, ref, mask=None):
    est, ref = np.asarray(est, float), np.asarray(ref, float)
    mask = np.ones(est.shape, bool) if mask is None else mask
    (row,) = evaluate({"q": est}, {"q": ref}, mask)
    return row


def test_q_rel_and_q_abs_by_hand():
    ref = np.array([[1.0, 2.0], [-4.0, 5.0]])
    est = np.array([[1.5, 1.0], [-5.0, 5.0]])
    mask = np.ones((2, 2), bool)
    # |0.5|/1, |1|/2, |1|/4, 0  -> mean 1.25 / 4
    assert q_rel(est, ref, mask) == pytest.approx((0.5 + 0.5 + 0.25 + 0.0) / 4, rel=1e-15)
    assert q_abs(est, ref, mask) == pytest.approx((0.5 + 1.0 + 1.0 + 0.0) / 4, rel=1e-15)
    mask[1, 1] = False
    assert q_abs(est, ref, mask) == pytest.approx(2.5 / 3, rel=1e-15)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_reference_of_one_sign_takes_the_relative_measure(sign):
    """Eq. 22: relative where the reference is non-zero and of one sign on every pixel:
    positive everywhere or negative everywhere (a2 < 0, Z_Y < 0 in the sweeps)."""
    ref = sign * np.array([[0.1, 0.2], [0.3, 0.4]])
    r = _one(ref * 1.1, ref)
    assert r["measure"] == "rel"
    assert r["q"] == r["q_rel"] == pytest.approx(0.1, rel=1e-12)


@pytest.mark.parametrize("ref", [[[0.1, -0.2], [0.3, 0.4]], [[0.0, 0.2], [0.3, 0.4]]])
def test_a_reference_crossing_or_touching_zero_takes_the_absolute_measure(ref):
    r = _one(np.asarray(ref) + 0.01, ref)
    assert r["measure"] == "abs" and r["q"] == r["q_abs"] == pytest.approx(0.01, rel=1e-12)
    if 0.0 in np.asarray(ref):
        assert np.isnan(r["q_rel"])


def test_invalid_estimates_are_counted_not_averaged():
    """NaN and infinite estimates inside the mask are counted (n_invalid) and left out of
    the means; pixels whose truth is NaN are not scored at all."""
    ref = np.array([[1.0, 1.0, 1.0], [1.0, np.nan, 1.0]])
    est = np.array([[1.1, np.nan, np.inf], [1.2, 5.0, -np.inf]])
    r = _one(est, ref)
    assert r["n_pixels"] == 5 and r["n_invalid"] == 3
    assert r["q_abs"] == pytest.approx(0.15, rel=1e-12)


def test_hci_scores_by_hand():
    """The toolkit's rule: MSE x 100 over finite estimates; BadPix(t): |error| > t, in
    percent of the scored pixels, a pixel without a value not counted as bad; 15 px
    border left out; pixels without truth not scored."""
    gt = np.zeros((40, 40))
    est = np.zeros((40, 40))
    inner = (slice(15, 25), slice(15, 25))          # the 10 x 10 pixels scored
    e = est[inner]
    e[0, :5] = 0.0699                               # below BadPix(0.07)
    e[0, 5:] = 0.0701                               # above
    e[1, :] = np.nan                                # not finite: not bad, not in the MSE
    est[:15] = 10.0                                 # in the border: never scored
    gt[24, 24] = np.nan                             # no truth: not scored
    h = hci_metrics(est, gt)
    assert h["n_pixels"] == 99 and h["n_nonfinite"] == 10
    assert h["badpix_007"] == pytest.approx(100 * 5 / 99, rel=1e-12)
    assert h["badpix_003"] == pytest.approx(100 * 10 / 99, rel=1e-12)
    mse = (5 * 0.0699 ** 2 + 5 * 0.0701 ** 2) / 89
    assert h["mse_x100"] == pytest.approx(100 * mse, rel=1e-12)
