"""Distributed sweeps: results come back to the client without a shared working
directory, a port that is not a scheduler fails within the timeout, and bad cluster
arguments are refused.

Every case must end in a clear error (exit 2 from the CLI, naming the file, key or
argument) or a correct result; none may crash, hang, exit 0 with garbage, or change a
file it was not asked to write.  The cases are counted (``builders.tried``) and the
count is printed in the pytest summary.
"""

from __future__ import annotations

import socket
import threading
import time

import pytest

from builders import SPEC_OK, tried
from gridflow.bench.cli import main
from gridflow.bench.spec import SweepSpec
from gridflow.bench.sweep import run_sweep


# --- distributed sweeps assume a shared working directory ------------------------------------

@pytest.mark.slow
def test_dask_results_come_back_to_the_client(tmp_path, monkeypatch):
    from gridflow.pipeline.executors import make_client

    spec = SweepSpec.from_dict(SPEC_OK)
    ref = tmp_path / "ref.csv"
    run_sweep(spec, ref, workers=1, progress=False)
    worker_dir = tmp_path / "workers"
    worker_dir.mkdir()
    monkeypatch.chdir(worker_dir)           # the workers start here ...
    client = make_client(workers=1)
    try:
        client_dir = tmp_path / "client"
        client_dir.mkdir()
        monkeypatch.chdir(client_dir)       # ... the client writes from here
        run_sweep(spec, "rel.csv", executor=client, progress=False, keep_parts=True)
    finally:
        client.close()
    assert (client_dir / "rel.csv").read_bytes() == ref.read_bytes()
    assert list((client_dir / "rel.csv.parts").glob("*.csv"))
    assert not list(worker_dir.rglob("*.csv"))
    tried("dask without a shared disk")


def test_a_port_that_is_not_a_scheduler_fails_within_the_timeout():
    from gridflow.pipeline.executors import make_client

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(4)
    port = srv.getsockname()[1]
    conns = []
    stop = threading.Event()

    def accept():                           # accept and say nothing
        srv.settimeout(0.2)
        while not stop.is_set():
            try:
                conns.append(srv.accept()[0])
            except OSError:
                pass

    th = threading.Thread(target=accept, daemon=True)
    th.start()
    t0 = time.monotonic()
    try:
        with pytest.raises(RuntimeError, match="tcp://127.0.0.1"):
            make_client(f"tcp://127.0.0.1:{port}", timeout=2)
    finally:
        stop.set()
        th.join()
        for c in conns:
            c.close()
        srv.close()
    assert time.monotonic() - t0 < 10
    tried("silent port as scheduler")


@pytest.mark.parametrize("args, match", [
    (["--workers", "-1"], "expected a positive integer"),
    (["--workers", "0"], "expected a positive integer"),
    (["--processes", "0"], "expected a positive integer"),
    (["--scheduler", "localhost"], "expected an address"),
    (["--scheduler", "tcp://127.0.0.1:9", "--workers", "2"], "exclude each other"),
])
def test_bad_cluster_arguments(tmp_path, capsys, args, match):
    try:
        rc = main(["sweep", "smoke", "-o", str(tmp_path / "s.csv"), *args])
    except SystemExit as exc:              # argparse refuses the value itself
        rc = exc.code
    assert rc == 2 and match in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
    tried("bad cluster argument")
