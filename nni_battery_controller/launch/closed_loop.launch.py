"""Launch the closed loop of one generator: plant, controller and MCAP logger.

    ros2 launch nni_battery_controller closed_loop.launch.py \
        namespace:=gen1 mode:=realtime battery_limit_pu:=0.3 output_path:=run.mcap

Each node reads its defaults from its package's config/*.yaml; the arguments
below override the ones people change most. All topics are relative, so the
namespace argument puts one generator's loop under /<namespace>.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    args = {
        "namespace": ("", "namespace of this generator's nodes and topics"),
        "mode": ("realtime", "realtime (wall clock) or lockstep (simulated /clock)"),
        "pmu_rate_hz": ("50.0", "PMU reporting rate, frames/s"),
        "battery_limit_pu": ("0.3", "battery power limit b, pu (.inf for unlimited)"),
        "duration_s": ("0.0", "simulated seconds before the plant exits; 0 runs until stopped"),
        "output_path": ("", "MCAP file of the run; empty: a dated name in the working directory"),
    }
    config = {name: LaunchConfiguration(name) for name in args}
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in args.items()),
        Node(package="nni_msgs_adapter", executable="mcap_logger", name="mcap_logger",
             namespace=config["namespace"], parameters=[{"output_path": config["output_path"]}]),
        Node(package="nni_battery_controller", executable="controller_node", name="controller",
             namespace=config["namespace"],
             parameters=[{"battery_limit_pu": config["battery_limit_pu"],
                          "sample_rate_hz": config["pmu_rate_hz"]}]),
        Node(package="nni_plant_sim", executable="plant_node", name="plant", namespace=config["namespace"],
             parameters=[{"mode": config["mode"], "pmu_rate_hz": config["pmu_rate_hz"],
                          "duration_s": config["duration_s"], "wait_for_subscribers": 2}]),
    ])
