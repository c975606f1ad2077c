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

__all__ = ["estimate", "RunOptions", "RunReport", "growth_report", "growth_table",
           "draw_growth"]

# names imported on first use (PEP 562): importing one part (the executors, which the
# benchmark's sweeps use) does not import the others, nor the growth report's pandas and
# matplotlib
_WHERE = {"estimate": "run", "RunOptions": "run", "RunReport": "run",
          "growth_report": "growth", "growth_table": "growth", "draw_growth": "growth"}


def __getattr__(name):
    if name in _WHERE:
        import importlib

        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_WHERE))
