"""The screen on real Dask processes: a LocalCluster worker killed mid-screen, and a cluster of `dask scheduler` and
two `dask worker` processes on 127.0.0.1 reached with ``--scheduler``.

Both give the rows of the serial path (``--workers 0``) of the same contingencies; every process a test
starts is stopped by it. Both depend on timing (a kill mid-screen, workers joining), so they run with two
busy processes beside them.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

SIMULATE = str(Path(sys.executable).with_name("nni-simulate"))
DASK = str(Path(sys.executable).with_name("dask"))
SCREEN = ["--case", "kundur_two_area", "--screen", "--b", "0", "0.1"]
#: A few contingencies of each kind for the --scheduler run (its workers are the test's).
SOME = ["bus:7", "bus:9", "line:7-8:1@7", "line:8-9:2@9"]


def serial_rows(tmp_path, *args):
    result = subprocess.run([SIMULATE, *SCREEN, *args, "--workers", "0", "--json", str(tmp_path / "serial.json")],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads((tmp_path / "serial.json").read_text())["rows"]


def workers_of(pid: int) -> list:
    """The LocalCluster's worker processes: the command's children started by multiprocessing's spawn."""
    return [child for child in psutil.Process(pid).children(recursive=True)
            if "spawn_main" in " ".join(child.cmdline())]


def test_a_worker_killed_mid_screen_loses_no_row(tmp_path, busy):
    out = tmp_path / "out"
    proc = subprocess.Popen([SIMULATE, *SCREEN, "--workers", "2", "--out", str(out), "--json",
                             str(tmp_path / "cluster.json")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline = time.monotonic() + 120
        while not list((out / "rows").glob("part-*.parquet")) and time.monotonic() < deadline:
            time.sleep(0.02)
        workers = workers_of(proc.pid)
        assert len(workers) == 2, [w.cmdline() for w in workers]
        victim = workers[0]
        os.kill(victim.pid, signal.SIGKILL)  # mid-screen: one part written, 18 contingencies to go
        written_at_kill = len(list((out / "rows").glob("part-*.parquet")))
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    assert not psutil.pid_exists(victim.pid) or victim.status() == psutil.STATUS_ZOMBIE
    assert written_at_kill < 19
    rows = json.loads((tmp_path / "cluster.json").read_text())["rows"]
    assert len(rows) == 38 and len(list((out / "rows").glob("part-*.parquet"))) == 19
    assert rows == serial_rows(tmp_path)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture
def dask_cluster(tmp_path):
    """A `dask scheduler` and two `dask worker` processes on 127.0.0.1 (free ports); its address."""
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = [open(tmp_path / f"{name}.log", "w") for name in ("scheduler", "worker1", "worker2")]
    procs = [subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--dashboard-address", "127.0.0.1:0"], stdout=logs[0], stderr=subprocess.STDOUT)]
    try:
        for log in logs[1:]:
            procs.append(subprocess.Popen([DASK, "worker", address, "--host", "127.0.0.1", "--nthreads", "1",
                                           "--nworkers", "1", "--dashboard-address", "127.0.0.1:0"],
                                          stdout=log, stderr=subprocess.STDOUT))
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in reversed(procs):
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for log in logs:
            log.close()


def test_a_screen_through_scheduler_runs_on_the_clusters_two_workers(tmp_path, dask_cluster, busy):
    result = subprocess.run([SIMULATE, *SCREEN, "--contingencies", *SOME, "--scheduler", dask_cluster, "--json",
                             str(tmp_path / "remote.json")], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert f"4 tasks on the Dask scheduler at {dask_cluster}, 2 workers" in result.stderr
    assert "computed by scheduler, 2 workers" in result.stdout
    rows = json.loads((tmp_path / "remote.json").read_text())["rows"]
    assert [row["contingency"] for row in rows] == [name for name in SOME for _ in range(2)]
    assert rows == serial_rows(tmp_path, "--contingencies", *SOME)
