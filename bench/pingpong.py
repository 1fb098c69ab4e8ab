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
  lockstep plant's next sample waits for the command: the lockstep floor. As
  the plant's lockstep timeout, an instant unanswered after
  ``CHAINED_TIMEOUT_S`` is given up (counted unanswered) and the next sent:
  an echo can answer the first ping before its writer has discovered the
  ping's reader, and that pong is lost (seen once in three fan-outs to 10).
* ``ping --fanout N``: the fan-out to N echoes, as the network plant's to its
  N controllers: echo i runs in namespace ``/gen<i>`` (``--ros-args -r
  __ns:=/gen<i>``), and each instant sends one ping to every echo, stamped
  alike. An instant's round trip is its last pong's (chained: the next
  instant waits for all N, as the lockstep network plant's next sample does);
  each echo's own round trips and misses (a tick finding its previous ping
  unanswered) are kept too. Without ``--fanout``, one echo on the
  unnamespaced topics.
* ``echo --composed N``: the N echoes of a fan-out as N nodes (``/gen1``
  .. ``/genN``) of this one process on one executor, as
  ``composed_controllers`` runs N controllers: the floor of the composed
  deployment.

``ping`` prints :data:`STARTED_LINE` when it sends its first ping, then at the end one JSON line (round
trips in ns, misses, and its CPU time over the pinging: what the transport costs the plant's side) and exits.
Run with ``python -m bench.pingpong echo|ping ...`` from the repository root.
"""

from __future__ import annotations

import argparse
import json
import resource
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
#: What the ping prints when it sends its first ping (the echoes' CPU is counted from then).
STARTED_LINE = "pingpong: pinging"
#: Chained: an instant still unanswered after this long (wall time, s) is given up and the next one sent.
CHAINED_TIMEOUT_S = 1.0


class Echo(Node):
    """Publishes every ping back on the pong topic, unchanged (in ``namespace``, or the one given by -r __ns)."""

    def __init__(self, namespace: str | None = None):
        super().__init__("pingpong_echo", namespace=namespace)
        self._pub = self.create_publisher(JointState, PONG_TOPIC, contract.SAMPLE_QOS)
        self.create_subscription(JointState, PING_TOPIC, self._pub.publish, contract.SAMPLE_QOS)


def fanout_namespaces(count: int) -> list[str]:
    """The echoes' namespaces for a fan-out to ``count`` (as the network plant's generators); none without."""
    return [f"/gen{i + 1}" for i in range(count)] if count else [""]


class Ping(Node):
    """Sends pings (timed or chained) to every echo and records each round trip, ns."""

    def __init__(self, mode: str, rate_hz: float, duration_s: float, samples: int, fanout: int = 0):
        super().__init__("pingpong_ping")
        self.mode, self.period_s, self.duration_s, self.samples = mode, 1.0 / rate_hz, duration_s, samples
        namespaces = fanout_namespaces(fanout)
        self.round_trips_ns: list[int] = []
        self.echo_round_trips_ns: list[list[int]] = [[] for _ in namespaces]
        self.deadline_misses = 0
        self.echo_deadline_misses = [0] * len(namespaces)
        self.sent = 0
        self.done = Future()
        self._pending: dict[int, set[int]] = {}  # instant -> the echoes that still owe its pong
        self._outstanding = None
        self._pubs = [self.create_publisher(JointState, topic(ns, PING_TOPIC), contract.SAMPLE_QOS)
                      for ns in namespaces]
        self._subs = [self.create_subscription(JointState, topic(ns, PONG_TOPIC),
                                               lambda msg, index=i: self._on_pong(index, msg), contract.SAMPLE_QOS)
                      for i, ns in enumerate(namespaces)]
        self._matched_ns = None
        self._start_timer = self.create_timer(0.01, self._try_start)
        self._tick_timer = None

    def _now_ns(self) -> int:
        # Wall time: a ping is stamped with it, and the real controller (one of the echoes) drops
        # measurements whose stamps are implausible against its own wall clock.
        return time.time_ns()

    def _try_start(self) -> None:
        if (min(pub.get_subscription_count() for pub in self._pubs) < 1
                or min(sub.get_publisher_count() for sub in self._subs) < 1):
            return
        now = self._now_ns()
        self._matched_ns = self._matched_ns or now
        if now - self._matched_ns < 500_000_000:  # as the plant's discovery_settle_s: let discovery finish
            return
        self._start_timer.cancel()
        self._t0_ns = now
        self._cpu_start_s = cpu_time_s()
        print(STARTED_LINE, flush=True)
        if self.mode == "timed":
            self._tick_timer = self.create_timer(self.period_s, self._on_tick)
            # Ideal instants on the timer's own grid (its period in whole ns), as the plant's.
            self._period_ns = self._tick_timer.timer_period_ns
        else:
            self._tick_timer = self.create_timer(CHAINED_TIMEOUT_S / 10, self._on_watchdog)
        self._send(now)

    def _send(self, instant_ns: int) -> None:
        """One ping to every echo, stamped with (and timed from) ``instant_ns``."""
        self._outstanding = instant_ns
        self._pending[instant_ns] = set(range(len(self._pubs)))
        message = contract.pmu_message(instant_ns, 0.9, 0.0, 0.8)
        for pub in self._pubs:
            pub.publish(message)
        self.sent += 1

    def _on_tick(self) -> None:
        now = self._now_ns()
        owing = self._pending.get(self._outstanding, ())
        if owing:
            self.deadline_misses += 1
            for index in owing:
                self.echo_deadline_misses[index] += 1
        if (now - self._t0_ns) * 1e-9 >= self.duration_s:
            self._tick_timer.cancel()
            self.done.set_result(True)
            return
        self._send(self._t0_ns + (now - self._t0_ns) // self._period_ns * self._period_ns)

    def _on_watchdog(self) -> None:
        """Chained: give up the instant in flight once it is older than ``CHAINED_TIMEOUT_S``; send the next."""
        instant = self._outstanding
        if instant in self._pending and self._now_ns() - instant > CHAINED_TIMEOUT_S * 1e9:
            del self._pending[instant]
            self._send_next()

    def _send_next(self) -> None:
        """Chained: the next instant, or the end once ``samples`` instants were sent."""
        if self.sent >= self.samples:
            self._tick_timer.cancel()
            self.done.set_result(True)
        else:
            self._send(self._now_ns())

    def _on_pong(self, index: int, msg) -> None:
        arrival = self._now_ns()
        stamp = contract.ns_from_time(msg.header.stamp)
        owing = self._pending.get(stamp)
        if owing is None or index not in owing:
            return
        owing.remove(index)
        self.echo_round_trips_ns[index].append(arrival - stamp)
        if owing:
            return
        del self._pending[stamp]
        self.round_trips_ns.append(arrival - stamp)
        if self.mode == "chained":
            self._send_next()

    def close(self) -> None:
        lost = self.sent - len(self.round_trips_ns)
        print(RESULT_PREFIX + json.dumps({
            "mode": self.mode, "rate_hz": 1.0 / self.period_s, "sent": self.sent, "lost_or_unanswered": lost,
            "deadline_misses": self.deadline_misses, "round_trips_ns": self.round_trips_ns,
            "echoes": len(self._pubs), "echo_round_trips_ns": self.echo_round_trips_ns,
            "echo_deadline_misses": self.echo_deadline_misses,
            "wall_s": (self._now_ns() - self._t0_ns) * 1e-9 if self._matched_ns else None,
            "cpu_s": cpu_time_s() - self._cpu_start_s if self._matched_ns else None,
        }), flush=True)


def cpu_time_s() -> float:
    """This process's user and system CPU time so far, all threads (Fast DDS's too), s."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def topic(namespace: str, name: str) -> str:
    """``name`` under ``namespace`` (absolute), or relative as given when there is none."""
    return f"{namespace}/{name}" if namespace else name


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.pingpong")
    parser.add_argument("role", choices=("echo", "ping"))
    parser.add_argument("--mode", choices=("timed", "chained"), default="timed")
    parser.add_argument("--rate", type=float, default=100.0, help="timed: pings/s")
    parser.add_argument("--duration", type=float, default=30.0, help="timed: seconds")
    parser.add_argument("--samples", type=int, default=1000, help="chained: round trips")
    parser.add_argument("--fanout", type=int, default=0,
                        help="ping: fan out to echoes in namespaces /gen1 .. /genN (default: one, unnamespaced)")
    parser.add_argument("--composed", type=int, default=0, metavar="N",
                        help="echo: N echo nodes in /gen1 .. /genN, all in this process on one executor")
    args, ros_args = parser.parse_known_args(argv)
    if args.fanout < 0 or args.composed < 0:
        parser.error(f"--fanout and --composed take a count >= 0, got {args.fanout} and {args.composed}")
    if args.composed and args.role != "echo":
        parser.error("--composed applies to echo")
    if args.role == "echo":
        if args.composed:
            return run_node(lambda: [Echo(ns) for ns in fanout_namespaces(args.composed)], ros_args,
                            prog="pingpong echo")
        return run_node(Echo, ros_args, prog="pingpong echo")
    return run_node(lambda: Ping(args.mode, args.rate, args.duration, args.samples, args.fanout), ros_args,
                    prog="pingpong ping")


if __name__ == "__main__":
    sys.exit(main())
