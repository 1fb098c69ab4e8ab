"""One source of defaults, read lazily (issue 12 item 3).

The package YAML files hold every node default. Importing a node, ``nni-demo`` or
``nni-simulate`` reads none of them (they are read on first use, then cached),
and a default changed in the YAML is what the nodes, ``nni-simulate`` and
``nni-demo`` show in ``--help`` and use. The changed YAML comes in through the
ament index, as a colcon install's config files do: an overlay prefix on
``AMENT_PREFIX_PATH`` (before the venv's own) whose ``share/<package>/config`` holds the edited copies.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import yaml
from rosproc import fresh_domain_id

from nni_msgs_adapter.ros.defaults import config_path

#: Importing these must read no config file (each used to, through its parameter table).
MODULES = ("nni_plant_sim.plant_node", "nni_battery_controller.controller_node", "nni_battery_controller.demo_command",
           "nni_battery_controller.simulate_command", "nni_battery_controller.options", "nni_msgs_adapter.recording.mcap_logger",
           "nni_msgs_adapter.viewing.rerun_bridge", "nni_msgs_adapter.viewing.foxglove_bridge", "nni_plant_sim.plant_config", "nni_battery_controller.controller_config")

#: Keys of a demo summary that depend on the wall clock or on the output name, not on the run's values.
WALL_CLOCK = ("recording", "wall_time_s", "latency_ms")
#: max |delta - delta_bar| of the paper's case (P_M 0.8, P_max 1): its start, asin(0.8) - 0.2 rad.
DEFAULT_RUN_MAX_ANGLE_DEV_RAD = math.asin(0.8) - 0.2

COUNT_READS = """
import json, sys
import nni_msgs_adapter.ros.defaults as defaults
reads, original = [], defaults.config_path
defaults.config_path = lambda *args: reads.append(args[1]) or original(*args)
for name in sys.argv[1:]:
    __import__(name)
at_import = list(reads)
from nni_plant_sim.plant_config import parameters as plant
from nni_battery_controller.controller_config import parameters as controller
plant(), plant(), controller(), controller()
print(json.dumps({"at_import": at_import, "after_use": reads}))
"""


def test_importing_the_nodes_and_the_clis_reads_no_yaml():
    done = subprocess.run([sys.executable, "-c", COUNT_READS, *MODULES], capture_output=True, text=True,
                          timeout=120, check=True)
    reads = json.loads(done.stdout.splitlines()[-1])
    assert reads["at_import"] == []
    assert reads["after_use"] == ["plant.yaml", "controller.yaml"], "read on first use, once each (cached)"


def overlay(tmp_path: Path, package: str, filename: str, node: str, changes: dict) -> Path:
    """An ament prefix whose ``share/<package>/config/<filename>`` is the package's file with ``changes``."""
    prefix = tmp_path / "overlay"
    (prefix / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True, exist_ok=True)
    (prefix / "share" / "ament_index" / "resource_index" / "packages" / package).write_text("")
    values = yaml.safe_load(config_path(package, filename).read_text())
    values[f"/**/{node}"]["ros__parameters"].update(changes)
    (prefix / "share" / package / "config").mkdir(parents=True, exist_ok=True)
    (prefix / "share" / package / "config" / filename).write_text(yaml.safe_dump(values))
    return prefix


def run(name: str, package: str, args: list, prefix: Path, tmp_path: Path) -> str:
    # The overlay first, then the venv's own ament index (message packages), as a sourced overlay does.
    env = dict(os.environ, AMENT_PREFIX_PATH=os.pathsep.join((str(prefix), sys.prefix)),
               ROS_LOG_DIR=str(tmp_path / "ros_log"))
    done = subprocess.run([str(Path(sys.prefix) / "lib" / package / name), *args], capture_output=True, text=True,
                          timeout=120, env=env, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_a_default_changed_in_the_yaml_reaches_the_nodes_nni_simulate_and_nni_demo(tmp_path):
    """P_M 0.8 -> 0.75 and K 1 -> 0.9 in the overlay's YAML: every entry point shows and uses them."""
    prefix = overlay(tmp_path, "nni_plant_sim", "plant.yaml", "plant", {"p_mech_pu": 0.75, "pmu_rate_hz": 40.0})
    overlay(tmp_path, "nni_battery_controller", "controller.yaml", "controller", {"gain_k": 0.9})
    plant = run("plant_node", "nni_plant_sim", ["--help"], prefix, tmp_path).splitlines()
    assert "  p_mech_pu [0.75]" in plant and "  pmu_rate_hz [40.0]" in plant
    assert "  gain_k [0.9]" in run("controller_node", "nni_battery_controller", ["--help"], prefix, tmp_path).splitlines()
    for name in ("nni-simulate", "nni-demo"):
        text = " ".join(run(name, "nni_battery_controller", ["--help"], prefix, tmp_path).split())
        assert "mechanical power P_M, pu (default: 0.75)" in text and "gain K, pu/rad (default: 0.9)" in text, name
    assert "PMU reporting rate, frames/s (default: 40)" in " ".join(
        run("nni-demo", "nni_battery_controller", ["--help"], prefix, tmp_path).split())
    # nni-simulate runs with them: its output is that of the same values given as options.
    simulate = ["--b", "0.3", "--duration", "2"]
    changed = run("nni-simulate", "nni_battery_controller", simulate, prefix, tmp_path)
    assert "P_M 0.75," in changed.splitlines()[0] and "K 0.9," in changed.splitlines()[0]
    assert changed == run("nni-simulate", "nni_battery_controller", [*simulate, "--P-M", "0.75", "--K", "0.9"],
                          tmp_path / "no_overlay", tmp_path)


def test_nni_demo_and_its_nodes_run_with_a_default_changed_in_the_yaml(tmp_path):
    """The demo's nodes start from the overlay's YAML: the run equals one given the same values as options."""
    prefix = overlay(tmp_path, "nni_plant_sim", "plant.yaml", "plant", {"p_mech_pu": 0.75})
    overlay(tmp_path, "nni_battery_controller", "controller.yaml", "controller", {"gain_k": 0.9})
    summaries = []
    for name, where, options in (("overlay", prefix, []), ("options", tmp_path / "no_overlay", ["--P-M", "0.75", "--K", "0.9"])):
        out = tmp_path / f"demo_{name}"
        run("nni-demo", "nni_battery_controller", ["--b", "0.3", "--duration", "2", "--out", str(out),
                                                   "--domain-id", str(fresh_domain_id()), *options], where, tmp_path)
        (result,) = json.loads((out / "summary.json").read_text())["scenarios"]
        # The statuses on /diagnostics come once a second of wall time: their count is the run's wall time.
        result["logger_counts"] = {topic: n for topic, n in result["logger_counts"].items() if topic != "/diagnostics"}
        summaries.append({key: value for key, value in result.items() if key not in WALL_CLOCK})
    assert summaries[0] == summaries[1]
    assert summaries[0]["max_abs_angle_dev_rad"] != DEFAULT_RUN_MAX_ANGLE_DEV_RAD, "the values changed the run"
