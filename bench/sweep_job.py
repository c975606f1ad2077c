"""A sweep as the command line asks for it: ``gridflow sweep`` runs :func:`run_sweep_job`.

The spec is a TOML file or a shipped spec's name, with the command line's changes
(:func:`build_spec`: another axis, other models, motions, noise levels, seeds or setup);
the outputs are checked before anything runs; the points run in this process's pool, on
a local ``dask.distributed`` cluster or on a running scheduler
(:func:`gridflow.pipeline.executors.make_client`) through :func:`gridflow.bench.sweep.
run_sweep`.  (A module of its own, outside the sources that key a sweep's finished points:
how a sweep is asked for changes none of its rows.)
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["build_spec", "run_sweep_job", "SweepJobReport", "CHANGES"]

# what the command line may change in a spec (besides the axis: param and values)
CHANGES = ("models", "motions", "noise", "seeds", "setup", "methods", "method_cmds",
           "method_timeout")


@dataclass
class SweepJobReport:
    """What :func:`run_sweep_job` ran.

    Attributes
    ----------
    rows : pandas.DataFrame
        The rows written (:func:`gridflow.bench.sweep.run_sweep`).
    output : Path
    seconds : float
        Wall time of the run.
    """

    rows: object
    output: Path
    seconds: float


def build_spec(source=None, *, name: str = "sweep", param=None, values=None, **changes):
    """The sweep spec ``source`` (a TOML file or a shipped spec's name; without one, every
    model on noise-free data, seed 0, called ``name``), with ``param`` swept over
    ``values`` instead of the spec's axes, and each of :data:`CHANGES` given (not None) in
    ``changes`` replacing the spec's; validated."""
    from gridflow.errors import UsageError

    from .spec import SweepSpec

    if source:
        spec = SweepSpec.from_toml(source)
    else:
        from gridflow.estimator import MODELS

        spec = SweepSpec(name=name, models=list(MODELS), noise=[0.0], seeds=[0])
    if param or values:
        if not (param and values):
            raise UsageError("--param and --values go together")
        spec.axes = [(param, list(values))]
    unknown = set(changes) - set(CHANGES)
    if unknown:
        raise TypeError(f"build_spec: unknown changes {sorted(unknown)}")
    if changes.get("method_cmds") is not None or changes.get("methods") is not None:
        # the command line's methods (--method and --method-cmd together) replace the
        # spec's
        changes["methods"] = changes.get("methods") or []
        changes["method_cmds"] = changes.get("method_cmds") or []
    for key, value in changes.items():
        if value is not None:
            setattr(spec, key, value)
    spec.validate(source or "command line")
    return spec


def run_sweep_job(spec, output, *, processes=None, workers=None, scheduler=None,
                  connect_timeout: float = 10.0, progress: bool = True,
                  log=None) -> SweepJobReport:
    """Run ``spec`` (a :class:`~gridflow.bench.spec.SweepSpec`, or a dict of
    :func:`build_spec`'s arguments, which the outputs are checked against first) into
    the tidy CSV ``output`` and its provenance sidecar ``output.json``.

    Parameters
    ----------
    processes : int, optional
        The in-process pool's size (default all cores).
    workers : int, optional
        Start a local ``dask.distributed`` cluster of that many single-threaded workers.
    scheduler : str, optional
        Address of a running dask scheduler (``tcp://HOST:PORT``); excludes ``workers``.
    connect_timeout : float
        Seconds to wait for the cluster to answer.
    progress : bool
        The progress bar.
    log : callable, optional
        Called with a line before the run (the points) and on connecting (the workers).

    Raises
    ------
    gridflow.bench.sweep.SweepInterrupted
        On SIGINT or SIGTERM (the finished points are kept).
    """
    from gridflow.errors import UsageError
    from gridflow.io import check_output

    from .spec import resolve_spec
    from .sweep import run_sweep

    log = log or (lambda line: None)
    source = spec.get("source") if isinstance(spec, dict) else None
    inputs = [resolve_spec(source)] if source else []
    check_output(output, suffixes=".csv", inputs=inputs, what="-o")
    check_output(Path(output).with_suffix(".json"), suffixes=".json", inputs=inputs,
                 what="the provenance sidecar of -o")
    from .sweep import times_path

    check_output(times_path(output), suffixes=".csv", inputs=inputs,
                 what="the wall times of -o")
    if scheduler and workers:
        raise UsageError("--scheduler and --workers exclude each other (--workers starts a "
                         "local cluster)")
    if isinstance(spec, dict):
        spec = build_spec(**spec)
    others = [m for m in spec.methods if m != "gridflow"] + list(spec.method_cmds)
    log(f"sweep {spec.name}: {len(spec.points())} points x "
        + (f"{len(spec.models)} models" if "gridflow" in spec.methods else "")
        + (" + " if others and "gridflow" in spec.methods else "")
        + (f"{len(others)} other method(s)" if others else "") + " -> "
        f"{output}")
    t0 = time.perf_counter()
    client = None
    if scheduler or workers:
        from gridflow.pipeline.executors import make_client

        client = make_client(scheduler, workers, timeout=connect_timeout)
        log(f"dask: {len(client.scheduler_info()['workers'])} workers")
    try:
        rows = run_sweep(spec, output, workers=processes, progress=progress,
                         executor=client)
    finally:
        if client is not None:
            client.close()
    return SweepJobReport(rows, Path(output), time.perf_counter() - t0)
