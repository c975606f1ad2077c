"""Running sweep points on dask.distributed (edge: cluster set-up).

``gridflow sweep ... --scheduler tcp://HOST:PORT`` sends the points to an existing cluster
(every worker needs gridflow installed, the same version); ``--workers N`` starts a local
cluster of N single-threaded worker processes.  Without either, sweeps run in a
local process pool and need no server.  Each point is seeded by its own parameters, so
the CSV is the same whichever executor ran it.
"""

from __future__ import annotations

__all__ = ["make_client"]


def make_client(scheduler: str | None = None, workers: int | None = None):
    """A ``dask.distributed.Client`` for ``scheduler``, or a local cluster of ``workers``.

    Raises
    ------
    RuntimeError
        If dask.distributed is not installed or the scheduler cannot be reached.
    """
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:
        raise RuntimeError("dask.distributed is not installed: pip install "
                           "'dask[distributed]'") from exc
    if scheduler:
        try:
            return Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise RuntimeError(f"cannot reach the dask scheduler at {scheduler}: {exc}") from None
    cluster = LocalCluster(n_workers=workers or 1, threads_per_worker=1, processes=True,
                           dashboard_address=None,
                           env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                                "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"})
    client = Client(cluster)
    # close the cluster with the client
    client._gridflow_cluster = cluster
    orig_close = client.close

    def close(*a, **k):
        orig_close(*a, **k)
        cluster.close()

    client.close = close
    return client
