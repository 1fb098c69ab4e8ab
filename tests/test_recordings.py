"""The shipped recordings (``recordings/``): independent readers, regeneration, Rerun conversion.

Each paper case (b = 0, 0.2, 0.3, inf) was recorded by ``nni-demo`` in lockstep mode;
``recordings/counts.json`` holds the per-topic counts its logger printed. The
tests read the files with rosbags and ``rerun mcap check`` (neither shares code
with the writer), regenerate all four with ``nni-demo`` and compare, convert
each to ``.rrd`` with ``nni-replay`` and stream one to a running Rerun server.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader
from rosbags.highlevel import AnyReader

from nni_battery_controller.options import PAPER_BATTERY_LIMITS
from nni_battery_controller.smib_demo import recording_name
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.recording.mcap_io import read_messages
from nni_msgs_adapter.recording.runs import SAMPLE_TOPICS, read_generator_run
from nni_msgs_adapter.viewing.rerun_layout import run_paths
from rosproc import fresh_domain_id

pytestmark = pytest.mark.ros

RECORDINGS = Path(__file__).resolve().parent.parent / "recordings"
VENV_BIN = Path(sys.executable).parent
CASES = [recording_name(b) for b in PAPER_BATTERY_LIMITS]
SHIPPED_COUNTS = json.loads((RECORDINGS / "counts.json").read_text())
SAMPLE_TOPIC_NAMES = {topic if topic.startswith("/") else "/" + topic for topic in SAMPLE_TOPICS}

# Lockstep is deterministic: the plant advances exactly one reporting period per answered
# sample with the same fixed-step RK4, the controller runs the same sampled law, and CDR
# carries float64 bit for bit, so a regeneration on the same build reproduces every value
# exactly (the difference observed is 0.0). The allowance, relative and absolute 1e-12 (a
# few ulps of the largest magnitudes), only admits a numpy/libm build that rounds sin or
# exp differently in the last bit; anything larger is a change of behaviour.
VALUE_TOLERANCE = 1e-12


def file_counts(path: Path) -> dict[str, int]:
    """Messages per topic, read with the project's reader."""
    return dict(Counter(record.topic for record in read_messages(path)))


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory) -> tuple[Path, dict]:
    """All four paper cases recorded afresh by nni-demo (lockstep); the folder and its summary runs."""
    out = tmp_path_factory.mktemp("regenerated")
    result = subprocess.run(
        [str(VENV_BIN / "nni-demo"), "--out", str(out), "--domain-id", str(fresh_domain_id()),
         "--b", *(str(b) for b in PAPER_BATTERY_LIMITS)],
        capture_output=True, text=True, timeout=240,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    summary = json.loads((out / "summary.json").read_text())
    return out, {Path(run["recording"]).name: run for run in summary["scenarios"]}


def test_every_paper_case_is_shipped():
    assert sorted(path.name for path in RECORDINGS.glob("*.mcap")) == sorted(CASES)
    assert sorted(SHIPPED_COUNTS) == sorted(CASES)
    for case in CASES:
        assert (RECORDINGS / case).stat().st_size < 200_000, "recordings stay small"


@pytest.mark.parametrize("case", CASES)
def test_rosbags_reads_every_message_the_logger_counted(case):
    path = RECORDINGS / case
    counts: Counter = Counter()
    with AnyReader([path]) as reader:
        types = {connection.topic: connection.msgtype for connection in reader.connections}
        plant_states = []
        for connection, _, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)  # typestore built from the file's schemas
            counts[connection.topic] += 1
            if connection.topic == "/" + contract.TOPIC_PLANT_STATE:
                plant_states.append((message.position[0], message.velocity[0], message.effort[0]))
    assert dict(counts) == SHIPPED_COUNTS[case]
    for topic, type_name in types.items():
        name = topic if topic in contract.TOPICS else topic[1:]  # /clock and /diagnostics are absolute
        assert type_name == contract.TOPICS[name][0]
    # Two decoders (rosbags' own CDR reader, rclpy's) agree on every value.
    run = read_generator_run(path)
    np.testing.assert_array_equal(np.array(plant_states),
                                  np.column_stack([run.delta_rad, run.speed_rad_s, run.battery_power_pu]))


@pytest.mark.parametrize("full", [False, True], ids=["structure", "decoded"])
@pytest.mark.parametrize("case", CASES)
def test_rerun_mcap_check_reports_no_problem(case, full):
    path = RECORDINGS / case
    result = subprocess.run([str(VENV_BIN / "rerun"), "mcap", "check", *(["--full"] if full else []), str(path)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    # It exits 0 even when it finds problems; they are rows with the status PROBLEM.
    assert "PROBLEM" not in result.stdout, result.stdout
    for topic in SHIPPED_COUNTS[case]:
        assert topic in result.stdout


@pytest.mark.parametrize("case", CASES)
def test_fresh_recording_holds_what_its_logger_counted(regenerated, case):
    out, runs = regenerated
    logged = runs[case]["logger_counts"]
    # Nothing lost at the end of the run: 10 s at 50/s is 500 samples and 501 states (t = 0 .. 10 s),
    # although the plant exits right after its last one (it waits for the acknowledgements).
    assert (logged["/pmu"], logged["/controller/state"], logged["/plant/state"]) == (500, 500, 501)
    # One answer per sample and no zero command after the last: the plant said its run ended.
    assert logged["/battery/command"] == 500
    assert file_counts(out / case) == logged
    with AnyReader([out / case]) as reader:
        assert dict(Counter(connection.topic for connection, _, _ in reader.messages())) == logged


@pytest.mark.parametrize("case", CASES)
def test_regenerated_recording_matches_shipped(regenerated, case):
    out, _ = regenerated
    shipped, fresh = RECORDINGS / case, out / case
    shipped_counts, fresh_counts = file_counts(shipped), file_counts(fresh)
    assert set(fresh_counts) == set(shipped_counts)
    # Per-sample topics are fixed by the lockstep run; diagnostics follow wall time and vary.
    for topic in SAMPLE_TOPIC_NAMES:
        assert fresh_counts[topic] == shipped_counts[topic], topic
    old, new = read_generator_run(shipped), read_generator_run(fresh)
    np.testing.assert_array_equal(new.stamp_ns, old.stamp_ns)  # simulated time, integer ns
    for name in ("delta_rad", "speed_rad_s", "battery_power_pu"):
        np.testing.assert_allclose(getattr(new, name), getattr(old, name), rtol=VALUE_TOLERANCE,
                                   atol=VALUE_TOLERANCE, err_msg=name)
    for name in contract.CONTROLLER_SIGNALS:
        np.testing.assert_allclose(new.signals[name], old.signals[name], rtol=VALUE_TOLERANCE,
                                   atol=VALUE_TOLERANCE, equal_nan=True, err_msg=name)
    np.testing.assert_array_equal(new.omega_boundary, old.omega_boundary)


def rrd_chunks(rrd: Path) -> dict[str, list]:
    """Record batches per entity path of a Rerun file (read with rerun's own reader)."""
    chunks: dict[str, list] = {}
    for chunk in RrdReader(rrd).stream():
        chunks.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return chunks


def logged_series(chunks: dict, path: str) -> tuple[np.ndarray, np.ndarray]:
    """``(time s, value)`` of a scalar series on the sim_time timeline, in time order."""
    rows = sorted((t, v[0]) for batch in chunks[path] if "sim_time" in batch.schema.names
                  for t, v in zip(batch.column("sim_time").cast("int64").to_pylist(),
                                  batch.column("Scalars:scalars").to_pylist()))
    return np.array([t for t, _ in rows]) * 1e-9, np.array([v for _, v in rows])


def assert_views_hold_the_recording(chunks: dict, recording: Path, b: float) -> None:
    """Every view of the blueprint has the run; the series are the answered samples of the
    recording at their times; +-b is drawn for a finite battery only."""
    run = read_generator_run(recording)
    paths = run_paths("b=inf" if math.isinf(b) else f"b={b:g}")
    answered = run.answered
    drawn = set(paths) - ({paths.limit_upper, paths.limit_lower} if math.isinf(b) else set()) - {paths.charge}
    assert drawn <= set(chunks), sorted(drawn - set(chunks))
    assert paths.charge not in chunks, "an unlimited battery has no charge to draw"
    assert (paths.limit_upper in chunks) == math.isfinite(b), "+-b drawn for a finite battery only"
    expected = {
        paths.angle: run.signals["angle_dev"][answered],
        paths.frequency: run.speed_rad_s[answered] / (2 * math.pi),  # Hz
        paths.power: run.signals["battery_power"][answered],
        paths.saturation: run.signals["saturated"][answered],
        paths.w_hat: run.signals["w_hat"][answered],
    }
    for path, values in expected.items():
        t_s, logged = logged_series(chunks, path)
        np.testing.assert_allclose(t_s, run.t_s[answered], rtol=0, atol=1e-9, err_msg=path)
        np.testing.assert_allclose(logged, values, rtol=1e-12, atol=0, err_msg=path)


@pytest.mark.parametrize("b", PAPER_BATTERY_LIMITS, ids=CASES)
def test_replay_converts_to_rrd_that_rerun_verifies(tmp_path, b):
    recording, rrd = RECORDINGS / recording_name(b), tmp_path / "out.rrd"
    result = subprocess.run([str(VENV_BIN / "nni-replay"), str(recording), "--rrd", str(rrd)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    verify = subprocess.run([str(VENV_BIN / "rerun"), "rrd", "verify", str(rrd)],
                            capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0, verify.stdout + verify.stderr
    assert_views_hold_the_recording(rrd_chunks(rrd), recording, b)
    assert len(RrdReader(rrd).blueprints()) == 1


def free_port() -> int:
    """A TCP port on localhost that nobody listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_listening(port: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return True
        except OSError:
            time.sleep(0.1)
    return False


# The server streams to its file and is stopped, so the file has no footer: expected here.
@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_replay_streams_to_a_running_viewer(tmp_path):
    """--connect PORT: a headless Rerun server (`rerun --port P --save F`, what a viewer listens
    with) receives the views and the blueprint."""
    b, port, saved = 0.2, free_port(), tmp_path / "received.rrd"
    server = subprocess.Popen([str(VENV_BIN / "rerun"), "--port", str(port), "--save", str(saved)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        assert wait_listening(port, 30.0), "the Rerun server did not start"
        result = subprocess.run([str(VENV_BIN / "nni-replay"), str(RECORDINGS / recording_name(b)),
                                 "--connect", str(port)], capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stderr
        # The server writes what it receives as it comes; wait for the last angle sample.
        run = read_generator_run(RECORDINGS / recording_name(b))
        angle_path = run_paths(f"b={b:g}").angle
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline:
            if saved.exists() and saved.stat().st_size > 0:
                chunks = rrd_chunks(saved)
                timed = [batch for batch in chunks.get(angle_path, []) if "sim_time" in batch.schema.names]
                if sum(batch.num_rows for batch in timed) >= run.answered.sum():
                    break
            time.sleep(0.2)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=10)
    assert_views_hold_the_recording(rrd_chunks(saved), RECORDINGS / recording_name(b), b)
    assert len(RrdReader(saved).blueprints()) == 1
