"""A rogue ROS 2 participant for the network-exposure test: ``python tests/rogue_peer.py SECONDS``.

Run inside another network namespace with ``ROS_STATIC_PEERS`` naming the
root namespace's address on a veth link, it does what an attacker on a
neighbouring host would: it uses plain Fast DDS defaults (no profile of ours,
no ``node_main``), listens for ``pmu`` and answers every measurement it hears
with a 5 pu battery command stamped as the answer, and publishes 5 pu commands
at 50/s in any case. After SECONDS it prints one JSON line: the nodes it
discovered (and after how many seconds the first), how many measurements it
received, the most subscribers its command publisher ever matched and how
many commands it sent.
"""

from __future__ import annotations

import json
import sys
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor

from nni_msgs_adapter.ros import contract

#: What the rogue commands, pu: far beyond any battery limit of the loop under test.
ROGUE_POWER_PU = 5.0
#: Prefix of the JSON report line.
REPORT_PREFIX = "rogue report: "
_PUBLISH_PERIOD_S = 0.02


def main(seconds: float) -> dict:
    """Attack for ``seconds`` and return the report."""
    rclpy.init()
    node = rclpy.create_node("rogue")
    command = node.create_publisher(*contract.endpoint(contract.TOPIC_BATTERY_COMMAND))
    report = {"nodes": [], "first_node_s": None, "measurements": 0, "max_command_subscribers": 0,
              "commands_sent": 0}
    started = time.monotonic()

    def send(stamp_ns: int) -> None:
        command.publish(contract.command_message(stamp_ns, ROGUE_POWER_PU))
        report["commands_sent"] += 1

    def on_measurement(msg) -> None:
        report["measurements"] += 1
        send(contract.ns_from_time(msg.header.stamp))

    msg_class, name, qos = contract.endpoint(contract.TOPIC_PMU)
    node.create_subscription(msg_class, name, on_measurement, qos)
    node.create_timer(_PUBLISH_PERIOD_S, lambda: send(time.time_ns()))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.01)
        report["max_command_subscribers"] = max(report["max_command_subscribers"], command.get_subscription_count())
        found = {f"{ns.rstrip('/')}/{n}" for n, ns in node.get_node_names_and_namespaces() if n != "rogue"}
        if found and report["first_node_s"] is None:
            report["first_node_s"] = round(time.monotonic() - started, 3)
        report["nodes"] = sorted(set(report["nodes"]) | found)
    executor.shutdown(timeout_sec=1.0)
    node.destroy_node()
    rclpy.try_shutdown()
    return report


if __name__ == "__main__":
    print(REPORT_PREFIX + json.dumps(main(float(sys.argv[1]))), flush=True)
