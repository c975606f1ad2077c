"""The documentation's numbers agree with ``results/``.

``docs/reproduction.md`` states results in blocks that the commands making them rewrite
(``bench/markdown.py``).  These tests regenerate each block from the committed CSVs and
compare it with the text, so a number in the docs that disagrees with ``results/`` (a
block edited by hand, a CSV regenerated without its doc, a checker changed without its
results) fails here; the claims CSVs and the paper-terms CSV are regenerated from the
sweeps the same way.  The prose outside the blocks that quotes the shipped sweeps is
checked against them value by value (:func:`test_zoom_table_agrees_with_the_sweeps`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gridflow.bench.claims import (check_claims, claims_markdown, paper_terms,
                                   paper_terms_markdown, render_checks, GROWTH_CLAIMS)
from gridflow.bench.cube_experiment import cube_markdown, observation11, observation12
from gridflow.bench.cube_variants import variants_markdown
from gridflow.bench.markdown import replace_block
from gridflow.bench.sweep import read_sweep_csv

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "reproduction.md"
RESULTS = ROOT / "results"
SWEEPS = {"paper": "sweep_paper.csv", "paper_setup": "sweep_paper_setup.csv",
          "growth": "sweep_growth.csv", "paper_setup_zoom": "sweep_paper_setup_zoom.csv"}
CLAIMS_CSV = {"paper": "claims.csv", "paper_setup": "claims_paper_setup.csv",
              "growth": "claims_growth.csv", "paper_setup_zoom": "claims_paper_setup_zoom.csv"}


def block(tag: str, text: str | None = None) -> str:
    text = DOC.read_text() if text is None else text
    start, end = f"<!-- {tag}:start -->", f"<!-- {tag}:end -->"
    assert start in text and end in text, f"docs/reproduction.md has no {tag} block"
    return text[text.index(start) + len(start):text.index(end)].strip()


@pytest.fixture(scope="module")
def claims():
    return {name: check_claims(read_sweep_csv(RESULTS / csv)) for name, csv in SWEEPS.items()}


@pytest.mark.parametrize("name", list(SWEEPS))
def test_claims_blocks_agree_with_the_sweeps(claims, name):
    want = claims_markdown(claims[name], f"results/{SWEEPS[name]}")
    assert block(f"claims:{name}") == want


@pytest.mark.parametrize("name", list(SWEEPS))
def test_claims_csvs_agree_with_the_sweeps(claims, name):
    stored = pd.read_csv(RESULTS / CLAIMS_CSV[name], dtype=str, keep_default_na=False)
    fresh = claims[name][["id", "verdict", "parts", "numbers"]].astype(str)
    pd.testing.assert_frame_equal(stored.reset_index(drop=True), fresh.reset_index(drop=True))


def test_check_descriptions_agree_with_the_checker():
    assert block("claims-checks") == render_checks()
    assert block("claims-checks-growth") == render_checks(GROWTH_CLAIMS)


def test_paper_terms_agree_with_the_sweeps(claims):
    tables = {"gridflow": claims["paper"], "paper": claims["paper_setup"]}
    terms = paper_terms(tables)
    stored = pd.read_csv(RESULTS / "paper_terms.csv", dtype=str, keep_default_na=False)
    pd.testing.assert_frame_equal(stored, terms.astype(str))
    src = f"results/{SWEEPS['paper']} results/{SWEEPS['paper_setup']}"
    assert block("paper-terms") == paper_terms_markdown(terms, list(tables), src)


def test_cube_block_agrees_with_cube_csv():
    table = pd.read_csv(RESULTS / "cube.csv")
    text = block("cube")
    source = re.match(r"Made by `gridflow cube` from (.*) \(`results/cube\.csv`\)\.", text)
    assert source, "the cube block does not name its source"
    checks = observation11(table) + observation12(table)
    assert text == cube_markdown(table, checks, source.group(1))
    # the source it names is the shipped scene and window (not only whatever the doc says)
    from gridflow.bench.cli import build_parser
    from gridflow.scenes import CubeScene

    d = build_parser().parse_args(["cube"])                  # gridflow cube's defaults
    assert source.group(1) == (f"the scene `cube-{CubeScene().key()}`, sigma {d.sigma:g}, "
                               f"{d.window} taps")
    v = pd.read_csv(RESULTS / "cube_variants.csv")
    assert v[v.variant == "shipped"].options.isna().all()      # the variants' row agrees


def test_cube_variants_block_agrees_with_its_csv():
    table = pd.read_csv(RESULTS / "cube_variants.csv")
    assert block("cube-variants") == variants_markdown(table)


def test_cube_variants_as_shipped_is_the_cube_table():
    """The study's first row is the scene and settings of ``results/cube.csv``: its numbers
    are that table's full-model interiors (both written with 6 significant digits)."""
    v = pd.read_csv(RESULTS / "cube_variants.csv")
    v = v[v.variant == "shipped"].set_index("face")
    c = pd.read_csv(RESULTS / "cube.csv")
    c = c[(c.region == "interior") & (c.model == "full")].set_index("face")
    assert sorted(v.index) == sorted(c.index) == ["left", "right"]
    for col in ("n_pixels", "shown_right", "median_angle_deg", "p90_angle_deg", "q_rel_Uz"):
        assert (v[col] == c.loc[v.index, col]).all(), col


def test_cube_variants_conclusions_follow_the_numbers():
    """A conclusion is written only where the numbers support it: with the no-spotlight
    row below "almost everywhere", the sentence blaming the spotlight goes."""
    table = pd.read_csv(RESULTS / "cube_variants.csv")
    text = variants_markdown(table)
    assert "The spotlight is the cause" in text
    worse = table.copy()
    worse.loc[(worse.variant == "no_spotlight") & (worse.face == "left"), "shown_right"] = 0.5
    text = variants_markdown(worse)
    assert "The spotlight is the cause" not in text
    assert "does not explain" in text
    moved = table.copy()
    moved.loc[(moved.variant == "paper_window") & (moved.face == "left"), "shown_right"] += 0.3
    assert "Neither the window nor the image size" not in variants_markdown(moved)


def test_cube_window_choice_agrees_with_the_variants():
    """The cube's window row (why sigma 8, not the paper's 16) and the left face's sign
    paragraph quote results/cube_variants.csv and results/cube.csv, number by number."""
    text = re.sub(r"\s+", " ", DOC.read_text())
    v = pd.read_csv(RESULTS / "cube_variants.csv").set_index(["variant", "face"])
    c = pd.read_csv(RESULTS / "cube.csv")
    left = c[(c.face == "left") & (c.region == "interior") & (c.model == "full")].iloc[0]
    pw, sh = "paper_window", "shipped"
    for phrase in (
            f"(full: {v.loc[(pw, 'left'), 'q_rel_Uz']:.3f} left, "
            f"{v.loc[(pw, 'right'), 'q_rel_Uz']:.3f} right)",
            f"the left face keeps {v.loc[(pw, 'left'), 'n_pixels']} interior pixels",
            f"its median Z_X error grows from {v.loc[(sh, 'left'), 'median_abs_Zx']:.2g} to "
            f"{v.loc[(pw, 'left'), 'median_abs_Zx']:.2g}",
            f"becomes {v.loc[(pw, 'right'), 'spot_model_error_ratio']:.2g}× its value "
            f"elsewhere ({v.loc[(sh, 'right'), 'spot_model_error_ratio']:.2g}× at σ = 8)",
            f"median Z_X error on the left face's interior is {left.median_abs_Zx:.2g}"):
        assert phrase.replace("(1× at", "(1.0× at") in text, phrase


def _readings():
    v = pd.read_csv(RESULTS / "readings_verdicts.csv")
    t = pd.read_csv(RESULTS / "readings.csv", keep_default_na=False)
    return v, t


def test_readings_block_agrees_with_its_csvs():
    from gridflow.bench.readings import readings_markdown

    assert block("readings") == readings_markdown(*_readings())


def test_readings_paper_column_is_the_shipped_paper_setup():
    """The readings' `paper` setup column was made by the same checks from the same sweep as
    the paper-terms table (results/paper_terms.csv, regenerated from the committed sweep
    by the tests above): statement by statement the same number and verdict."""
    _, t = _readings()
    terms = pd.read_csv(RESULTS / "paper_terms.csv", keep_default_na=False)
    assert len(t) == len(terms)
    assert (t["statement"] == terms["statement"]).all()
    assert (t["paper_setup"] == terms["paper"]).all()
    assert (t["paper_setup verdict"] == terms["paper verdict"]).all()


def test_readings_prose_follows_the_verdicts():
    """What the text says of each reading, checked against results/readings*.csv."""
    v, t = _readings()
    verdict = v.set_index(["reading", "id"]).verdict
    term = t.set_index("statement")
    text = re.sub(r"\s+", " ", DOC.read_text())
    # offset 1 under gridflow: BCC breaks down earlier in a2 and a2x than with offset 0
    gf = pd.read_csv(RESULTS / "paper_terms.csv", keep_default_na=False).set_index("statement")
    assert "with offset 1 BCC breaks down earlier in `a2` and `a2x`" in text

    def upper(cell):
        return float(re.search(r"\(([0-9.]+), ([0-9.]+)\]", cell).group(2))

    for s in ("BCC breaks down at |a2| ≈ 0.1", "BCC breaks down at |a2x| ≈ 0.02"):
        assert upper(term.loc[s, "paper_offset1"]) < upper(gf.loc[s, "gridflow"]), s
    # inverse-variance weights: observations 10 and 7 "do not" hold
    assert "read as gridflow's inverse-variance weights, they do not" in text
    assert verdict["paper_setup", 7] == verdict["paper_setup", 10] == "holds"
    assert verdict["paper_setup_ivw", 7] != "holds" and verdict["paper_setup_ivw", 10] != "holds"
    # offset 1 under paper: 1 holds, most others not
    assert "so observation 1 holds; but most of the others then fail" in text
    others = [verdict["paper_setup_offset1", i] for i in range(2, 11)]
    assert verdict["paper_setup_offset1", 1] == "holds"
    assert sum(x != "holds" for x in others) > len(others) / 2
    # 3-tap filters: the floor holds, beyond 1 not moderate, obs. 7's larger a1, 9 partly
    m3 = "paper_setup_matched3 verdict"
    assert term.loc["Q_rel(a1) well below 0.5 % for a1 < 1", m3] == "holds"
    assert term.loc["beyond a1 = 1 rising moderately", m3] == "does not hold"
    assert term.loc["HF, full: only weakly for larger a1", m3] == "does not hold"
    assert verdict["paper_setup_matched3", 9] == "partly"
    # none makes 1-10 hold together; the paper setup has the most that hold
    assert "None of the three readings" in text
    holds = {r: int((v[v.reading == r].verdict == "holds").sum()) for r in v.reading.unique()}
    for r in ("paper_setup_offset1", "paper_setup_matched3", "paper_setup_ivw"):
        assert holds[r] < 10 and holds[r] <= holds["paper_setup"], (r, holds)


def test_a_stale_block_is_caught(claims):
    """The comparison can fail: one number changed in a regenerated block differs."""
    good = claims_markdown(claims["paper"], "results/sweep_paper.csv")
    text = replace_block("", "claims:paper", good.replace("0.0054", "0.0055", 1))
    assert "0.0054" in good and block("claims:paper", text) != good


# --- prose outside the blocks ----------------------------------------------------------


def _q(df, model, quantity, param, value):
    d = df[(df.model == model) & (df.quantity == quantity) & (df.param == param)
           & (df.noise == 0) & np.isclose(df.value, value)]
    assert len(d), (model, quantity, param, value)
    return float(d.q.mean())


def _agrees(text: str, x: float) -> bool:
    """``text`` (as printed: 2 significant digits, or 3 as in 0.0257) is ``x`` rounded."""
    digits = len(re.sub(r"e.*|[^0-9]", "", text).lstrip("0"))
    return f"{x:.{max(digits, 1)}g}" == f"{float(text):.{max(digits, 1)}g}"


def test_choices_prose_agrees_with_the_sweep():
    """The choices table's interior size and the derivative-filter paragraph's a2 numbers
    quote results/sweep_paper.csv (two significant digits: within 1/20; the slope to its
    printed 1.33 within 1 %)."""
    df = read_sweep_csv(RESULTS / "sweep_paper.csv")
    text = re.sub(r"\s+", " ", DOC.read_text())
    n = df[(df.noise == 0)].n_pixels.unique()
    assert len(n) == 1 and f"({n[0]:,} pixels)".replace(",", " ") in text, n
    # a literal f = 10 px across the 192-px image
    from gridflow.generators import SinusoidParams

    field = 2 * np.degrees(np.arctan(SinusoidParams().width / 2 / 10.0))
    assert f"would see a {field:.0f}° field" in text, field
    q01, q1 = _q(df, "full", "a2", "a2", -0.01), _q(df, "full", "a2", "a2", -0.1)
    assert ("measured 1.33 |a2| at `a2 = −0.01` (`Q_rel(a2)` = 0.013) and 1.2 |a2| at −0.1 "
            "(0.12)") in text
    assert abs(q01 / 0.01 / 1.33 - 1) < 0.01 and abs(q1 / 0.1 / 1.2 - 1) <= 0.05, (q01, q1)
    assert abs(q01 / 0.013 - 1) <= 0.05 and abs(q1 / 0.12 - 1) <= 0.05, (q01, q1)


def test_geometry_numbers_agree_with_the_scenes():
    """The numbers the choice tables derive from the geometry (the sinusoid's defaults and
    the cube's truth), computed here and compared at their printed precision."""
    from gridflow.generators import SinusoidParams
    from gridflow.scenes import CubeScene, cube_truth

    text = re.sub(r"\s+", " ", DOC.read_text())
    p = SinusoidParams()
    f, Z0, t = p.f, p.Z0, (p.frames - 1) / 2
    X = (p.width / 2) * Z0 / f                       # world X at the image's edge
    window = 65
    inner = p.width - 2 * (window // 2 + 2)          # 65 taps, matched5's radius 2
    for phrase, got, printed in (
            ("at 33 px from the centre", 10.0 / 0.3, 33),
            ("a pixel spans 0.1 world units at `Z0 = 100`", Z0 / f, 0.1),
            ("`U_X = 0.05` is 0.5 px/frame", 0.05 * f / Z0, 0.5),
            ("of ±0.31 across the image", 0.002 * X * t * t, 0.31),
            ("reaches 15 at the image's edge", 0.1 * X * t * t, 15),
            ("leave a 124 × 124 interior", inner, 124),
            ("1.5 periods of the 80-px y-wavelength", inner / p.wavelength_y, 1.5),
            ("Disparity `f ds / Z0` = 0.5 px", f * p.spacing[0] / Z0, 0.5),
            ("2 px across the grid", f * p.spacing[0] / Z0 * (p.grid[1] - 1), 2),
            ("— 15 % for the slanted test plane", 0.05 * 0.3 / 0.1, 0.15)):
        assert phrase in text, phrase
        assert abs(got / printed - 1) <= 0.05, (phrase, got)
    s = CubeScene()
    tr = cube_truth(s)
    Z = tr["Z"]
    on = np.isfinite(Z)
    disp = s.f * s.spacing[0] / Z[on]
    H, W = Z.shape
    x, y = np.meshgrid(np.arange(W) - (W - 1) / 2, np.arange(H) - (H - 1) / 2)
    motion = np.hypot((s.f * tr["Ux"] - x * tr["Uz"]) / Z, (s.f * tr["Uy"] - y * tr["Uz"]) / Z)
    left = (tr["face"] == 1).sum(axis=1).max()
    for phrase in (f"1 px ≈ {s.center_z / s.f:.2f} mm there",
                   f"disparity {disp.min():.2f}–{disp.max():.2f} px between neighbours",
                   f"image motion ≤ {np.nanmax(motion):.2f} px/frame on the cube",
                   f"the steep left face is at most {left} px wide at 256 px"):
        assert phrase in text, phrase


def test_setups_table_agrees_with_the_setups():
    """The two setups' table states what bench/setups.py and the library defaults set."""
    from gridflow.bench.setups import SETUPS
    from gridflow.estimator import EstimatorSettings
    from gridflow.generators import SinusoidParams

    text = DOC.read_text()
    sec = text[text.index("| what | `gridflow` | `paper` |"):]
    rows = {}
    for line in sec.splitlines()[2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        rows[cells[0]] = cells[1:]
    g, pb = SinusoidParams(), SinusoidParams(**SETUPS["paper"].base)
    ge, pe = EstimatorSettings(), EstimatorSettings(**SETUPS["paper"].estimator)
    assert rows["texture"][0].startswith(f"{g.texture} of the two sinusoids, offset "
                                         f"{g.offset:g}") and rows["texture"][1] == pb.texture
    assert rows["amplitude"][0].startswith(f"{g.amplitude:g} ")
    assert rows["amplitude"][1].startswith(f"{pb.amplitude:g}:")
    d = [q.f * q.spacing[0] / q.Z0 for q in (g, pb)]
    assert rows["disparity between neighbours"][0] == f"{d[0]:g} px"
    assert rows["disparity between neighbours"][1] == f"{d[1]:g} px (`spacing` {pb.spacing[0]:g})"
    assert rows["image"] == [f"{q.height} × {q.width}" for q in (g, pb)]
    radius = [2 if ge.temporal_radius is None else ge.temporal_radius, pe.temporal_radius]
    assert rows["Ω in time"] == [f"±{radius[0]} frames", f"±{radius[1]} frame"]
    assert ge.combine == "inverse_variance" and "inverse variance" in rows[
        "combination of the two estimates"][0]
    assert f'`combine = "{pe.combine}"`' in rows["combination of the two estimates"][1]
    assert SETUPS["paper"].brightness_reference == "global"
    assert rows["brightness errors against"][1].startswith("the global `a`")


def test_zoom_table_agrees_with_the_sweeps():
    """Every number of the zoom-blur table quotes a shipped sweep: the paper setup without
    and with the correction, and the gridflow setup."""
    text = DOC.read_text()
    sec = text[text.index("| | `paper` setup, as shipped |"):]
    cells = [re.split(r"(?<!\\)\|", r) for r in sec.splitlines()[2:7]]   # not at "\|"
    rows = {c[1].strip(): [x.strip() for x in c[2:-1]] for c in cells}
    sweeps = [read_sweep_csv(RESULTS / SWEEPS[n])
              for n in ("paper_setup", "paper_setup_zoom", "paper")]
    tables = [check_claims(df).set_index("id") for df in sweeps]
    claims = [t.verdict for t in tables]
    for col, df in enumerate(sweeps):
        assert _agrees(rows["BCC's U_Z error at a2 = 0"][col], _q(df, "bcc", "Uz", "a2", 0.0))
        hf, full = (v.strip() for v in rows["HF's / full's U_Z error at a2 = 0"][col].split("/"))
        assert _agrees(hf, _q(df, "hf", "Uz", "a2", 0.0))
        assert _agrees(full, _q(df, "full", "Uz", "a2", 0.0))
        assert _agrees(rows["full's Q_rel(a1) at a1 = 0.1"][col],
                       _q(df, "full", "a1", "a1", 0.1))
        # the verdict opens each observation's cell
        for obs in ("1", "9"):
            cell = rows[f"observation {obs}"][col]
            verdict = "partly" if cell.startswith("partly") else \
                "does not hold" if cell.startswith("does not hold") else \
                "holds" if cell.startswith("holds") else cell
            assert verdict == claims[col][obs], (obs, col, cell)
            # and the numbers in brackets are the claims table's
            numbers = tables[col].numbers[obs]
            for x in re.findall(r"from a1 = ([0-9.]+) on", cell):
                assert f"below 0.25 % from a1 = {x} on" in numbers, (cell, numbers)
            for q, lo, hi in re.findall(r"\\\|(a2x?)\\\| ([0-9.]+)–([0-9.]+)", cell):
                assert f"|{q}| = {lo} and {hi}" in numbers, (cell, numbers)
            # a count k/n is the claims table's, and a cell with nothing checkable is
            # not let through: each says either numbers or a count
            for k in re.findall(r"\((\d+/\d+)\)", cell):
                assert tables[col].parts[obs].startswith(f"{k} hold"), (cell, k)
            assert re.search(r"from a1 = |\d+/\d+|\\\|a2", cell) or cell == "holds", cell
    # the prose after the table: the paper setup's BCC breakdown with the correction
    after = re.sub(r"\s+", " ", text[text.index("<!-- claims:paper_setup_zoom:end -->"):])
    m = re.search(r"breaks down at \|a2\| in \(([0-9.]+), ([0-9.]+)\] and \|a2x\| "
                  r"in \(([0-9.]+), ([0-9.]+)\] as without it", after)
    assert m, "the zoom prose's intervals"
    for t in tables[:2]:
        assert f"|a2| = {m[1]} and {m[2]}" in t.numbers["9"], t.numbers["9"]
        assert f"|a2x| = {m[3]} and {m[4]}" in t.numbers["9"], t.numbers["9"]


def test_claims_cli_refuses_ambiguous_outputs(tmp_path, capsys):
    from gridflow.bench.cli import main

    two = [str(RESULTS / SWEEPS["paper"]), str(RESULTS / SWEEPS["paper_setup"])]
    assert main(["claims", *two, "--write-csv", str(tmp_path / "v.csv")]) == 2
    assert "--write-csv takes the verdicts of one sweep" in capsys.readouterr().err
    assert main(["claims", str(RESULTS / SWEEPS["growth"]), "--write-terms",
                 str(tmp_path / "t.csv")]) == 2
    assert "no paper terms" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_filter_numbers_agree_with_the_filters():
    """The derivative-filter paragraph's numbers (docs/reproduction.md, *Derivative
    filters*), computed from the shipped pairs; printed to one or two digits."""
    from gridflow.estimator.filters import get_filter_pair

    text = DOC.read_text()
    sec = text[text.index("### Derivative filters"):text.index("## Beyond the paper")]

    def exp_error(name, a):
        p = get_filter_pair(name)
        k = np.arange(-p.radius, p.radius + 1)
        return abs(np.dot(p.derivative, np.exp(a * k)) / np.dot(p.prefilter, np.exp(a * k))
                   / a - 1)

    def wave_error(name, wavelength=8):
        p = get_filter_pair(name)
        k = np.arange(-p.radius, p.radius + 1)
        w = 2 * np.pi / wavelength
        return abs(np.dot(p.derivative, np.sin(w * k)) / (w * np.dot(p.prefilter,
                                                                       np.cos(w * k))) - 1)

    m2 = float(np.dot(get_filter_pair("matched5").prefilter, np.arange(-2, 3) ** 2))
    quoted = [  # (the phrase as printed, the number in it, the value it states)
        ("`|D(a)/P(a)/a − 1|`: 3.2e-3 at `a = 0.5`", "3.2e-3", exp_error("fs5", 0.5)),
        ("and 1.4e-2 at `a = 1` for Farid–Simoncelli", "1.4e-2", exp_error("fs5", 1.0)),
        ("Its exponential error is 4e-6 at `a = 0.5`", "4e-6", exp_error("matched5", 0.5)),
        ("and 2.5e-4 at `a = 1`,", "2.5e-4", exp_error("matched5", 1.0)),
        ("`d/(ω p)` is 1 within 7e-5", "7e-5", wave_error("matched5")),
        ("(`fs5`: 6e-3)", "6e-3", wave_error("fs5")),
        ("`m₂ = Σ p_k k² = 0.67`", "0.67", m2),
    ]
    flat = re.sub(r"\s+", " ", sec)
    for phrase, number, value in quoted:
        assert phrase in flat, phrase
        assert _agrees(number, value), (phrase, value)


def test_growth_maps_block_agrees_with_its_csv():
    """bench/README.md's growth-maps table is the table of results/growth_maps.csv, with
    the command that made it (python -m gridflow.bench.growth_maps --write-doc)."""
    from gridflow.bench.growth_maps import table

    rows = pd.read_csv(RESULTS / "growth_maps.csv").to_dict("records")
    text = block("growth-maps", (ROOT / "bench" / "README.md").read_text())
    head, _, body = text.partition("\n\n")
    assert head.startswith("Generated by `python -m gridflow.bench.growth_maps --csv "
                           "results/growth_maps.csv --seeds 0 1 --noise 0.003`")
    assert body == table(rows)
    # the shipped benchmark's defaults are the ones the block names
    import inspect

    from gridflow.bench import growth_maps

    assert inspect.signature(growth_maps.run).parameters["seeds"].default == (0, 1)
    assert set(pd.DataFrame(rows).leaf) == set(growth_maps.LEAVES)


def test_uneven_leaf_block_agrees_with_its_csv():
    """bench/README.md's uneven-leaf table is the table of results/uneven_leaf.csv (python
    -m gridflow.bench.uneven_leaf --write-doc), over every method and region it names."""
    from gridflow.bench.uneven_leaf import METHODS, REGIONS, table

    rows = pd.read_csv(RESULTS / "uneven_leaf.csv").to_dict("records")
    text = block("uneven-leaf", (ROOT / "bench" / "README.md").read_text())
    head, _, body = text.partition("\n\n")
    assert head.startswith("Generated by `python -m gridflow.bench.uneven_leaf --write-doc")
    assert body == table(rows)
    df = pd.DataFrame(rows)
    assert set(df.method) == set(METHODS) and set(df.region) == set(REGIONS)


def test_leaderboard_block_agrees_with_its_csv_and_its_suites():
    """bench/README.md's leaderboard is the table of results/leaderboard.csv (python -m
    gridflow.bench.leaderboard --write-doc); the CSV ranks every entry of each suite's
    methods, and the ranking recomputed from the suites' sweeps is the CSV (to its
    6 digits): run here on the growth suite, the cheaper of the two."""
    from gridflow.bench.leaderboard import SUITES, ranking, table
    from gridflow.bench.spec import SweepSpec
    from gridflow.bench.sweep import run_sweep

    rank = pd.read_csv(RESULTS / "leaderboard.csv")
    text = block("leaderboard", (ROOT / "bench" / "README.md").read_text())
    head, _, body = text.partition("\n\n")
    assert head.startswith("Generated by `python -m gridflow.bench.leaderboard --write-doc")
    assert body.strip() == table(rank).strip()
    assert set(rank.suite) == set(SUITES)
    for suite in SUITES:
        methods = set(SweepSpec.from_toml(suite).methods)
        assert set(rank[rank.suite == suite].method) == methods
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        rows = run_sweep(SweepSpec.from_toml("leaderboard_growth"), f"{tmp}/g.csv",
                         progress=False)
    fresh = ranking(rows)
    stored = rank[rank.suite == "leaderboard_growth"].reset_index(drop=True)
    assert list(fresh["entry"]) == list(stored["entry"])
    np.testing.assert_allclose(fresh["median_q"], stored["median_q"], rtol=1e-5)


def test_the_readmes_planner_numbers_are_the_planners():
    """README's memory the planner counts for a step of 5 x 5 views of 512^2 px (a
    recording: float32, read as stored; the default window of each motion model) is what
    pipeline.run.step_memory gives, to the two decimals printed, and for one and two
    steps one frame apart with their frames kept what pipeline.run._framed_need gives."""
    from gridflow.estimator import temporal_reach
    from gridflow.pipeline.run import _framed_need, step_memory
    from gridflow.pipeline.strategies import SinglePass

    text = " ".join((ROOT / "README.md").read_text().split())
    m = re.search(r"([\d.]+) GiB for one step of 5 × 5 views of 512² px under translation, "
                  r"([\d.]+) GiB under the affine model", text)
    assert m, "the planner's sentence is gone from README.md"
    kept = re.search(r"with the frames kept for them ([\d.]+) GiB for one such step and "
                     r"([\d.]+) GiB for two under translation, ([\d.]+) and ([\d.]+) GiB "
                     r"under the affine model", text)
    assert kept, "the planner's sentence on steps with kept frames is gone from README.md"
    for i, (motion, stated) in enumerate(zip(("translation", "affine"), m.groups())):
        s = SinglePass(("full",), {"motion": motion})
        frames = 2 * temporal_reach(s.estimator_settings) + 1
        need = step_memory((200, 5, 5, 512, 512), frames, itemsize=4, strategy=s)
        assert f"{need / 2**30:.2f}" == stated, (motion, need / 2**30, stated)
        for tasks, said in zip((1, 2), kept.groups()[2 * i:2 * i + 2]):
            need = _framed_need((200, 5, 5, 512, 512), frames, 1, tasks, itemsize=4,
                                strategy=s)
            assert f"{need / 2**30:.2f}" == said, (motion, tasks, need / 2**30, said)
