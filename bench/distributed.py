"""Running sweep points on dask.distributed (edge: cluster set-up).

``gridflow sweep ... --scheduler tcp://HOST:PORT`` sends the points to an existing cluster
(every worker needs gridflow installed, the same version); ``--workers N`` starts a local
cluster of N single-threaded worker processes.  Without either, sweeps run in a local
process pool and need no server.  Results come back to the client, which alone writes
files, so workers need no shared disk.  Each point is seeded by its own parameters, so the
CSV is the same whichever executor ran it.
"""

from __future__ import annotations

import re
import threading

__all__ = ["make_client"]

_ADDRESS = re.compile(r"(tcp|tls|inproc|ucx|ws|wss)://[^\s/]+(:\d+)?/?")


def make_client(scheduler: str | None = None, workers: int | None = None, *,
                timeout: float = 10.0):
    """A ``dask.distributed.Client`` for ``scheduler``, or a local cluster of ``workers``.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler, ``tcp://HOST:PORT``.
    workers : int, optional
        Size of a local cluster (>= 1) when no scheduler is given.
    timeout : float
        Seconds to wait for the scheduler or the local cluster; after that a
        ``RuntimeError`` (a port that is open but not a dask scheduler does not answer
        the handshake, and would otherwise wait forever).

    Raises
    ------
    ValueError
        A malformed address or a worker count below 1.
    RuntimeError
        If dask.distributed is not installed or nothing answers within ``timeout``.
    """
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:
        raise RuntimeError("dask.distributed is not installed: pip install "
                           "'dask[distributed]'") from exc
    if scheduler is not None and not _ADDRESS.fullmatch(scheduler):
        raise ValueError(f"--scheduler {scheduler!r}: expected an address such as "
                         "tcp://HOST:8786")
    if scheduler is None and (workers is None or int(workers) < 1):
        raise ValueError(f"--workers must be a positive number of workers, got {workers}")
    if not timeout > 0:
        raise ValueError(f"timeout must be positive, got {timeout}")

    def connect():
        if scheduler:
            return Client(scheduler, timeout=f"{timeout}s")
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=None,
                               env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                                    "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"})
        client = Client(cluster, timeout=f"{timeout}s")
        orig_close = client.close

        def close(*a, **k):     # close the cluster with the client
            orig_close(*a, **k)
            cluster.close()

        client.close = close
        return client

    # The handshake itself can block past Client's own timeout: run it in a daemon thread
    # and give up after the timeout (plus the local cluster's start-up).
    box: dict = {}

    def target():
        try:
            box["client"] = connect()
        except BaseException as exc:     # reported to the caller below
            box["error"] = exc

    th = threading.Thread(target=target, daemon=True, name="gridflow-dask-connect")
    th.start()
    th.join(timeout + (60 if scheduler is None else 2))
    what = f"the dask scheduler at {scheduler}" if scheduler else "a local dask cluster"
    if th.is_alive():
        raise RuntimeError(f"no answer from {what} within {timeout:g} s")
    if "error" in box:
        exc = box["error"]
        raise RuntimeError(f"cannot reach {what}: {type(exc).__name__}: {exc}") from None
    return box["client"]
