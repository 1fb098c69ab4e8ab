"""Replay node: publishes a planned recording (:class:`replay_ros.Playback`) with its original timing.

The ROS half of ``nni-replay``; the command line is in :mod:`nni_battery_controller.replay`,
the reading in :mod:`replay_load` and the planning in :mod:`replay_ros`, which imports
this module only for ROS playback. Messages go out as recorded CDR bytes (``publish`` of
``bytes``), on their recorded topic names, with the planned QoS. One timer drives the
playback: each callback publishes every message that is due and re-arms the
timer for the next one, so nothing sleeps and signals are handled at once.
Scheduling uses the monotonic clock, never ROS time (which ``--clock`` itself
may be driving).

Before the first message it waits for its audience: ``wait_for_subscribers`` (N) distinct
subscriber nodes on the replayed topics (or on ``wait_topic`` only), each matched by the
replay's publisher on every replayed topic the graph shows it subscribing to, and then
``_DISCOVERY_SETTLE_S`` more with nothing new appearing (the subscriber's side of discovery
matches the replay's writers too; a reader drops data from a writer it has not matched yet).
A subscriber of one topic is enough; none is asked to subscribe to every topic. While it
waits it logs, once a second, what it waits for. N = 0 starts at once.
"""

from __future__ import annotations

import time

from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.recording.mcap_io import message_class

#: Wait between subscriber checks before the start, s.
_START_POLL_S = 0.05
#: Once the wanted subscribers are matched, wait this long so that their side of DDS
#: discovery has matched the replay's publishers too (a reader drops data from a writer
#: it has not matched yet), s.
_DISCOVERY_SETTLE_S = 0.3
#: /clock publication rate with --clock, Hz (ros2 bag play --clock's default).
_CLOCK_RATE_HZ = 40.0
#: How often the wait says what it waits for, s.
_WAIT_REPORT_S = 1.0


class ReplayNode(Node):
    """Publishes a :class:`replay_ros.Playback` at ``rate`` times its recorded pace.

    ``done`` completes after the last message (never with ``loop``); ``close()`` waits up
    to two seconds for reliable subscribers to acknowledge what was sent.
    """

    def __init__(self, playback, *, rate: float = 1.0, loop: bool = False, clock: bool = False,
                 wait_for_subscribers: int = 0, wait_topic: str | None = None, **kwargs):
        super().__init__("replay", **kwargs)
        self._playback = playback
        self._rate = rate
        self._loop = loop
        self._wait_for = wait_for_subscribers
        self._wait_topics = [wait_topic] if wait_topic is not None else list(playback.topics)
        self._audience = None        # what the graph showed at the last check
        self._next_report_ns = 0
        self.done = Future()
        self._publishers_by_topic = {
            topic: self.create_publisher(message_class(type_name), topic, qos.to_rclpy())
            for topic, (type_name, qos) in playback.topics.items()
        }
        self._clock_pub = self.create_publisher(*contract.endpoint(contract.TOPIC_CLOCK)) if clock else None
        self._settled_at_ns = None
        self._pass_start_ns = None  # monotonic time of the current pass's start point
        self._next = 0              # index into playback.timed
        self._timer = self.create_timer(_START_POLL_S, self._on_timer)
        if clock:
            self.create_timer(1.0 / _CLOCK_RATE_HZ, self._publish_clock)

    def _on_timer(self) -> None:
        if self._pass_start_ns is None:
            if not self._subscribers_ready():
                return
            self._start_pass()
        self._publish_due()

    def _subscribers_ready(self) -> bool:
        if self._wait_for <= 0:
            return True
        audience, unmatched = self._graph_audience()
        now_ns = time.monotonic_ns()
        if len(audience) < self._wait_for or unmatched or audience != self._audience:
            self._audience = audience if len(audience) >= self._wait_for and not unmatched else None
            self._settled_at_ns = now_ns + int(_DISCOVERY_SETTLE_S * 1e9)
            if now_ns >= self._next_report_ns:
                self._next_report_ns = now_ns + int(_WAIT_REPORT_S * 1e9)
                self.get_logger().info(
                    f"waiting for {self._wait_for} subscriber(s) on {', '.join(self._wait_topics)}: "
                    f"{len(audience)} seen" + (f", not yet matched on {', '.join(sorted(unmatched))}" if unmatched else ""))
            return False
        return now_ns >= self._settled_at_ns

    def _graph_audience(self) -> tuple[frozenset, set]:
        """Subscriber nodes of the wait topics, and the replayed topics where one is not matched yet.

        A node counts once however many topics it takes; for each replayed topic it subscribes to,
        the publisher's matched count must have caught up with the subscriptions the graph shows.
        """
        nodes = set()
        for topic in self._wait_topics:
            nodes |= {(info.node_namespace, info.node_name) for info in self.get_subscriptions_info_by_topic(topic)}
        unmatched = set()
        for topic, publisher in self._publishers_by_topic.items():
            infos = [info for info in self.get_subscriptions_info_by_topic(topic)
                     if (info.node_namespace, info.node_name) in nodes]
            if infos and publisher.get_subscription_count() < len(infos):
                unmatched.add(topic)
        return frozenset(nodes), unmatched

    def _start_pass(self) -> None:
        self._pass_start_ns = time.monotonic_ns()
        self._next = 0
        for record in self._playback.prelude:
            self._publishers_by_topic[record.topic].publish(record.cdr_bytes)

    def _publish_due(self) -> None:
        timed = self._playback.timed
        elapsed_ns = (time.monotonic_ns() - self._pass_start_ns) * self._rate
        while self._next < len(timed) and timed[self._next][0] <= elapsed_ns:
            record = timed[self._next][1]
            self._publishers_by_topic[record.topic].publish(record.cdr_bytes)
            self._next += 1
        if self._next == len(timed):
            if not self._loop:
                self._timer.cancel()
                self.done.set_result(True)
                return
            self._start_pass()
            elapsed_ns = 0
        wait_ns = (timed[self._next][0] - elapsed_ns) / self._rate
        self._timer.timer_period_ns = max(int(wait_ns), 1)
        self._timer.reset()

    def _publish_clock(self) -> None:
        if self._pass_start_ns is None or self.done.done():
            return
        elapsed_ns = (time.monotonic_ns() - self._pass_start_ns) * self._rate
        msg = Clock()
        msg.clock = contract.time_from_ns(self._playback.start_log_time_ns + int(elapsed_ns))
        self._clock_pub.publish(msg)
