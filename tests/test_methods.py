"""Anyone's method beside gridflow's (gridflow.bench.methods): a Python function in a module
of the current folder, one registered as an entry point, and a program in a subprocess,
through ``gridflow sweep`` and ``gridflow estimate``; bad methods refused in one line."""

import importlib
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest

from gridflow.bench.cli import main
from gridflow.bench.methods import MethodError, command_method, load_method, run_method

# a method in a module of the current folder: the built-in estimator wrapped, whole and
# partial, and methods that go wrong in each way the interface names
MODULE = '''
import time
import numpy as np
from gridflow.estimator import estimate


def wrapped(volume, focal_length, camera_spacing, *, principal_point=None):
    return dict(estimate(volume, focal_length, camera_spacing,
                         principal_point=principal_point).maps)


def partial(volume, focal_length, camera_spacing, *, principal_point=None):
    e = estimate(volume, focal_length, camera_spacing, principal_point=principal_point)
    return {"Z": e["Z"], "Uz": e["Uz"]}


def raises(volume, focal_length, camera_spacing, *, principal_point=None):
    raise RuntimeError("no convergence")


def wrong_shape(volume, focal_length, camera_spacing, *, principal_point=None):
    return {"Z": np.zeros((3, 3))}


def a_list(volume, focal_length, camera_spacing, *, principal_point=None):
    return [np.zeros(volume.shape[-2:])]


def typo(volume, focal_length, camera_spacing, *, principal_point=None):
    return {"depth": np.zeros(volume.shape[-2:])}


def strings(volume, focal_length, camera_spacing, *, principal_point=None):
    return {"Z": np.full(volume.shape[-2:], "x")}


def bools(volume, focal_length, camera_spacing, *, principal_point=None):
    return {"Z": np.ones(volume.shape[-2:], bool)}


def mutate(volume, focal_length, camera_spacing, *, principal_point=None):
    volume *= 0
    return {"Z": np.ones(volume.shape[-2:])}


def exits(volume, focal_length, camera_spacing, *, principal_point=None):
    raise SystemExit(3)


def unscored(volume, focal_length, camera_spacing, *, principal_point=None):
    return {"model_error": np.zeros(volume.shape[-2:])}
'''

# a program: reads the interchange volume, writes the built-in estimator's maps
PROGRAM = '''
import sys
import numpy as np
from gridflow.estimator import estimate

z = np.load(sys.argv[1])
assert not any(k.startswith("truth") for k in z.files), "the interchange file has no truth"
e = estimate(z["volume"], float(z["focal_length"]), tuple(z["camera_spacing"]),
             principal_point=tuple(z["principal_point"]))
np.savez(sys.argv[2], **e.maps)
'''

SPEC = '''
[sweep]
name = "methods"
models = ["full"]
noise = [0.0, 0.01]
seeds = [0]

[base]
height = 96
width = 96
frames = 9

[[axis]]
param = "a1"
values = [0.0, 0.4]
'''
KEY = ["param", "value", "noise", "seed", "quantity"]


@pytest.fixture
def here(tmp_path, monkeypatch):
    """A working folder holding the module ``mymethods``, the program and a spec; the
    module importable from it as from the current folder."""
    (tmp_path / "mymethods.py").write_text(MODULE)
    (tmp_path / "program.py").write_text(PROGRAM)
    (tmp_path / "spec.toml").write_text(SPEC)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    sys.modules.pop("mymethods", None)


def _program():
    return f"{sys.executable} program.py {{input}} {{output}}"


def test_a_wrapped_estimator_scores_as_the_built_in_one(here):
    """The built-in estimator wrapped as a method, through --method and --method-cmd,
    gives the rows of the built-in estimator itself (asked: 1e-12 relative; the same code
    on the same volume: measured equal), scored by the same code over the same pixels; a
    partial method (Z and U_Z only) is scored on those two alone; every row carries its
    method, and the wall times are written beside the CSV."""
    out = here / "s.csv"
    assert main(["sweep", "spec.toml", "-o", str(out), "--method", "gridflow", "--method",
                 "mymethods:wrapped", "--method", "mymethods:partial", "--method-cmd",
                 _program(), "--no-progress", "--processes", "1"]) == 0
    df = pd.read_csv(out)
    assert list(df["method"].unique()) == ["gridflow", "mymethods:wrapped",
                                           "mymethods:partial", _program()]
    ref = df[df.method == "gridflow"].set_index(KEY)
    for name in ("mymethods:wrapped", _program()):
        d = df[df.method == name].set_index(KEY)
        assert len(d) == len(ref) == 4 * 12
        assert (d.model == "-").all() and (d.motion == "-").all()
        for col in ("q_rel", "q_abs", "n_pixels", "n_invalid"):
            np.testing.assert_allclose(d[col], ref.loc[d.index, col], rtol=1e-12, atol=0)
    part = df[df.method == "mymethods:partial"]
    assert sorted(part.quantity.unique()) == ["Uz", "Z"] and len(part) == 4 * 2
    # the wall times apart: a row per point and method (gridflow: and motion)
    times = pd.read_csv(here / "s.times.csv")
    assert len(times) == 4 * 4 and (times.seconds > 0).all()
    assert set(times.method) == set(df.method)


def test_an_entry_point_is_a_method(here, monkeypatch):
    """A package that registers ``wrapped`` in the group gridflow.methods (its dist-info on
    sys.path, as pip installs it) is found by its name, and scores as its function."""
    info = here / "mymethods_pkg-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: mymethods-pkg\n"
                                   "Version: 1.0\n")
    (info / "entry_points.txt").write_text("[gridflow.methods]\nwrapped-ep = "
                                           "mymethods:wrapped\n")
    importlib.invalidate_caches()
    m = load_method("wrapped-ep")
    assert m.name == "wrapped-ep" and m.kind == "python"
    from gridflow.generators import make_sinusoid

    sv = make_sinusoid(height=96, width=96, grid=(3, 3))
    maps, _ = run_method(m, sv.volume, sv.focal_length, sv.camera_spacing)
    direct = load_method("mymethods:wrapped").fn(sv.volume, sv.focal_length,
                                                 sv.camera_spacing)
    assert set(maps) == set(direct)
    for k in maps:
        np.testing.assert_array_equal(maps[k], direct[k])
    assert main(["sweep", "spec.toml", "-o", str(here / "ep.csv"), "--method", "wrapped-ep",
                 "--no-progress", "--processes", "1"]) == 0
    assert set(pd.read_csv(here / "ep.csv").method) == {"wrapped-ep"}


@pytest.mark.parametrize("method, match", [
    (["--method", "nosuchmodule:f"], "module 'nosuchmodule' does not import"),
    (["--method", "mymethods:nothing"], "has no 'nothing'"),
    (["--method", "not-registered"], "no installed package registers it"),
    (["--method", "mymethods:raises"], "raised RuntimeError: no convergence"),
    (["--method", "mymethods:wrong_shape"], r"map 'Z' has shape \(3, 3\), expected"),
    (["--method", "mymethods:a_list"], "returned list, expected a mapping"),
    (["--method", "mymethods:typo"], "names gridflow does not score: depth"),
    (["--method", "mymethods:strings"], "map 'Z' is not an array of real numbers"),
    (["--method", "mymethods:bools"], "map 'Z' is not an array of real numbers"),
    (["--method", "mymethods:mutate"], "raised ValueError: .*read-only"),
    (["--method", "mymethods:exits"], "raised SystemExit: 3"),
    (["--method", "mymethods:unscored"], "returned none of the quantities this sweep has"),
    (["--method-cmd", "false {input} {output}"], "exited with status 1"),
    (["--method-cmd", "true {input} {output}"], "wrote nothing"),
    (["--method-cmd", f"{sys.executable} -c 'import time; time.sleep(30)' {{input}} {{output}}",
      "--method-timeout", "1"],
     "did not finish within 1 s"),
    (["--method-cmd", "cat {input}"], "must contain {input} and {output}"),
    (["--method-cmd", "no-such-program-xyz {input} {output}"], "no program"),
])
def test_a_bad_method_is_one_line_naming_it_and_leaves_no_csv(here, capsys, method, match):
    out = here / "bad.csv"
    assert main(["sweep", "spec.toml", "-o", str(out), *method, "--no-progress",
                 "--processes", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) <= 2 and "Traceback" not in "\n".join(err), err
    import re

    assert re.search(match, err[-1]), err
    assert not out.exists()
    if "does not import" in match:
        # resolved before anything is written: not even the parts folder
        assert not (here / "bad.csv.parts").exists()


def test_a_resumed_sweep_never_mixes_two_versions_of_a_method(here, capsys):
    """A method's code keys its finished points: after its module changes, the points are
    run again (not reused), and the CSV holds the new code's rows alone."""
    from gridflow.bench.spec import SweepSpec
    from gridflow.bench.sweep import run_sweep

    spec = SweepSpec.from_toml(here / "spec.toml")
    spec.methods = ["mymethods:partial"]
    spec.validate()
    out = here / "r.csv"
    first = run_sweep(spec, out, workers=1, progress=False, keep_parts=True)
    parts = set((here / "r.csv.parts").glob("*.csv"))
    assert len(parts) == 4
    # a new version: Z doubled
    (here / "mymethods.py").write_text(MODULE.replace('return {"Z": e["Z"], "Uz": e["Uz"]}',
                                                      'return {"Z": 2 * e["Z"], "Uz": e["Uz"]}'))
    second = run_sweep(spec, out, workers=1, progress=True, keep_parts=True)
    assert "not reused" in capsys.readouterr().err
    assert len(set((here / "r.csv.parts").glob("*.csv")) - parts) == 4
    z1 = first[first.quantity == "Z"].q_rel.to_numpy()
    z2 = second[second.quantity == "Z"].q_rel.to_numpy()
    assert np.all(z2 > 0.9) and np.all(z1 < 1e-2)


def test_gridflow_estimate_runs_a_method_and_evaluate_scores_it(here, capsys):
    """gridflow estimate VOL.npz --method / --method-cmd writes an estimate .npz over the
    built-in estimator's interior; gridflow evaluate scores it as it scores gridflow's
    own (the wrapped estimator: the same table)."""
    assert main(["generate", "--height", "96", "--width", "96", "-o", "v.npz"]) == 0
    assert main(["estimate", "v.npz", "-o", "g.npz", "--no-progress"]) == 0
    assert main(["estimate", "v.npz", "--method", "mymethods:wrapped", "-o", "w.npz"]) == 0
    assert main(["estimate", "v.npz", "--method-cmd", _program(), "-o", "c.npz"]) == 0
    capsys.readouterr()
    tables = []
    for f in ("g.npz", "w.npz", "c.npz"):
        assert main(["evaluate", f, "v.npz"]) == 0
        tables.append(capsys.readouterr().out.splitlines()[1:])
    assert tables[0] == tables[1] == tables[2]
    # gridflow estimate itself as the program: its estimate file is read as maps
    gf = f"{sys.executable} -m gridflow.bench.cli estimate {{input}} -o {{output}} --no-progress"
    assert main(["estimate", "v.npz", "--method-cmd", gf, "-o", "p.npz"]) == 0
    capsys.readouterr()
    assert main(["evaluate", "p.npz", "v.npz"]) == 0
    assert capsys.readouterr().out.splitlines()[1:] == tables[0]
    # the implementation choice is still --method's too
    assert main(["estimate", "v.npz", "--method", "reference", "-o", "r.npz",
                 "--no-progress"]) == 0
    assert main(["estimate", "v.npz", "--method", "mymethods:raises", "-o", "x.npz"]) == 2
    assert "raised RuntimeError" in capsys.readouterr().err
    assert not (here / "x.npz").exists()
    # the built-in estimator's settings are refused beside another method, not ignored
    assert main(["estimate", "v.npz", "--method", "mymethods:wrapped", "--sigma", "4",
                 "--motion", "affine", "-o", "x.npz"]) == 2
    err = capsys.readouterr().err
    assert "--motion, --sigma" in err and "built-in estimator only" in err
    assert main(["estimate", "v.npz", "--method-cmd", _program(), "--mask", "auto",
                 "-o", "x.npz"]) == 2
    assert "--mask" in capsys.readouterr().err and not (here / "x.npz").exists()
    assert main(["estimate", "v.npz", "--method", "mymethods:wrapped", "--ref-frame", "0",
                 "-o", "x.npz"]) == 2                    # a 0 is given too
    assert "--ref-frame set(s)" in capsys.readouterr().err


def test_command_method_checks_its_line():
    with pytest.raises(MethodError, match="must contain"):
        command_method("prog {input}")
    with pytest.raises(MethodError, match="method-timeout"):
        command_method("prog {input} {output}", timeout=float("nan"))
    m = command_method(textwrap.dedent("prog --x 1 {input} {output}"))
    assert m.kind == "command" and len(m.version) == 12


def test_an_exported_suite_scored_from_files_equals_the_sweep(here, capsys):
    """gridflow export writes the spec's volumes without truth, the truth apart and a
    manifest with checksums; estimates made outside gridflow from those files (here the
    program above) and scored by gridflow score give the sweep's own rows of that method
    (the same numbers: the same code on the same data); a missing estimate or a changed
    truth file is refused by name."""
    import json

    assert main(["export", "spec.toml", "suite", "--no-progress"]) == 0
    manifest = json.loads((here / "suite" / "manifest.json").read_text())
    assert manifest["suite"] == "methods" and len(manifest["items"]) == 4
    for it in manifest["items"]:
        with np.load(here / "suite" / it["volume"]) as z:
            assert not [k for k in z.files if k.startswith("truth")]
    (here / "est").mkdir()
    import subprocess

    for it in manifest["items"]:
        subprocess.run([sys.executable, "program.py", f"suite/{it['volume']}",
                        f"est/{it['id']}.npz"], check=True)
    assert main(["score", "suite", "est", "-o", "scored.csv", "--name", "program"]) == 0
    assert main(["sweep", "spec.toml", "-o", "s.csv", "--method-cmd", _program(),
                 "--no-progress", "--processes", "1"]) == 0
    a = pd.read_csv("scored.csv").set_index(KEY)
    b = pd.read_csv("s.csv").set_index(KEY).loc[a.index]
    assert len(a) == len(b) == 4 * 12 and (a.method == "program").all()
    for col in ("q_rel", "q_abs", "n_pixels", "n_invalid", "generator"):
        assert (a[col].fillna(-1) == b[col].fillna(-1)).all(), col
    capsys.readouterr()
    first = manifest["items"][0]["id"]
    (here / "est" / f"{first}.npz").unlink()
    assert main(["score", "suite", "est", "-o", "x.csv"]) == 2
    assert "1 of 4 estimates missing" in capsys.readouterr().err
    assert main(["export", "spec.toml", "suite"]) == 2          # not into a full folder
    # the review's cases: the suite readable as a new folder is; a manifest, an estimate or
    # a setting that does not fit is one line naming it
    import os
    import stat

    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE((here / "suite").stat().st_mode) == 0o777 & ~umask
    assert manifest["only"] is None
    np.savez(here / "est" / f"{first}.npz")
    assert main(["score", "suite", "est", "-o", "x.csv"]) == 2
    assert "holds no maps" in capsys.readouterr().err
    del manifest["items"][0]["point"]
    (here / "suite" / "manifest.json").write_text(json.dumps(manifest))
    assert main(["score", "suite", "est", "-o", "x.csv"]) == 2
    assert "item 0 is not an item of a sweep suite" in capsys.readouterr().err
    assert main(["export", "spec.toml", "other", "--cache", "c"]) == 2
    assert "cache: not a setting of suite spec.toml" in capsys.readouterr().err
    (here / "empty").mkdir()
    os.chdir(here / "empty")
    assert main(["export", str(here / "spec.toml"), "."]) == 2
    assert "the current folder" in capsys.readouterr().err
    assert not (here / "other").exists() and not (here / "x.csv").exists()


def test_a_program_past_its_time_is_stopped_with_what_it_started():
    """--method-timeout stops the program's whole process group: a shell's child (here a
    sleep of a duration no other process uses) does not outlive it."""
    import time

    m = command_method("sh -c 'sleep 61.37; true' {input} {output}", timeout=1.0)
    vol = np.zeros((3, 1, 3, 8, 8))
    t0 = time.perf_counter()
    with pytest.raises(MethodError, match="did not finish within 1 s"):
        run_method(m, vol, 100.0, (0.1, 0.1))
    assert time.perf_counter() - t0 < 10
    time.sleep(0.2)
    from pathlib import Path

    left = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if b"61.37" in cmdline.read_bytes():
                left.append(cmdline)
        except OSError:          # a process that ended meanwhile
            pass
    assert not left, left


def test_the_growth_study_takes_a_method(here):
    """bench/growth_maps.py --method: a method on the same leaves, scored as gridflow's
    default is; the default estimate wrapped as a method scores as the default does (the
    same numbers), with its growth_sd's calibration."""
    from gridflow.bench.growth_maps import run

    (here / "growthm.py").write_text(
        "from gridflow.estimator import estimate\n"
        "def default(volume, focal_length, camera_spacing, *, principal_point=None):\n"
        "    e = estimate(volume, focal_length, camera_spacing, motion='affine',\n"
        "                 principal_point=principal_point)\n"
        "    return {'growth': e['growth'], 'growth_sd': e['growth_sd']}\n")
    rows = run(seeds=(0,), leaves=("still",), progress=lambda *a, **k: None,
               methods=["growthm:default"])
    by = {r["method"]: r for r in rows}
    a, b = by["growthm:default"], by["gridflow (default)"]
    for k in ("median_rel_error", "profile_corr", "profile_slope", "within_1sd"):
        assert a[k] == b[k], k
    with pytest.raises(MethodError, match="returned no growth map"):
        run(seeds=(0,), leaves=("still",), progress=lambda *a, **k: None,
            methods=["mymethods:partial"])


def test_the_leaf_table_scores_a_method_on_what_it_returns():
    """bench/leaf_experiment.leaf_table with a method's maps (growth alone, U_Z alone)
    beside gridflow's kind of estimate: each scored on its own maps, the other columns
    NaN; the same pixels (the estimate's interior within each region)."""
    from gridflow.bench.leaf_experiment import leaf_table
    from gridflow.estimator import Estimate

    H = W = 20
    inner = np.zeros((H, W), bool)
    inner[5:15, 5:15] = True
    truth = {"growth": np.full((H, W), 2e-3), "Uz": np.full((H, W), 0.1)}
    masks = {"interior": inner, "edge": np.zeros((H, W), bool), "spot_border": inner,
             "away": inner}
    everywhere = np.ones((H, W), bool)
    results = {("-", "g"): Estimate({"growth": np.full((H, W), 2.2e-3)}, "g", everywhere),
               ("-", "u"): Estimate({"Uz": np.full((H, W), 0.09)}, "u", everywhere)}
    t = leaf_table(truth, results, masks).set_index(["model", "region"])
    assert t.loc[("g", "interior"), "median_rel_growth"] == pytest.approx(0.1)
    assert np.isnan(t.loc[("g", "interior"), "median_rel_Uz"])
    assert t.loc[("u", "interior"), "median_rel_Uz"] == pytest.approx(0.1)
    assert np.isnan(t.loc[("u", "interior"), "median_rel_growth"])
    assert t.loc[("g", "interior"), "n_valid"] == 100


def test_the_growth_leaves_exported_and_scored_from_files_as_the_study_scores(here):
    """gridflow export growth_maps --only: the study's leaf (the same volume, no truth in
    it), its truth apart with the pixels the study scores; an estimate made from the file
    and scored by gridflow score gives the study's numbers for it (its score() over the
    default estimate's interior, the same code), with its growth_sd's calibration; an
    estimate without growth is refused by name; a pattern matching nothing is refused and
    leaves no folder."""
    import json

    from gridflow.bench.growth_maps import make_leaf, score, uncertainty
    from gridflow.estimator import estimate

    assert main(["export", "growth_maps", "g", "--only", "still_seed=0",
                 "--no-progress"]) == 0
    m = json.loads((here / "g" / "manifest.json").read_text())
    assert m["kind"] == "growth_maps" and [it["id"] for it in m["items"]] == ["still_seed=0"]
    with np.load(here / "g" / "volumes" / "still_seed=0.npz") as z:
        assert not [k for k in z.files if k.startswith("truth")]
        vol, f, b = z["volume"], float(z["focal_length"]), tuple(z["camera_spacing"])
    sv = make_leaf("still", 0.003, 0)
    np.testing.assert_array_equal(vol, sv.volume)
    e = estimate(vol, f, b, motion="affine")
    (here / "est").mkdir()
    np.savez(here / "est" / "still_seed=0.npz", growth=e["growth"], growth_sd=e["growth_sd"])
    assert main(["score", "g", "est", "-o", "g.csv", "--name", "mine"]) == 0
    row = pd.read_csv("g.csv").iloc[0]
    truth = sv.truth["growth"]
    want = {**score(e["growth"], truth, e.interior),
            **uncertainty(e["growth"], e["growth_sd"], truth, e.interior)}
    assert row["method"] == "mine" and row["leaf"] == "still"
    for k, v in want.items():
        assert row[k] == pytest.approx(v, rel=1e-6), k       # the CSV keeps 7 digits
    # a map of no value is scored as covering nothing (it was a traceback)
    np.savez(here / "est" / "still_seed=0.npz", growth=np.full(e["growth"].shape, np.nan))
    assert main(["score", "g", "est", "-o", "n.csv"]) == 0
    row = pd.read_csv("n.csv").iloc[0]
    assert row["coverage"] == 0 and np.isnan(row["median_rel_error"])
    np.savez(here / "est" / "still_seed=0.npz", Uz=e["Uz"])
    assert main(["score", "g", "est", "-o", "h.csv"]) == 2 and not (here / "h.csv").exists()
    assert main(["export", "growth_maps", "none", "--only", "nothing*",
                 "--no-progress"]) == 2
    assert not (here / "none").exists()
    assert not [p for p in here.iterdir() if p.name.startswith(".")]


def test_the_epi_peer_refuses_a_grid_of_unequal_spacing():
    """The EPI structure tensor reads one disparity per camera step from the horizontal and
    the vertical EPIs: with unequal steps its depth would be wrong, so it refuses."""
    from gridflow.bench.peer_methods import epi_structure_tensor

    for b in ((0.1, 0.2), (0.1, -0.1), (1e-9, 2e-9)):
        with pytest.raises(ValueError, match="equal camera spacing in x and y"):
            epi_structure_tensor(np.zeros((1, 3, 3, 16, 16)), 100.0, b)
    assert set(epi_structure_tensor(np.random.default_rng(0).random((1, 3, 3, 16, 16)),
                                    100.0, (0.1, 0.1))) == {"disparity", "Z"}
