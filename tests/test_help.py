"""``--help`` on every executable (issue 10, section 7): usage on stdout, exit 0, nothing started or written.

The executables are the console_scripts of the three packages, read from their
installed metadata, and run as installed (``lib/<package>/<name>``, where
``ros2 run`` finds them). Each runs in an empty working folder with its own ROS
log folder: a node that started would leave a ROS log file there (rcl writes
one at init), and the logger or the Rerun bridge a recording in the working
folder, as they did before.
"""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGES = ("nni_plant_sim", "nni_battery_controller", "nni_msgs_adapter")
NODES = {"plant_node", "controller_node", "mcap_logger", "rerun_bridge", "c37118_client", "foxglove_bridge"}


def executables() -> list[tuple[str, str]]:
    return sorted((package, entry.name) for package in PACKAGES
                  for entry in importlib.metadata.distribution(package).entry_points
                  if entry.group == "console_scripts")


def test_every_package_has_its_executables():
    names = {name for _, name in executables()}
    assert names >= NODES | {"nni-simulate", "nni-demo", "nni-replay", "replay"}


@pytest.mark.parametrize("package, name", executables())
def test_help_prints_usage_and_starts_nothing(tmp_path, package, name):
    cwd, log_dir = tmp_path / "cwd", tmp_path / "ros_log"
    cwd.mkdir()
    exe = Path(sys.prefix) / "lib" / package / name
    env = dict(os.environ, ROS_LOG_DIR=str(log_dir), ROS_DOMAIN_ID="0", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        done = subprocess.run([str(exe), "--help"], cwd=cwd, env=env, capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"{name} --help did not exit: it ran as if started ({exc.stdout!r})")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: ") and done.stderr == "", (done.stdout, done.stderr)
    assert list(cwd.iterdir()) == [], f"{name} --help wrote into the working folder"
    assert not log_dir.exists(), f"{name} --help initialised ROS"
    if name in NODES:
        assert "parameters (-p NAME:=VALUE" in done.stdout and "NNI_NETWORK [loopback]" in done.stdout


def test_node_help_lists_each_parameter_with_its_default_and_description():
    """The plant's help shows what its parameter table declares (a few spot checks, values from the YAML)."""
    exe = Path(sys.prefix) / "lib" / "nni_plant_sim" / "plant_node"
    text = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60, check=True).stdout
    lines = text.splitlines()
    assert "  mode [realtime]" in lines and "  pmu_rate_hz [50.0]" in lines and "  fault_at_start [true]" in lines
    following = lines[lines.index("  pmu_rate_hz [50.0]") + 1]
    assert following.strip().startswith("PMU reporting rate, frames/s")
    words = " ".join(text.split())  # descriptions are wrapped
    assert "Range 10 to 1000." in words and "One of: initial_angle, mechanical_step, transfer_limit_fault." in words


@pytest.mark.parametrize("args, expected", [
    (["out.mcap"], "mcap_logger: error: unrecognized arguments: out.mcap (node parameters go after --ros-args: "
                   "-p name:=value; see --help)"),
    (["--ros-args", "--help"], "mcap_logger: error: unknown arguments after --ros-args: ['--help'] (see --help)"),
    (["--ros-args", "-p"], "mcap_logger: error: Failed to parse ROS arguments: Couldn't parse trailing -p flag. "
                           "No parameter override rule found. (see --help)"),
])
def test_a_bad_argument_is_refused_with_one_line(tmp_path, args, expected):
    exe = Path(sys.prefix) / "lib" / "nni_msgs_adapter" / "mcap_logger"
    done = subprocess.run([str(exe), *args], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and list(tmp_path.iterdir()) == []
    assert done.stdout == "" and done.stderr == expected + "\n"
