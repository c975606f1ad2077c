"""Signals and kills: SIGINT, SIGTERM and SIGKILL during a pooled sweep, a single
estimate, generate --hci and a render, and two runs onto the same name, leave the old
outputs or a whole new set, and no process, temporary file or half of a set behind.

Every case must end in a clear error (exit 2 from the CLI, naming the file, key or
argument) or a correct result; none may crash, hang, exit 0 with garbage, or change a
file it was not asked to write.  The cases are counted (``builders.tried``) and the
count is printed in the pytest summary.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from builders import tried
from gridflow.loader import load_folder

ROOT = Path(__file__).resolve().parent.parent


# --- interrupts and kills of a sweep ---------------------------------------------------------

SLOW_SPEC = """
[sweep]
name = "slow"
models = ["full"]
[base]
height = 160
width = 160
frames = 7
[estimator]
sigma = 4.0
window = 17
[[axis]]
param = "a1"
values = [0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.09, 0.1, 0.11, 0.12, 0.13,
          0.14, 0.15]
"""


def _start_sweep(tmp_path, processes=2):
    spec = tmp_path / "slow.toml"
    spec.write_text(SLOW_SPEC)
    out = tmp_path / "s.csv"
    p = subprocess.Popen([sys.executable, "-m", "gridflow.bench.cli", "sweep", str(spec), "-o",
                          str(out), "--processes", str(processes), "--no-progress"],
                         cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    parts = tmp_path / "s.csv.parts"
    t0 = time.monotonic()
    while not (parts.is_dir() and list(parts.glob("*.csv"))):
        assert p.poll() is None, p.communicate()
        assert time.monotonic() - t0 < 240, "the sweep made no progress"
        time.sleep(0.05)
    return p, out, parts


def _descendants(pid: int) -> list:
    import psutil

    return psutil.Process(pid).children(recursive=True)


def _alive(procs) -> list:
    import psutil

    out = []
    for c in procs:
        try:
            if c.is_running() and c.status() != psutil.STATUS_ZOMBIE:
                out.append(c)
        except psutil.NoSuchProcess:
            pass
    return out


@pytest.mark.slow
@pytest.mark.parametrize("sig, code, name", [(signal.SIGINT, 130, "SIGINT"),
                                             (signal.SIGTERM, 143, "SIGTERM")])
def test_signal_stops_a_pooled_sweep_within_seconds(tmp_path, sig, code, name):
    p, out, parts = _start_sweep(tmp_path)
    children = _descendants(p.pid)
    assert children, "the pool has no worker processes"
    t0 = time.monotonic()
    os.kill(p.pid, sig)
    _, err = p.communicate(timeout=30)
    took = time.monotonic() - t0
    assert took < 5, f"stopping took {took:.1f} s"
    assert p.returncode == code, err
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("sweep slow:")]
    assert lines == [lines[0]] and f"interrupted by {name}" in lines[0], err
    assert "Traceback" not in err
    kept = list(parts.glob("*.csv"))
    assert kept and not out.exists()
    for part in kept:                                       # whole parts only
        assert len(pd.read_csv(part)) == 12
    time.sleep(1)
    assert not _alive(children)
    tried(f"{name} during a pooled sweep")


@pytest.mark.slow
def test_no_process_outlives_a_killed_sweep(tmp_path):
    p, out, parts = _start_sweep(tmp_path)
    children = _descendants(p.pid)
    names = sorted(c.name() for c in children)
    assert len(children) >= 2, names                # workers (and the resource tracker)
    os.kill(p.pid, signal.SIGKILL)                  # the parent alone
    p.communicate()
    t0 = time.monotonic()
    alive = children
    while alive and time.monotonic() - t0 < 15:
        alive = _alive(children)
        time.sleep(0.2)
    assert not alive, f"still running after the parent's SIGKILL: {alive}"
    tried("SIGKILL of the sweep's parent")


# --- a render killed with SIGKILL ------------------------------------------------------------

def test_a_killed_render_leaves_nothing_behind(tmp_path):
    """What a render killed with SIGKILL leaves (a half-written image under a temporary
    name, its scene files) is removed by the next render of the scene, under its lock."""
    from gridflow.scenes import CubeScene, render_cube

    scene = CubeScene(width=24, height=24, grid=(3, 3), frames=3)
    folder = tmp_path / f"cube-{scene.key()}"
    folder.mkdir()
    (folder / ".t00_y0_x0.png.12345.tmp.png").write_bytes(b"half an image")
    (folder / ".pov-dead").mkdir()
    (folder / ".pov-dead" / "r0_0_0_12345.pov").write_text("// scene")
    out = render_cube(scene, tmp_path, progress=False)
    assert out == folder
    left = sorted(p.name for p in folder.iterdir() if p.name.startswith(".") and
                  p.name != ".lock")
    assert left == [], left
    assert load_folder(folder).volume.shape == (3, 3, 3, 24, 24)
    tried("leftovers of a killed render")


# --- a signal at a random time during a single estimate --------------------------------------

SIGNAL_TRIALS = 50


@pytest.mark.slow
@pytest.mark.parametrize("models", [None, "all"])
def test_a_signal_at_random_times_leaves_the_old_outputs_or_a_whole_new_set(
        tmp_path, small_volume, models):
    """``gridflow estimate`` (one output, and --model all: three) is sent SIGTERM or SIGINT
    at a random time from its start to a quarter past its measured end, 50 times (15
    more against a duration measured again, should all fall on one side of the end).
    Every time the output folder holds exactly the expected outputs, each complete (it
    loads), all of them
    from the old run (sigma 2) or all from the new one (sigma 3), and nothing else (no
    temporary file, no lock, no half of a set)."""
    from gridflow.io import load_estimate

    out = tmp_path / "out"
    out.mkdir()
    names = ["e.npz"] if models is None else ["e_bcc.npz", "e_full.npz", "e_hf.npz"]

    def command(sigma):
        cmd = [sys.executable, "-m", "gridflow.bench.cli", "estimate", str(small_volume),
               "-o", str(out / "e.npz"), "--sigma", str(sigma), "--window", "9"]
        return cmd + (["--model", models] if models else [])

    def state():
        assert sorted(p.name for p in out.iterdir()) == names, sorted(out.iterdir())
        sigmas = {load_estimate(out / n)[2]["settings"]["sigma"] for n in names}
        assert len(sigmas) == 1, f"a set of outputs from different runs: {sigmas}"
        return sigmas.pop()

    assert subprocess.run(command(2), cwd=ROOT, capture_output=True).returncode == 0
    old = {n: (out / n).read_bytes() for n in names}

    def measured():
        # one uninterrupted run: how long the command takes under the machine's load now
        t0 = time.monotonic()
        assert subprocess.run(command(3), cwd=ROOT, capture_output=True).returncode == 0
        return time.monotonic() - t0

    duration = measured()
    assert state() == 3
    rng = np.random.default_rng(26)
    seen = {2.0: 0, 3.0: 0}
    trials = SIGNAL_TRIALS
    trial = 0
    while True:
        if trial == trials:
            if (seen[2.0] and seen[3.0]) or trials > SIGNAL_TRIALS:
                break
            # every signal fell on one side of the rename: under the other tests' load the
            # runs took longer than the one measured (CI, once: {2.0: 50, 3.0: 0}).  That
            # is the sampling, not the property: measure again and draw more
            duration = measured()
            trials += SIGNAL_TRIALS * 3 // 10
        for n, data in old.items():                      # the old set back in place
            (out / n).write_bytes(data)
        sig = (signal.SIGTERM, signal.SIGINT)[trial % 2]
        p = subprocess.Popen(command(3), cwd=ROOT, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
        # a fifth of the range lies past the measured run, so that the rename falls inside
        # it (over [0, duration] only about 2 of 50 signals came after the rename, and
        # "both outcomes" failed by chance in about 1 run in 8)
        time.sleep(rng.uniform(0, 1.25 * duration))
        p.send_signal(sig)
        _, err = p.communicate(timeout=60)
        seen[state()] += 1
        trial += 1
    # both outcomes occurred: the signals fell before and after the rename
    assert seen[2.0] and seen[3.0], seen
    tried(f"signal at a random time during estimate ({'--model all' if models else 'one model'})",
          trials)


HCI_SIGNAL_TRIALS = 30


@pytest.mark.slow
def test_a_signal_at_random_times_during_generate_hci_leaves_no_partial_scene(tmp_path):
    """``gridflow generate --hci FOLDER`` (a folder output: 25 views and the truth) sent
    SIGTERM or SIGINT at a random time from its start to a quarter past its measured end,
    30 times (10 more against a duration measured again, should all fall on one side of
    the end), each onto a new name: every time the folder is absent or a whole scene that
    loads, and nothing else is beside it (no temporary folder).  An absent folder comes
    with exit 130/143 (gridflow's handlers), or with Python's own status 1 where a SIGINT
    fell into the interpreter's start-up, before gridflow's code runs."""
    from gridflow.hci import load_hci

    def command(folder):
        return [sys.executable, "-m", "gridflow.bench.cli", "generate", "--height", "256",
                "--width", "256", "--hci", str(folder)]

    def measured(name):
        # one uninterrupted run: how long the command takes under the machine's load now
        t0 = time.monotonic()
        assert subprocess.run(command(tmp_path / name), cwd=ROOT,
                              capture_output=True).returncode == 0
        return time.monotonic() - t0

    duration = measured("first")
    whole = sorted(p.name for p in (tmp_path / "first").iterdir())
    rng = np.random.default_rng(2026)
    seen = {"absent": 0, "whole": 0, "start-up": 0}
    trials = HCI_SIGNAL_TRIALS
    trial = 0
    while True:
        if trial == trials:
            if (seen["absent"] and seen["whole"]) or trials > HCI_SIGNAL_TRIALS:
                break
            # every signal fell on one side of the end: under the other tests' load the
            # runs took longer (or shorter) than the one measured (CI, once: 29 absent, 1
            # in the start-up).  That is the sampling, not the property: measure again
            # and draw more
            duration = measured("again")
            trials += HCI_SIGNAL_TRIALS // 3
        folder = tmp_path / f"s{trial}"
        sig = (signal.SIGTERM, signal.SIGINT)[trial % 2]
        p = subprocess.Popen(command(folder), cwd=ROOT, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
        time.sleep(rng.uniform(0, 1.25 * duration))
        p.send_signal(sig)
        _, err = p.communicate(timeout=60)
        beside = sorted(q.name for q in tmp_path.iterdir() if q.name.startswith("."))
        assert beside == [], (trial, beside, err)
        if folder.exists():
            assert sorted(q.name for q in folder.iterdir()) == whole, (trial, err)
            assert load_hci(folder).volume.shape == (1, 5, 5, 256, 256)
            seen["whole"] += 1
        elif (sig == signal.SIGINT and p.returncode == 1 and "KeyboardInterrupt" in err
              and "gridflow" not in err):
            # the SIGINT landed in the interpreter's own start-up (CI's machine: "Could not
            # import runpy module", a traceback of importlib's frames only), before any of
            # gridflow's code could handle it: Python's exit status, and nothing written
            seen["start-up"] += 1
        else:
            assert p.returncode in (130, 143, -sig), (trial, p.returncode, err)
            seen["absent"] += 1
        trial += 1
    assert seen["absent"] and seen["whole"], seen
    tried("signal at a random time during generate --hci", trials)


@pytest.mark.slow
def test_two_concurrent_model_all_runs_leave_one_whole_set(tmp_path, small_volume):
    """Two ``--model all`` runs started together onto the same name (sigma 2 and 3), 8
    rounds: each time the three outputs all come from one run (the review saw a mixed
    set in 1 of 8 rounds before the lock)."""
    from gridflow.io import load_estimate

    out = tmp_path / "out"
    out.mkdir()
    names = ["e_bcc.npz", "e_full.npz", "e_hf.npz"]

    def start(sigma):
        return subprocess.Popen(
            [sys.executable, "-m", "gridflow.bench.cli", "estimate", str(small_volume),
             "--model", "all", "-o", str(out / "e.npz"), "--sigma", str(sigma), "--window",
             "9"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    for _ in range(8):
        procs = [start(2), start(3)]
        for p in procs:
            _, err = p.communicate(timeout=60)
            assert p.returncode == 0, err
        assert sorted(p.name for p in out.iterdir()) == names
        sigmas = {load_estimate(out / n)[2]["settings"]["sigma"] for n in names}
        assert len(sigmas) == 1, f"a set of outputs from two runs: {sigmas}"
    tried("two concurrent --model all runs", 8)
