"""Hostile outputs: an output path that is the input, a FIFO, a folder, a link, a device
or of the wrong kind is refused before anything is written, as is one the file system
refuses (a name too long, a folder not writable, a read-only file system), before the
input is read; a failed write leaves no temporary file.

Every case must end in a clear error (exit 2 from the CLI, naming the file, key or
argument) or a correct result; none may crash, hang, exit 0 with garbage, or change a
file it was not asked to write.  The cases are counted (``builders.tried``) and the
count is printed in the pytest summary.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from builders import cli_fails, snapshot, tried
from gridflow.bench.cli import main
from gridflow.io import OutputError, atomic_write, check_output


# --- outputs clobber what they should not ----------------------------------------------------

def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("make_target, match", [
    (lambda d, v: v, "is an input of this command"),                        # -o the input
    (lambda d, v: _fifo(d / "pipe.npz"), "not a regular file"),             # a FIFO
    (lambda d, v: (d / "dir.npz").mkdir() or d / "dir.npz", "not a regular file"),
    (lambda d, v: d / "est.txt", "expected an estimate .npz (one step) or a map series .zarr"),
    (lambda d, v: d / "est", "expected an estimate .npz (one step) or a map series .zarr"),
    (lambda d, v: (d / "link.npz").symlink_to(v) or d / "link.npz", "not a regular file"),
    (lambda d, v: ((d / "afile").write_text("x"), d / "afile" / "e.npz")[1], "not a folder"),
])
def test_estimate_output_refused_and_nothing_changes(tmp_path, small_volume, capsys,
                                                     make_target, match):
    work = tmp_path / "w"
    work.mkdir()
    vol = work / "v.npz"
    vol.write_bytes(small_volume.read_bytes())
    target = make_target(work, vol)
    before = snapshot(work)
    cli_fails(["estimate", vol, "-o", target, "--sigma", "2", "--window", "9"], capsys, match)
    assert snapshot(work) == before
    tried("output path refused (estimate)")


@pytest.mark.parametrize("args, match", [
    (["generate", "-o", "{d}/v.txt"], "expected a .npz"),
    (["sweep", "{spec}", "-o", "{d}/out.json"], "expected a .csv"),
    (["sweep", "{spec}", "-o", "{spec}"], "expected a .csv"),
    (["sweep", "{spec}", "-o", "{d}/pipe.csv"], "not a regular file"),
    (["sweep", "{spec}", "-o", "{d}/side.csv"], "provenance sidecar"),
    (["claims", "{d}/s.csv", "--write-csv", "{d}/s.csv"], "is an input"),
    (["claims", "{d}/s.csv", "--write-doc", "{d}/doc.txt"], "expected a .md"),
    (["figures", "--sweep", "{d}/s.csv", "--out", "{d}/s.csv"], "not a folder"),
    (["cube", "--csv", "{d}/cube.txt"], "expected a .csv"),
    (["cube", "--fig-dir", "{d}/s.csv"], "not a folder"),
])
def test_every_writer_checks_its_outputs_first(tmp_path, capsys, args, match):
    spec = tmp_path / "spec.toml"
    spec.write_text('[sweep]\nmodels = ["full"]\n[base]\nheight = 40\nwidth = 40\n'
                    'frames = 5\ngrid = [3, 3]\n[estimator]\nsigma = 2.0\nwindow = 9\n'
                    '[[axis]]\nparam = "a1"\nvalues = [0.1]\n')
    (tmp_path / "s.csv").write_text("param,value\n")
    _fifo(tmp_path / "pipe.csv")
    (tmp_path / "side.json").mkdir()          # the sidecar of side.csv cannot be written
    before = snapshot(tmp_path)
    cli_fails([a.format(d=tmp_path, spec=spec) for a in args], capsys, match)
    assert snapshot(tmp_path) == before      # nothing written, nothing replaced
    tried("output path refused (other commands)")


def test_failed_writes_leave_no_temporary_file(tmp_path):
    target = tmp_path / "x.csv"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_write(target, "w") as fh:
            fh.write("new")
            raise RuntimeError("disk full")
    assert target.read_text() == "old" and sorted(tmp_path.iterdir()) == [target]
    # the rename itself fails: the target became a folder after the check
    late = tmp_path / "late.csv"
    with pytest.raises(OSError):
        with atomic_write(late, "w") as fh:
            fh.write("new")
            late.mkdir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["late.csv", "x.csv"]
    tried("failed write", 2)


def test_device_files_are_never_replaced():
    # the check alone: /dev/null exists and is not a regular file
    with pytest.raises(OutputError, match="not a regular file"):
        check_output("/dev/null", suffixes=("",), what="-o")
    with pytest.raises(OutputError, match="not a regular file"):
        with atomic_write("/dev/null", "w"):
            pass
    assert Path("/dev/null").is_char_device()
    tried("output path refused (device)", 2)


# --- outputs the file system refuses: checked before the input is read -----------------------

def _input_never_read(monkeypatch):
    """Make reading any input fail loudly: an output check that comes after the read shows
    up as this error instead of the expected message."""
    import gridflow.sources as sources

    def refuse(*a, **k):
        raise AssertionError("the input was read before the outputs were checked")

    monkeypatch.setattr(sources, "open_source", refuse)


@pytest.mark.parametrize("models", [None, "all"])
def test_a_name_too_long_is_refused_before_any_work(tmp_path, small_volume, capsys,
                                                    monkeypatch, models):
    """A name over the file system's limit (255 bytes here) is refused before the input
    is read; with --model all the longest per-model name counts."""
    from gridflow.io import name_max

    limit = name_max(tmp_path)
    stem = "a" * (limit - len(".npz") - (len("_full") - 1 if models else -1))
    _input_never_read(monkeypatch)
    before = snapshot(tmp_path)
    args = ["estimate", small_volume, "-o", tmp_path / f"{stem}.npz"]
    cli_fails(args + (["--model", models] if models else []), capsys, "this file system allows")
    assert snapshot(tmp_path) == before
    tried("output name too long (estimate)")


def test_the_longest_legal_name_is_written_and_leaves_no_temporary(tmp_path, small_volume):
    """A name of exactly the limit: the temporary name beside it is shortened to fit, the
    output is written, nothing else is left."""
    from gridflow.io import name_max

    out = tmp_path / ("b" * (name_max(tmp_path) - 4) + ".npz")
    assert main(["estimate", str(small_volume), "-o", str(out), "--sigma", "2",
                 "--window", "9"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == [out.name]
    tried("output name at the limit (estimate)")


def test_an_unwritable_folder_is_refused_before_any_work(tmp_path, small_volume, capsys,
                                                         monkeypatch):
    """As root a mode-0555 folder is writable, so the check is made to see one that is not
    (os.access says no); the real read-only file system follows."""
    target = tmp_path / "ro"
    target.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, m, **k: False if Path(p) == target
                        else real(p, m, **k))
    _input_never_read(monkeypatch)
    cli_fails(["estimate", small_volume, "-o", target / "e.npz"], capsys,
               f"cannot write into {target}")
    assert list(target.iterdir()) == []
    tried("output folder not writable (estimate)")


def test_a_read_only_file_system_is_refused_before_any_work(tmp_path, small_volume, capsys,
                                                            monkeypatch):
    """A read-only bind mount (needs root and mount; where the machine forbids it the
    test says so and is skipped, visibly)."""
    src, mnt = tmp_path / "src", tmp_path / "mnt"
    src.mkdir()
    mnt.mkdir()
    r = subprocess.run(["mount", "--bind", str(src), str(mnt)], capture_output=True)
    if r.returncode:
        pytest.skip(f"cannot make a read-only bind mount here: {r.stderr.decode().strip()}")
    try:
        r = subprocess.run(["mount", "-o", "remount,ro,bind", str(mnt)], capture_output=True)
        if r.returncode:
            pytest.skip(f"cannot remount read-only here: {r.stderr.decode().strip()}")
        _input_never_read(monkeypatch)
        cli_fails(["estimate", small_volume, "-o", mnt / "e.npz"], capsys,
                   "a read-only file system")
        cli_fails(["generate", "-o", mnt / "v.npz"], capsys, "a read-only file system")
        tried("read-only file system (estimate, generate)", 2)
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)
