"""The three packages build with colcon and their executables start the way ``ros2 run`` finds them.

ros2cli is not installable here, so the test resolves each executable as
``ros2 run`` does (ros2pkg's get_executable_path: the package's prefix from the
ament index, then ``lib/<package>/<executable>``) with ament_index_python, and
starts it from the installed tree.
"""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from rosproc import fresh_domain_id, ros_env

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("nni_plant_sim", "nni_battery_controller", "nni_msgs_adapter")
EXECUTABLES = {
    "nni_plant_sim": ("plant_node",),
    "nni_battery_controller": ("controller_node", "nni-simulate", "nni-demo", "replay", "nni-replay"),
    "nni_msgs_adapter": ("mcap_logger",),
}


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A colcon workspace with the three packages (copied), built with --merge-install off."""
    ws = tmp_path_factory.mktemp("ws")
    for package in PACKAGES:
        shutil.copytree(REPO / package, ws / "src" / package,
                        ignore=shutil.ignore_patterns("*.egg-info", "__pycache__"))
    colcon = Path(sys.executable).parent / "colcon"
    result = subprocess.run([str(colcon), "build", "--base-paths", "src"], cwd=ws, capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Summary: 3 packages finished" in result.stdout, result.stdout
    assert "failed" not in result.stdout.lower()
    return ws


def installed_env(ws: Path, domain_id: int) -> dict:
    """What sourcing install/setup.bash over the venv gives: ament prefixes and PYTHONPATH.

    The venv (sys.prefix) plays the underlay, as /opt/ros/jazzy does on a ROS install.
    """
    prefixes = [ws / "install" / package for package in PACKAGES]
    site = [str(p / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages")
            for p in prefixes]
    return ros_env(domain_id, AMENT_PREFIX_PATH=os.pathsep.join(map(str, [*prefixes, sys.prefix])),
                   PYTHONPATH=os.pathsep.join(site))


def resolve_executable(env: dict, package: str, executable: str) -> Path:
    """ros2 run's lookup, done with ament_index_python in a child with the workspace env."""
    code = ("import os, sys; from ament_index_python.packages import get_package_prefix; "
            "print(os.path.join(get_package_prefix(sys.argv[1]), 'lib', sys.argv[1], sys.argv[2]))")
    out = subprocess.run([sys.executable, "-c", code, package, executable], env=env, capture_output=True,
                         text=True, check=True)
    return Path(out.stdout.strip())


def test_install_layout(workspace):
    """Every executable under lib/<package>, the ament index marker, package.xml, config and launch files."""
    install = workspace / "install"
    env = installed_env(workspace, 0)
    for package, executables in EXECUTABLES.items():
        prefix = install / package
        assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / package).is_file()
        assert (prefix / "share" / package / "package.xml").is_file()
        for executable in executables:
            path = resolve_executable(env, package, executable)
            assert path == prefix / "lib" / package / executable
            assert os.access(path, os.X_OK), path
    assert (install / "nni_battery_controller" / "share" / "nni_battery_controller" / "launch"
            / "closed_loop.launch.py").is_file()
    for package, config in (("nni_plant_sim", "plant.yaml"), ("nni_battery_controller", "controller.yaml"),
                            ("nni_msgs_adapter", "mcap_logger.yaml"), ("nni_msgs_adapter", "foxglove_bridge.yaml")):
        assert (install / package / "share" / package / "config" / config).is_file()


def test_installed_modules_come_from_the_workspace(workspace):
    """With the workspace environment, the packages import from install/, not from the source tree."""
    env = installed_env(workspace, 0)
    for package in PACKAGES:
        out = subprocess.run([sys.executable, "-c", f"import {package}; print({package}.__file__)"], env=env,
                             capture_output=True, text=True, check=True)
        assert str(workspace / "install" / package) in out.stdout


def test_installed_nodes_run_the_loop(workspace, tmp_path):
    """The installed plant, controller and logger executables run a lockstep loop and record it."""
    from nni_msgs_adapter.ros import contract
    from nni_msgs_adapter.recording.mcap_io import read_messages

    domain = fresh_domain_id()
    env = installed_env(workspace, domain)
    recording = tmp_path / "installed.mcap"

    def start(package, executable, *params):
        args = [a for p in params for a in ("-p", p)]
        log = open(tmp_path / f"{executable}.log", "wb")
        return subprocess.Popen([str(resolve_executable(env, package, executable)), "--ros-args", *args],
                                env=env, stdout=log, stderr=subprocess.STDOUT)

    logger = start("nni_msgs_adapter", "mcap_logger", f"output_path:={recording}", "discovery_period_s:=0.1")
    controller = start("nni_battery_controller", "controller_node", "battery_limit_pu:=0.3")
    plant = start("nni_plant_sim", "plant_node", "mode:=lockstep", "duration_s:=2.0", "wait_for_subscribers:=2")
    try:
        assert plant.wait(timeout=60) == 0, (tmp_path / "plant_node.log").read_text()
        time.sleep(0.5)  # the last reliable messages reach the logger
    finally:
        for proc in (controller, logger, plant):
            if proc.poll() is None:
                proc.send_signal(2)
            proc.wait(timeout=10)
    assert controller.returncode == 0 and logger.returncode == 0
    states = [r for r in read_messages(recording) if r.topic == "/" + contract.TOPIC_PLANT_STATE]
    assert len(states) == 101, "2 s at 50 frames/s: samples t_0 .. t_100"


def launch_file_constants(path: Path) -> tuple[ast.Module, dict]:
    """The launch file's syntax tree and its module-level literal constants (argument lists, CONFIG)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    constants = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            try:
                constants[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                continue
    return tree, constants


def test_launch_file_matches_the_installed_nodes(workspace):
    """launch is not installable here, so the launch file is not run: what can be checked without it is.

    Its arguments are parameters the nodes declare, the config files it passes exist in the
    install and hold a default for every argument, every Node it starts resolves as ros2 run
    would, and the plant's exit is wired to a Shutdown.
    """
    from nni_battery_controller.controller_node import parameters as controller
    from nni_msgs_adapter.recording.mcap_logger import parameters as logger
    from nni_plant_sim.plant_node import parameters as plant

    install = workspace / "install"
    path = install / "nni_battery_controller" / "share" / "nni_battery_controller" / "launch" / "closed_loop.launch.py"
    tree, constants = launch_file_constants(path)
    declared = {"plant": {s.name for s in plant()}, "controller": {s.name for s in controller()},
                "mcap_logger": {s.name for s in logger()}}
    for names, nodes in (("PLANT_ARGUMENTS", ("plant",)), ("CONTROLLER_ARGUMENTS", ("controller",)),
                         ("MODEL_ARGUMENTS", ("plant", "controller")), ("LOGGER_ARGUMENTS", ("mcap_logger",))):
        for node in nodes:
            assert set(constants[names]) <= declared[node], (names, node, set(constants[names]) - declared[node])
    # The scenario, each scenario's options and the gains are all arguments.
    assert {"scenario", "delta0_rad", "speed0_rad_s", "step_p_mech_pu", "step_duration_s", "fault_p_max_pu",
            "clearing_time_s"} <= set(constants["PLANT_ARGUMENTS"])
    assert {"tau_s", "gain_k", "gain_l", "alpha", "battery_limit_pu"} <= set(constants["CONTROLLER_ARGUMENTS"])
    for node, (package, filename, node_name) in constants["CONFIG"].items():
        config = install / package / "share" / package / "config" / filename
        assert config.is_file(), config
        assert node_name == node
    for names, node in (("PLANT_ARGUMENTS", "plant"), ("MODEL_ARGUMENTS", "plant"),
                        ("CONTROLLER_ARGUMENTS", "controller"), ("LOGGER_ARGUMENTS", "mcap_logger")):
        package, filename, node_name = constants["CONFIG"][node]
        config = install / package / "share" / package / "config" / filename
        defaults = yaml.safe_load(config.read_text())[f"/**/{node_name}"]["ros__parameters"]
        assert set(constants[names]) <= set(defaults), (names, set(constants[names]) - set(defaults))
    env = installed_env(workspace, 0)
    started = [{kw.arg: kw.value.value for kw in call.keywords if isinstance(kw.value, ast.Constant)}
               for call in ast.walk(tree) if isinstance(call, ast.Call) and getattr(call.func, "id", "") == "Node"]
    assert {(n["package"], n["executable"]) for n in started} == {
        ("nni_plant_sim", "plant_node"), ("nni_battery_controller", "controller_node"),
        ("nni_msgs_adapter", "mcap_logger"), ("nni_msgs_adapter", "c37118_client"),
        ("nni_msgs_adapter", "foxglove_bridge")}
    for node in started:
        assert os.access(resolve_executable(env, node["package"], node["executable"]), os.X_OK)
    handlers = [call for call in ast.walk(tree) if isinstance(call, ast.Call)
                and getattr(call.func, "id", "") == "OnProcessExit"]
    (handler,) = handlers
    target = {kw.arg: kw.value for kw in handler.keywords}["target_action"]
    assert isinstance(target, ast.Name) and target.id == "plant"
    assert "Shutdown" in ast.unparse(handler)
