"""Launch the closed loop of one generator: plant, controller and MCAP logger.

    ros2 launch nni_battery_controller closed_loop.launch.py \
        namespace:=gen1 mode:=lockstep duration_s:=10.0 battery_limit_pu:=0.3 \
        scenario:=transfer_limit_fault clearing_time_s:=0.2 output_path:=run.mcap

Every argument is a node parameter under its own name (``ros2 launch ...
--show-args`` lists them with their defaults). Each node's parameters are its
package's ``config/*.yaml`` (where the defaults live; the arguments' defaults
are read from the same files) and then the arguments. The model arguments
(``p_mech_pu``, ``p_max_pu``, ``inertia_h_s``, ``f0_hz``) go to the plant and
to the controller's model of it, ``pmu_rate_hz`` to the plant and as
``sample_rate_hz`` to the controller. ``pmu_port`` (-1: none) serves the
plant's PMU as an IEEE C37.118.2 stream on that TCP port of ``pmu_host``
(loopback by default) with IDCODE ``pmu_idcode``. ``measurements:=c37118``
feeds the controller through that stream (on port 4712 when ``pmu_port`` gives
none; 0, a port the launch cannot learn, is refused) and a ``c37118_client``
node (as ``nni-demo --measurements c37118``; the rate must be one C37.118
allows). ``foxglove:=true`` adds a ``foxglove_bridge`` node streaming every loop topic live over the Foxglove
WebSocket protocol at ``foxglove_address`` (127.0.0.1:8765 by default; the plant waits for it too). All topics
are relative, so the namespace
argument puts one generator's loop under /<namespace>. With ``duration_s > 0``
the launch shuts down when the plant exits: the controller and the logger get
SIGINT, and the logger finishes the recording.

The plant's battery is rated b (``battery_limit_pu``: it clips every command
there). Each launch makes a fresh command key, handed to the plant and the
controller only (``NNI_COMMAND_KEY_FILE``) and removed at shutdown, and starts
the plant's run only once both nodes have stated at start the parameters it
gave them (:mod:`nni_msgs_adapter.ros.launch_trust`); on a difference it logs
one line and shuts down before any sample.
"""

import os

import yaml

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import EnvironmentVariable, LaunchConfiguration
from launch_ros.actions import Node

from nni_battery_controller import demo_c37118, demo_foxglove
from nni_msgs_adapter.ros.processes import parameter_text
from nni_msgs_adapter.ros.defaults import load_defaults

#: Launch arguments that are plant parameters (package nni_plant_sim, config/plant.yaml).
PLANT_ARGUMENTS = (
    "mode", "pmu_rate_hz", "duration_s", "scenario", "delta0_rad", "speed0_rad_s", "step_p_mech_pu",
    "step_duration_s", "fault_p_max_pu", "clearing_time_s", "damping_pu", "pmu_port", "pmu_host", "pmu_idcode",
    "battery_energy_pu_s",
)
#: Launch arguments that are controller parameters (package nni_battery_controller, config/controller.yaml).
CONTROLLER_ARGUMENTS = ("law", "tau_s", "gain_k", "gain_l", "alpha", "battery_limit_pu")
#: Model parameters shared by the plant and the controller's model of it (the plant's defaults).
MODEL_ARGUMENTS = ("p_mech_pu", "p_max_pu", "inertia_h_s", "f0_hz")
#: Launch arguments that are logger parameters (package nni_msgs_adapter, config/mcap_logger.yaml).
LOGGER_ARGUMENTS = ("output_path",)
#: (package, config file, node name) of each node.
CONFIG = {
    "plant": ("nni_plant_sim", "plant.yaml", "plant"),
    "controller": ("nni_battery_controller", "controller.yaml", "controller"),
    "mcap_logger": ("nni_msgs_adapter", "mcap_logger.yaml", "mcap_logger"),
    "foxglove_bridge": ("nni_msgs_adapter", "foxglove_bridge.yaml", "foxglove_bridge"),
}


def config_file(node: str) -> str:
    """The installed config/*.yaml of ``node``."""
    package, filename, _ = CONFIG[node]
    return os.path.join(get_package_share_directory(package), "config", filename)


def arguments(node: str, names) -> list:
    """DeclareLaunchArgument for each parameter ``names`` of ``node``, its default from the node's YAML."""
    defaults = load_defaults(*CONFIG[node])
    return [DeclareLaunchArgument(name, default_value=parameter_text(defaults[name]),
                                  description=f"{node} parameter {name} (default from {CONFIG[node][1]})")
            for name in names]


def launched_nodes(values: dict) -> dict:
    """``{node: the parameters the launch gives it beside its config YAML}`` for the launch arguments ``values``
    (each as a value): the plant's battery rated the controller's b, its run held for the read-back; with
    ``measurements`` c37118 the client node too (ValueError for a ``measurements`` or port that cannot be)."""
    measurements = values["measurements"]
    port, stream = demo_c37118.launch_stream(measurements, values["pmu_port"], values["pmu_host"])
    bridge = demo_foxglove.launch_bridge(values["foxglove"], values["foxglove_address"], {
        "b": values["battery_limit_pu"], "law": values["law"], "scenario": values["scenario"], "mode": values["mode"]})
    plant = {**{name: values[name] for name in (*PLANT_ARGUMENTS, *MODEL_ARGUMENTS)},
             "battery_rating_pu": values["battery_limit_pu"], "hold_until_released": True,
             # the controller and the logger, and the Foxglove bridge when there is one
             "wait_for_subscribers": demo_c37118.plant_readers(measurements, 2, bridge is not None),
             "wait_for_recorders": 1 + (bridge is not None),  # on plant/state: the logger and the bridge
             **stream}
    nodes = {
        "plant": plant,
        "controller": {**{name: values[name] for name in (*CONTROLLER_ARGUMENTS, *MODEL_ARGUMENTS)},
                       "sample_rate_hz": values["pmu_rate_hz"], **demo_c37118.controller_parameters(measurements)},
        "mcap_logger": {name: values[name] for name in LOGGER_ARGUMENTS},
    }
    if bridge is not None:
        nodes["foxglove_bridge"] = bridge
    if measurements == "c37118":  # it connects once the controller and the logger read its c37118/pmu
        nodes["c37118_client"] = demo_c37118.client_parameters(port, values["mode"], 2, (),
                                                               demo_c37118.client_host(values["pmu_host"]),
                                                               values["pmu_idcode"])
    return nodes


def generate_launch_description():
    from nni_battery_controller.controller_config import parameters as controller_node_parameters
    from nni_msgs_adapter.ros.launch_trust import readback_release, run_key_environment
    from nni_msgs_adapter.ros.readback import expected_parameters
    from nni_plant_sim.plant_config import parameters as plant_node_parameters

    names = (*PLANT_ARGUMENTS, *MODEL_ARGUMENTS, *CONTROLLER_ARGUMENTS, *LOGGER_ARGUMENTS, "measurements")

    def setup(context):
        values = {name: yaml.safe_load(context.launch_configurations[name]) for name in names}
        values["pmu_host"] = context.launch_configurations["pmu_host"]  # an address, text whatever YAML makes of it
        for name in ("foxglove", "foxglove_address"):
            values[name] = context.launch_configurations[name]
        given = launched_nodes(values)
        namespace = context.launch_configurations["namespace"]
        key_env, remove_key = run_key_environment()  # every node's: each seals what it sends, checks what it reads
        plant = Node(package="nni_plant_sim", executable="plant_node", name="plant", namespace=namespace,
                     ros_arguments=["--enclave", "/nni/plant"], parameters=[config_file("plant"), given["plant"]],
                     additional_env=key_env)
        controller = Node(package="nni_battery_controller", executable="controller_node", name="controller",
                          namespace=namespace, ros_arguments=["--enclave", "/nni/controller"],
                          parameters=[config_file("controller"), given["controller"]], additional_env=key_env)
        logger = Node(package="nni_msgs_adapter", executable="mcap_logger", name="mcap_logger", namespace=namespace,
                      ros_arguments=["--enclave", "/nni/mcap_logger"],
                      parameters=[config_file("mcap_logger"), given["mcap_logger"]], additional_env=key_env)
        # The C37.118 client and the Foxglove bridge, when asked for.
        extra = {}
        if "c37118_client" in given:
            extra["c37118_client"] = Node(
                package="nni_msgs_adapter", executable="c37118_client", name="c37118_client", namespace=namespace,
                ros_arguments=["--enclave", "/nni/c37118_client"], parameters=[given["c37118_client"]],
                additional_env=key_env)
        if "foxglove_bridge" in given:
            extra["foxglove_bridge"] = Node(
                package="nni_msgs_adapter", executable="foxglove_bridge", name="foxglove_bridge", namespace=namespace,
                ros_arguments=["--enclave", "/nni/foxglove_bridge"],
                parameters=[config_file("foxglove_bridge"), given["foxglove_bridge"]], additional_env=key_env)
        prefix = "/".join(("", *filter(None, (namespace.strip("/"),))))
        started = [(controller, {f"{prefix}/controller": expected_parameters(controller_node_parameters(),
                                                                              given["controller"])}),
                   (plant, {f"{prefix}/plant": expected_parameters(plant_node_parameters(), given["plant"])}),
                   # stated, nothing to compare: they have read the run's key, removed once every node has
                   (logger, {f"{prefix}/mcap_logger": {}}),
                   *((node, {f"{prefix}/{name}": {}}) for name, node in extra.items())]
        # The plant runs once both nodes stated what they were given; the run is over when it exits
        # (duration_s > 0): stop the others, finish the recording.
        return [*remove_key, *readback_release(started, plant, key_env), logger, controller, *extra.values(), plant,
                RegisterEventHandler(OnProcessExit(target_action=plant, on_exit=[
                    EmitEvent(event=Shutdown(reason="the plant finished its run"))]))]

    secure = IfCondition(LaunchConfiguration("use_security"))
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="", description="namespace of this generator's nodes"),
        *arguments("plant", (*PLANT_ARGUMENTS, *MODEL_ARGUMENTS)),
        *arguments("controller", CONTROLLER_ARGUMENTS),
        *arguments("mcap_logger", LOGGER_ARGUMENTS),
        DeclareLaunchArgument("measurements", default_value="ros",
                              description="ros: the controller reads the plant's pmu; c37118: the plant's C37.118.2 "
                                          "stream on pmu_port (4712 if none), through the c37118_client node"),
        DeclareLaunchArgument("foxglove", default_value="false",
                              description="true: a foxglove_bridge node streams every loop topic live over the "
                                          "Foxglove WebSocket protocol at foxglove_address"),
        DeclareLaunchArgument("foxglove_address", default_value="127.0.0.1:8765",
                              description="[HOST:]PORT of the Foxglove server (loopback unless a host is named)"),
        DeclareLaunchArgument("use_security", default_value="false",
                              description="true: SROS2 (Enforce), each node in its enclave /nni/<node> of the "
                                          "keystore made by scripts/sros2_keystore; ROS 2 Jazzy installs only"),
        DeclareLaunchArgument("keystore", default_value=EnvironmentVariable("ROS_SECURITY_KEYSTORE", default_value=""),
                              description="SROS2 keystore folder"),
        SetEnvironmentVariable("ROS_SECURITY_ENABLE", "true", condition=secure),
        SetEnvironmentVariable("ROS_SECURITY_STRATEGY", "Enforce", condition=secure),
        SetEnvironmentVariable("ROS_SECURITY_KEYSTORE", LaunchConfiguration("keystore"), condition=secure),
        OpaqueFunction(function=setup),
    ])
