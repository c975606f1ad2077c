"""Long recordings (issue 25): the synthetic growth recording, the map series in Zarr,
resuming, Dask, and bad recordings.

Small data throughout (64 x 64 px, 3 x 3 views, sigma 2 / 9 taps): the properties, not
the throughput, which bench/series_bench.py measures.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from builders import RECORDING, record, run_series, same_arrays, store_arrays
from gridflow.bench.cli import main
from gridflow.generators.recording import GrowthRecording, RecordingParams

ROOT = Path(__file__).resolve().parents[1]
# a recording is estimated for its growth maps: the affine motion model
# the temporal window pinned at +-2 frames (the affine default is 6): the series' steps,
# bands and the rhythm's bias below are derived for it
EST = ["--sigma", "2", "--window", "9", "--motion", "affine", "--temporal-radius", "2",
       "--no-progress"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    return record(tmp_path_factory.mktemp("rec") / "rec.zarr")


# --- the synthetic recording's truth -----------------------------------------------------------

def test_recording_truth_is_the_rate_of_the_rendered_scale():
    """The growth truth is the relative area rate of the plane as rendered: the linear
    scale s(t) that frame() applies, differentiated numerically (central difference,
    error O(h^2) ~ 1e-9 here), gives g(t) = 2 s'/s at every frame tried."""
    gen = GrowthRecording(RecordingParams(**RECORDING))
    h = 1e-3
    for k in (0, 3, 7, 12, 19):
        rate = (np.log(gen.scale(k + h)) - np.log(gen.scale(k - h))) / h     # 2 s'/s
        assert rate == pytest.approx(float(gen.growth_rate(k)), rel=1e-6, abs=1e-12)
        assert np.all(gen.truth(k)["growth"] == pytest.approx(float(gen.growth_rate(k))))
    # the day/night rhythm: the rate spans g0 (1 -+ m)
    g = gen.growth_rate(np.arange(0, RECORDING["period"], 0.01))
    assert g.max() == pytest.approx(2e-3 * 1.8, rel=1e-4)
    assert g.min() == pytest.approx(2e-3 * 0.2, rel=1e-3)


def test_recording_frames_move_as_the_truth_says():
    """The rendered texture moves as the truth's velocity says: frame k+1 warped back by
    the truth's (Ux, Uy) (in px: U f / Z) matches frame k far better than unwarped."""
    from scipy.ndimage import map_coordinates

    gen = GrowthRecording(RecordingParams(**{**RECORDING, "growth": 2e-2,
                                             "illumination": 0.0, "wavelength_x": 16.0}))
    k = 5
    a, b = gen.frame(k)[1, 1], gen.frame(k + 1)[1, 1]
    tr = gen.truth(k + 0.5)          # the velocity half-way
    f, Z = gen.params.f, tr["Z"]
    yy, xx = np.mgrid[0:64, 0:64].astype(float)
    warped = map_coordinates(b, [yy + tr["Uy"] * f / Z, xx + tr["Ux"] * f / Z], order=3)
    inner = np.s_[8:-8, 8:-8]
    assert np.abs(warped - a)[inner].mean() < 0.05 * np.abs(b - a)[inner].mean()


# --- the series: format, accuracy, resume ----------------------------------------------------------

def test_series_store_opens_in_xarray_with_dimensions_and_coordinates(recording, tmp_path):
    """gridflow estimate REC -o maps.zarr: each quantity a (time, y, x) array with the frame
    index and the seconds as coordinates, the settings as attributes, readable by
    xarray.open_zarr in a fresh process."""
    out = tmp_path / "maps.zarr"
    assert main(["estimate", str(recording), "-o", str(out), "--every", "3", *EST]) == 0
    code = ("import xarray as xr, json; ds = xr.open_zarr(%r); "
            "print(json.dumps({'dims': dict(ds.sizes), 'gdims': list(ds['growth'].dims), "
            "'coords': sorted(ds.coords), 'time': ds['time'].values.tolist(), "
            "'time_s': ds['time_s'].values.tolist(), 'model': ds.attrs['gridflow']['model'], "
            "'motion': ds.attrs['gridflow']['settings']['motion']}))" % str(out))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    # 40 frames, a step needs frames k-4 .. k+4: steps at 4, 7, ..., 34
    assert info["time"] == list(range(4, 36, 3))
    assert info["time_s"] == [120.0 * k for k in info["time"]]
    assert info["gdims"] == ["time", "y", "x"]
    assert info["dims"] == {"time": 11, "y": 64, "x": 64, "band": 1}   # one row band
    assert {"time", "time_s", "x", "y"} <= set(info["coords"])
    assert info["model"] == "full" and info["motion"] == "affine"


def test_series_growth_follows_the_rhythm(recording, tmp_path, capsys):
    """Every step's growth map against the truth of its frame.

    The bound is derived, not fitted: the estimator's own error on a plane growing at a
    constant rate at these settings (sigma 2 px, 9 taps, 3 x 3 views, 64 px; measured here
    on the sinusoid generator: about 5 %, a scale bias of small windows that falls to
    0.25 % at the default sigma 16), plus what a rate changing inside the temporal window
    adds: the window averages g(t) over about +-2 frames (variance <= 4 frames^2), a bias
    of at most 1/2 g'' 4 / g_min = 2 g0 m w^2 / (g0 (1 - m)) = 2.2 % with the rhythm here
    (m 0.8, period 60 frames); 3 % is allowed.  The rhythm itself is recovered: the
    correlation of the mean growth with the truth over the steps exceeds 0.999."""
    from gridflow.metrics import q_rel
    from gridflow.pipeline import growth_table
    from gridflow.estimator import estimate
    from gridflow.generators import make_sinusoid

    const = make_sinusoid(height=64, width=64, grid=(3, 3), U_Z=0.0, growth=2e-3)
    est = estimate(const.volume, const.focal_length, const.camera_spacing, sigma=2.0,
                   window=9, motion="affine")
    base = q_rel(est["growth"], const.truth["growth"], est.interior)
    assert 0 < base < 0.1
    out = tmp_path / "maps.zarr"
    assert main(["estimate", str(recording), "-o", str(out), *EST]) == 0
    table = growth_table(out, recording)
    assert len(table) == 32
    assert table["q_rel"].max() < base + 0.03, (base, table[["frame", "mean", "truth",
                                                              "q_rel"]])
    assert table["mean"].corr(table["truth"]) > 0.999
    assert main(["growth", str(out), "--truth", str(recording), "--fig-dir",
                 str(tmp_path / "figs"), "--csv", str(tmp_path / "g.csv")]) == 0
    assert (tmp_path / "figs" / "growth_maps.png").stat().st_size > 10_000
    assert (tmp_path / "figs" / "growth_series.png").stat().st_size > 10_000
    assert "Q_rel(growth) over the steps" in capsys.readouterr().out


def test_growth_profile_along_the_leaf_and_its_kymograph(recording, tmp_path, capsys):
    """gridflow growth --profile-csv: per step and image column, the median growth across
    the rows over the interior, per frame and per hour from the recording's frame
    interval; the kymograph drawn beside the maps.  The recording grows evenly, so each
    step's profile has the step's median growth at every position (to the map's spread),
    and its median over the positions is the table's median to within that spread."""
    import pandas as pd

    from gridflow.pipeline import growth_table

    out = tmp_path / "maps.zarr"
    assert main(["estimate", str(recording), "-o", str(out), "--every", "8", *EST]) == 0
    prof_csv, figs = tmp_path / "profile.csv", tmp_path / "figs"
    assert main(["growth", str(out), "--fig-dir", str(figs), "--profile-csv",
                 str(prof_csv)]) == 0
    assert (figs / "growth_kymograph.png").stat().st_size > 10_000
    prof, table = pd.read_csv(prof_csv), growth_table(out)
    assert list(prof.columns) == ["step", "frame", "time_s", "position_px", "median",
                                  "per_hour", "n_pixels"]
    fi = 120.0                                       # the recording's frame interval, s
    np.testing.assert_allclose(prof["per_hour"], prof["median"] * 3600 / fi, rtol=1e-5)
    np.testing.assert_allclose(table["median_per_hour"], table["median"] * 3600 / fi,
                               rtol=1e-12)
    interior = np.flatnonzero(np.asarray(
        __import__("gridflow.recording", fromlist=["MapStore"]).MapStore.open(out)
        .group["interior"][:]).any(0))
    for _, row in table.iterrows():
        p = prof[prof["frame"] == row["frame"]]
        assert list(p["position_px"]) == list(interior)
        spread = row["p90"] - row["p10"]
        assert abs(p["median"].median() - row["median"]) < spread / 2
    # an output inside the input, or the input itself, is refused, nothing written
    capsys.readouterr()
    for args in (["--profile-csv", str(out / "p.csv")], ["--csv", str(out / "t.csv")],
                 ["--fig-dir", str(out / "figs")], ["--fig-dir", str(out)],
                 ["--csv", str(recording / "x.csv")]):
        assert main(["growth", str(out), "--fig-dir", str(figs), *args]
                    if args[0] != "--fig-dir" else ["growth", str(out), *args]) == 2, args
        assert "input" in capsys.readouterr().err, args
    assert not any(p.name in ("p.csv", "t.csv", "figs", "x.csv") for p in out.iterdir())
    assert not (recording / "x.csv").exists()


def test_an_interrupted_series_resumes_to_the_same_store(recording, tmp_path):
    """A run stopped after 3 steps, then the same command again: the second run does only
    the rest (the steps done are skipped), and the store equals, array for array, that of
    one uninterrupted run."""

    settings = {"sigma": 2.0, "window": 9, "temporal_radius": 2}
    whole, parts = tmp_path / "whole.zarr", tmp_path / "parts.zarr"
    run_series(recording, whole, every=2, settings=settings)
    first = run_series(recording, parts, every=2, settings=settings, limit=3)
    assert first.done == 3
    second = run_series(recording, parts, every=2, settings=settings)
    assert second.skipped == 3 and second.done == second.steps == 16
    assert same_arrays(store_arrays(whole), store_arrays(parts))


@pytest.mark.parametrize("masked, motion", [(False, "affine"), (True, "affine"),
                                            (True, "translation")])
def test_row_bands_give_the_whole_steps_maps(recording, tmp_path, masked, motion):
    """Steps cut into row bands (--band-rows), each a task reading only its rows and the
    halo, give the maps of whole steps, to the estimator's own rounding sensitivity; with
    a mask file too (a disc: windows use only its pixels; each band's mask is cut from it,
    and the halo grows by the erosion's reach so that the cut does not erode the band's
    rows: without it the translation model, whose halo is the window's alone, differed
    on the rows next to each cut).

    The bound is derived from the estimator itself, not fitted: its maps move at the level
    of rounding whenever the rows a computation spans change (its internal ``band_rows``
    does that within one call: measured up to 2.5e-10 in Z_Y, 1.8e-11 in U_Z at these
    settings).  Each quantity of the banded store may differ from the whole store's by at
    most 4 times that internal-banding difference on the same step, plus the float32
    rounding of both stored values."""
    from gridflow.estimator import estimate_models
    from gridflow.recording import MapStore
    from gridflow.sources import open_source

    settings = {"sigma": 2.0, "window": 9, "temporal_radius": 2, "motion": motion}
    whole, banded = tmp_path / "whole.zarr", tmp_path / "banded.zarr"
    disc = None
    if masked:
        yy, xx = np.mgrid[:64, :64]
        disc = (yy - 30) ** 2 + (xx - 34) ** 2 <= 24 ** 2
        np.save(tmp_path / "disc.npy", disc)
    opts = {"mask": str(tmp_path / "disc.npy")} if masked else {}
    run_series(recording, whole, every=5, settings=settings, **opts)
    rep = run_series(recording, banded, every=5, settings=settings, band_rows=10, **opts)
    a, b = MapStore.open(whole), MapStore.open(banded)
    assert b.bands() == [(r, min(r + 10, 64)) for r in range(0, 64, 10)]
    assert rep.done == a.done().sum() == 7 and b.band_done().shape == (7, 7)
    assert np.array_equal(a.group["interior"][:], b.group["interior"][:])
    # the estimator's rounding sensitivity on the first step: one call, two internal bandings
    rec = open_source(recording)
    k, reach = int(a.frames()[0]), a.attrs["gridflow"]["reach"]
    kw = dict(models=("full",), ref_frame=reach, **settings,
              principal_point=rec.principal_point, mask=disc)
    w = rec.read(k - reach, k + reach + 1)
    one = estimate_models(w, rec.focal_length, rec.camera_spacing, **kw)["full"]
    other = estimate_models(w, rec.focal_length, rec.camera_spacing, band_rows=7, **kw)["full"]
    m = one.interior
    if masked:
        # the estimate's interior is on the disc; the series' is the image's (every step's
        # mask may differ), the disc showing as NaN in the maps
        assert m.sum() > 500 and not m[~disc].any()
        assert a.group["interior"][:][~disc].any()
        assert np.isnan(a.group["Uz"][0][~disc]).all()
    for q in a.quantities:
        x, y = a.group[q][0].astype(float), b.group[q][0].astype(float)
        assert np.array_equal(np.isnan(x), np.isnan(y)), q
        sens = np.nanmax(np.abs(one[q][m] - other[q][m]))
        f32 = 2 * np.finfo(np.float32).eps * np.maximum(np.abs(x), np.abs(y))
        assert np.all(np.abs(x - y)[m] <= 4 * sens + f32[m]), (q, sens)


def test_an_interrupted_banded_series_resumes_band_by_band(recording, tmp_path):
    """Stopped after 10 band tasks (a step and a half of 7 bands), the same command does
    only the remaining bands, and the store equals, array for array, an uninterrupted
    banded run's."""
    from gridflow.recording import MapStore

    settings = {"sigma": 2.0, "window": 9, "temporal_radius": 2}
    whole, parts = tmp_path / "whole.zarr", tmp_path / "parts.zarr"
    run_series(recording, whole, every=5, settings=settings, band_rows=10)
    run_series(recording, parts, every=5, settings=settings, band_rows=10, limit=10)
    bd = MapStore.open(parts).band_done()
    assert bd.sum() == 10 and bd[0].all() and bd[1].sum() == 3
    again = run_series(recording, parts, every=5, settings=settings, band_rows=10)
    assert again.skipped == 1 and again.done == 7
    assert same_arrays(store_arrays(whole), store_arrays(parts))


def test_a_map_series_of_another_format_is_refused_by_name(recording, tmp_path, capsys):
    """A store written by a gridflow with another map format (1: one band per step) is named
    with both formats, not read wrongly."""
    import zarr

    out = tmp_path / "maps.zarr"
    assert main(["estimate", str(recording), "-o", str(out), "--every", "10", *EST]) == 0
    g = zarr.open_group(str(out), mode="r+")
    g.attrs["gridflow"] = {**g.attrs["gridflow"], "version": 1}
    assert main(["growth", str(out), "--fig-dir", str(tmp_path / "f")]) == 2
    err = capsys.readouterr().err
    assert str(out) in err and "format 1" in err and "format 2" in err


def test_a_step_over_the_memory_budget_runs_in_row_bands(recording, tmp_path, capsys):
    """With a budget one step's frames do not fit, the steps are cut into the widest row
    bands that fit (said before the run); a budget not even a minimal band fits is refused
    before anything is written."""
    from gridflow.pipeline.run import RunOptions, choose_strategy, step_memory
    from gridflow.recording import MapStore
    from gridflow.sources import open_source

    rec = open_source(recording)
    # each pixel solved alone (--growth-support 0): the halo is the window's alone (the
    # pooled rates' reach would make a band of this 64-px image read all of it)
    halo = 4 + 2                                    # 9 taps; matched5's radius
    EST = [*globals()["EST"][:-1], "--growth-support", "0", "--no-progress"]
    # a budget that fits a 16-row band but not a whole step (at 64 px a band saves memory
    # only when it is narrow: the model charges a band more per byte of its window)
    strategy, _ = choose_strategy(rec, RunOptions(settings={
        "sigma": 2.0, "window": 9, "motion": "affine", "temporal_radius": 2,
        "growth_support": 0}))

    def need(*rows):
        # the run's own model: its settings, and the recording's float32 read as it is
        return step_memory(rec.shape, 9, *rows, itemsize=4, strategy=strategy)

    budget = (need(16, halo) + 1024) / 2**30   # 1 KiB: the option's rounding
    assert need() > budget * 2**30
    out = tmp_path / "maps.zarr"
    assert main(["estimate", str(recording), "-o", str(out), "--every", "10",
                 "--memory", f"{budget:.9f}", "--workers", "1", *EST[:-1]]) == 0
    err = capsys.readouterr().err
    store = MapStore.open(out)
    assert 1 < len(store.bands()) and store.done().all()
    assert "row bands of" in err and store.band_rows == 16
    assert need(store.band_rows, halo) <= budget * 2**30 < need(store.band_rows + 1, halo)
    tiny = tmp_path / "tiny.zarr"
    assert main(["estimate", str(recording), "-o", str(tiny), "--memory", "0.0001",
                 *EST]) == 2
    assert "even a band of" in capsys.readouterr().err and not tiny.exists()
    # with the pooled rates (the default growth support) a band's halo spans the 64-px
    # image: the refusal says the step reads the whole image, not a band wider than it
    assert main(["estimate", str(recording), "-o", str(tiny), "--memory", "0.0001",
                 *globals()["EST"]]) == 2
    err = capsys.readouterr().err
    assert "a step reads the whole image" in err and "the image has 64" in err, err
    assert "even a band" not in err and not tiny.exists()


def test_a_budget_that_holds_a_step_with_its_frames_kept_runs_whole_steps(recording,
                                                                         tmp_path,
                                                                         monkeypatch):
    """Steps one frame apart whose worker keeps each frame's values hold no window of
    their own (FramedVolume): under a budget that holds one such step and its kept
    frames, but not a step reading its window, the run makes whole steps one at a time
    with the frames kept (not row bands, nor a refusal), and its maps are those of a run
    with room to spare."""
    from gridflow.pipeline import RunOptions
    from gridflow.pipeline import run as run_mod
    from gridflow.pipeline.run import _framed_need, _read_itemsize, choose_strategy, step_memory
    from gridflow.sources import open_source

    rec = open_source(recording)
    settings = {"sigma": 2.0, "window": 9, "motion": "affine"}
    strategy, _ = choose_strategy(rec, RunOptions(settings=settings))
    frames = 2 * strategy.reach + 1
    itemsize = _read_itemsize(rec, strategy)
    window = step_memory(rec.shape, frames, itemsize=itemsize, strategy=strategy)
    one = _framed_need(rec.shape, frames, 1, 1, itemsize=itemsize, strategy=strategy)
    assert one < window
    budget = (one + window) / 2 / 2**30
    planned = []
    real = run_mod.frame_cache

    def spy(plan, tasks, budget):
        planned.append((len(plan.bands), tasks, real(plan, tasks, budget)))
        return planned[-1][2]

    monkeypatch.setattr(run_mod, "frame_cache", spy)
    span = dict(every=1, first=12, last=15)
    out, spare = tmp_path / "tight.zarr", tmp_path / "spare.zarr"
    report = run_series(recording, out, settings=settings, memory=budget, **span)
    # one band, one step at once, the frames of a window kept (before, this budget, which
    # holds no step reading its window, refused the run: the pooled rates reach over the
    # whole image, so bands could not help)
    assert planned == [(1, 1, frames)], planned
    assert any("1 step(s) at once" in line for line in report.lines), report.lines
    run_series(recording, spare, settings=settings, **span)
    assert same_arrays(store_arrays(out), store_arrays(spare))


@pytest.mark.slow
def test_kill_9_mid_way_then_rerun_gives_the_same_store(recording, tmp_path):
    """SIGKILL (nothing can catch it) part-way through a series, then the same command:
    it resumes (skips finished steps) and the store is the same as an uninterrupted run's."""
    whole, parts = tmp_path / "whole.zarr", tmp_path / "parts.zarr"

    def cmd(out):
        return [sys.executable, "-m", "gridflow.bench.cli", "estimate", str(recording),
                "-o", str(out), *EST, "--workers", "1"]

    assert subprocess.run(cmd(whole), cwd=ROOT, capture_output=True).returncode == 0
    p = subprocess.Popen(cmd(parts), cwd=ROOT, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    # killed once the first steps are done (the store is watched, not a clock: start-up
    # takes from 1 to 10 s depending on the machine's load)
    from gridflow.recording import MapStore

    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and p.poll() is None:
        done = parts / "done" / "c"
        if done.is_dir() and sum(1 for _ in done.rglob("*")) >= 2:
            break
        time.sleep(0.02)
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=30)

    done_before = int(MapStore.open(parts).done().sum())
    r = subprocess.run(cmd(parts), cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    if done_before:
        assert f"{done_before} done by an earlier run" in r.stdout
    assert same_arrays(store_arrays(whole), store_arrays(parts))
    assert 0 < done_before < 32, ("the kill fell outside the steps; the test proved nothing",
                                  done_before)


@pytest.mark.slow
def test_a_local_dask_cluster_gives_the_same_store(recording, tmp_path):
    """The steps on a 2-worker dask.distributed LocalCluster (--connect) write the same
    store, bit for bit, as the local threaded scheduler."""
    from dask.distributed import LocalCluster


    settings = {"sigma": 2.0, "window": 9, "temporal_radius": 2}
    local, remote = tmp_path / "local.zarr", tmp_path / "remote.zarr"
    run_series(recording, local, every=3, settings=settings)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster:
        rep = run_series(recording, remote, every=3, settings=settings,
                         connect=cluster.scheduler_address)
    assert rep.done == 11
    assert same_arrays(store_arrays(local), store_arrays(remote))


# --- refusals and bad recordings ------------------------------------------------------------------

def test_outputs_that_are_not_this_runs_store_are_refused(recording, tmp_path, capsys):
    """The recording itself, a folder inside it, a folder that is not a gridflow store, a
    store of another run (other settings): each refused by name, nothing changed."""
    other = tmp_path / "other.zarr"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    ran = tmp_path / "ran.zarr"
    assert main(["estimate", str(recording), "-o", str(ran), "--every", "5", *EST]) == 0
    before = store_arrays(ran)
    listing = sorted(p.relative_to(recording) for p in recording.rglob("*"))
    for out, extra, match in ((recording, [], "is the input"),
                              (recording / "sub.zarr", [], "is the input"),
                              (other, [], "not a gridflow map store"),
                              (ran, ["--sigma", "3"], "holds another run's results")):
        rc = main(["estimate", str(recording), "-o", str(out), "--every", "5", *EST, *extra])
        err = capsys.readouterr().err
        assert rc == 2 and match in err, (out, err)
    assert sorted(other.iterdir()) == [other / "notes.txt"]
    assert (other / "notes.txt").read_text() == "mine"
    assert same_arrays(before, store_arrays(ran))
    assert sorted(p.relative_to(recording) for p in recording.rglob("*")) == listing


def test_options_that_do_not_apply_are_refused(recording, tmp_path, capsys):
    """One pipeline, one set of options: what an output or input cannot take is refused
    by name, before anything is written."""
    vol = tmp_path / "v.npz"
    assert main(["generate", "--height", "32", "--width", "32", "-o", str(vol)]) == 0
    for args, match in (
            (["estimate", str(vol), "-o", str(tmp_path / "e.npz"), "--every", "2"],
             "--every: for a series of steps (-o MAPS.zarr)"),
            (["estimate", str(recording), "-o", str(tmp_path / "m.zarr"), "--shears", "-1",
              "1"], "--shears refocuses a light field of one frame"),
            (["estimate", str(recording), "-o", str(tmp_path / "m.zarr"), "--ref-frame", "5",
              "--every", "2"], "--ref-frame and --every"),
            (["estimate", str(recording), "-o", str(tmp_path / "m.txt")],
             "expected an estimate .npz (one step) or a map series .zarr"),
            (["estimate", str(recording), "-o", str(tmp_path / "m.zarr"), "--connect",
              "tcp://127.0.0.1:1", "--workers", "2"], "--workers: for this machine's"),
            (["estimate", str(recording), "-o", str(tmp_path / "m.zarr"), "--memory",
              "0.0001", *EST], "more than the memory budget")):
        assert main(args) == 2
        assert match in capsys.readouterr().err, args
    assert not (tmp_path / "m.zarr").exists() or not any(
        p.name.startswith(("Z", "growth")) for p in (tmp_path / "m.zarr").iterdir())


def test_a_step_is_the_same_in_either_sink(recording, tmp_path):
    """Any input to any output: a recording estimated into an .npz (one step, at
    --ref-frame) gives the maps the map series holds for that step, to the store's
    float32 rounding (relative 2^-24, asked 1e-6 of each map's largest value)."""
    from gridflow.io import load_estimate
    from gridflow.recording import MapStore

    npz, zarr_out = tmp_path / "e.npz", tmp_path / "m.zarr"
    assert main(["estimate", str(recording), "-o", str(npz), "--ref-frame", "20", *EST]) == 0
    assert main(["estimate", str(recording), "-o", str(zarr_out), "--first", "16", "--last",
                 "24", "--every", "4", *EST]) == 0
    maps, interior, meta = load_estimate(npz)
    store = MapStore.open(zarr_out)
    assert list(store.frames()) == [16, 20, 24] and meta["settings"]["ref_frame"] == 20
    assert np.array_equal(interior, np.asarray(store.group["interior"][:]))
    for q in store.quantities:
        a, b = maps[q], np.asarray(store.group[q][1], dtype=np.float64)
        assert np.array_equal(np.isnan(a), np.isnan(b)), q
        scale = np.nanmax(np.abs(a))
        assert np.nanmax(np.abs(a - b)) <= 1e-6 * scale, q


def _folder_recording(folder: Path, frames: int = 12) -> Path:
    """The small recording as a camera-grid image folder (16-bit PNGs)."""
    import imageio.v3 as iio

    gen = GrowthRecording(RecordingParams(**{**RECORDING, "frames": frames, "offset": 1.0,
                                             "amplitude": 0.5}))
    folder.mkdir()
    for k in range(frames):
        views = gen.frame(k)
        for i in range(3):
            for j in range(3):
                iio.imwrite(folder / f"t{k:03d}_y{i}_x{j}.png",
                            np.round(np.clip(views[i, j] / 2.0, 0, 1) * 65535).astype(np.uint16))
    (folder / "grid.json").write_text(json.dumps({
        "focal_length": 1000.0, "camera_spacing": [0.05, 0.05], "grid": [3, 3],
        "frames": frames, "pattern": "t{t:03d}_y{sy}_x{sx}.png", "frame_interval": 60.0}))
    return folder


@pytest.mark.parametrize("damage", ["corrupt", "size", "missing"])
def test_a_bad_frame_in_the_middle_is_named_and_finished_steps_kept(tmp_path, capsys,
                                                                    damage):
    """A camera-grid folder recording (12 frames: steps at frames 4..7) whose frame 9 is
    damaged after a first run finished the step at frame 4: a corrupt PNG or one of
    another size stops the run at the first step that reads it, a missing one when the
    recording opens; each error names the file, the step done before is kept, and once
    the frame is repaired the same command finishes the rest."""
    import imageio.v3 as iio

    from gridflow.recording import MapStore

    folder = _folder_recording(tmp_path / "rec")
    out = tmp_path / "maps.zarr"
    run = ["estimate", str(folder), "-o", str(out), "--workers", "1", *EST]

    run_series(folder, out, settings={"sigma": 2.0, "window": 9, "temporal_radius": 2}, limit=1)
    assert MapStore.open(out).done().tolist() == [True, False, False, False]
    bad = folder / "t009_y1_x2.png"
    good = bad.read_bytes()
    if damage == "corrupt":
        bad.write_bytes(good[:100])
    elif damage == "size":
        iio.imwrite(bad, np.zeros((64, 60), np.uint16))
    else:
        bad.unlink()
    assert main(run) == 2
    err = capsys.readouterr().err
    # the file by its path (missing: the folder and the file's name)
    assert (str(bad) in err if damage != "missing" else
            str(folder) in err and bad.name in err), err
    assert MapStore.open(out).done()[0]
    bad.write_bytes(good)
    assert main(run) == 0
    assert "1 done by an earlier run" in capsys.readouterr().out
    assert MapStore.open(out).done().all()


def test_a_store_that_is_not_a_recording_is_refused(tmp_path, capsys):
    import zarr

    z = tmp_path / "foreign.zarr"
    g = zarr.open_group(str(z), mode="w")
    g.create_array("data", shape=(3,), dtype="f4")
    assert main(["estimate", str(z), "-o", str(tmp_path / "m.zarr"), *EST]) == 2
    err = capsys.readouterr().err
    assert f"{z}: a Zarr store that is not a gridflow recording" in err, err


def test_a_step_whose_frames_changed_is_estimated_again(tmp_path, capsys):
    """After a complete run, frame 0's images are written again (a repair): only the step
    that read frame 0 (at frame 4: frames 0..8) is estimated again, the others are kept."""
    folder = _folder_recording(tmp_path / "rec")
    out = tmp_path / "maps.zarr"
    run = ["estimate", str(folder), "-o", str(out), "--workers", "1", *EST]
    assert main(run) == 0
    capsys.readouterr()
    time.sleep(0.01)
    for p in sorted(folder.glob("t000_*.png")):
        p.write_bytes(p.read_bytes())
    assert main(run) == 0
    text = capsys.readouterr().out
    assert "1 step(s) estimated again: frames they read changed since (steps at frames [4]" \
        in text, text
    assert "3 done by an earlier run" in text, text


def _linked_package(root: Path) -> Path:
    """The installed layout of the package as links to the repository's files (the
    layout of tests/mutation.py), so that a test may edit one module of it."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("gridflow_layout", ROOT / "tests" /
                                                  "mutation.py")
    layout = importlib.util.module_from_spec(spec)
    sys.modules["gridflow_layout"] = layout
    try:
        spec.loader.exec_module(layout)
    finally:
        del sys.modules["gridflow_layout"]
    for folder, dest in layout.LAYOUT.items():
        for f in sorted((ROOT / folder).iterdir()):
            if f.is_file() and f.suffix in (".py", ".toml"):
                (root / dest).mkdir(parents=True, exist_ok=True)
                (root / dest / f.name).symlink_to(f)
    return root


def _edit(path: Path, old: str, new: str) -> None:
    """Replace a link by an edited copy of its file."""
    text = path.read_text()
    assert text.count(old) == 1, (path, old)
    path.unlink()
    path.write_text(text.replace(old, new))


@pytest.mark.slow
def test_a_series_resumes_after_the_benchmark_changes(recording, tmp_path):
    """A map series half-written, then benchmark code changed (a docstring of the metrics
    and of the sweep runner, whose code keyed map series before, and a statement of the
    claims) and a docstring of the estimator: the same command resumes the store and
    ends with the uninterrupted run's maps.  A change of a statement in the estimator
    makes the store another run's (refused, kept).  Run in a linked copy of the package,
    the repository untouched."""
    tree = _linked_package(tmp_path / "tree")
    whole, parts = tmp_path / "whole.zarr", tmp_path / "parts.zarr"
    env = {**__import__("os").environ, "PYTHONPATH": str(tree)}
    code = ("import sys; from gridflow.pipeline import RunOptions, estimate; "
            "r = estimate(sys.argv[1], sys.argv[2], RunOptions(settings={'sigma': 2.0, "
            "'window': 9, 'motion': 'affine', 'temporal_radius': 2}, every=8, "
            "limit=int(sys.argv[3]) or None)); "
            "print(r.skipped, r.done, r.steps)")

    def run(out, limit):
        r = subprocess.run([sys.executable, "-c", code, str(recording), str(out), str(limit)],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        return [int(v) for v in r.stdout.split()]

    probe = subprocess.run([sys.executable, "-c", "import gridflow; print(gridflow.__file__)"],
                           cwd=tmp_path, env=env, capture_output=True, text=True)
    assert probe.stdout.startswith(str(tree)), probe      # the linked copy is what runs
    assert run(whole, 0) == [0, 4, 4]
    assert run(parts, 2) == [0, 2, 4]
    _edit(tree / "gridflow" / "metrics.py", '"""Error measures:', '"""Errors:')
    _edit(tree / "gridflow" / "bench" / "sweep.py", '"""Running a sweep:', '"""A sweep:')
    _edit(tree / "gridflow" / "bench" / "claims.py", "\nBREAK = ", "\nBREAK = 1.0 * ")
    _edit(tree / "gridflow" / "estimator" / "driver.py", '"""The public driver',
          '"""The driver')
    assert run(parts, 0) == [2, 4, 4]                     # resumed: 2 done before
    assert same_arrays(store_arrays(whole), store_arrays(parts))
    # a change of the estimator's code is another run: refused, the store kept
    _edit(tree / "gridflow" / "estimator" / "driver.py",
          "    return s.window // 2 + get_filter_pair(s.filters).radius",
          "    return s.window // 2 + get_filter_pair(s.filters).radius + 0")
    r = subprocess.run([sys.executable, "-c", code, str(recording), str(parts), "0"],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and "holds another run's results" in r.stderr, r.stderr
    assert same_arrays(store_arrays(whole), store_arrays(parts))


# --- the new user's review of the one pipeline ---------------------------------------------

def test_a_light_field_of_one_frame_goes_to_a_map_series(tmp_path):
    """A one-frame volume estimated with the single pass (--shears none) into a .zarr:
    the store holds the maps a static light field has (no motion), equal to the .npz's
    (the review: a KeyError on 'Ux' and a half-written store)."""
    from gridflow.io import load_estimate
    from gridflow.recording import MapStore

    vol = tmp_path / "one.npz"
    assert main(["generate", "--frames", "1", "--width", "48", "--height", "48", "-o",
                 str(vol)]) == 0
    args = ["--shears", "none", "--sigma", "2", "--window", "9", "--no-progress"]
    assert main(["estimate", str(vol), "-o", str(tmp_path / "one.zarr"), *args]) == 0
    assert main(["estimate", str(vol), "-o", str(tmp_path / "one_e.npz"), *args]) == 0
    store = MapStore.open(tmp_path / "one.zarr")
    maps, _, _ = load_estimate(tmp_path / "one_e.npz")
    assert store.quantities == list(maps) and "Ux" not in store.quantities
    for q in store.quantities:
        a, b = maps[q], np.asarray(store.group[q][0], dtype=np.float64)
        assert np.nanmax(np.abs(a - b)) <= 1e-6 * np.nanmax(np.abs(a)), q


def test_what_cannot_run_is_refused_before_an_output_is_made(recording, tmp_path, capsys):
    """Options of a series with an .npz, an image too small for the window and a cluster
    that does not answer are refused before anything is written (the review: --connect
    and --workers ignored with an .npz; c2.zarr left behind by a bad address; a store
    made before 'too small for a 65-tap window')."""
    vol = tmp_path / "v.npz"
    assert main(["generate", "--height", "32", "--width", "32", "-o", str(vol)]) == 0
    cases = (
        (["estimate", str(vol), "-o", str(tmp_path / "e.npz"), "--workers", "2"],
         "--workers: for a series of steps"),
        (["estimate", str(vol), "-o", str(tmp_path / "e.npz"), "--connect", "tcp://h:1"],
         "--connect: for a series of steps"),
        (["estimate", str(recording), "-o", str(tmp_path / "m.zarr"), "--no-progress"],
         "too small for a 65-tap window"),
        (["estimate", str(recording), "-o", str(tmp_path / "m.zarr"), *EST, "--connect",
          "nonsense"], "--connect 'nonsense': expected an address"))
    for args, match in cases:
        assert main(args) == 2
        assert match in capsys.readouterr().err, args
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.npz"]


def test_growth_against_a_truth_that_is_not_the_input_is_refused(recording, tmp_path, capsys):
    """gridflow growth --truth with another recording (of the same size: it was scored
    without a word) or another image size (a traceback) is refused naming both."""
    maps = tmp_path / "maps.zarr"
    assert main(["estimate", str(recording), "-o", str(maps), "--every", "10", *EST]) == 0
    other = record(tmp_path / "other.zarr", growth=1e-2)
    small = record(tmp_path / "small.zarr", height=48, width=48, frames=12)
    for truth, match in ((other, f"was estimated from {recording.resolve()}"),
                         (small, "images of 48x48 px")):
        assert main(["growth", str(maps), "--truth", str(truth), "--fig-dir",
                     str(tmp_path / "g")]) == 2
        assert match in capsys.readouterr().err
    assert main(["growth", str(maps), "--truth", str(recording), "--fig-dir",
                 str(tmp_path / "g")]) == 0


def test_a_sources_truth_and_a_false_npz_are_named(recording, tmp_path, capsys):
    from gridflow.sources import SourceError, open_source

    src = open_source(recording)
    assert set(src.truth(3)) == set(src.truth_names)
    for bad in (-1, src.frames, 2.0):
        with pytest.raises(SourceError, match="truth of frame"):
            src.truth(bad)
    fake = tmp_path / "t.npz"
    fake.write_text("hello")
    assert main(["estimate", str(fake), "-o", str(tmp_path / "e.npz")]) == 2
    assert "t.npz: not a zip archive, so not an .npz file" in capsys.readouterr().err


def test_growth_of_a_missing_store_says_so(tmp_path, capsys):
    assert main(["growth", str(tmp_path / "nothing.zarr"), "--fig-dir",
                 str(tmp_path / "g")]) == 2
    assert "nothing.zarr: no such folder" in capsys.readouterr().err


def test_a_mask_that_cannot_be_used_is_refused_by_name(recording, tmp_path, capsys):
    """--mask: a missing file, one of another size, an empty one, and a light field that
    is refocused are refused before anything is written, naming the file and what was
    expected."""
    from gridflow.bench.cli import main

    np.save(tmp_path / "small.npy", np.ones((32, 64), bool))
    np.save(tmp_path / "empty.npy", np.zeros((64, 64), bool))
    for spec, text in ((tmp_path / "none.npy", "no such file"),
                       (tmp_path / "small.npy", "expected 64x64 px"),
                       (tmp_path / "empty.npy", "no pixel is on the object")):
        out = tmp_path / "maps.zarr"
        assert main(["estimate", str(recording), "-o", str(out), "--motion", "affine",
                     "--mask", str(spec), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert str(spec) in err and text in err, err
        assert not out.exists()


# --- time stamps with gaps (issue 36) ----------------------------------------------------

def _with_times(recording, path, times):
    """The recording's frames and truth again, with these time stamps."""
    from gridflow.recording import write_recording
    from gridflow.sources import open_source

    rec = open_source(recording)
    return write_recording(path, ((rec.read(k, k + 1)[0], rec.truth(k))
                                  for k in range(rec.frames)),
                           shape=rec.shape, focal_length=rec.focal_length,
                           camera_spacing=rec.camera_spacing, frame_interval=60.0,
                           truth_names=rec.truth_names, times=times)


def test_steps_whose_window_spans_a_gap_are_left_out_and_growth_per_hour_uses_the_times(
        recording, tmp_path):
    """Frames 60 s apart, the lights off for an hour between frames 19 and 20, and a
    slower timer (66 s, within the 25 % that counts as jitter) from frame 30 on.  Under
    the affine model each step reads 8 frames either side: the steps at frames 12..27
    read across the gap and are left out, named in the report; the others are estimated
    as without stamps (the same maps), stored at their actual times, and the growth per
    hour is the median per frame over each step's own frame interval."""
    from gridflow.pipeline import growth_table
    from gridflow.recording import MapStore

    times = np.arange(40) * 60.0
    times[20:] += 3600.0
    times[30:] += np.arange(1, 11) * 6.0
    gappy = _with_times(recording, tmp_path / "gappy.zarr", times)
    settings = {"sigma": 2.0, "window": 9}
    rep = run_series(gappy, tmp_path / "g.zarr", every=1, settings=settings)
    text = "\n".join(rep.lines)
    assert "left out 16 step(s) at frames 12..27" in text, text
    assert "frames 19 -> 20: 3660 s (the median interval 60 s" in text, text
    store = MapStore.open(tmp_path / "g.zarr")
    frames = list(store.frames())
    assert frames == list(range(8, 12)) + list(range(28, 32))
    t, dt = store.step_times()
    np.testing.assert_allclose(t, times[frames] - times[0])
    # the mean interval over each window: 60 s before the gap; 60 or 66 s after it
    want = [(times[k + 8] - times[k - 8]) / 16 for k in frames]
    np.testing.assert_allclose(dt, want)
    assert dt[0] == 60.0 and dt[-1] > 60.0
    table = growth_table(tmp_path / "g.zarr")
    np.testing.assert_allclose(table.median_per_hour, table["median"] * 3600.0 / dt)
    # the steps kept are those of the recording without stamps
    run_series(recording, tmp_path / "plain.zarr", every=1, settings=settings)
    plain = MapStore.open(tmp_path / "plain.zarr")
    idx = [list(plain.frames()).index(k) for k in frames]
    np.testing.assert_array_equal(np.asarray(plain.group["growth"][idx]),
                                  np.asarray(store.group["growth"][:]))


def test_one_step_across_a_gap_and_bad_time_stamps_are_refused(recording, tmp_path, capsys):
    """A single step whose window spans the gap is refused (naming the gap and what to do);
    time stamps that go back, have the wrong count or are not finite are refused naming
    the array and the frame."""
    from gridflow.bench.cli import main
    from gridflow.sources import SourceError

    times = np.arange(40) * 60.0
    times[20:] += 3600.0
    gappy = _with_times(recording, tmp_path / "gappy.zarr", times)
    assert main(["estimate", str(gappy), "-o", str(tmp_path / "e.npz"), "--motion", "affine",
                 "--ref-frame", "18", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "frames 19 -> 20: 3660 s" in err and "--ref-frame" in err, err
    assert not (tmp_path / "e.npz").exists()
    assert main(["estimate", str(gappy), "-o", str(tmp_path / "e.npz"), "--motion", "affine",
                 "--sigma", "2", "--window", "9", "--ref-frame", "30", "--no-progress"]) == 0
    back = times.copy()
    back[7] = back[6]
    for bad, text in ((back, "frame 7 at 360 s is not after frame 6"),
                      (times[:39], "39 time stamps for 40 frames"),
                      (np.where(np.arange(40) == 3, np.nan, times), "frame 3 is nan")):
        with pytest.raises(SourceError, match=text):
            _with_times(recording, tmp_path / "bad.zarr", bad)
        assert not (tmp_path / "bad.zarr").exists()


def test_the_growth_maps_scale_bar_is_a_round_length_near_a_fifth_of_the_image():
    """The scale bar: at 420 mm and f = 650 px a pixel is 0.646 mm, a fifth of 256 px is
    33 mm, the bar 20 mm (31 px); 1, 2 or 5 times a power of ten, never more than the
    fifth nor less than 0.4 of it."""
    from gridflow.pipeline.growth import scale_bar_length

    assert scale_bar_length(420.0, 650.0, 256) == pytest.approx((20.0, 20.0 / (420 / 650)))
    for depth, f, w in ((100.0, 1000.0, 512), (3.3, 5000.0, 64), (2e4, 80.0, 1000)):
        length, px = scale_bar_length(depth, f, w)
        fifth = w * depth / f / 5
        mant = length / 10 ** np.floor(np.log10(length) + 1e-12)
        assert round(mant, 9) in (1.0, 2.0, 5.0) and 0.4 * fifth <= length <= fifth
        assert px == pytest.approx(length * f / depth)


def test_growth_report_per_leaf_over_confident_pixels(recording, tmp_path, capsys):
    """Two leaves (a mask of two disjoint rectangles) and a 2 x 2 speck: gridflow growth
    reports a row per leaf and step (the speck, under 5 % of the largest part, left out
    and said so), each leaf's median near the recording's uniform growth, and the pixels
    left out as uncertain counted beside those used.  The recording grows at the same
    rate everywhere, so both leaves' medians must agree with the truth alike: within the
    bound of test_series_growth_follows_the_rhythm (5 % scale bias of sigma 2 windows,
    2.2 % from the rhythm inside the window) plus what a leaf 24 px wide costs (its
    windows' erosion leaves about 10 px across, so few windows: 5 % more), 0.12 in all."""
    import pandas as pd

    from gridflow.pipeline.growth import confident, leaves

    mask = np.zeros((64, 64), bool)
    mask[6:58, 4:28] = mask[12:50, 38:62] = True
    mask[61:63, 31:33] = True                        # a speck between them
    np.save(tmp_path / "two.npy", mask)
    out = tmp_path / "maps.zarr"
    assert main(["estimate", str(recording), "-o", str(out), "--every", "8",
                 "--mask", str(tmp_path / "two.npy"), *EST]) == 0
    labels, fragments = leaves(out)
    assert labels.max() == 2 and not labels[:, 28:36].any()
    assert np.all(labels[:, :28][labels[:, :28] > 0] == 1)
    csv = tmp_path / "g.csv"
    assert main(["growth", str(out), "--truth", str(recording), "--csv", str(csv),
                 "--fig-dir", str(tmp_path / "figs")]) == 0
    text = capsys.readouterr().out
    table = pd.read_csv(csv)
    assert list(table.columns[:2]) == ["leaf", "step"]
    assert sorted(set(table["leaf"])) == [1, 2]
    assert (table.groupby("leaf").size() == table["step"].nunique()).all()
    assert (table["n_pixels"] > 100).all()
    err = (table["median"] / table["truth"] - 1).abs()
    assert err.max() < 0.12, table[["leaf", "frame", "median", "truth"]]
    assert "2 leaf part(s)" in text and "pixels left out as uncertain" in text
    # --sd-limit 0 keeps every pixel: none uncertain, more used
    assert main(["growth", str(out), "--csv", str(tmp_path / "all.csv"), "--sd-limit", "0",
                 "--fig-dir", str(tmp_path / "figs0")]) == 0
    every = pd.read_csv(tmp_path / "all.csv")
    assert (every["n_uncertain"] == 0).all()
    assert (every["n_pixels"] == table["n_pixels"] + table["n_uncertain"]).all()
    assert main(["growth", str(out), "--sd-limit", "nan"]) == 2
    # confident(): the median's multiple, over the given pixels only
    sd = np.ones((4, 4))
    sd[0, 0], sd[1, 1], sd[2, 2] = 10.0, 2.9, np.nan
    where = np.ones((4, 4), bool)
    kept = confident(sd, where, 3.0)
    assert not kept[0, 0] and kept[1, 1] and not kept[2, 2] and kept.sum() == 14
    assert confident(sd, where, 0.0).all() and confident(None, where).all()


# --- frames decoded once (issue 39) -------------------------------------------------------


def _counting(source, monkeypatch) -> list:
    """Every frame the recording's reader decodes, in order."""
    reader = source._reader
    decoded = []
    volume = reader.volume

    class Counting:
        def __getattr__(self, name):
            return getattr(volume, name)

        def __getitem__(self, key):
            decoded.append(key)
            return volume[key]

    monkeypatch.setattr(reader, "volume", Counting())
    return decoded


def test_steps_one_frame_apart_decode_each_frame_once(recording, tmp_path, monkeypatch):
    """With frames kept (Source.cache_frames), windows 0..4 then 1..5 decode frames 0..5
    once each and read the same numbers as a reader that keeps none; float32 reads are
    the stored frames exactly; a frame rewritten since it was kept is decoded again; at
    most the capacity is kept."""
    import shutil

    import zarr

    from gridflow.sources import open_source

    rec = tmp_path / "rec.zarr"
    shutil.copytree(recording, rec)
    plain = open_source(rec)
    kept = open_source(rec)
    kept.cache_frames(6)
    decoded = _counting(kept, monkeypatch)
    a = kept.read(0, 5)
    b = kept.read(1, 6)
    assert decoded == [0, 1, 2, 3, 4, 5]
    assert np.array_equal(a, plain.read(0, 5)) and np.array_equal(b, plain.read(1, 6))
    assert a.dtype == np.float64
    f32 = kept.read(1, 6, dtype=np.float32)
    assert f32.dtype == np.float32 and decoded == [0, 1, 2, 3, 4, 5]
    stored = np.asarray(zarr.open_group(str(rec), mode="r")["volume"][1:6])
    assert np.array_equal(f32, stored)
    # a repair of frame 3 (new content, a later modification time): decoded again
    time.sleep(0.01)
    g = zarr.open_group(str(rec), mode="r+")
    g["volume"][3] = stored[2] + 1.0
    c = kept.read(1, 6)
    assert decoded[6:] == [3], decoded
    assert np.array_equal(c[2], (stored[2] + np.float32(1.0)).astype(np.float64))
    assert len(kept._reader._cache) == 6
    kept.cache_frames(2)
    assert sorted(kept._reader._cache) == [4, 5]
    with pytest.raises(Exception, match="float32 or float64"):
        kept.read(0, 2, dtype=np.int16)


def test_a_frames_kept_values_are_computed_once_and_again_after_a_rewrite(
        recording, tmp_path, monkeypatch):
    """Source.frame_value keeps what was computed from a frame (Source.keep_values): a
    second call with the same key does not decode or compute again, another key reads
    the same frame; a frame rewritten since is decoded and computed again; the frames
    farthest from the last one go first; without keep_values nothing is kept."""
    import shutil

    import zarr

    from gridflow.sources import open_source

    rec = tmp_path / "rec.zarr"
    shutil.copytree(recording, rec)
    src = open_source(rec)
    src.keep_values(3)
    decoded = _counting(src, monkeypatch)
    calls = []

    def total(frame):
        calls.append(frame.dtype)
        return float(frame.sum(dtype=np.float64))

    stored = np.asarray(zarr.open_group(str(rec), mode="r")["volume"][:6])
    for t in range(6):
        assert src.frame_value(t, "sum", total, np.float32) == stored[t].sum(
            dtype=np.float64)
    assert decoded == list(range(6)) and calls == [np.float32] * 6
    assert sorted(src._reader._values) == [3, 4, 5]
    assert src.frame_value(5, "sum", total, np.float32) == stored[5].sum(dtype=np.float64)
    assert len(calls) == 6 and decoded == list(range(6))
    # another key: computed from the frame (decoded again: no decoded frame is kept)
    assert src.frame_value(5, "max", lambda f: float(f.max()), np.float64) == stored[5].max()
    assert decoded[6:] == [5]
    time.sleep(0.01)
    g = zarr.open_group(str(rec), mode="r+")
    g["volume"][4] = stored[4] + 1.0
    new = src.frame_value(4, "sum", total, np.float32)
    assert decoded[7:] == [4] and len(calls) == 7
    assert new == (stored[4] + np.float32(1.0)).sum(dtype=np.float64)
    # out of order: the frames farthest from the one computed go first (not the oldest)
    src.frame_value(0, "sum", total, np.float32)
    src.frame_value(1, "sum", total, np.float32)
    assert sorted(src._reader._values) == [0, 1, 3], sorted(src._reader._values)
    plain = open_source(rec)
    assert plain.values_kept == 0
    plain.frame_value(2, "sum", total, np.float32)
    plain.frame_value(2, "sum", total, np.float32)
    assert len(calls) == 11


def test_a_value_of_several_frames_is_kept_until_one_of_them_is_rewritten(recording,
                                                                        tmp_path):
    """Source.span_value keeps a value computed from several frames (a frame's signals,
    from the camera sums of the frames its temporal taps reach) under one frame, while
    every frame of its span is as it was: a second call does not compute it again, a
    rewrite of another frame of the span (not the frame it is kept under) does (and the
    value from the former files is dropped), a value during whose computation a frame of
    its span was rewritten is not kept, and a value of another span is another value;
    without keep_values nothing is kept; a frame outside the recording is refused by
    number."""
    import shutil

    import zarr

    from gridflow.recording import RecordingError
    from gridflow.sources import open_source

    rec = tmp_path / "rec.zarr"
    shutil.copytree(recording, rec)
    src = open_source(rec)
    src.keep_values(4)
    calls = []

    def fn():
        calls.append(1)
        return len(calls)

    assert src.span_value(3, (1, 2, 3, 4, 5), "signals", fn) == 1
    assert src.span_value(3, (1, 2, 3, 4, 5), "signals", fn) == 1
    assert src.span_value(3, (2, 3, 4), "signals", fn) == 2
    assert len(calls) == 2
    time.sleep(0.01)
    g = zarr.open_group(str(rec), mode="r+")
    g["volume"][5] = np.asarray(g["volume"][5]) + 1.0
    assert src.span_value(3, (1, 2, 3, 4, 5), "signals", fn) == 3
    assert src.span_value(3, (2, 3, 4), "signals", fn) == 2
    # the value from the files before the rewrite is dropped, not kept beside the new one
    assert sum(isinstance(k, tuple) and len(k) == 3 and k[:2] == ("signals", (1, 2, 3, 4, 5))
               for k in src._reader._values[3][1]) == 1

    def rewriting():
        # a frame of the span rewritten while the value is computed: not kept
        time.sleep(0.01)
        g["volume"][1] = np.asarray(g["volume"][1]) + 1.0
        return fn()

    assert src.span_value(2, (0, 1, 2), "signals", rewriting) == 4
    hit = src._reader._values.get(2)
    assert hit is None or not any(isinstance(k, tuple) and len(k) == 3
                                  and k[:2] == ("signals", (0, 1, 2)) for k in hit[1])
    assert src.span_value(2, (0, 1, 2), "signals", fn) == 5
    assert src.span_value(2, (0, 1, 2), "signals", fn) == 5
    with pytest.raises(RecordingError, match="frame 40 requested of 0..39"):
        src.span_value(38, (36, 37, 38, 39, 40), "signals", fn)
    plain = open_source(rec)
    assert plain.span_value(3, (2, 3, 4), "signals", fn) == 6
    assert plain.span_value(3, (2, 3, 4), "signals", fn) == 7


def test_kept_signals_give_the_store_of_windows_read_whole(tmp_path, monkeypatch):
    """At 128^2 px (the numba backend) a worker keeps each frame's filtered signals
    for the steps that share it (estimator.driver._kept_signals, through
    Source.span_value), one step at a time or two: each frame of the steps' temporal
    windows is filtered once, and the store equals, array for array, one made from
    whole windows with nothing kept."""
    from gridflow.pipeline import run as run_mod
    from gridflow.recording import _ZarrReader

    rec = record(tmp_path / "rec.zarr", frames=24, height=128, width=128)
    settings = {"sigma": 2.0, "window": 9}
    derived = []
    real = _ZarrReader.span_value

    def counting(self, t, span, key, fn):
        def counted():
            derived.append(t)
            return fn()
        return real(self, t, span, key, counted)

    monkeypatch.setattr(_ZarrReader, "span_value", counting)
    stores = {}
    for workers in (1, 2):
        derived.clear()
        stores[workers] = tmp_path / f"kept{workers}.zarr"
        run_series(rec, stores[workers], every=1, settings=settings, first=9, last=12,
                   workers=workers)
        # 4 steps of 13-frame temporal windows (affine, frames 3..18): 16 frames
        assert sorted(set(derived)) == list(range(3, 19)), derived
        assert len(derived) == 16 if workers == 1 else len(derived) <= 16 + 13, derived
    monkeypatch.setattr(run_mod, "frame_cache", lambda *a, **k: 0)
    derived.clear()
    plain = tmp_path / "plain.zarr"
    run_series(rec, plain, every=1, settings=settings, first=9, last=12, workers=1)
    assert not derived
    assert same_arrays(store_arrays(stores[1]), store_arrays(plain))
    assert same_arrays(store_arrays(stores[2]), store_arrays(plain))


@pytest.mark.parametrize("cache", [0, 6])
def test_a_non_finite_frame_is_named_whether_frames_are_kept_or_not(recording, tmp_path,
                                                                    cache):
    """A frame holding NaN is refused by number on a read that decodes it, kept frames
    or not."""
    import shutil

    import zarr

    from gridflow.recording import RecordingError
    from gridflow.sources import open_source

    rec = tmp_path / "rec.zarr"
    shutil.copytree(recording, rec)
    g = zarr.open_group(str(rec), mode="r+")
    frame = np.asarray(g["volume"][7])
    frame[1, 2, 10, 11] = np.nan
    g["volume"][7] = frame
    src = open_source(rec)
    src.cache_frames(cache)
    src.read(0, 7)
    with pytest.raises(RecordingError, match="frame 7 holds non-finite intensities"):
        src.read(5, 9)


def test_float32_windows_and_kept_frames_give_the_same_store(recording, tmp_path,
                                                             monkeypatch):
    """The pipeline reads a float32 recording as float32 and keeps what the estimator
    computes from each frame (its camera sums) for the next steps, which it runs in
    order: 9 steps one frame apart with a 17-frame window decode 17 + 8 frames one step
    at a time (at most 17 + 2 x 8 two at once, measured 25; in random order about 90),
    and the store equals, array for array, one read as float64 windows with nothing
    kept (the estimator's arithmetic is float64 either way)."""
    from gridflow.pipeline import run as run_mod
    from gridflow.pipeline import strategies
    from gridflow.recording import _ZarrReader

    settings = {"sigma": 2.0, "window": 9}
    decoded, dtypes = [], []
    check = _ZarrReader._check_finite

    def counting(self, out, start):
        if out.ndim == 4:                       # one frame, decoded for the cache
            decoded.append(start)
        return check(self, out, start)

    monkeypatch.setattr(_ZarrReader, "_check_finite", counting)
    real = run_mod.estimate_step

    def spy(plan, i, b, progress=None):
        read, value = plan.source.read, plan.source.frame_value

        def typed(*a, **k):
            out = read(*a, **k)
            dtypes.append(out.dtype)
            return out

        def typed_value(t, key, fn, dtype=np.float64):
            # kept frames: the estimator reads each frame once, through frame_value
            def fn_typed(frame):
                dtypes.append(frame.dtype)
                return fn(frame)
            return value(t, key, fn_typed, dtype)

        plan.source.read = typed
        plan.source.frame_value = typed_value
        return real(plan, i, b, progress)

    monkeypatch.setattr(run_mod, "estimate_step", spy)
    stores = {}
    for workers in (1, 2):
        decoded.clear()
        stores[workers] = tmp_path / f"fast{workers}.zarr"
        run_series(recording, stores[workers], every=1, settings=settings, first=12,
                   last=20, workers=workers)
        assert sorted(set(decoded)) == list(range(4, 29)), decoded
        if workers == 1:
            assert len(decoded) == 17 + 8, decoded
        else:
            assert len(decoded) <= 17 + 2 * 8, (decoded, len(decoded))
    assert set(dtypes) == {np.dtype(np.float32)}
    plain = tmp_path / "plain.zarr"
    monkeypatch.setattr(strategies.SinglePass, "takes_float32", False)
    monkeypatch.setattr(run_mod, "frame_cache", lambda *a, **k: 0)
    dtypes.clear()
    decoded.clear()
    run_series(recording, plain, every=1, settings=settings, first=12, last=20, workers=1)
    assert set(dtypes) == {np.dtype(np.float64)} and not decoded
    assert same_arrays(store_arrays(stores[1]), store_arrays(plain))
    assert same_arrays(store_arrays(stores[2]), store_arrays(plain))
