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
(loopback by default) with IDCODE ``pmu_idcode``. All topics are relative, so the namespace
argument puts one generator's loop under /<namespace>. ``measurements:=c37118``
feeds the controller through that stream (on port 4712 when ``pmu_port`` gives
none) and a ``c37118_client`` node (as ``nni-demo --measurements c37118``;
the rate must be one C37.118 allows). With ``duration_s > 0``
the launch shuts down when the plant exits: the controller and the logger get
SIGINT, and the logger finishes the recording.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import EnvironmentVariable, LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

from nni_battery_controller.demo_c37118 import LAUNCH_PORT, STREAM_TOPIC, client_parameters
from nni_msgs_adapter.ros.processes import parameter_text
from nni_msgs_adapter.ros.defaults import load_defaults

#: Launch arguments that are plant parameters (package nni_plant_sim, config/plant.yaml).
PLANT_ARGUMENTS = (
    "mode", "pmu_rate_hz", "duration_s", "scenario", "delta0_rad", "speed0_rad_s", "step_p_mech_pu",
    "step_duration_s", "fault_p_max_pu", "clearing_time_s", "damping_pu", "battery_rating_pu",
    "pmu_port", "pmu_host", "pmu_idcode",
)
#: Launch arguments that are controller parameters (package nni_battery_controller, config/controller.yaml).
CONTROLLER_ARGUMENTS = ("tau_s", "gain_k", "gain_l", "alpha", "battery_limit_pu")
#: Model parameters shared by the plant and the controller's model of it (the plant's defaults).
MODEL_ARGUMENTS = ("p_mech_pu", "p_max_pu", "inertia_h_s", "f0_hz")
#: Launch arguments that are logger parameters (package nni_msgs_adapter, config/mcap_logger.yaml).
LOGGER_ARGUMENTS = ("output_path",)
#: (package, config file, node name) of each node.
CONFIG = {
    "plant": ("nni_plant_sim", "plant.yaml", "plant"),
    "controller": ("nni_battery_controller", "controller.yaml", "controller"),
    "mcap_logger": ("nni_msgs_adapter", "mcap_logger.yaml", "mcap_logger"),
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


def generate_launch_description():
    config = {name: LaunchConfiguration(name)
              for name in (*PLANT_ARGUMENTS, *MODEL_ARGUMENTS, *CONTROLLER_ARGUMENTS, *LOGGER_ARGUMENTS)}
    namespace = LaunchConfiguration("namespace")
    secure = IfCondition(LaunchConfiguration("use_security"))
    through_stream = ["'", LaunchConfiguration("measurements"), "' == 'c37118'"]

    def chosen(stream, ros):
        """``stream`` with measurements:=c37118, else ``ros`` (Python literals, or substitutions)."""
        return PythonExpression([*stream, " if ", *through_stream, " else ", *ros])

    # Through the stream: served (on LAUNCH_PORT when pmu_port gives none), FREQ as floats, waiting for the client.
    port = config["pmu_port"]
    stream = {"pmu_port": chosen([f"({LAUNCH_PORT} if int('", port, "') < 0 else int('", port, "'))"], [port]),
              "pmu_freq_format": chosen(["'float'"], ["'integer'"]), "pmu_wait_for_pdcs": chosen(["1"], ["0"])}
    plant = Node(package="nni_plant_sim", executable="plant_node", name="plant", namespace=namespace,
                 ros_arguments=["--enclave", "/nni/plant"],
                 parameters=[config_file("plant"),
                             {**{name: config[name] for name in (*PLANT_ARGUMENTS, *MODEL_ARGUMENTS)},
                              # the controller and the logger on pmu; through the stream the logger, and the client
                              "wait_for_subscribers": chosen(["1"], ["2"]), **stream}])
    controller = Node(package="nni_battery_controller", executable="controller_node", name="controller",
                      namespace=namespace, ros_arguments=["--enclave", "/nni/controller"],
                      parameters=[config_file("controller"),
                                  {**{name: config[name] for name in (*CONTROLLER_ARGUMENTS, *MODEL_ARGUMENTS)},
                                   "sample_rate_hz": config["pmu_rate_hz"],
                                   "measurement_topic": chosen([repr(STREAM_TOPIC)], ["'pmu'"])}])
    # It connects once the controller and the logger read its c37118/pmu.
    client = Node(package="nni_msgs_adapter", executable="c37118_client", name="c37118_client", namespace=namespace,
                  condition=IfCondition(PythonExpression(through_stream)),
                  ros_arguments=["--enclave", "/nni/c37118_client"],
                  parameters=[client_parameters(stream["pmu_port"], config["mode"], 2, host=config["pmu_host"],
                                                idcode=config["pmu_idcode"])])
    logger = Node(package="nni_msgs_adapter", executable="mcap_logger", name="mcap_logger", namespace=namespace,
                  ros_arguments=["--enclave", "/nni/mcap_logger"],
                  parameters=[config_file("mcap_logger"), {name: config[name] for name in LOGGER_ARGUMENTS}])
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="", description="namespace of this generator's nodes"),
        *arguments("plant", (*PLANT_ARGUMENTS, *MODEL_ARGUMENTS)),
        *arguments("controller", CONTROLLER_ARGUMENTS),
        *arguments("mcap_logger", LOGGER_ARGUMENTS),
        DeclareLaunchArgument("measurements", default_value="ros",
                              description="ros: the controller reads the plant's pmu; c37118: the plant's C37.118.2 "
                                          "stream on pmu_port (4712 if none), through the c37118_client node"),
        DeclareLaunchArgument("use_security", default_value="false",
                              description="true: SROS2 (Enforce), each node in its enclave /nni/<node> of the "
                                          "keystore made by scripts/sros2_keystore; ROS 2 Jazzy installs only"),
        DeclareLaunchArgument("keystore", default_value=EnvironmentVariable("ROS_SECURITY_KEYSTORE", default_value=""),
                              description="SROS2 keystore folder"),
        SetEnvironmentVariable("ROS_SECURITY_ENABLE", "true", condition=secure),
        SetEnvironmentVariable("ROS_SECURITY_STRATEGY", "Enforce", condition=secure),
        SetEnvironmentVariable("ROS_SECURITY_KEYSTORE", LaunchConfiguration("keystore"), condition=secure),
        logger,
        controller,
        client,
        plant,
        # The run is over when the plant exits (duration_s > 0): stop the others, finish the recording.
        RegisterEventHandler(OnProcessExit(target_action=plant, on_exit=[
            EmitEvent(event=Shutdown(reason="the plant finished its run"))])),
    ])
