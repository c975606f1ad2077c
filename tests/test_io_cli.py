"""Interchange files and the command line, end to end."""


import os

import numpy as np
import pytest

from gridflow.generators import make_sinusoid
from gridflow.bench.cli import main
from gridflow.io import load_estimate, load_volume, save_volume
from gridflow.volume import GridVolume

SMALL = ["--height", "80", "--width", "80", "--frames", "7"]


def test_volume_roundtrip(tmp_path):
    sv = make_sinusoid(height=16, width=20, grid=(3, 3), frames=5, a1=0.2)
    save_volume(tmp_path / "v.npz", sv)
    back = load_volume(tmp_path / "v.npz")
    np.testing.assert_array_equal(back.volume, sv.volume)
    assert back.focal_length == sv.focal_length
    assert back.camera_spacing == sv.camera_spacing
    assert set(back.truth) == set(sv.truth)
    assert back.meta["params"]["a1"] == 0.2


def test_file_written_without_gridflow_is_read(tmp_path):
    # the documented interchange format, written with plain numpy; principal point omitted
    vol = np.random.default_rng(0).random((5, 3, 3, 10, 12))
    np.savez(tmp_path / "mine.npz", volume=vol, focal_length=800.0, camera_spacing=[0.1, 0.2],
             truth_Z=np.full((10, 12), 50.0))
    d = load_volume(tmp_path / "mine.npz")
    assert d.principal_point == (5.5, 4.5)
    assert d.camera_spacing == (0.1, 0.2)
    assert d.truth["Z"].shape == (10, 12)


@pytest.mark.parametrize("arrays, match", [
    (dict(volume=np.zeros((3, 3, 10, 10)), focal_length=1.0, camera_spacing=[1, 1]), "shape"),
    (dict(volume=np.zeros((3, 1, 3, 10, 10)), camera_spacing=[1, 1]), "focal_length"),
    (dict(volume=np.zeros((3, 1, 3, 10, 10)), focal_length=1.0, camera_spacing=[1, 1, 1]),
     "camera_spacing"),
    (dict(volume=np.zeros((3, 1, 3, 10, 10)), focal_length=1.0, camera_spacing=[1, 1],
          truth_Z=np.zeros((5, 5))), "truth_Z"),
])
def test_bad_volume_files(tmp_path, arrays, match):
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match=match):
        load_volume(tmp_path / "bad.npz")


def test_unreadable_and_missing_files(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"this is not a zip file")
    with pytest.raises(ValueError, match="not a zip archive, so not an .npz file"):
        load_volume(tmp_path / "junk.npz")
    with pytest.raises(FileNotFoundError, match="no such file"):
        load_volume(tmp_path / "absent.npz")


def test_failed_write_keeps_existing_file(tmp_path, monkeypatch):
    target = tmp_path / "v.npz"
    target.write_bytes(b"precious")

    def half_write(fh, **arrays):
        fh.write(b"PK partial")
        raise OSError("disk full")

    monkeypatch.setattr("gridflow.io.np.savez", half_write)
    with pytest.raises(OSError, match="disk full"):
        save_volume(target, GridVolume(np.zeros((1, 1, 1, 2, 2)), 1.0, (1.0, 1.0), (0.5, 0.5)))
    assert target.read_bytes() == b"precious"
    assert [p.name for p in tmp_path.iterdir()] == ["v.npz"]   # no temp file left


def test_cli_generate_estimate_evaluate(tmp_path, capsys):
    vol, est = tmp_path / "vol.npz", tmp_path / "est.npz"
    assert main(["generate", *SMALL, "--a1", "0.3", "-o", str(vol)]) == 0
    assert main(["estimate", str(vol), "--model", "full", "-o", str(est)]) == 0
    maps, interior, meta = load_estimate(est)
    assert meta["model"] == "full" and meta["settings"]["filters_xy"] == "matched5"
    expected = {"Z", "Zx", "Zy", "disparity", "Ux", "Uy", "Uz", "a1", "a2", "a1x", "a1y", "a2x", "a2y",
                "model_error"}
    assert set(maps) == expected
    assert all(m.shape == (80, 80) and m.dtype == np.float64 for m in maps.values())
    capsys.readouterr()
    assert main(["evaluate", str(est), str(vol)]) == 0
    out = capsys.readouterr().out
    line = next(l for l in out.splitlines() if l.startswith("a1 "))
    # Q_rel(a1) at a1 = 0.3 on this 80^2, 7-frame volume: measured 5.5e-4; asked 3x
    assert float(line.split()[1]) < 3 * 5.5e-4


def test_cli_bcc_writes_only_its_maps(tmp_path):
    vol, est = tmp_path / "vol.npz", tmp_path / "est.npz"
    main(["generate", *SMALL, "-o", str(vol)])
    assert main(["estimate", str(vol), "--model", "bcc", "--sigma", "8", "--window", "33",
                 "-o", str(est)]) == 0
    maps, _, meta = load_estimate(est)
    assert set(maps) == {"Z", "Zx", "Zy", "disparity", "Ux", "Uy", "Uz", "model_error"}
    assert meta["settings"]["sigma"] == 8.0


def test_cli_several_models_share_one_run(tmp_path, capsys):
    """``--model all`` writes one file per model, each equal to a single-model run."""
    vol, est = tmp_path / "vol.npz", tmp_path / "est.npz"
    main(["generate", *SMALL, "--a1", "0.3", "-o", str(vol)])
    assert main(["estimate", str(vol), "--model", "all", "-o", str(est)]) == 0
    assert sorted(p.name for p in tmp_path.glob("est_*.npz")) == [
        "est_bcc.npz", "est_full.npz", "est_hf.npz"]
    assert not est.exists()
    one = tmp_path / "one.npz"
    assert main(["estimate", str(vol), "--model", "hf", "-o", str(one)]) == 0
    a, _, meta = load_estimate(tmp_path / "est_hf.npz")
    b, _, _ = load_estimate(one)
    assert meta["model"] == "hf"
    for k in b:
        np.testing.assert_array_equal(a[k], b[k])   # the same computation, bit for bit
    assert main(["estimate", str(vol), "--model", "bcc,full", "-o", str(tmp_path / "two.npz")]) == 0
    assert sorted(p.name for p in tmp_path.glob("two_*.npz")) == ["two_bcc.npz", "two_full.npz"]
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["estimate", str(vol), "--model", "bcc,xyz", "-o", str(tmp_path / "x.npz")])
    assert "bcc,xyz" in capsys.readouterr().err


def test_cli_errors_are_clear(tmp_path, capsys):
    assert main(["estimate", str(tmp_path / "none.npz"), "-o", str(tmp_path / "e.npz")]) == 2
    assert "no such file" in capsys.readouterr().err
    vol = tmp_path / "vol.npz"
    main(["generate", "--height", "40", "--width", "40", "--frames", "7", "-o", str(vol)])
    assert main(["estimate", str(vol), "-o", str(tmp_path / "e.npz")]) == 2
    assert "too small" in capsys.readouterr().err
    assert not (tmp_path / "e.npz").exists()
    assert main(["generate", "--a1", "500", "-o", str(tmp_path / "x.npz")]) == 2
    assert "exponent" in capsys.readouterr().err


def _earlier_model_all_set(tmp_path):
    """A volume and an output folder holding an earlier run's --model all set (three
    files reading b"earlier run"): ``(volume, folder, names)``."""
    vol = tmp_path / "v.npz"
    assert main(["generate", "--height", "48", "--width", "48", "-o", str(vol)]) == 0
    out = tmp_path / "out"
    out.mkdir()
    names = [f"e_{m}.npz" for m in ("bcc", "hf", "full")]
    for n in names:
        (out / n).write_bytes(b"earlier run")
    return vol, out, names


def test_model_all_outputs_replace_as_a_set(tmp_path, monkeypatch, capsys):
    """``--model all`` writes its three outputs as a set: a failure at the second (a full
    disk) leaves the outputs of an earlier run unchanged and no temporary file; the
    successful rerun replaces all three."""
    import errno

    import gridflow.io as gio
    from gridflow.bench.cli import main

    vol, out, names = _earlier_model_all_set(tmp_path)
    real = gio.np.savez
    calls = []

    def full_disk(fh, **arrays):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fh, **arrays)

    monkeypatch.setattr(gio.np, "savez", full_disk)
    assert main(["estimate", str(vol), "--model", "all", "--sigma", "2", "--window", "9",
                 "-o", str(out / "e.npz")]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == sorted(names)       # no temporaries
    assert all((out / n).read_bytes() == b"earlier run" for n in names)
    monkeypatch.setattr(gio.np, "savez", real)
    assert main(["estimate", str(vol), "--model", "all", "--sigma", "2", "--window", "9",
                 "-o", str(out / "e.npz")]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(names)
    assert all((out / n).read_bytes()[:2] == b"PK" for n in names)


@pytest.mark.parametrize("key", ["volume", "focal_length", "camera_spacing"])
def test_an_object_array_names_the_file_and_key(tmp_path, capsys, key):
    """A volume file whose array holds Python objects (a pickle, never loaded): the error
    names the file and the key (it named neither)."""
    from gridflow.bench.cli import main
    from gridflow.io import save_volume

    save_volume(tmp_path / "good.npz", make_sinusoid(height=16, width=20, grid=(3, 3),
                                                     frames=5))
    arrays = dict(np.load(tmp_path / "good.npz", allow_pickle=False))
    arrays[key] = np.array(arrays[key].tolist() if arrays[key].ndim else [1.0], dtype=object)
    np.savez(tmp_path / "bad.npz", **arrays)
    assert main(["estimate", str(tmp_path / "bad.npz"), "-o", str(tmp_path / "e.npz")]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "bad.npz") in err and f"'{key}'" in err, err
    assert not (tmp_path / "e.npz").exists()


def test_a_signal_between_the_renames_of_a_set_waits_for_them(tmp_path, capsys, monkeypatch):
    """SIGTERM arriving after the first of --model all's three renames: the renames
    finish (all three outputs new), then the command ends as interrupted (exit 143, one
    line).  Without holding the signal back the first output would be new and the other
    two old: a set from two runs."""
    import signal

    import gridflow.io as gio

    vol, out, names = _earlier_model_all_set(tmp_path)
    real = os.replace
    calls = []

    def replace_then_signal(src, dst):
        real(src, dst)
        calls.append(dst)
        if len(calls) == 1 and str(dst).endswith(".npz"):
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(gio.os, "replace", replace_then_signal)
    capsys.readouterr()
    assert main(["estimate", str(vol), "--model", "all", "--sigma", "2", "--window", "9",
                 "--no-progress", "-o", str(out / "e.npz")]) == 143
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "interrupted (SIGTERM)" in err[0], err
    assert sorted(p.name for p in out.iterdir()) == sorted(names)
    assert all((out / n).read_bytes()[:2] == b"PK" for n in names), \
        ({n: (out / n).read_bytes()[:12] for n in names}, calls)


@pytest.mark.parametrize("target", ["one", "set-first", "set-second", "hci"])
def test_a_signal_as_the_temporary_is_made_leaves_nothing(tmp_path, monkeypatch, target):
    """SIGINT arriving the moment ``mkstemp`` (or, for a scene folder, ``mkdtemp``) returns,
    before the caller has kept the name: the write is interrupted and no temporary is left.

    The random-time signal test met this once in CI (a ``.e_bcc.npz.*.tmp`` beside a
    whole old set); here the moment is hit every time.  Without holding the signal back
    until the name is kept, each case leaves its temporary file or folder."""
    import signal
    import tempfile

    import gridflow.io as gio
    from gridflow.hci import write_hci

    made = []

    def then_signal(real):
        def wrapped(*args, **kwargs):
            out = real(*args, **kwargs)
            made.append(out)
            if target != "set-second" or len(made) == 2:
                signal.raise_signal(signal.SIGINT)      # handled at the next bytecode
            return out
        return wrapped

    kind = "mkdtemp" if target == "hci" else "mkstemp"
    monkeypatch.setattr(tempfile, kind, then_signal(getattr(tempfile, kind)))
    (tmp_path / "a.npz").write_bytes(b"old")
    with pytest.raises(KeyboardInterrupt):
        if target == "one":
            with gio.atomic_write(tmp_path / "a.npz") as fh:
                fh.write(b"new")
        elif target == "hci":
            write_hci(tmp_path / "scene", np.zeros((3, 3, 4, 4)))
        else:
            with gio.atomic_write_set([tmp_path / "a.npz", tmp_path / "b.npz"]) as fhs:
                for fh in fhs:
                    fh.write(b"new")
    assert made, "the temporary was never made: the test did not reach its moment"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]
    assert (tmp_path / "a.npz").read_bytes() == b"old"


def _subcommands():
    import argparse

    from gridflow.bench.cli import build_parser

    sub = next(a for a in build_parser()._actions
               if isinstance(a, argparse._SubParsersAction))
    return sub.choices


def test_every_option_says_what_it_means():
    """Every option and argument of every subcommand has a help that says more than its
    default (was: the dataclass options said only "default X", some none at all)."""
    import argparse
    import re

    bare = []
    for name, p in _subcommands().items():
        for act in p._actions:
            if isinstance(act, argparse._HelpAction):
                continue
            text = re.sub(r"\s+", " ", act.help or "")
            meaning = re.sub(r"\(?\bdefault\b.*$", "", text, flags=re.I).strip(" (;,:")
            if act.help == argparse.SUPPRESS or len(meaning.split()) < 2:
                bare.append(f"gridflow {name} {'/'.join(act.option_strings) or act.dest}: "
                            f"{act.help!r}")
    assert not bare, "options whose help says nothing of their meaning:\n" + "\n".join(bare)


def test_parameter_options_read_their_help_from_the_docstrings():
    """generate's and record's options are the fields of SinusoidParams and
    RecordingParams, each with its docstring entry's first sentence (an entry "As
    SinusoidParams" reads that one's), so the help cannot drift from the docs."""
    from dataclasses import fields

    from gridflow.bench.cli._common import field_docs
    from gridflow.generators import SinusoidParams
    from gridflow.generators.recording import RecordingParams

    docs = field_docs(SinusoidParams)
    assert docs["f"] == "Focal length in pixels."
    assert docs["U_Y"] == "U_X, U_Y, U_Z: Velocity, world units per unit time."
    assert docs["a2"].endswith("additionally per world unit.")      # "Eq. 11" not an end
    rec = field_docs(RecordingParams)
    assert rec["wavelength_x"] == docs["wavelength_x"]
    assert rec["frame_interval"].startswith("Seconds between frames")
    subs = _subcommands()
    for cmd, cls in (("generate", SinusoidParams), ("record", RecordingParams)):
        helps = {a.dest: a.help for a in subs[cmd]._actions}
        expect = {**docs, **field_docs(cls)}
        for fl in fields(cls):
            text = expect[fl.name].rstrip(".").replace("``", "").replace("%", "%%")
            assert helps[fl.name].startswith(text), (cmd, fl.name, helps[fl.name])
            assert "(default " in helps[fl.name]


def test_cli_defaults_come_from_the_library():
    """The scenes' and experiments' defaults are the library's, not copies."""
    from gridflow.bench.cube_experiment import CUBE_SIGMA as SIGMA
    from gridflow.bench.cube_experiment import CUBE_WINDOW as WINDOW
    from gridflow.bench.cli import build_parser
    from gridflow.scenes import RENDER_CACHE, CubeScene, LeafRecording, LeafScene

    ap = build_parser()
    cube = ap.parse_args(["cube"])
    d = CubeScene()
    assert (cube.size, cube.grid, cube.frames, cube.texture_scale) == (
        d.width, d.grid[0], d.frames, d.texture_scale)
    assert (cube.sigma, cube.window, cube.cache) == (SIGMA, WINDOW, RENDER_CACHE)
    leaf = ap.parse_args(["leaf"])
    assert (leaf.growth, leaf.sigma, leaf.window) == (LeafScene().growth, SIGMA, WINDOW)
    rec = ap.parse_args(["record-leaf", "-o", "x.zarr"])
    assert (rec.margin, rec.frames, rec.cache) == (LeafRecording().margin,
                                                   LeafRecording().frames, RENDER_CACHE)
    assert "median" in _subcommands()["growth"].description


@pytest.mark.parametrize("target", ["one", "set", "folder"])
def test_an_interrupt_at_every_line_of_the_writers_leaves_old_or_new(tmp_path, target):
    """A KeyboardInterrupt raised at each line and call of the atomic writers in
    turn, wherever a real signal could land (not inside ``signals_deferred``, which holds
    SIGINT and SIGTERM back): afterwards the folder holds the old set or the whole new
    one, and no temporary.

    CI's random-time signal test met three ``.e_*.npz.*.tmp`` beside a whole old set
    once in 50 signals: the set writer's ``__enter__`` built its list of handles outside
    the block that removes the temporaries, so an interrupt there left them all.  This
    test hits that moment, and every other one, every time.  An interrupt as ``__exit__``
    starts cannot be caught inside the writer; the CLI removes those temporaries
    (``remove_temporaries``), and so does this test, after the interrupt, and checks that
    it had nothing to remove after an interrupt anywhere else (the writers clean up
    themselves)."""
    import linecache
    import os
    import signal
    import sys

    import gridflow.io as gio

    io_file = gio.atomic_write.__init__.__code__.co_filename
    names = {"one": ["a.npz"], "set": ["a.npz", "b.npz", "c.npz"], "folder": []}[target]

    def write():
        if target == "one":
            with gio.atomic_write(tmp_path / "a.npz") as fh:
                fh.write(b"new")
        elif target == "set":
            with gio.atomic_write_set([tmp_path / n for n in names]) as fhs:
                for fh in fhs:
                    fh.write(b"new")
        else:
            with gio.folder_beside(tmp_path / "scene") as tmp:
                (tmp / "x").write_bytes(b"new")
                os.rename(tmp, tmp_path / "scene")

    def deferred():
        h = signal.getsignal(signal.SIGINT)
        return "signals_deferred" in getattr(h, "__qualname__", "")

    hit_at = 1
    while True:
        for n in names:
            (tmp_path / n).write_bytes(b"old")
        seen = [0]
        where = []

        def tracer(frame, event, arg):
            if frame.f_code.co_filename != io_file:
                return None                 # not a writer's frame, nor its lines
            # a signal is acted on at a frame's start or at one of its lines' calls and
            # jumps: a 'call' or a 'line' event.  Not at a 'return': raised there, it would
            # land in the caller between the call and its next instruction, where CPython
            # does not look for signals (a with statement's __enter__ and its body)
            if event in ("call", "line") and not deferred():
                seen[0] += 1
                if seen[0] == hit_at:
                    line = linecache.getline(frame.f_code.co_filename, frame.f_lineno)
                    where.append((frame.f_code.co_name, event, line.strip()))
                    raise KeyboardInterrupt(f"at {frame.f_code.co_name}:{frame.f_lineno}")
            return tracer

        sys.settrace(tracer)
        removed = []
        try:
            write()
            interrupted = None
        except KeyboardInterrupt as exc:
            interrupted = str(exc)
            removed = gio.remove_temporaries()      # as the CLI's interrupt handler does
        finally:
            sys.settrace(None)
        left = sorted(p.name for p in tmp_path.iterdir())
        if target == "folder":
            assert left in ([], ["scene"]), (interrupted, left)
            if left:
                assert (tmp_path / "scene" / "x").read_bytes() == b"new"
                (tmp_path / "scene" / "x").unlink()
                (tmp_path / "scene").rmdir()
        else:
            contents = {(tmp_path / n).read_bytes() for n in names}
            assert left == sorted(names), (interrupted, left)
            assert contents in ({b"old"}, {b"new"}), (interrupted, contents)
        # only an interrupt as an __exit__ starts (its 'call' event, or its first line,
        # the try, where CPython itself would not look for signals) needs the registry
        starts = where and where[0][0] == "__exit__" and (where[0][1] == "call"
                                                        or where[0][2] == "try:")
        assert not removed or starts, (interrupted, where, removed)
        if interrupted is None:
            break                           # past the last moment: the write ran through
        hit_at += 1
    assert hit_at > 10, "too few moments were hit for the test to mean anything"
