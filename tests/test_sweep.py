"""Sweep runner: spec validation, reproducibility, interruption, CLI."""

from functools import partial

import pandas as pd
import pytest

import gridflow.bench.sweep as sweep_mod
from builders import sweep_spec
from gridflow.bench.cli import main
from gridflow.bench.spec import SpecError, SweepSpec, shipped_specs
from gridflow.bench.sweep import run_point, run_sweep

SMALL = {"height": 80, "width": 80, "frames": 7}
SPEC = {"sweep": {"name": "t", "models": ["bcc", "full"], "noise": [0.0, 0.02], "seeds": [3]},
        "base": SMALL, "axis": [{"param": "a1", "values": [0.0, 0.3]},
                                {"param": "a2x", "values": [-0.001]}]}
# SPEC with whole sections replaced: _spec(**over) -> SweepSpec
_spec = partial(sweep_spec, SPEC, replace=True)


@pytest.mark.parametrize("over, match", [
    ({"axis": [{"param": "a3", "values": [1.0]}]}, "unknown parameter 'a3'"),
    ({"axis": [{"param": "a1", "values": []}]}, "empty or missing 'values'"),
    ({"axis": [{"param": "a1"}]}, "empty or missing 'values'"),
    ({"axis": []}, "no \\[\\[axis\\]\\]"),
    ({"axis": [{"param": "a1", "values": [0.1, 0.1]}]}, "repeats"),
    ({"axis": [{"param": "a2", "values": [-0.1, -50.0]}]}, "a2 = -50.0: brightness exponent"),
    ({"sweep": {"models": ["bcc", "affine"]}}, "unknown or no model"),
    ({"sweep": {"noise": [-0.1]}}, "noise"),
    ({"base": {"height": 80, "colour": 3}}, "unknown sinusoid parameter"),
    ({"estimator": {"sigma": 8, "gamma": 2}}, "\\[estimator\\]"),
    ({"plots": {}}, "unknown section"),
])
def test_bad_specs_fail_before_any_work(over, match, tmp_path):
    with pytest.raises(SpecError, match=match):
        _spec(**over)


def test_spec_file_errors(tmp_path):
    with pytest.raises(SpecError, match="no such sweep spec"):
        SweepSpec.from_toml(tmp_path / "none.toml")
    (tmp_path / "bad.toml").write_text("[sweep\nname=1")
    with pytest.raises(SpecError, match="not valid TOML"):
        SweepSpec.from_toml(tmp_path / "bad.toml")


def test_repository_specs_are_valid():
    spec = SweepSpec.from_toml("bench/sweeps/paper.toml")
    assert [p for p, _ in spec.axes] == ["a1", "a1x", "a2", "a2x"]


def test_shipped_specs_are_found_by_name(tmp_path, monkeypatch):
    from pathlib import Path

    folder = Path(__file__).resolve().parents[1] / "bench" / "sweeps"
    assert set(shipped_specs()) == {p.stem for p in folder.glob("*.toml")}
    assert {"growth", "paper", "paper_setup", "paper_setup_zoom", "smoke"} <= set(shipped_specs())
    for name in shipped_specs():                    # each found by name, and valid
        assert SweepSpec.from_toml(name) == SweepSpec.from_toml(folder / f"{name}.toml")
    assert SweepSpec.from_toml("paper") == SweepSpec.from_toml("bench/sweeps/paper.toml")
    # a file of that name in the working folder wins over the shipped spec
    monkeypatch.chdir(tmp_path)
    (tmp_path / "paper").write_text('[sweep]\nname = "mine"\n[[axis]]\nparam = "a1"\n'
                                    'values = [0.1]\n')
    assert SweepSpec.from_toml("paper").name == "mine"
    with pytest.raises(SpecError, match="not the name of a shipped spec"):
        SweepSpec.from_toml("papr")


def test_rows_and_order_do_not_depend_on_execution(tmp_path):
    spec = _spec()
    a = run_sweep(spec, tmp_path / "a.csv", workers=1, progress=False)
    b = run_sweep(spec, tmp_path / "b.csv", workers=2, progress=False)
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    # one row per (point, model, quantity); every estimated quantity recorded
    assert len(a) == 3 * 2 * (6 + 12)
    assert set(a[a.model == "full"].quantity) == {"Z", "Zx", "Zy", "Ux", "Uy", "Uz", "a1", "a2",
                                                   "a1x", "a1y", "a2x", "a2y"}
    assert list(a.columns) == sweep_mod.COLUMNS
    # a point computed on its own gives the same numbers as inside the sweep
    p = spec.points()[3]
    alone = run_point(spec, p)
    inside = b[(b.param == p.param) & (b.value == p.value) & (b.noise == p.noise)]
    pd.testing.assert_series_equal(alone.q_abs.reset_index(drop=True),
                                   inside.q_abs.reset_index(drop=True), rtol=1e-6)
    assert not (tmp_path / "a.csv.parts").exists()
    assert (tmp_path / "a.json").exists()


def test_one_rendering_per_axis_value_gives_the_same_rows():
    """A sweep renders each noise-free volume once and adds each point's noise to it
    (add_noise): the rows are those of rendering every point on its own, to the bit."""
    spec = _spec()
    spec.noise, spec.seeds = [0.0, 0.025], [0, 1]
    points = [p for p in spec.points() if (p.param, p.value) == (spec.points()[0].param,
                                                                 spec.points()[0].value)]
    # the noise-free point once (the seed only draws noise), the noisy one per seed
    assert [(p.noise, p.seed) for p in points] == [(0.0, 0), (0.025, 0), (0.025, 1)]
    grouped = sweep_mod.run_group(spec, points)
    for p, df in zip(points, grouped):
        # (but the wall times, which no two runs share)
        pd.testing.assert_frame_equal(df.drop(columns="seconds"),
                                      run_point(spec, p).drop(columns="seconds"),
                                      check_exact=True)


def test_interrupted_sweep_leaves_no_csv_and_resumes(tmp_path, monkeypatch):
    spec = _spec()
    calls, armed = [], [True]
    real = sweep_mod.run_point

    def flaky(spec_, point, clean=None):
        calls.append(point)
        if armed[0] and len(calls) == 3:
            armed[0] = False
            raise KeyboardInterrupt("killed")
        return real(spec_, point, clean)

    monkeypatch.setattr(sweep_mod, "run_point", flaky)
    out = tmp_path / "s.csv"
    out.write_text("old result\n")
    with pytest.raises(sweep_mod.SweepInterrupted, match="2 of 6 points finished") as info:
        run_sweep(spec, out, workers=1, progress=False)
    assert info.value.signal_name == "SIGINT" and info.value.done == 2
    assert out.read_text() == "old result\n"             # the old file is untouched
    parts = list((tmp_path / "s.csv.parts").glob("*.csv"))
    assert len(parts) == 2                               # the finished points survived
    assert not list((tmp_path / "s.csv.parts").glob(".*tmp"))
    calls.clear()
    df = run_sweep(spec, out, workers=1, progress=False)
    assert len(calls) == len(spec.points()) - 2           # only the missing points ran
    fresh = run_sweep(spec, tmp_path / "fresh.csv", workers=1, progress=False)
    pd.testing.assert_frame_equal(df, fresh)


def test_cli_sweep_with_flags(tmp_path, capsys):
    out = tmp_path / "s.csv"
    assert main(["sweep", "--param", "a1", "--values", "0", "0.2", "--models", "hf",
                 "--no-progress", "-o", str(out), "--processes", "1"]) == 0
    df = pd.read_csv(out)
    assert set(df.model) == {"hf"} and sorted(set(df.value)) == [0.0, 0.2]
    assert main(["sweep", "--param", "a9", "--values", "1", "-o", str(out)]) == 2
    assert "unknown parameter" in capsys.readouterr().err
