"""Command-line interface, the top floor of gridflow (imported by no other module; its own
modules import each other).

Each command parses its arguments, calls one function of the library and prints what it
reports.  The commands come in groups, a module each, each with ``register(subparsers)``:

- :mod:`.estimate`: ``generate``, ``estimate``, ``evaluate`` (:mod:`gridflow.bench.single`,
  :func:`gridflow.pipeline.estimate`);
- :mod:`.recordings`: ``record``, ``record-leaf`` (:mod:`gridflow.bench.recordings`),
  ``growth`` (:func:`gridflow.pipeline.growth_report`);
- :mod:`.sweeps`: ``sweep`` (:mod:`gridflow.bench.sweep_job`), ``figures``
  (:mod:`gridflow.bench.figures`), ``readings`` (:mod:`gridflow.bench.readings`),
  ``claims`` (:mod:`gridflow.bench.claims`);
- :mod:`.experiments`: ``cube``, ``cube-variants``, ``leaf``, ``peers``
  (:mod:`gridflow.bench.cube_experiment`, :mod:`~gridflow.bench.cube_variants`,
  :mod:`~gridflow.bench.leaf_experiment`, :mod:`~gridflow.bench.peers`).

Choices, defaults and the parameters' help come from the library
(:mod:`gridflow.estimator.settings`, the parameter dataclasses and their docstrings, the
experiments' constants; :mod:`._common`), so the help cannot drift from what runs.
Errors about the user's input (:mod:`gridflow.errors`, the estimator's ``InputError``, the
operating system's) are printed in one line with exit status 2; anything else is a bug
and keeps its traceback.  Heavy libraries are imported inside the commands that need them.
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["main", "build_parser"]

# the command groups' modules, imported by build_parser (inside main's handling of Ctrl-C:
# imported here, at the console script's import, an interrupt printed a traceback)
GROUPS = ("estimate", "recordings", "sweeps", "experiments")


def build_parser() -> argparse.ArgumentParser:
    """The parser of every command (each group's :func:`register`)."""
    import importlib

    from gridflow import __version__

    ap = argparse.ArgumentParser(
        prog="gridflow",
        description="Surface motion, depth and slopes from a camera grid under changing "
                    "illumination (Schuchert & Scharr, DAGM 2007), and the benchmark that "
                    "reproduces the paper's figures.")
    ap.add_argument("--version", action="version", version=f"gridflow {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    for group in GROUPS:
        importlib.import_module(f"{__name__}.{group}").register(sub)
    return ap


def _user_errors() -> tuple[type, ...]:
    """The exceptions that are about the user's input, not bugs in gridflow."""
    from gridflow.errors import GridflowError
    from gridflow.estimator import InputError
    from gridflow.pipeline.executors import ClusterError
    from gridflow.scenes.render import PovrayMissing, RenderError

    return (GridflowError, InputError, OSError, PovrayMissing, RenderError, ClusterError)


def _log_to_stderr() -> None:
    """The library reports long silent steps (first-run kernel compilation) at INFO level."""
    import logging

    log = logging.getLogger("gridflow")
    if not log.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("gridflow: %(message)s"))
        log.addHandler(handler)
        log.setLevel(logging.INFO)


def _quiet_io_loop() -> None:
    """After an error or an interrupt, Zarr's reads still in flight on its IO loop (it reads
    a store's chunks concurrently; one failed, or the run was stopped) are dropped, and
    asyncio reported each at exit ("Task was destroyed but it is pending!", "Task
    exception was never retrieved") under the one line that says what happened."""
    import logging

    logging.getLogger("asyncio").setLevel(logging.CRITICAL)


def main(argv=None) -> int:
    import signal
    import threading

    # the parser reads the estimator's defaults: numpy, scipy and numba import here, the
    # first ~0.3 s.  Ctrl-C there gave a bare KeyboardInterrupt traceback, or, inside
    # numpy's C import, numpy's ImportError ("could not import module datetime") and
    # status 1 (CI, once): the SIGINT is held until the imports are done
    held = []
    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:
        before = signal.signal(signal.SIGINT, lambda sig, frame: held.append(sig))
    try:
        if argv is None:
            from ._allocator import tune_allocator

            # the command line's own process (the console script, python -m): before
            # numpy, numba or any thread starts, as an arena given to a thread stays its
            # own.  Not where main is called with arguments from someone's process
            # (tests, scripts)
            tune_allocator()
        a = build_parser().parse_args(argv)
        _log_to_stderr()
        from gridflow.pipeline.executors import Terminated, signals_raise
    except KeyboardInterrupt:
        held.append(signal.SIGINT)
    finally:
        if main_thread:
            signal.signal(signal.SIGINT, before)
    if held:
        print("gridflow: interrupted (SIGINT) while starting; nothing was written",
              file=sys.stderr)
        return 130

    try:
        # SIGTERM raises like Ctrl-C, so that a file being written is removed (atomic
        # writes) and the interruption reads as one line, not a traceback
        with signals_raise():
            return a.func(a)
    except _user_errors() as exc:
        _quiet_io_loop()
        print(f"gridflow {a.command}: error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Terminated) as exc:
        from gridflow.io import remove_temporaries

        # a writer removes its temporary itself, except when the signal is acted on as its
        # __exit__ starts (see gridflow.io.remove_temporaries)
        remove_temporaries()
        _quiet_io_loop()
        name = "SIGTERM" if isinstance(exc, Terminated) else "SIGINT"
        print(f"gridflow {a.command}: interrupted ({name}); outputs already written are "
              "complete, the one being written was not left behind", file=sys.stderr)
        return 143 if name == "SIGTERM" else 130
