"""The network plant's defaults come from ``config/network_plant.yaml``, read on first use (issue 14 item 1)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from rosproc import fresh_domain_id, printed_json, ros_env
from test_defaults import overlay, run

from nni_msgs_adapter.ros.defaults import config_path
from nni_plant_sim.network_plant_node import SUMMARY_PREFIX

COUNT_READS = """
import json
import nni_msgs_adapter.ros.defaults as defaults
reads, original = [], defaults.config_path
defaults.config_path = lambda *args: reads.append(args[1]) or original(*args)
import nni_plant_sim.network_plant_node
at_import = list(reads)
from nni_plant_sim.network_plant_config import parameters
parameters(), parameters()
print(json.dumps({"at_import": at_import, "after_use": reads}))
"""


def test_importing_the_network_plant_reads_no_yaml_and_its_table_reads_its_own_once():
    done = subprocess.run([sys.executable, "-c", COUNT_READS], capture_output=True, text=True, timeout=120, check=True)
    reads = json.loads(done.stdout.splitlines()[-1])
    assert reads == {"at_import": [], "after_use": ["network_plant.yaml"]}


def test_a_default_changed_in_network_plant_yaml_is_what_the_node_shows(tmp_path):
    prefix = overlay(tmp_path, "nni_plant_sim", "network_plant.yaml", "network_plant",
                     {"fault_bus": 8, "machine": [2], "pmu_rate_hz": 40.0})
    lines = run("network_plant_node", "nni_plant_sim", ["--help"], prefix, tmp_path).splitlines()
    assert "  fault_bus [8]" in lines and "  machine [[2]]" in lines and "  pmu_rate_hz [40.0]" in lines
    assert "  case [kundur_two_area]" in lines and "  scenario [bus_fault]" in lines


@pytest.mark.ros
def test_the_network_plant_runs_with_its_own_yaml_as_params_file(tmp_path):
    """As a launch file passes it (``parameters=[<share>/config/network_plant.yaml, ...]``): its ``machine: []``
    (which rcl reads as unset) and every other default are taken; the run ends with its per-generator summary."""
    yaml_path = config_path("nni_plant_sim", "network_plant.yaml")
    done = subprocess.run([sys.executable, "-m", "nni_plant_sim.network_plant_node", "--ros-args", "--params-file",
                           str(yaml_path), "-p", "mode:=realtime", "-p", "duration_s:=0.2", "-p", "wait_for_subscribers:=0"],
                          env=ros_env(fresh_domain_id()), capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    summary = printed_json(done.stdout, SUMMARY_PREFIX)
    assert list(summary) == ["gen1", "gen2", "gen3", "gen4"]
    assert all(values["run_ended"] and values["sim_time_s"] == pytest.approx(0.2) for values in summary.values()), summary
