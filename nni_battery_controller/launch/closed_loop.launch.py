"""Launch the closed loop of one generator: plant, controller and MCAP logger.

    ros2 launch nni_battery_controller closed_loop.launch.py \
        namespace:=gen1 mode:=realtime battery_limit_pu:=0.3 output_path:=run.mcap

Each node reads its defaults from its package's config/*.yaml; the arguments
below override the ones people change most. All topics are relative, so the
namespace argument puts one generator's loop under /<namespace>.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import EnvironmentVariable, LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    args = {
        "namespace": ("", "namespace of this generator's nodes and topics"),
        "mode": ("realtime", "realtime (wall clock) or lockstep (simulated /clock)"),
        "pmu_rate_hz": ("50.0", "PMU reporting rate, frames/s"),
        "battery_limit_pu": ("0.3", "battery power limit b, pu (.inf for unlimited)"),
        "duration_s": ("0.0", "simulated seconds before the plant exits; 0 runs until stopped"),
        "output_path": ("", "MCAP file of the run; empty: a dated name in the working directory"),
        "use_security": ("false", "true: SROS2 (Enforce), each node in its enclave /nni/<node> of the keystore "
                                  "made by scripts/sros2_keystore; ROS 2 Jazzy installs only"),
        "keystore": (EnvironmentVariable("ROS_SECURITY_KEYSTORE", default_value=""), "SROS2 keystore folder"),
    }
    config = {name: LaunchConfiguration(name) for name in args}
    secure = IfCondition(config["use_security"])
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in args.items()),
        SetEnvironmentVariable("ROS_SECURITY_ENABLE", "true", condition=secure),
        SetEnvironmentVariable("ROS_SECURITY_STRATEGY", "Enforce", condition=secure),
        SetEnvironmentVariable("ROS_SECURITY_KEYSTORE", config["keystore"], condition=secure),
        Node(package="nni_msgs_adapter", executable="mcap_logger", name="mcap_logger",
             ros_arguments=["--enclave", "/nni/mcap_logger"],
             namespace=config["namespace"], parameters=[{"output_path": config["output_path"]}]),
        Node(package="nni_battery_controller", executable="controller_node", name="controller",
             ros_arguments=["--enclave", "/nni/controller"], namespace=config["namespace"],
             parameters=[{"battery_limit_pu": config["battery_limit_pu"],
                          "sample_rate_hz": config["pmu_rate_hz"]}]),
        Node(package="nni_plant_sim", executable="plant_node", name="plant", namespace=config["namespace"],
             ros_arguments=["--enclave", "/nni/plant"],
             parameters=[{"mode": config["mode"], "pmu_rate_hz": config["pmu_rate_hz"],
                          "duration_s": config["duration_s"], "wait_for_subscribers": 2}]),
    ])
