"""A rogue process on the loop's ROS domain that attacks the measurement path (issue 31), every attack at once.

    python tests/rogue_measurements.py --topics /pmu [/gen1/pmu ...] --period 0.02 --status /plant

For every measurement the plant sends on a topic it listens to (sealed: it cannot make one of its own), it
sends at once:

* **same-stamp race**: three copies at the same stamp, the angle mirrored about the message's own and the speed
  negated, carrying the real message's seal (which then does not verify);
* **one-period-ahead injection**: one mirrored copy stamped one period later, unsealed;
* **replay**: the real message's bytes sent again as they are, and those of the measurement five before;
* **forged /clock**: a tick 100 s ahead of the measurement, one at its stamp and one five periods before (it is a
  /clock writer from the start);
* **forged run_ended**: every tenth measurement, a plant status under ``--status`` saying the run has ended.

And **flood**: each of its own fakes that comes back to it makes one more, up to ``--flood`` in all. At SIGINT or
SIGTERM it prints one JSON line of what it sent (``rogue: {...}``) and exits 0.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rosgraph_msgs.msg import Clock

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.node_main import select_dds_profile


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--topics", nargs="+", default=["/pmu"])
    parser.add_argument("--period", type=float, default=0.02)
    parser.add_argument("--status", action="append", default=[], help="hardware_id of a plant status to forge")
    parser.add_argument("--flood", type=int, default=500)
    args = parser.parse_args()
    period_ns = round(args.period * 1e9)
    select_dds_profile(os.environ)  # the loop's own transports (loopback and shared memory): a local process
    rclpy.init()
    node = rclpy.create_node("rogue")
    sent = {"real_seen": 0, "race": 0, "ahead": 0, "replays": 0, "flood": 0, "clock": 0, "statuses": 0}
    clock = node.create_publisher(*contract.endpoint(contract.TOPIC_CLOCK))
    diagnostics = node.create_publisher(*contract.endpoint(contract.TOPIC_DIAGNOSTICS))

    def attack(topic: str):
        qos = contract.endpoint(contract.TOPIC_PMU)[2]
        publisher = node.create_publisher(contract.TOPICS[contract.TOPIC_PMU][1], topic, qos)
        captured: list[bytes] = []
        own: set = set()  # (stamp, angle) of its race copies, which carry a seal too

        def fake(stamp_ns, delta, speed, p_elec, seal=None):
            return contract.pmu_message(stamp_ns, -delta, -speed, p_elec, seal)

        def on_message(data: bytes) -> None:
            try:
                (stamp_ns, delta, speed), efforts, seal = contract.pmu_from_bytes(data)
            except contract.ContractError:
                return
            p_elec = efforts[0] if efforts else 0.0
            if seal is None:  # one of its own: feed the flood
                if sent["flood"] < args.flood:
                    sent["flood"] += 1
                    publisher.publish(fake(stamp_ns + period_ns, delta, speed, p_elec))
                return
            if data in captured or (stamp_ns, delta) in own:
                return  # a replay or a race copy of its own coming back
            sent["real_seen"] += 1
            own.add((stamp_ns, -delta))
            for _ in range(3):
                publisher.publish(fake(stamp_ns, delta, speed, p_elec, seal))
            sent["race"] += 3
            publisher.publish(fake(stamp_ns + period_ns, delta, speed, p_elec))
            sent["ahead"] += 1
            publisher.publish(data)
            if len(captured) >= 5:
                publisher.publish(captured[-5])
                sent["replays"] += 1
            sent["replays"] += 1
            captured.append(data)
            for tick_ns in (stamp_ns + 100 * 10**9, stamp_ns, stamp_ns - 5 * period_ns):
                clock.publish(Clock(clock=contract.time_from_ns(tick_ns)))
            sent["clock"] += 3
            if sent["real_seen"] % 10 == 1:
                for hardware_id in args.status:
                    diagnostics.publish(contract.diagnostics_message(
                        stamp_ns, "plant", "OK", "run ended", {contract.RUN_ENDED: True}, hardware_id))
                    sent["statuses"] += 1

        node.create_subscription(contract.TOPICS[contract.TOPIC_PMU][1], topic, on_message, qos, raw=True)

    for topic in args.topics:
        attack(topic)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.append(1))
    print("rogue: ready", flush=True)
    try:
        while not stop:
            executor.spin_once(timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    print("rogue: " + json.dumps(sent), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
