"""The MCAP logger when its file cannot be written to the end: real processes over Fast DDS.

A full disk (a 256 KiB tmpfs the test mounts and removes; it needs root, which CI has: where
mount is refused the test fails, it does not pass silently) and an output folder removed
mid-run: the logger publishes an ERROR status on /diagnostics at once, prints one line and
exits 1, never claims counts for a file that is not there, and the file keeps every message
flushed before the failure.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.recording.mcap_io import read_recording
from nni_msgs_adapter.recording.mcap_logger import COUNTS_PREFIX, header_stamp_ns
from rosproc import Probe, fresh_domain_id, node_processes

pytestmark = pytest.mark.ros

PLANT = "nni_plant_sim.plant_node"
CONTROLLER = "nni_battery_controller.controller_node"
LOGGER = "nni_msgs_adapter.recording.mcap_logger"


@pytest.fixture
def small_disk(tmp_path):
    """A 256 KiB tmpfs, mounted for the test and removed after it."""
    mount_point = tmp_path / "disk"
    mount_point.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount_point)],
                             capture_output=True, text=True)
    assert mounted.returncode == 0, f"cannot mount a small tmpfs (the test needs root): {mounted.stderr.strip()}"
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=True)


def error_lines(output: str) -> list[str]:
    return [line for line in output.splitlines() if line.startswith("mcap_logger: error: ")]


def logger_errors(probe: Probe) -> list:
    return [status for msg in probe.take(contract.TOPIC_DIAGNOSTICS) for status in msg.status
            if status.name == "mcap_logger" and status.level == DiagnosticStatus.ERROR]


def run_until_the_logger_fails(tmp_path, path: Path, pmu_rate_hz: float, during=None):
    """Logger, controller and a realtime plant.

    Returns the logger's exit status, its output, the ERROR statuses seen on /diagnostics and the
    stamps of the plant states a subscriber of the test received.
    """
    domain = fresh_domain_id()
    probe = Probe(domain, (contract.TOPIC_DIAGNOSTICS, contract.TOPIC_PLANT_STATE))
    try:
        with node_processes(tmp_path, domain) as start:
            logger = start("logger", LOGGER, {"output_path": str(path), "discovery_period_s": 0.1,
                                              "flush_period_s": 0.1})
            # The ERROR goes out on a volatile topic: the probe must hear the logger before it can fail
            # (under CI load the probe once matched the logger only after the folder was gone).
            assert probe.wait_for_publishers(contract.TOPIC_DIAGNOSTICS, 1, timeout=30.0), \
                "the probe never matched the logger's /diagnostics publisher"
            start("controller", CONTROLLER, {"battery_limit_pu": 0.3, "sample_rate_hz": pmu_rate_hz})
            plant = start("plant", PLANT, {"mode": "realtime", "duration_s": 0.0, "pmu_rate_hz": pmu_rate_hz,
                                           "wait_for_subscribers": 2, "hold_until_released": True})
            # The run starts once the probe hears the plant's states: at 500 frames/s the small disk fills in
            # under a second, and a probe matched after that (seen under load) received nothing to compare.
            assert probe.wait_for_publishers(contract.TOPIC_PLANT_STATE, 1, timeout=30.0)
            plant.proc.send_signal(signal.SIGUSR1)
            if during is not None:
                during(probe)
            status = logger.wait(timeout=60)
            # "At once": the ERROR is on /diagnostics by the time the logger has exited.
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline and not logger_errors(probe):
                time.sleep(0.05)
            received = [contract.ns_from_time(msg.header.stamp) for msg in probe.take(contract.TOPIC_PLANT_STATE)]
            return status, logger.output(), logger_errors(probe), received
    finally:
        probe.close()


def test_a_full_disk_is_an_error_at_once_and_the_file_keeps_what_was_flushed(tmp_path, small_disk):
    path = small_disk / "run.mcap"
    status, output, errors, received = run_until_the_logger_fails(tmp_path, path, pmu_rate_hz=500.0)
    assert status == 1, output
    [line] = error_lines(output)
    assert "No space left on device" in line, line
    assert "Traceback" not in output and COUNTS_PREFIX not in output, output
    assert errors and "No space left on device" in errors[0].message
    kept = int(line.split("keeps the ")[1].split(" messages")[0])
    recording = read_recording(path)
    assert not recording.complete, "no summary on a full disk"
    assert len(recording.messages) == kept > 0, "what the logger says the file keeps"
    # Every message up to the failure: each state the test's own subscriber received up to the last
    # recorded one is in the file (the subscriber may have matched after the first few).
    stamps = [header_stamp_ns(m.cdr_bytes) for m in recording.messages if m.topic == "/" + contract.TOPIC_PLANT_STATE]
    assert len(stamps) > 100 and stamps == sorted(set(stamps))
    within = [stamp for stamp in received if stamp <= stamps[-1]]
    assert within and set(within) <= set(stamps)


def test_an_output_folder_removed_mid_run_is_reported(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()

    def remove_folder_after_a_second_of_states(probe: Probe) -> None:
        probe.wait_for(contract.TOPIC_PLANT_STATE, 50, timeout=30.0)
        shutil.rmtree(folder)

    status, output, errors, _ = run_until_the_logger_fails(tmp_path, folder / "run.mcap", 50.0,
                                                        remove_folder_after_a_second_of_states)
    assert status == 1, output
    [line] = error_lines(output)
    assert "removed or replaced" in line and "nothing recorded is kept" in line, line
    assert COUNTS_PREFIX not in output, "no counts claimed for a file that is gone"
    assert errors and "removed" in errors[0].message
    assert not folder.exists()
