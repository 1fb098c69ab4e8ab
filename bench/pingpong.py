"""Bare rclpy ping-pong: the floor of the closed loop on this stack.

Two processes, the same message type (sensor_msgs/JointState, filled as a PMU
measurement) and QoS (``contract.SAMPLE_QOS``) as the loop, the same
executor loop as the nodes (``node_main.run_node``), and no
work in between: ``echo`` publishes every message it receives straight back,
``ping`` measures the round trip.

* ``ping --mode timed --rate R``: a wall-clock timer publishes R pings/s, as
  the realtime plant publishes measurements, each stamped with its ideal
  instant t0 + k / R and timed from it (the plant's latency runs from its
  measurement instant, so the timer's lateness counts in both); a deadline
  miss is a tick that finds the previous ping unanswered (the plant's
  definition).
* ``ping --mode chained``: each pong triggers the next ping at once, as the
  lockstep plant's next sample waits for the command: the lockstep floor.

``ping`` prints one JSON line (round trips in ns, misses) and exits.
Run with ``python -m bench.pingpong echo|ping ...`` from the repository root.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.node_main import run_node

PING_TOPIC = "bench/ping"
PONG_TOPIC = "bench/pong"
RESULT_PREFIX = "PINGPONG "


class Echo(Node):
    """Publishes every ping back on the pong topic, unchanged."""

    def __init__(self):
        super().__init__("pingpong_echo")
        self._pub = self.create_publisher(JointState, PONG_TOPIC, contract.SAMPLE_QOS)
        self.create_subscription(JointState, PING_TOPIC, self._pub.publish, contract.SAMPLE_QOS)


class Ping(Node):
    """Sends pings (timed or chained) and records each round trip, ns."""

    def __init__(self, mode: str, rate_hz: float, duration_s: float, samples: int):
        super().__init__("pingpong_ping")
        self.mode, self.period_s, self.duration_s, self.samples = mode, 1.0 / rate_hz, duration_s, samples
        self.round_trips_ns: list[int] = []
        self.deadline_misses = 0
        self.sent = 0
        self.done = Future()
        self._sent_ns: dict[int, int] = {}
        self._outstanding = None
        self._pub = self.create_publisher(JointState, PING_TOPIC, contract.SAMPLE_QOS)
        self._sub = self.create_subscription(JointState, PONG_TOPIC, self._on_pong, contract.SAMPLE_QOS)
        self._matched_ns = None
        self._start_timer = self.create_timer(0.01, self._try_start)
        self._tick_timer = None

    def _now_ns(self) -> int:
        # Wall time: a ping is stamped with it, and the real controller (one of the echoes) drops
        # measurements whose stamps are implausible against its own wall clock.
        return time.time_ns()

    def _try_start(self) -> None:
        if self._pub.get_subscription_count() < 1 or self._sub.get_publisher_count() < 1:
            return
        now = self._now_ns()
        self._matched_ns = self._matched_ns or now
        if now - self._matched_ns < 500_000_000:  # as the plant's discovery_settle_s: let discovery finish
            return
        self._start_timer.cancel()
        self._t0_ns = now
        if self.mode == "timed":
            self._tick_timer = self.create_timer(self.period_s, self._on_tick)
            # Ideal instants on the timer's own grid (its period in whole ns), as the plant's.
            self._period_ns = self._tick_timer.timer_period_ns
        self._send(now)

    def _send(self, instant_ns: int) -> None:
        """A ping stamped with (and timed from) ``instant_ns``."""
        self._outstanding = instant_ns
        self._sent_ns[instant_ns] = instant_ns
        self._pub.publish(contract.pmu_message(instant_ns, 0.9, 0.0, 0.8))
        self.sent += 1

    def _on_tick(self) -> None:
        now = self._now_ns()
        if self._outstanding is not None:
            self.deadline_misses += 1
        if (now - self._t0_ns) * 1e-9 >= self.duration_s:
            self._tick_timer.cancel()
            self.done.set_result(True)
            return
        self._send(self._t0_ns + (now - self._t0_ns) // self._period_ns * self._period_ns)

    def _on_pong(self, msg) -> None:
        arrival = self._now_ns()
        stamp = contract.ns_from_time(msg.header.stamp)
        sent = self._sent_ns.pop(stamp, None)
        if sent is None:
            return
        self.round_trips_ns.append(arrival - sent)
        if stamp == self._outstanding:
            self._outstanding = None
        if self.mode == "chained":
            if len(self.round_trips_ns) >= self.samples:
                self.done.set_result(True)
            else:
                self._send(self._now_ns())

    def close(self) -> None:
        lost = self.sent - len(self.round_trips_ns)
        print(RESULT_PREFIX + json.dumps({
            "mode": self.mode, "rate_hz": 1.0 / self.period_s, "sent": self.sent, "lost_or_unanswered": lost,
            "deadline_misses": self.deadline_misses, "round_trips_ns": self.round_trips_ns,
            "wall_s": (self._now_ns() - self._t0_ns) * 1e-9 if self._matched_ns else None,
        }), flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.pingpong")
    parser.add_argument("role", choices=("echo", "ping"))
    parser.add_argument("--mode", choices=("timed", "chained"), default="timed")
    parser.add_argument("--rate", type=float, default=100.0, help="timed: pings/s")
    parser.add_argument("--duration", type=float, default=30.0, help="timed: seconds")
    parser.add_argument("--samples", type=int, default=1000, help="chained: round trips")
    args, ros_args = parser.parse_known_args(argv)
    if args.role == "echo":
        return run_node(Echo, ros_args, prog="pingpong echo")
    return run_node(lambda: Ping(args.mode, args.rate, args.duration, args.samples), ros_args, prog="pingpong ping")


if __name__ == "__main__":
    sys.exit(main())
