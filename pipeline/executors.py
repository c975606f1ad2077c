"""Where the tasks of a sweep run: in this process, in a local process pool, or on a
dask.distributed cluster, each behind the same ``map`` call.

Every executor starts its workers with one environment, :func:`worker_env`: the threads
of BLAS (``OMP``, ``OPENBLAS``, ``MKL``), of numba and of ``scipy.fft`` (the estimator
gives ``scipy.fft`` as many workers as numba has threads, :mod:`gridflow.estimator.
backends`) set together, so that workers sharing the cores do not each start a thread per
core.  Pool workers also leave Ctrl-C to the parent (which ends them) and die with it even
when it is killed with SIGKILL; SIGTERM raises in the main thread like Ctrl-C
(:func:`signals_raise`), so both stop a sweep the same way.

``--scheduler tcp://HOST:PORT`` sends the tasks to an existing cluster (every worker needs
gridflow installed, the same version); ``--workers N`` starts a local cluster of N
single-threaded worker processes.  Results come back to the client, which alone writes
files, so workers need no shared disk (:attr:`Executor.shared_disk`).
"""

from __future__ import annotations

import os
import re
import signal
import sys
import threading
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager

from gridflow.errors import UsageError

__all__ = ["Executor", "InProcess", "Pool", "Dask", "worker_env", "worker_environment",
           "Terminated", "signals_raise", "make_client", "ClusterError"]


def worker_env(threads: int = 1) -> dict[str, str]:
    """The environment of a worker process that may use ``threads`` threads: BLAS, numba
    and (through numba's count) ``scipy.fft``."""
    n = str(max(1, int(threads)))
    return {"OMP_NUM_THREADS": n, "OPENBLAS_NUM_THREADS": n, "MKL_NUM_THREADS": n,
            "NUMBA_NUM_THREADS": n}


@contextmanager
def worker_environment(threads: int = 1):
    """Set :func:`worker_env` in this process's environment while workers are started
    (spawned processes inherit it), and restore it afterwards."""
    env = worker_env(threads)
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield env
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class Terminated(BaseException):
    """Raised in the main thread by the SIGTERM handler (a BaseException, like Ctrl-C)."""


@contextmanager
def signals_raise():
    """SIGTERM raises :class:`Terminated` in the main thread like Ctrl-C raises
    KeyboardInterrupt, so both stop a sweep the same way."""
    def on_term(signum, frame):
        raise Terminated()

    try:
        old = signal.signal(signal.SIGTERM, on_term)
    except ValueError:           # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _worker_init(parent: int) -> None:
    """Start-up of a pool worker: Ctrl-C is the parent's to handle (it ends the workers),
    and a worker dies with its parent even when the parent is killed with SIGKILL."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        import ctypes

        PR_SET_PDEATHSIG = 1
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:       # the parent died before the line above took effect
        os._exit(1)


class Executor:
    """Runs ``fn(*task)`` for every task and hands each result to ``on_result(task,
    result)`` in this process, in the order they finish.

    Attributes
    ----------
    name : str
    shared_disk : bool
        Whether the tasks run where this process's files are (they may write their own
        results), or elsewhere (results must come back).
    """

    name = "executor"
    shared_disk = True

    def map(self, fn, tasks, on_result) -> None:
        raise NotImplementedError


class InProcess(Executor):
    """One task after the other, in this process."""

    name = "in-process"

    def map(self, fn, tasks, on_result) -> None:
        for t in tasks:
            on_result(t, fn(*t))


class Pool(Executor):
    """A local pool of ``workers`` spawned processes sharing the cores: each worker gets
    ``cores // workers`` threads (:func:`worker_env`).  On an interrupt the queued tasks
    are dropped and the running workers ended at once."""

    name = "process pool"

    def __init__(self, workers: int):
        self.workers = max(1, int(workers))

    def map(self, fn, tasks, on_result) -> None:
        import multiprocessing as mp

        tasks = list(tasks)
        n = min(self.workers, len(tasks)) or 1
        ex = ProcessPoolExecutor(max_workers=n, mp_context=mp.get_context("spawn"),
                                 initializer=_worker_init, initargs=(os.getpid(),))
        try:
            # the workers start during submit, in this (the main) thread: the death signal
            # of _worker_init is tied to it, and they inherit the worker environment
            with worker_environment(max(1, (os.cpu_count() or 1) // n)):
                futs = {ex.submit(fn, *t): t for t in tasks}
            for fut in as_completed(futs):
                on_result(futs[fut], fut.result())     # re-raises a worker's error here
        except BaseException:
            # stop now: drop the queued tasks and end the running ones (results are
            # written atomically, so a killed task leaves nothing half-written)
            procs = list((ex._processes or {}).values())
            ex.shutdown(wait=False, cancel_futures=True)
            for proc in procs:
                proc.terminate()
            for proc in procs:
                proc.join(timeout=5)
            raise
        ex.shutdown(wait=True)


class Dask(Executor):
    """The tasks on a dask.distributed cluster (``client``); results come back here."""

    name = "dask"
    shared_disk = False

    def __init__(self, client):
        self.client = client

    def map(self, fn, tasks, on_result) -> None:
        from dask.distributed import as_completed as dask_completed

        futs = {self.client.submit(fn, *t, pure=False): t for t in tasks}
        try:
            for fut in dask_completed(list(futs)):
                on_result(futs[fut], fut.result())
        except BaseException:
            self.client.cancel(list(futs))
            raise


# --- cluster set-up ----------------------------------------------------------------------

_ADDRESS = re.compile(r"(tcp|tls|inproc|ucx|ws|wss)://[^\s/]+(:\d+)?/?")


class ClusterError(RuntimeError):
    """dask.distributed is missing, or a scheduler does not answer."""


def make_client(scheduler: str | None = None, workers: int | None = None, *,
                timeout: float = 10.0, option: str = "--scheduler"):
    """A ``dask.distributed.Client`` for ``scheduler``, or a local cluster of ``workers``.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler, ``tcp://HOST:PORT``.
    workers : int, optional
        Size of a local cluster (>= 1) when no scheduler is given; its workers are
        single-threaded (:func:`worker_env`).
    option : str
        The command-line option that gave ``scheduler``, named in errors.
    timeout : float
        Seconds to wait for the scheduler or the local cluster; after that a
        :class:`ClusterError` (a port that is open but not a dask scheduler does not
        answer the handshake, and would otherwise wait forever).

    Raises
    ------
    UsageError
        A malformed address, a worker count below 1 or a timeout that is not positive.
    ClusterError
        If dask.distributed is not installed or nothing answers within ``timeout``.
    """
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:
        raise ClusterError("dask.distributed is not installed: pip install "
                           "'dask[distributed]'") from exc
    if scheduler is not None and not _ADDRESS.fullmatch(scheduler):
        raise UsageError(f"{option} {scheduler!r}: expected an address such as "
                         "tcp://HOST:8786")
    if scheduler is None and (workers is None or int(workers) < 1):
        raise UsageError(f"--workers must be a positive number of workers, got {workers}")
    if not timeout > 0:
        raise UsageError(f"timeout must be positive, got {timeout}")

    def connect():
        if scheduler:
            return Client(scheduler, timeout=f"{timeout}s")
        # the dashboard on a free port: None still asks for dask's default, which another dask
        # (a user's own dashboard, a second run) may hold
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=":0", env=worker_env(1))
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
        raise ClusterError(f"no answer from {what} within {timeout:g} s")
    if "error" in box:
        exc = box["error"]
        raise ClusterError(f"cannot reach {what}: {type(exc).__name__}: {exc}") from None
    client = box["client"]
    if scheduler:
        # a scheduler without workers accepts tasks and never runs them: wait for one
        # within the timeout, else say so (and what to do) instead of waiting forever
        try:
            client.wait_for_workers(1, timeout=timeout)
        except Exception as exc:    # dask's WorkerStartTimeoutError, or the scheduler gone
            client.close()
            if not isinstance(exc, TimeoutError):
                raise ClusterError(f"the dask scheduler at {scheduler}: {type(exc).__name__}:"
                                   f" {exc}") from None
            raise ClusterError(f"the dask scheduler at {scheduler} has no workers (none "
                               f"joined within {timeout:g} s): start some with 'dask worker "
                               f"{scheduler}' (an adaptive cluster: start one first), then "
                               "run again") from None
    return client
