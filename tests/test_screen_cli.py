"""``nni-simulate --case CASE --screen``: the command a user types, on one machine and on real Dask processes,
and what it writes and refuses.

Kundur's two-area system screened completely (every bus fault and line-end fault, two battery limits) in this
process (``--workers 0``, computed once for the module) is the reference of every other path: a 2-worker
LocalCluster one of whose workers is killed mid-screen, and a cluster of `dask scheduler` and two `dask worker`
processes on 127.0.0.1 reached with ``--scheduler``, give its rows; an interrupted screen resumed computes only
what was not written; bad input is one line, exit 2, and nothing written. The Dask tests depend on timing (a kill
mid-screen, workers joining), so they run with two busy processes beside them; every process a test starts is
stopped by it.
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
from test_verdicts_options import png_title

SIMULATE = str(Path(sys.executable).with_name("nni-simulate"))
DASK = str(Path(sys.executable).with_name("dask"))
#: The screen of these tests: Kundur, every contingency, no battery and 0.1 pu, 10 s runs (the defaults).
SCREEN = ["--case", "kundur_two_area", "--screen", "--b", "0", "0.1"]
#: Kundur has 11 buses and 12 circuits (24 line ends), of which 8 circuits island it when tripped.
SCREENED, SKIPPED = 19, 16
#: A few contingencies of each kind for the --scheduler run (its workers are the test's).
SOME = ["bus:7", "bus:9", "line:7-8:1@7", "line:8-9:2@9"]


def screen(*args, timeout=300):
    return subprocess.run([SIMULATE, *SCREEN, *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    """The serial path's screen: its output, JSON and folder."""
    folder = tmp_path_factory.mktemp("serial")
    result = screen("--workers", "0", "--out", str(folder / "out"), "--json", str(folder / "screen.json"))
    assert result.returncode == 0, result.stderr
    return result, json.loads((folder / "screen.json").read_text()), folder / "out"


def keyed(rows):
    return {(row["contingency"], row["law"], row["b"]): row for row in rows}


def test_the_serial_screen_prints_the_weakest_per_b_writes_every_row_the_figures_and_the_json(serial):
    result, data, folder = serial
    lines = result.stdout.splitlines()
    assert lines[0].startswith("kundur_two_area: dynamic security screen of 35 contingencies (11 bus faults, "
                               "24 line-end faults cleared by tripping the line), 16 skipped")
    assert "  line:1-5:1@1, line:1-5:1@5: the trip of 1-5 islands the network: bus 1 with generator G1@1 cut off" \
        in lines
    assert len(data["rows"]) == 2 * SCREENED and len(data["skipped"]) == SKIPPED
    assert {row["b"] for row in data["rows"]} == {0, 0.1}
    assert set(data["rows"][0]) == {"contingency", "kind", "fault_bus", "line", "law", "b", "reference", "cct_s",
                                    "bracket_low_s", "bracket_high_s", "at_search_limit", "clearing_time_s",
                                    "verdict", "loss_at_s", "weakest_generator", "weakest_swing_deg"}
    rows = keyed(data["rows"])
    # The CCT of the fault at bus 7 cleared by tripping 7-8 is nni-simulate --cct's (docs/networks.md: 162 ms).
    assert rows[("line:7-8:1@7", "nni", 0)]["cct_s"] == pytest.approx(0.162)
    assert rows[("line:7-8:1@7", "nni", 0)]["bracket_high_s"] == pytest.approx(0.163)
    # The table: per b the weakest first, the 7-8 line-end faults at bus 7 at the top without batteries.
    head = lines.index("  b = 0 (no battery), law nni: the 10 weakest of 19")
    first = lines[head + 2].split()
    assert first[:3] == ["1", "line:7-8:1@7", "0.162"] and "in synchronism" in lines[head + 2]
    assert data["case_digest"] and data["software_version"] and data["settings"]["limits_pu"] == [0.0, 0.1]
    assert png_title(folder / "heatmap.png") == ("kundur_two_area: critical clearing time per contingency and "
                                                 "battery limit (law nni, reference pmu, 10 s runs)")
    assert png_title(folder / "cct_gain.png") == ("kundur_two_area: critical clearing time gain with batteries per "
                                                  "contingency (law nni, reference pmu, 10 s runs)")
    assert len(list((folder / "rows").glob("part-*.parquet"))) == SCREENED


def workers_of(pid: int) -> list:
    """The LocalCluster's worker processes: the command's children started by multiprocessing's spawn."""
    return [child for child in psutil.Process(pid).children(recursive=True)
            if "spawn_main" in " ".join(child.cmdline())]


def test_a_two_worker_local_cluster_gives_the_serial_rows_though_a_worker_is_killed_mid_screen(serial, tmp_path,
                                                                                              busy):
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
    assert "tasks on a LocalCluster started here, 2 workers" in stderr
    assert "computed by LocalCluster, 2 workers, task overhead" in stdout
    assert not psutil.pid_exists(victim.pid) or victim.status() == psutil.STATUS_ZOMBIE
    assert written_at_kill < 19
    rows = json.loads((tmp_path / "cluster.json").read_text())["rows"]
    assert len(rows) == 38 and len(list((out / "rows").glob("part-*.parquet"))) == 19
    assert rows == serial[1]["rows"]  # every contingency, every b: the same CCTs, verdicts, generators


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


def test_a_screen_through_scheduler_runs_on_the_clusters_two_workers(serial, tmp_path, dask_cluster, busy):
    result = subprocess.run([SIMULATE, *SCREEN, "--contingencies", *SOME, "--scheduler", dask_cluster, "--json",
                             str(tmp_path / "remote.json")], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert f"4 tasks on the Dask scheduler at {dask_cluster}, 2 workers" in result.stderr
    assert "computed by scheduler, 2 workers" in result.stdout
    rows = json.loads((tmp_path / "remote.json").read_text())["rows"]
    assert [row["contingency"] for row in rows] == [name for name in SOME for _ in range(2)]
    assert rows == [row for row in serial[1]["rows"] if row["contingency"] in SOME]


def parts(folder: Path) -> dict:
    return {path.name: (path.read_bytes(), path.stat().st_mtime_ns) for path in (folder / "rows").glob("*.parquet")}


def test_resume_after_an_interrupt_computes_only_what_was_not_written(serial, tmp_path):
    out = tmp_path / "out"
    proc = subprocess.Popen([SIMULATE, *SCREEN, "--workers", "0", "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while len(list((out / "rows").glob("part-*.parquet"))) < 4 and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(60) == 130
    before = parts(out)
    assert 4 <= len(before) < SCREENED
    result = subprocess.run([SIMULATE, *SCREEN, "--workers", "0", "--out", str(out), "--resume", "--json",
                             str(tmp_path / "resumed.json")], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert f"resumed {out}: {len(before)} of {SCREENED} contingencies already there, " \
           f"{SCREENED - len(before)} to compute" in result.stdout
    after = parts(out)
    assert {name: after[name] for name in before} == before  # not one written part touched
    assert len(after) == SCREENED
    assert json.loads((tmp_path / "resumed.json").read_text())["rows"] == serial[1]["rows"]
    again = subprocess.run([SIMULATE, *SCREEN, "--out", str(out), "--resume"], capture_output=True, text=True,
                           timeout=120)
    assert again.returncode == 0 and "0 contingencies computed by none (nothing left to compute)" in again.stdout
    assert parts(out) == after


@pytest.mark.parametrize("args, words", [
    (["--contingencies", "bus:99"], "contingency 'bus:99': bus 99 is not in the case (buses 1..11)"),
    (["--contingencies", "line:7-10@7"], "contingency 'line:7-10@7': no circuit 1 between buses 7 and 10"),
    (["--contingencies", "bus,tie"], "contingency 'tie': expected bus:B or line:F-T[:C]@E"),
    (["--laws", "nni,bogus"], "--laws bogus: not a law (laws: nni, nni-unsaturated, droop, vsm, pss)"),
    (["--law", "droop"], "--law does not apply to --screen: a screen takes its laws with --laws"),
    (["--cct"], "--cct does not apply to --screen"),
    (["--trip-line", "7", "8"], "--trip-line does not apply to --screen"),
    (["--reference", "pmu", "coi"], "--screen takes one --reference"),
    (["--resume"], "--resume needs --out DIR"),
])
def test_bad_input_is_one_line_and_exit_2(args, words):
    result = screen(*args, timeout=60)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and words in result.stderr, result.stderr


def test_screen_options_without_screen_are_refused():
    result = subprocess.run([SIMULATE, "--case", "kundur_two_area", "--workers", "2"], capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 2 and "--workers applies to --screen only" in result.stderr


def test_a_scheduler_that_cannot_be_reached_is_one_line_within_10_s():
    started = time.monotonic()
    result = screen("--scheduler", "tcp://127.0.0.1:9", timeout=60)
    assert time.monotonic() - started < 10.0
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert result.stderr.startswith("nni-simulate: error: cannot reach the Dask scheduler at tcp://127.0.0.1:9 "
                                    "within 5 s")


def test_resume_refuses_a_folder_of_another_case_version_or_settings_and_writes_nothing(serial, tmp_path):
    folder = serial[2]
    manifest = folder / "manifest.json"
    before = {path: path.read_bytes() for path in folder.rglob("*") if path.is_file()}
    other_case = subprocess.run([SIMULATE, "--case", "ieee39", "--screen", "--contingencies", "bus:16", "--out",
                                 str(folder), "--resume"], capture_output=True, text=True, timeout=120)
    assert other_case.returncode == 2 and "is a screen of another case (kundur_two_area, data" in other_case.stderr
    other_settings = screen("--out", str(folder), "--resume", "--duration", "5", timeout=120)
    assert other_settings.returncode == 2
    assert "other settings (duration_s 10.0 there, 5.0 here)" in other_settings.stderr
    not_resumed = screen("--out", str(folder), timeout=120)
    assert not_resumed.returncode == 2 and "holds a screen: --resume continues it" in not_resumed.stderr
    older = tmp_path / "older"
    older.mkdir()
    (older / "manifest.json").write_text(json.dumps({**json.loads(manifest.read_text()),
                                                     "software_version": "0.0.1"}))
    other_version = screen("--out", str(older), "--resume", timeout=120)
    assert other_version.returncode == 2
    assert "was written by version 0.0.1 (this is" in other_version.stderr
    assert sorted(path.name for path in older.iterdir()) == ["manifest.json"]
    assert {path: path.read_bytes() for path in folder.rglob("*") if path.is_file()} == before


def test_a_users_matpower_case_is_screened_from_its_text(serial, tmp_path):
    cases = Path(__file__).resolve().parent.parent / "nni_plant_sim" / "nni_plant_sim" / "cases"
    (tmp_path / "mine.m").write_text((cases / "kundur_two_area.m").read_text())
    (tmp_path / "mine.csv").write_text((cases / "kundur_two_area_machines.csv").read_text())
    result = subprocess.run([SIMULATE, "--case", str(tmp_path / "mine.m"), "--machines", str(tmp_path / "mine.csv"),
                             "--f0", "60", "--screen", "--b", "0", "0.1", "--contingencies", "line:7-8@7", "--workers",
                             "0", "--json", str(tmp_path / "mine.json")], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    mine = json.loads((tmp_path / "mine.json").read_text())
    assert mine["case_digest"] == serial[1]["case_digest"]  # the same data as the shipped case
    assert mine["rows"] == [row for row in serial[1]["rows"] if row["contingency"] == "line:7-8:1@7"]
