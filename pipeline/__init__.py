"""The grower's path: from any source to any sink in one run, and the growth report.

- :func:`estimate` (:mod:`.run`): estimate a source (a volume ``.npz``, a camera-grid
  folder, an HCI scene, a recording store: :func:`gridflow.sources.open_source`) into a
  sink (an ``.npz`` per model, or a Zarr map series: :mod:`.sinks`), with
  :class:`RunOptions`; the steps run in this process, on Dask's threads or on a
  ``dask.distributed`` cluster (:mod:`.executors`);
- the strategies that estimate a step (:mod:`.strategies`: the estimator's single pass,
  a refocused light field);
- :func:`growth_report`, :func:`growth_table`, :func:`draw_growth` (:mod:`.growth`): what
  a grower reads from a map series.

This package imports the estimator and the formats (``gridflow``), never the benchmark
(:mod:`gridflow.bench`), which builds on it.
"""

from .run import RunOptions, RunReport, estimate

__all__ = ["estimate", "RunOptions", "RunReport", "growth_report", "growth_table",
           "draw_growth"]


def __getattr__(name):
    # the report's pandas and matplotlib only when asked for
    if name in ("growth_report", "growth_table", "draw_growth"):
        from . import growth

        return getattr(growth, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
