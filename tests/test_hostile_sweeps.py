"""Hostile sweep specs and resumes: every field of a spec is honoured or refused naming
it, and a resumed sweep never reuses parts of other code, specs or versions.

Every case must end in a clear error (exit 2 from the CLI, naming the file, key or
argument) or a correct result; none may crash, hang, exit 0 with garbage, or change a
file it was not asked to write.  The cases are counted (``builders.tried``) and the
count is printed in the pytest summary.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from builders import SPEC_OK, spec_dict, tried
from gridflow.bench.spec import SpecError, SweepSpec
from gridflow.bench.sweep import run_sweep

ROOT = Path(__file__).resolve().parent.parent
# SPEC_OK with sections merged in (None removes one): _with(**sections) -> dict
_with = partial(spec_dict, SPEC_OK)


# --- sweep specs -----------------------------------------------------------------------------

@pytest.mark.parametrize("raw, match", [
    (_with(sweep={"modles": ["bcc"]}), r"\[sweep\]: unknown key\(s\) \['modles'\]"),
    (_with(axis=[{"param": "a1", "vals": [0.1]}]), r"unknown key\(s\) \['vals'\]"),
    (_with(axis=[{"param": "a1", "values": [0.1]}, {"param": "a1", "values": [0.2]}]),
     "more than one"),
    (_with(sweep={"noise": [0.0, 0.0]}), "repeats a value"),
    (_with(sweep={"seeds": [1, 1]}), "repeats a value"),
    (_with(sweep={"models": ["full", "full"]}), "repeats a value"),
    (_with(sweep={"seeds": [1.5]}), "int values"),
    (_with(sweep={"noise": ["0.1"]}), "float values"),
    (_with(sweep={"noise": [float("nan")]}), "float values"),
    (_with(sweep={"name": 3}), "name must be a non-empty string"),
    (_with(base={"noise": 0.1}), r"\[base\] noise is set by \[sweep\] noise"),
    (_with(base={"seed": 3}), r"\[base\] seed is set by \[sweep\] seeds"),
    (_with(base={"a1": 0.3}), "which an \\[\\[axis\\]\\] sweeps"),
    (_with(base={"height": 40.5}), "height must be an integer"),
    (_with(base={"height": "40"}), "height must be a finite number"),
    (_with(base={"height": 10 ** 6, "width": 10 ** 6}), "GiB"),
    (_with(axis=[{"param": "frames", "values": [5.5]}]), "frames must be an integer"),
    (_with(axis=[{"param": "a1", "values": [True]}]), "a1 must be a finite number"),
    (_with(estimator={"band_rows": -5}), r"\[estimator\]: band_rows"),
    (_with(estimator={"model": "bcc"}), r"\[estimator\]"),
    (_with(axis={"param": "a1"}), "array of tables"),
    (_with(sweep=[1]), r"\[sweep\] must be a table"),
])
def test_every_spec_field_is_honoured_or_refused(raw, match):
    with pytest.raises(SpecError, match=match):
        SweepSpec.from_dict(raw, source="spec.toml")
    tried("malformed sweep spec")


def test_a_seed_of_any_size_is_checked_with_its_point():
    """Seeds are checked with every point (a spec checks the geometry once per swept
    value, but builds every point's parameters): a seed beyond 64 bits is a seed (it
    raised a bare TypeError from np.isfinite before), and its noisy points render."""
    from gridflow.generators import make_sinusoid

    spec = SweepSpec.from_dict(_with(sweep={"noise": [0.01], "seeds": [0, 2 ** 64]}))
    points = spec.points()
    assert [p.seed for p in points] == [0, 2 ** 64, 0, 2 ** 64]
    big = make_sinusoid(spec.params(points[1]).replace(height=8, width=8, frames=3))
    small = make_sinusoid(spec.params(points[0]).replace(height=8, width=8, frames=3))
    assert big.volume.shape == small.volume.shape and not np.array_equal(big.volume,
                                                                         small.volume)
    tried("seed beyond 64 bits")


def test_integer_axes_run(tmp_path):
    raw = _with(axis=[{"param": "height", "values": [36, 44]},
                      {"param": "frames", "values": [5.0, 7]}])
    raw["base"] = {"width": 40, "grid": [3, 3]}
    spec = SweepSpec.from_dict(raw)
    assert spec.axes == [("height", [36, 44]), ("frames", [5, 7])]
    df = run_sweep(spec, tmp_path / "s.csv", workers=1, progress=False)
    assert sorted(df.param.unique()) == ["frames", "height"]
    assert len(df) == 4 * 12                  # 4 points x 12 full-model quantities
    assert df.n_pixels.gt(0).all()
    tried("integer axis")


# --- resume reuses stale work ----------------------------------------------------------------

def test_resume_never_mixes_parts_of_other_code_specs_or_versions(tmp_path, monkeypatch):
    import gridflow.bench.sweep as sweep_mod

    spec = SweepSpec.from_dict(SPEC_OK)
    out = tmp_path / "s.csv"
    run_sweep(spec, out, workers=1, progress=False, keep_parts=True)
    good = out.read_bytes()
    parts = sorted((tmp_path / "s.csv.parts").glob("*.csv"))
    assert parts
    for part in parts:                      # poison the kept parts: any reuse shows
        df = pd.read_csv(part)
        df["q"] = df["q"] + 1000.0
        df.to_csv(part, index=False)
    good_rows = pd.read_csv(io.BytesIO(good)).drop(columns="sweep")
    changes = [("code", lambda: monkeypatch.setattr(sweep_mod, "_code_fingerprint",
                                                    lambda: "other-code")),
               ("versions", lambda: monkeypatch.setattr(
                   sweep_mod, "_versions", lambda: {"numpy": "0.0"})),
               ("name", lambda: setattr(spec, "name", "renamed"))]
    for what, change in changes:
        monkeypatch.undo()
        change()
        run_sweep(spec, out, workers=1, progress=False, keep_parts=True)
        df = pd.read_csv(out).drop(columns="sweep")
        pd.testing.assert_frame_equal(df, good_rows, obj=what)    # recomputed, not mixed
        tried("stale resume refused")
    monkeypatch.undo()
    spec.name = "t"
    for part in (tmp_path / "s.csv.parts").glob("*.csv"):
        part.unlink()
    run_sweep(spec, out, workers=1, progress=False)
    assert out.read_bytes() == good


def test_the_resume_key_covers_every_module_a_row_runs():
    """Run one point in a fresh interpreter and list the gridflow modules it loaded: each
    must be fingerprinted (a package's entry covers its folder)."""
    code = ("import sys, json; from gridflow.bench.spec import SweepSpec; "
            "from gridflow.bench.sweep import run_point, "
            "_ROW_SOURCES; spec = SweepSpec.from_dict(json.loads(sys.argv[1])); "
            "run_point(spec, spec.points()[0]); "
            "print(json.dumps([sorted(m for m in sys.modules if m.startswith('gridflow')), "
            "list(_ROW_SOURCES)]))")
    r = subprocess.run([sys.executable, "-c", code, json.dumps(SPEC_OK)], capture_output=True,
                       text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    loaded, sources = json.loads(r.stdout.splitlines()[-1])
    # package entry points whose own code is only imports or a version string
    entry = {"gridflow", "gridflow.bench"}
    uncovered = [m for m in loaded if m not in entry
                 and not any(m == s or m.startswith(s + ".") for s in sources)]
    assert not uncovered, f"rows depend on modules the resume key ignores: {uncovered}"
