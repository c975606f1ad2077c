"""Sweeps that survive SIGKILL and run identically on dask.distributed."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from gridflow.bench.spec import SweepSpec
from gridflow.bench.sweep import run_sweep

ROOT = Path(__file__).resolve().parent.parent
SPEC = """
[sweep]
name = "kill"
models = ["bcc", "full"]
noise = [0.0, 0.02]
seeds = [1]
[base]
height = 80
width = 80
frames = 7
[[axis]]
param = "a1"
values = [0.0, 0.1, 0.3, 0.6]
"""


def _parts(out: Path):
    d = out.parent / (out.name + ".parts")
    return sorted(d.glob("*.csv")) if d.exists() else []


def _start_sweep(spec, out):
    return subprocess.Popen([sys.executable, "-m", "gridflow.bench.cli", "sweep", str(spec), "-o",
                             str(out), "--processes", "1", "--no-progress"], cwd=ROOT,
                            start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)


@pytest.mark.slow
def test_sigkill_at_several_points_then_resume(tmp_path):
    spec = tmp_path / "kill.toml"
    spec.write_text(SPEC)
    reference = tmp_path / "reference.csv"
    run_sweep(SweepSpec.from_toml(spec), reference, workers=1, progress=False)
    out = tmp_path / "s.csv"
    n_points = 8
    for kill_after in (0, 2, 5):              # parts finished when the kill lands
        p = _start_sweep(spec, out)
        t0 = time.monotonic()
        while len(_parts(out)) < kill_after and p.poll() is None:
            assert time.monotonic() - t0 < 300, "sweep made no progress"
            time.sleep(0.05)
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        assert not out.exists()               # no half-written (or any) CSV
        for part in _parts(out):              # every finished point is whole
            df = pd.read_csv(part)
            assert len(df) == 6 + 12 and df.param.eq("a1").all()
        assert len(_parts(out)) < n_points
    done_before = len(_parts(out))
    p = _start_sweep(spec, out)
    assert p.wait(timeout=600) == 0
    assert done_before >= 5
    # same rows, same order, no duplicates
    assert out.read_bytes() == reference.read_bytes()
    assert not _parts(out)


@pytest.mark.slow
def test_local_dask_cluster_gives_the_in_process_result(tmp_path):
    from gridflow.pipeline.executors import make_client

    spec = SweepSpec.from_toml(_write(tmp_path))
    ref = tmp_path / "ref.csv"
    run_sweep(spec, ref, workers=1, progress=False)
    client = make_client(workers=2)
    try:
        assert len(client.scheduler_info()["workers"]) == 2
        run_sweep(spec, tmp_path / "dask.csv", executor=client, progress=False)
    finally:
        client.close()
    assert (tmp_path / "dask.csv").read_bytes() == ref.read_bytes()


def test_unreachable_scheduler_is_a_clear_error():
    from gridflow.pipeline.executors import make_client

    with pytest.raises(RuntimeError, match="cannot reach the dask scheduler"):
        make_client("tcp://127.0.0.1:9")


def _write(tmp_path):
    p = tmp_path / "spec.toml"
    p.write_text(SPEC)
    return p


@pytest.mark.slow
def test_a_local_clusters_dashboard_takes_a_free_port():
    """A local cluster's dashboard asks for a free port, not dask's fixed default, which
    another dask (a user's dashboard, a second run) may hold: under load dask's retries
    on other ports ran out once ('Port ... is already in use').  No port is named or
    bound here: two clusters started one after the other get their dashboards on ports
    the system chose, which differ (the fixed default would give both the same one)."""
    from urllib.parse import urlparse

    from gridflow.pipeline.executors import make_client

    ports = []
    for _ in range(2):
        client = make_client(workers=1, timeout=60)
        try:
            assert client.submit(sum, [1, 2]).result(timeout=60) == 3
            ports.append(urlparse(client.dashboard_link).port)
        finally:
            client.close()
    assert None not in ports and ports[0] != ports[1], ports
