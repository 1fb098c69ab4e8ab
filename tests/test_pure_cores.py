"""Pure cores, thin nodes: the model, the control law, the simulations and the analysis never import rclpy.

Each module is imported in a fresh interpreter (so that nothing imported by
another test hides an import), and rclpy must not be among the loaded modules.
The list holds every pure module of the three packages; the ROS side (nodes,
``contract`` with its QoS profiles, ``recording``, which decodes CDR through
the contract's message conversions) is left out on purpose.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

PURE_MODULES = [
    "nni_plant_sim.model",
    "nni_plant_sim.scenarios",
    "nni_plant_sim.integrators",
    "nni_plant_sim.network",
    "nni_plant_sim.network_scenarios",
    "nni_plant_sim.cases",
    "nni_plant_sim.cases.replicated",
    "nni_battery_controller.law",
    "nni_battery_controller.simulate",
    "nni_battery_controller.verdicts",
    "nni_battery_controller.margins",
    "nni_battery_controller.roa",
    "nni_battery_controller.figures",
    "nni_battery_controller.closed_loop",
    "nni_battery_controller.simulate_command",
    "nni_battery_controller.smib_study",
    "nni_battery_controller.study_common",
    "nni_battery_controller.network_sim",
    "nni_battery_controller.network_study",
    "nni_battery_controller.network_common",
    "nni_battery_controller.network_deployment",
    "nni_msgs_adapter.recording.mcap_io",
    "nni_msgs_adapter.recording.mcap_profile",
    "nni_msgs_adapter.recording.mcap_qos",
    "nni_msgs_adapter.recording.mcap_reader",
    "nni_msgs_adapter.recording.mcap_writer",
    "nni_msgs_adapter.recording.network_runs",
    "nni_msgs_adapter.viewing.rerun_view",
    "nni_msgs_adapter.ros.cli_support",
    "nni_msgs_adapter.ros.command_auth",
    "nni_msgs_adapter.ros.defaults",
    "nni_msgs_adapter.viewing.palette",
    "nni_battery_controller.options",
    "nni_msgs_adapter.ros.processes",
    "nni_msgs_adapter.ros.readback",
    "nni_plant_sim.loop_stats",
    "nni_plant_sim.reporting",
    "nni_plant_sim.link",
    "nni_battery_controller.input_gate",
    "nni_battery_controller.controller_core",
    "nni_battery_controller.controller_config",
    "nni_msgs_adapter.c37118.counting",
    "nni_msgs_adapter.c37118.frames",
    "nni_msgs_adapter.c37118.stream",
    "nni_msgs_adapter.c37118.server",
    "nni_msgs_adapter.c37118.client",
]

PROBE = """
import importlib, sys
importlib.import_module(sys.argv[1])
loaded = sorted(name for name in sys.modules if name == "rclpy" or name.startswith("rclpy."))
print(",".join(loaded))
"""


@pytest.mark.parametrize("module", PURE_MODULES)
def test_core_module_does_not_import_rclpy(module):
    result = subprocess.run([sys.executable, "-c", PROBE, module], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "", f"{module} pulls in {result.stdout.strip()}"


def test_the_probe_sees_rclpy_when_a_node_module_is_imported():
    """The check itself works: a node module does show rclpy."""
    result = subprocess.run([sys.executable, "-c", PROBE, "nni_plant_sim.plant_node"], capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "rclpy" in result.stdout.split(",")
