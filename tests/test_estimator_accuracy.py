"""Noise-free accuracy on the default sinusoid (5x5 cameras, 9 frames, 192x192).

Each bound is ``MARGIN`` times the error measured with the current defaults (the
zoom-blur correction on; the value is in the comment beside it), so that a change of the
estimator's accuracy by more than that fails (the doc-table test at the end holds the
same numbers to their printed precision); where the paper states a requirement it is named too, and every bound
lies inside it.  Noise-free estimates are deterministic: the margin is room for other
BLAS/CPU builds, whose roundoff (1e-12 of each quantity) is far below these errors.
"""

import pytest

MARGIN = 3.0
SLANTED = dict(Z_X=0.3, Z_Y=-0.2, U_X=0.05, U_Y=0.05, U_Z=0.1)


def test_full_model_brightness_constant(run):
    _, _, s = run()
    assert s["full"]["Z"]["q_rel"] <= MARGIN * 6.9e-5      # measured 6.85e-5
    assert s["full"]["Uz"]["q_rel"] <= MARGIN * 1.4e-6     # 1.41e-6 (paper: "well below 0.01")
    for m in ("bcc", "hf", "full"):
        assert s[m]["Z"]["n_invalid"] == 0


@pytest.mark.parametrize("a1, measured", [(0.1, 1.6e-6), (0.5, 4.5e-6)])
def test_a1_relative_error(run, a1, measured):
    # observation 1: well below 0.5 % for a1 < 1
    _, _, s = run(a1=a1)
    assert s["full"]["a1"]["q_rel"] <= MARGIN * measured


def test_a1_equal_one_reported(run):
    # measured 2.5e-4 (docs/reproduction.md); the paper: "moderately raises" past 1
    _, _, s = run(a1=1.0)
    assert s["full"]["a1"]["q_rel"] <= MARGIN * 2.5e-4


def test_slanted_translating_plane(run):
    _, _, s = run(**SLANTED)
    f = s["full"]
    assert f["Zx"]["q_abs"] <= MARGIN * 3.4e-4     # measured 3.4e-4 (per-axis Eq. 16: 1.9e-3)
    assert f["Zy"]["q_abs"] <= MARGIN * 1.0e-4     # 1.0e-4 (per-axis Eq. 16: 1.9e-3)
    assert f["Ux"]["q_rel"] <= MARGIN * 1.2e-4     # 1.2e-4
    assert f["Uy"]["q_rel"] <= MARGIN * 3.6e-5     # 3.6e-5
    assert f["Uz"]["q_rel"] <= MARGIN * 1.2e-4     # 1.2e-4


def test_slant_correction_is_what_makes_Uz_right(run):
    """The paper's reading of u_z ignores the slant-motion coupling, to first order a bias
    of U_X Z_X / U_Z = 0.15 (plus U_Y Z_Y / U_Z = -0.1 in y, averaged with it by the
    weights); measured 0.146 without the correction, within 13 % of the first-order 0.15
    asked here."""
    _, _, s = run(**SLANTED, est_slant_correction=False)
    assert 0.13 < s["full"]["Uz"]["q_rel"] < 0.17


def test_bcc_breaks_down_with_a1(run):
    # observation 7: BCC's U_Z error >= 10x the full model's at a1 = 0.5 (the claims
    # checker's level); measured 319 against 2.8e-5
    _, _, s = run(a1=0.5)
    assert s["bcc"]["Uz"]["q_rel"] >= 10 * s["full"]["Uz"]["q_rel"]
    assert s["full"]["Uz"]["q_rel"] <= MARGIN * 2.8e-5


def test_hf_breaks_down_with_a1x(run):
    # observation 8: with a1x only the full model stays stable; measured at a1x = 0.01:
    # HF 1.72e-2, BCC 0.106, full 4.12e-5 (420x and 2600x)
    _, _, s = run(a1x=0.01)
    assert s["hf"]["Uz"]["q_rel"] >= 10 * s["full"]["Uz"]["q_rel"]
    assert s["bcc"]["Uz"]["q_rel"] >= 10 * s["full"]["Uz"]["q_rel"]
    assert s["full"]["Uz"]["q_rel"] <= MARGIN * 4.1e-5


def test_one_dimensional_grid(run):
    """A horizontal row of the same 5 cameras: measured Q_rel(Z) 6.97e-5 against 6.86e-5
    on the 5 x 5 grid, Q_rel(U_Z) 1.53e-6 against 1.41e-6 (ratios 1.016, 1.086); asked: at
    most 10 % worse."""
    _, _, s2 = run()
    _, res, s1 = run(grid=(1, 5))
    assert res["full"].settings["filters_sy"] is None
    for q in ("Z", "Uz"):
        assert s1["full"][q]["q_rel"] <= 1.1 * s2["full"][q]["q_rel"]


def test_three_by_three_grid_five_frames(run):
    # the smallest grid the filters allow: 3-tap pairs across cameras and time;
    # measured Q_rel(Z) 2.0e-4, Q_rel(U_Z) 1.3e-4
    _, res, s = run(grid=(3, 3), frames=5)
    assert res["full"].settings["filters_sx"] == "matched3"
    assert res["full"].settings["filters_t"] == "matched3"
    assert s["full"]["Z"]["q_rel"] <= MARGIN * 2.0e-4
    assert s["full"]["Uz"]["q_rel"] <= MARGIN * 1.3e-4


def test_slopes_exact_for_a_plane_slanted_both_ways(run):
    """Eq. 16 (and Eq. 20) inverted with both slopes: at f = 100 px the pixel offsets x0/f
    reach 0.95, where the per-axis inversion is off by the other slope's term
    (Z_y y0 / f ~ 0.2): it measured Q_rel(Z_X) = 6.4 %, Q_rel(Z_Y) = 9.5 %,
    Q_rel(a1x) = 4.8 %, Q_rel(a1y) = 12.8 %; the exact form measures 0.56 %, 0.55 %,
    0.46 %, 0.90 %.  What remains is Eq. 17's truncation: second-order terms of relative
    size (z_x σ)^2 = (Z_X σ / Z0)^2 ~ (0.3 * 16 / 100)^2 = 2.3e-3 per slope.  Bounds:
    MARGIN times the exact form's errors, each below the per-axis form's."""
    _, res, scores = run(Z_X=0.3, Z_Y=-0.2, U_X=0.05, U_Y=0.05, U_Z=0.1, f=100.0,
                         spacing=(0.5, 0.5), a1=0.05, a1x=0.002, a1y=-0.001,
                         est_models=("full",))
    s = scores["full"]
    assert s["Zx"]["q_rel"] <= MARGIN * 5.6e-3 and s["Zy"]["q_rel"] <= MARGIN * 5.5e-3
    assert s["a1x"]["q_rel"] <= MARGIN * 4.6e-3
    assert s["a1y"]["q_rel"] <= MARGIN * 9.0e-3


# --- the accuracy table of docs/reproduction.md, measured ------------------------------
# Each row of "What the estimator achieves" (the numbers before any bracket: the current
# defaults) is measured here and must agree with the printed value to its printed
# precision: two significant digits are exact to 1/20 of the value (half a unit in the
# last digit is at most 5 %), plus 1 % for other BLAS/CPU builds (noise-free estimates
# differ there by roundoff; the smallest errors here, 1e-6, are differences of 1e-1
# quantities computed to 1e-12).  A change to the estimator that moves any of them, up or
# down, fails until the table is updated, so the table always states what the code does.
DOC_TOL = 0.05 + 0.01

DOC_CASES = {
    "`a1 = a2 = 0`": [({}, "full", "Z", "q_rel"), ({}, "full", "Uz", "q_rel")],
    "`a1 = 0.1, 0.5, 1`": [({"a1": 0.1}, "full", "a1", "q_rel"),
                           ({"a1": 0.5}, "full", "a1", "q_rel"),
                           ({"a1": 1.0}, "full", "a1", "q_rel")],
    "slanted, translating plane": [(SLANTED, "full", "Zx", "q_abs"),
                                   (SLANTED, "full", "Zy", "q_abs"),
                                   (SLANTED, "full", "Ux", "q_rel"),
                                   (SLANTED, "full", "Uy", "q_rel"),
                                   (SLANTED, "full", "Uz", "q_rel")],
    "`a1 = 0.5`: BCC vs full": [({"a1": 0.5}, "bcc", "Uz", "q_rel"),
                                ({"a1": 0.5}, "full", "Uz", "q_rel")],
    "`a1x = 0.01`: HF vs full": [({"a1x": 0.01}, "hf", "Uz", "q_rel"),
                                 ({"a1x": 0.01}, "full", "Uz", "q_rel")],
    "1-D grid (1 × 5)": [({"grid": (1, 5)}, "full", "Z", "q_rel"),
                         ({"grid": (1, 5)}, "full", "Uz", "q_rel")],
    "3 × 3 grid, 5 frames (3-tap filters)": [({"grid": (3, 3), "frames": 5}, "full", "Z",
                                              "q_rel"),
                                             ({"grid": (3, 3), "frames": 5}, "full", "Uz",
                                              "q_rel")],
    # one seed of the generator's noise: deterministic, so held like the others
    "σ_n = 0.025 (seed 0)": [({"noise": 0.025, "seed": 0}, "full", "Z", "q_rel"),
                             ({"noise": 0.025, "seed": 0}, "full", "Uz", "q_rel")],
}


def _doc_row(case: str) -> list[str]:
    """The numbers of one row of the accuracy table, before any bracket (the bracket
    holds the values before the zoom-blur correction), in order."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "reproduction.md").read_text()
    sec = text[text.index("## What the estimator achieves"):]
    for line in sec.splitlines():
        if line.startswith(f"| {case} |"):
            cell = re.sub(r"Q_\w+\([^)]*\)", "", line.split("|")[2])   # names, then
            cell = re.sub(r"\([^)]*\)", "", cell)                       # brackets
            return re.findall(r"\d+(?:\.\d+)?(?:e-?\d+)?", cell)
    raise AssertionError(f"docs/reproduction.md: no accuracy row {case!r}")


def _doc_brackets(case: str) -> list[tuple[int, str]]:
    """The bracketed numbers of one row (the values before the zoom-blur correction), each
    with the index of the value it belongs to: a bracket of k numbers holds the values of
    the k numbers before it (since the previous bracket)."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "reproduction.md").read_text()
    sec = text[text.index("## What the estimator achieves"):]
    line = next(ln for ln in sec.splitlines() if ln.startswith(f"| {case} |"))
    cell = re.sub(r"Q_\w+\([^)]*\)", "", line.split("|")[2])
    num = r"\d+(?:\.\d+)?(?:e-?\d+)?"
    out, index, pending = [], 0, []
    for outside, inside in re.findall(r"([^()]*)(?:\(([^)]*)\))?", cell):
        for _ in re.findall(num, outside):
            pending.append(index)
            index += 1
        if inside:
            values = re.findall(num, inside)
            assert len(values) <= len(pending), (case, inside)
            out += list(zip(pending[len(pending) - len(values):], values))
            pending = []
    return out


@pytest.mark.parametrize("case", list(DOC_CASES))
def test_accuracy_table_brackets_state_the_uncorrected_estimator(run, case):
    """The bracketed values (before the zoom-blur correction) measured with the correction
    off, to their printed precision as the others."""
    cases = DOC_CASES[case]
    for i, text in _doc_brackets(case):
        kw, model, quantity, measure = cases[i]
        got = run(**kw, est_zoom_correction=False)[2][model][quantity][measure]
        assert abs(got / float(text) - 1) <= DOC_TOL, \
            f"{case}: without the correction {model} {measure}({quantity}) measures " \
            f"{got:.3g}, the doc says {text}"


def test_slant_paragraph_states_what_the_estimator_does(run):
    """The numbers of "Slant–motion coupling" (docs/reproduction.md), measured, to their
    printed precision as above."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "reproduction.md").read_text()
    para = re.sub(r"\s+", " ", text[text.index("**Slant–motion coupling"):])
    para = para[:para.index("**Combining")]
    uz = lambda **kw: run(**SLANTED, **kw)[2]["full"]["Uz"]["q_rel"]  # noqa: E731
    for phrase, value in (
            ("`Q_rel(U_Z)` = 0.146 with the paper's reading", uz(est_slant_correction=False)),
            ("1.2e-4 with the correction", uz()),
            ("2.4e-4 without it", uz(est_zoom_correction=False))):
        assert phrase in para, phrase
        printed = float(re.search(r"\d+(?:\.\d+)?(?:e-\d+)?", phrase).group())
        assert abs(value / printed - 1) <= DOC_TOL, (phrase, value)


@pytest.mark.parametrize("case", list(DOC_CASES))
def test_accuracy_table_states_what_the_estimator_does(run, case):
    printed = _doc_row(case)
    cases = DOC_CASES[case]
    assert len(printed) == len(cases), (case, printed)
    for text, (kw, model, quantity, measure) in zip(printed, cases):
        _, _, s = run(**kw)
        got = s[model][quantity][measure]
        assert abs(got / float(text) - 1) <= DOC_TOL, \
            f"{case}: {model} {measure}({quantity}) measures {got:.3g}, the doc says {text}"


def test_systematic_effects_paragraph_states_what_the_estimator_does(run):
    """The numbers of "Two systematic effects worth knowing" (docs/reproduction.md),
    measured, to their printed precision as above (the floor at U_Z = 0 only as roundoff:
    far below the 1e-6 left at U_Z = 0.2, whatever the BLAS)."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "reproduction.md").read_text()
    para = re.sub(r"\s+", " ", text[text.index("Two systematic effects worth knowing"):])
    para = para[:para.index("## ")]

    def q(kw, quantity, measure="q_abs"):
        return run(**kw)[2]["full"][quantity][measure]

    off = {"est_zoom_correction": False}
    for phrase, value in (
            ("absolute error floor of 1.6e-4", q(off, "a1")),
            ("(2.25e-4 at `U_Z = 0.2` with offset 1)", q({**off, "U_Z": 0.2, "offset": 1.0},
                                                         "a1")),
            ("(1.1e-6 at `U_Z = 0.2` with offset 1", q({"U_Z": 0.2, "offset": 1.0}, "a1")),
            ("Q_rel(Z) = 1.9e-3 at `a1 = 0.5`", q({"a1": 0.5}, "Z", "q_rel"))):
        assert phrase in para, phrase
        printed = float(re.search(r"\d+(?:\.\d+)?e-\d+", phrase).group())
        assert abs(value / printed - 1) <= DOC_TOL, (phrase, value)
    assert "roundoff (below 1e-15) at `U_Z = 0`" in para
    assert q({"U_Z": 0.0}, "a1") < 1e-15
    # t_eff: the bias of Z read as U_Z t_eff / Z0 on the default sinusoid
    from gridflow.generators import SinusoidParams

    p = SinusoidParams()
    t_eff = q({"a1": 0.5}, "Z", "q_rel") * p.Z0 / abs(p.U_Z)
    assert "`t_eff ≈ 1.9`" in para and abs(t_eff / 1.9 - 1) <= DOC_TOL, t_eff
