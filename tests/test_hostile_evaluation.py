"""Hostile evaluation: truth with NaN and a truth mask, a bad sweep CSV for the claims,
and a sweep without an observation's data (its claims are 'not tested').

Every case must end in a clear error (exit 2 from the CLI, naming the file, key or
argument) or a correct result; none may crash, hang, exit 0 with garbage, or change a
file it was not asked to write.  The cases are counted (``builders.tried``) and the
count is printed in the pytest summary.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import pandas as pd
import pytest

from builders import SPEC_OK, cli_fails, spec_dict, tried
from gridflow.bench.cli import main
from gridflow.bench.spec import SweepSpec
from gridflow.bench.sweep import run_sweep
from gridflow.generators import make_sinusoid
from gridflow.io import save_volume

# SPEC_OK with sections merged in (None removes one): _with(**sections) -> dict
_with = partial(spec_dict, SPEC_OK)


# --- evaluation ------------------------------------------------------------------------------

def test_evaluate_leaves_out_pixels_without_truth(tmp_path, capsys):
    sv = make_sinusoid(height=48, width=48, frames=7, grid=(3, 3))
    sv.truth["Z"] = sv.truth["Z"].copy()
    sv.truth["Z"][:, :20] = np.nan                   # off the object
    sv.truth["interior"] = np.ones((48, 48), bool)
    sv.truth["interior"][30:] = False                # the scene's own mask
    save_volume(tmp_path / "v.npz", sv)
    assert main(["estimate", str(tmp_path / "v.npz"), "-o", str(tmp_path / "e.npz"),
                 "--sigma", "2", "--window", "9"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "e.npz"), str(tmp_path / "v.npz")]) == 0
    out = capsys.readouterr().out
    # quantity, Eq. 22 value, measure, Q_rel, Q_abs, pixels, invalid
    rows = {ln.split()[0]: ln.split() for ln in out.splitlines()[2:]}
    assert set(rows) == {"Z", "Zx", "Zy", "Ux", "Uy", "Uz", "a1", "a2", "a1x", "a1y", "a2x",
                         "a2y"}
    assert "nan" not in out.lower(), out            # every quantity is measured
    assert all(np.isfinite(float(r[1])) for r in rows.values())
    assert rows["Zx"][2] == "abs" and rows["Zx"][3] == "-"     # truth 0: no relative error
    assert int(rows["Z"][5]) < int(rows["Uz"][5])   # fewer pixels where Z's truth is NaN
    e = np.load(tmp_path / "e.npz")
    inner = e["interior"] & sv.truth["interior"]
    assert int(rows["Uz"][5]) == int(inner.sum())
    tried("evaluation with NaN truth and a truth mask")


@pytest.mark.parametrize("content, match", [
    ("", "not a readable CSV"),
    ("a,b\n1,2\n", "missing columns"),
    ("param,value,model,quantity,noise,q_rel,q_abs\na1,x,full,a1,0,1,1\n", "must hold numbers"),
])
def test_claims_on_a_bad_csv_is_a_clear_error(tmp_path, capsys, content, match):
    (tmp_path / "s.csv").write_text(content)
    cli_fails(["claims", tmp_path / "s.csv"], capsys, match)
    tried("bad sweep CSV for claims")


def test_claims_without_an_observations_data_say_not_tested(tmp_path, capsys):
    spec = SweepSpec.from_dict(_with(axis=[{"param": "a1", "values": [0.0, 0.2]}],
                                     sweep={"models": ["bcc", "hf", "full"]}))
    run_sweep(spec, tmp_path / "s.csv", workers=1, progress=False)
    assert main(["claims", str(tmp_path / "s.csv"), "--write-csv",
                 str(tmp_path / "c.csv")]) == 0
    table = pd.read_csv(tmp_path / "c.csv")
    assert (table.verdict == "not tested").all(), table
    assert table.numbers.str.contains("the sweep lacks its data").all()
    tried("claims on a sweep without the data", len(table))
