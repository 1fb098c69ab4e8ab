"""nni-demo: the distributed loop as a user runs it, end to end."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rosproc import fresh_domain_id, ros_env

pytestmark = pytest.mark.ros

DEMO = Path(sys.executable).parent / "nni-demo"


def processes_in_domain(domain_id: int) -> list[str]:
    """Command lines of live processes of this project started with ROS_DOMAIN_ID=domain_id."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            environ = (proc / "environ").read_bytes().split(b"\0")
            cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if f"ROS_DOMAIN_ID={domain_id}".encode() in environ and "nni_" in cmdline:
            found.append(cmdline)
    return found


def test_lockstep_demo_is_fast_complete_and_leaves_nothing_running(tmp_path):
    """The issue's command: well under 10 s of wall time, summary.json written, no process left."""
    domain = fresh_domain_id()
    started = time.monotonic()
    result = subprocess.run([str(DEMO), "--mode", "lockstep", "--b", "0.3", "--duration", "10",
                             "--out", str(tmp_path), "--domain-id", str(domain)],
                            env=ros_env(domain), capture_output=True, text=True, timeout=120)
    wall_s = time.monotonic() - started
    assert result.returncode == 0, result.stderr
    # Process start-up (~1 s each, in parallel) dominates; the 500 samples take about 1 s.
    assert wall_s < 10.0, f"lockstep demo took {wall_s:.1f} s of wall time"
    assert processes_in_domain(domain) == []
    summary = json.loads((tmp_path / "summary.json").read_text())
    (run,) = summary["scenarios"]
    for key in ("b", "stable", "final_angle_dev_rad", "max_abs_angle_dev_rad", "max_abs_battery_power_pu",
                "last_saturated_s", "settling_time_s"):
        assert key in run
    assert run["b"] == 0.3 and run["stable"] is True
    assert run["max_abs_battery_power_pu"] <= 0.3
    assert set(run["latency_ms"]) == {"p50", "p99", "max"}
    assert 0 < run["latency_ms"]["p50"] <= run["latency_ms"]["p99"] <= run["latency_ms"]["max"]
    assert run["dropped_samples"] == 0 and run["late_samples"] == 0
    assert run["samples"] == 500
    assert run["logger_counts"]["/plant/state"] == 501
    assert Path(run["recording"]).is_file()


def test_demo_bad_input_is_one_line(tmp_path):
    """Bad options: one line on stderr, non-zero exit, nothing started."""
    for args in (["--b", "-1"], ["--rate", "5"], ["--mode", "fast"], ["--rerun", "save"],
                 ["--domain-id", "999"]):
        result = subprocess.run([str(DEMO), *args, "--out", str(tmp_path / "o")], capture_output=True,
                                text=True, timeout=60)
        assert result.returncode != 0, args
        assert len(result.stderr.strip().splitlines()) == 1, (args, result.stderr)
        assert "Traceback" not in result.stderr
        assert not (tmp_path / "o" / "summary.json").exists()
