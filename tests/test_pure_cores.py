"""Pure cores, thin nodes: the model, the control law, the simulations and the analysis never import rclpy.

Every module of the three packages is pure unless :data:`ROS_SIDE` names it: a new module is checked
the day it is written, and putting it on the ROS side is a decision with its reason beside it. Each pure
module is imported in a fresh interpreter (so that nothing imported by another test hides an import),
and rclpy must not be among the loaded modules; each ROS-side one must really load rclpy, or it belongs
with the pure ones.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("nni_plant_sim", "nni_battery_controller", "nni_msgs_adapter")

#: The modules that import rclpy, and why.
ROS_SIDE = {
    # Nodes and what every node is built on.
    "nni_plant_sim.plant_node_base": "the plant node's ROS side, shared by both plants",
    "nni_plant_sim.plant_node": "a node",
    "nni_plant_sim.network_plant_node": "a node",
    "nni_battery_controller.controller_node": "a node",
    "nni_battery_controller.composed_controllers": "a process of several nodes",
    "nni_msgs_adapter.ros.contract": "the message contract: QoS profiles and message classes",
    "nni_msgs_adapter.ros.loop_node": "the loop nodes' common Node subclass",
    "nni_msgs_adapter.ros.node_main": "start-up, executor and shutdown of every node",
    "nni_msgs_adapter.recording.mcap_logger": "a node",
    "nni_msgs_adapter.recording.replay_node": "a node",
    "nni_msgs_adapter.viewing.rerun_bridge": "a node",
    "nni_msgs_adapter.viewing.foxglove_bridge": "a node",
    "nni_msgs_adapter.viewing.foxglove_layout": "the layouts name the contract's topics and signal order",
    "nni_msgs_adapter.c37118.client_node": "a node",
    # Decoding recorded CDR goes through the contract's message conversions.
    "nni_msgs_adapter.recording.runs": "reads recorded messages with the contract",
    "nni_battery_controller.recorded_runs": "recorded runs as trajectories, through runs",
    "nni_battery_controller.replay": "nni-replay's entry, on replay_load",
    "nni_battery_controller.replay_load": "what every nni-replay job reads, through runs",
    "nni_battery_controller.replay_ros": "ROS playback through replay_node",
    "nni_battery_controller.replay_info": "--info, on replay_load",
    "nni_battery_controller.replay_plot": "--plot, on replay_load",
    "nni_battery_controller.replay_rerun": "--rrd/--connect/--spawn, on replay_load",
    "nni_battery_controller.replay_c37118": "--pmu-server, on replay_load",
    # The demos start no node of their own, but read the nodes' output lines by the nodes' own constants.
    "nni_battery_controller.demo_common": "the nodes' summary and count line prefixes",
    "nni_battery_controller.smib_demo": "the demo, on demo_common",
    "nni_battery_controller.network_demo": "the network demo, on demo_common",
    "nni_battery_controller.demo_foxglove": "the demos' Foxglove bridge, by the node's own constants",
}


def package_modules() -> list[str]:
    """Every module of the three packages, from their source folders."""
    modules = []
    for package in PACKAGES:
        source = ROOT / package / package
        for path in sorted(source.rglob("*.py")):
            parts = path.relative_to(source.parent).with_suffix("").parts
            modules.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return modules


PURE_MODULES = [module for module in package_modules() if module not in ROS_SIDE]

PROBE = """
import importlib, sys
importlib.import_module(sys.argv[1])
loaded = sorted(name for name in sys.modules if name == "rclpy" or name.startswith("rclpy."))
print(",".join(loaded))
"""


def rclpy_loaded_by(module: str) -> list[str]:
    result = subprocess.run([sys.executable, "-c", PROBE, module], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    return [name for name in result.stdout.strip().split(",") if name]


@pytest.mark.parametrize("module", PURE_MODULES)
def test_core_module_does_not_import_rclpy(module):
    assert rclpy_loaded_by(module) == [], f"{module} pulls in rclpy: put it right, or on ROS_SIDE with a reason"


@pytest.mark.parametrize("module", sorted(ROS_SIDE))
def test_a_ros_side_module_exists_and_really_loads_rclpy(module):
    """The check itself sees rclpy, and no module sits on the ROS side that could be pure."""
    assert module in package_modules(), f"ROS_SIDE names {module}, which is no module of the packages"
    assert "rclpy" in rclpy_loaded_by(module), f"{module} loads no rclpy: it is pure, take it off ROS_SIDE"
