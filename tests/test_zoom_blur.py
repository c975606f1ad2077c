"""The zoom blur: why a1 has an error floor and BCC a U_Z floor without any brightness
change, and the correction that removes both (``zoom_correction``, on by default).

Under a divergence ``u_z`` the true temporal derivative is ``I_t = -(u_x + u_z x) ∂_x I``
(and likewise in y).  The data row ``I_t`` is prefiltered along x with ``p``, and

    Σ_j p_j (x - j) g(x - j) = x (p * g)(x) - Σ_j j p_j g(x - j),

so the filtered constraint carries an extra ``u_z Σ_j j p_j ∂_x I(x - j)`` that the
paper's model (and ours) does not have.  On a sinusoid of wavenumber k it is
``u_z β(k) I`` with ``β(k) = k Σ_j j p_j sin(kj) / Σ_j p_j cos(kj)``: a brightness change.
For the product texture ``sin(k_x X) sin(k_y Y)`` with offset 0 it is the whole of I, so
HF and full report ``a1 = -u_z (β(k_x) + β(k_y))`` (0.43 u_z with ``matched5`` at the 8-px
wavelength); BCC, with no brightness row, absorbs it in its weakly determined y-estimate
of ``u_z``.  docs/reproduction.md explains observations 1 and 9 under the paper setup
with these numbers.  The mechanism tests read the data rows as the paper does
(``zoom_correction=False``); the last tests check the correction against it.

Tolerance: the relation is first order in the frame-to-frame zoom (``u_z`` = 1e-3 per
frame here) and exact in the filters, so the remaining terms are O(u_z) relative, 1e-3;
the bounds below allow 1 %.
"""

import numpy as np
import pytest

from gridflow.estimator.filters import get_filter_pair

PAPER_GEOMETRY = dict(texture="product", amplitude=0.5, height=160, width=160,
                      spacing=(0.1, 0.1), est_temporal_radius=1, est_combine="mean",
                      est_zoom_correction=False)


def moment_kernel_error(filters: str, wavelength: float) -> float:
    """Relative error of the pair's ``moment_derivative`` kernel against ``(o p) * ∂I`` on
    a sinusoid of ``wavelength`` (what the corrected row can be no better than)."""
    pair = get_filter_pair(filters)
    o = np.arange(-pair.radius, pair.radius + 1)
    k = 2 * np.pi / wavelength
    x = np.arange(8)[:, None] + o[None, :]
    exact = (pair.moment * k * np.cos(k * x + 0.3)).sum(axis=1)
    ours = (pair.moment_derivative * np.sin(k * x + 0.3)).sum(axis=1)
    return float(np.abs(ours - exact).max() / np.abs(exact).max())


def beta(filters: str, wavelength: float) -> float:
    p = np.asarray(get_filter_pair(filters).prefilter, dtype=float)
    j = np.arange(p.size) - p.size // 2
    k = 2 * np.pi / wavelength
    return k * float((j * p * np.sin(k * j)).sum() / (p * np.cos(k * j)).sum())


def _a1_bias(run, **kw):
    sv, res, _ = run(**dict(PAPER_GEOMETRY, **kw))
    e = res["full"]
    a1 = e["a1"][e.interior]
    assert np.isfinite(a1).all()
    return float(np.mean(a1 - sv.params.a1)), float(np.std(a1)), sv


@pytest.mark.parametrize("filters", ["matched5", "matched3"])
def test_a1_bias_under_pure_zoom_is_the_prefilter_moment(run, filters):
    bias, spread, sv = _a1_bias(run, est_filters=filters)
    p = sv.params
    uz = p.U_Z / p.Z0                      # divergence per frame, magnitude
    predicted = -uz * (beta(filters, p.wavelength_x) + beta(filters, p.wavelength_y))
    # measured: matched5 -4.2790e-4 vs -4.2825e-4, matched3 -2.0704e-4 vs -2.0721e-4
    assert bias == pytest.approx(predicted, rel=0.01)
    assert spread < 0.01 * abs(bias)       # a uniform bias, not noise


def test_no_zoom_no_bias(run):
    bias, _, _ = _a1_bias(run, U_Z=0.0)
    assert abs(bias) < 1e-10                # measured 2.8e-11


def test_bcc_u_z_floor_scales_with_the_zoom_blur(run):
    """BCC's U_Z error with no brightness change follows β: doubling the x-wavelength
    divides β(k_x) by ~4, and BCC's error with it (measured 0.0257 -> 0.0065, a1 bias of
    HF 4.28e-4 -> 1.08e-4: both ratios 3.95)."""
    errs, biases = [], []
    for wl in (8.0, 16.0):
        _, _, s = run(**dict(PAPER_GEOMETRY, wavelength_x=wl))
        errs.append(s["bcc"]["Uz"]["q_rel"])
        biases.append(abs(_a1_bias(run, wavelength_x=wl)[0]))
    assert errs[0] > 0.01                   # far above HF/full (3.6e-5)
    assert errs[0] / errs[1] == pytest.approx(biases[0] / biases[1], rel=0.05)


@pytest.mark.parametrize("filters", ["matched5", "matched3"])
def test_the_correction_removes_the_a1_bias(run, filters):
    """With the correction the bias left is what the moment-derivative kernel misses of
    ``(o p) * ∂I`` at the texture's 8-px wavelength (1.1e-3 for matched5, 5.5e-2 for
    matched3: the pairs' own consistency), plus the 1 % of the first-order relation.
    Measured: matched5 -1.27e-7 against -4.28e-4 uncorrected (3e-4 of it), matched3
    1.19e-5 against -2.07e-4 (5.8 %)."""
    before, _, sv = _a1_bias(run, est_filters=filters)
    after, spread, _ = _a1_bias(run, est_filters=filters, est_zoom_correction=True)
    bound = moment_kernel_error(filters, sv.params.wavelength_x) + 0.01
    assert abs(after) <= bound * abs(before), (after, before, bound)
    assert spread < 0.01 * abs(before)


@pytest.mark.parametrize("filters", ["matched5", "matched3"])
def test_the_correction_removes_bccs_u_z_floor(run, filters):
    """Without brightness change BCC's U_Z error was 700x (matched5) and 11x (matched3)
    HF's; corrected it is HF's within a factor 1.5 (measured 1.11 and 1.33: what is left is
    the kernel error above, which BCC's y-estimate takes with more weight), so "all models
    agree for small values" (observation 9) holds for the reason the paper gives."""
    for correction, lo, hi in ((False, 10.0, np.inf), (True, 0.0, 1.5)):
        _, _, s = run(**dict(PAPER_GEOMETRY, est_filters=filters,
                             est_zoom_correction=correction))
        ratio = s["bcc"]["Uz"]["q_rel"] / s["hf"]["Uz"]["q_rel"]
        assert lo < ratio < hi, (correction, ratio)


def test_the_docs_zoom_paragraph_states_these_numbers(run):
    """docs/reproduction.md, "Why observations 1 and 9 fail under `paper`": its numbers are
    the formula's and these runs', to their printed precision (two significant digits:
    within 1/20; the ratio 3.95 within 0.5 %)."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "reproduction.md").read_text()
    text = re.sub(r"\s+", " ", text)
    sv = run(**PAPER_GEOMETRY)[0]
    wl = (sv.params.wavelength_x, sv.params.wavelength_y)          # 8 and 80 px
    assert abs(sv.params.U_Z) / sv.params.Z0 == pytest.approx(1e-3)
    b5 = beta("matched5", wl[0]) + beta("matched5", wl[1])
    b3 = beta("matched3", wl[0]) + beta("matched3", wl[1])
    ratio = lambda got, printed: abs(got / printed - 1) <= 0.05  # noqa: E731
    assert "That is 0.43 `u_z`, i.e. 4.3e-4 at the paper's `U_Z/Z0 = 1e-3`" in text
    assert ratio(b5, 0.43) and ratio(b5 * 1e-3, 4.3e-4), b5
    assert "(2.1e-4 with `matched3`)" in text and ratio(b3 * 1e-3, 2.1e-4), b3
    assert "So Q_rel(a1) is 0.43 % at `a1 = 0.1`" in text and ratio(b5 * 1e-3 / 0.1, 0.0043)
    floor = run(**PAPER_GEOMETRY)[2]["bcc"]["Uz"]["q_rel"]
    assert "gives BCC a U_Z error of 2.6 %" in text and ratio(floor, 0.026), floor
    errs = [run(**dict(PAPER_GEOMETRY, wavelength_x=wl))[2]["bcc"]["Uz"]["q_rel"]
            for wl in (8.0, 16.0)]
    assert "by the same factor (3.95)" in text
    assert abs(errs[0] / errs[1] / 3.95 - 1) < 0.005, errs
