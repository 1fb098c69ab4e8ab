"""The network plant's defaults come from ``config/network_plant.yaml``, read on first use (issue 14 item 1)."""

from __future__ import annotations

import json
import subprocess
import sys

from test_defaults import overlay, run

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
