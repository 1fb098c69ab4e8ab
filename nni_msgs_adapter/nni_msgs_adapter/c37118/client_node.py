"""C37.118 client node: reads any IEEE C37.118.2 PMU or PDC stream over TCP and feeds the controllers from it.

It connects to ``pmu_host:pmu_port`` (stream ``pmu_idcode``), asks for CFG-2,
turns data on and publishes each station's measurement on
``<namespace>/c37118/pmu`` (the contract's ``pmu`` layout: angle, speed
deviation, P_E; :mod:`.feed`), station k (data frame order) in the k-th of
``namespaces``, so that a controller started with ``measurement_topic
c37118/pmu`` in that namespace closes its loop through the stream: plant ->
its C37.118 server -> this node -> controller -> battery command. It lives
in nni_msgs_adapter beside the logger and replay because it adapts a wire
format into the message contract; the plant and the controller know nothing
of it. Reconnection, rejections and their reasons are the client core's
(:mod:`.client`); every rejection is counted on ``/diagnostics`` (status
``c37118_client``: WARN while one grows, ERROR while not connected), each
connection and loss logged in one line. With ``wait_for_subscribers`` it
connects only once every station's topic has that many subscribers (the
controllers, a recorder), so that a lockstep plant waiting for it finds the
loop closed.
"""

from __future__ import annotations

import functools
import math
import sys
import time

from nni_msgs_adapter.c37118.client import PdcClient
from nni_msgs_adapter.c37118.feed import StationFeeds
from nni_msgs_adapter.ros import command_auth, contract
from nni_msgs_adapter.ros.defaults import load_defaults
from nni_msgs_adapter.ros.loop_node import LoopNode, StampedPublisher
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.ros.ros_params import Spec, allow_tuning, locked_changes

#: How often, s, the node checks its subscribers before it connects, and logs the stream's events.
_POLL_S = 0.05
_EVENTS_S = 0.2
#: A wait for subscribers is said again on the log after this long, s.
_WAIT_LOG_S = 5.0


@functools.cache
def parameters() -> tuple[Spec, ...]:
    """The node's parameters, their defaults from ``config/c37118_client.yaml`` (read once, on first use)."""
    values = load_defaults("nni_msgs_adapter", "c37118_client.yaml", "c37118_client")
    return (
        Spec("pmu_host", values["pmu_host"], "Address of the PMU or PDC serving the stream."),
        Spec("pmu_port", values["pmu_port"], "Its TCP port (C37.118's customary port is 4712).", 1, 65535),
        Spec("pmu_idcode", values["pmu_idcode"], "The stream's IDCODE: frames of any other are rejected.", 1, 65534),
        Spec("mode", values["mode"], "The plant's time mode: realtime (SOC/FRACSEC are wall-clock UTC) or lockstep "
             "(simulated time from 2000-01-01T00:00:00Z, taken off again; no age bound).",
             choices=("realtime", "lockstep")),
        Spec("namespaces", values["namespaces"], "The generator namespace of each station in data frame order "
             "(absolute: /gen1 ...); empty: one station, in this node's own namespace.", array_of=str),
        Spec("angle_phasor", values["angle_phasor"], "The phasor whose angle is the rotor angle (by its CFG-2 "
             "name; empty: each station's first)."),
        Spec("power_analog", values["power_analog"], "The analog that is the electrical power P_E, pu (by its "
             "CFG-2 name; empty: none, the effort is NaN)."),
        Spec("plausible_step_rad", values["plausible_step_rad"], "A sample whose angle step since its station's "
             "last one differs from what its frequency explains by more than this is rejected (implausible), rad.",
             1e-4, math.pi),
        Spec("max_age_s", values["max_age_s"], "realtime: a frame older than this on arrival (from its SOC/FRACSEC) "
             "is rejected as stale, s (match the controllers' stamp_tolerance_s).", 1e-3, 1e6),
        Spec("wait_for_subscribers", values["wait_for_subscribers"], "Connect only once every station's topic has "
             "this many subscribers; 0: at once.", 0, 100),
        Spec("discovery_settle_s", values["discovery_settle_s"], "Then wait this long for the rest of discovery, s.",
             0.0, 10.0),
        allow_tuning(values["allow_tuning"]),
    )


class C37118ClientNode(LoopNode):
    """One stream in, one ``c37118/pmu`` topic per station out."""

    def __init__(self, **kwargs):
        super().__init__("c37118_client", parameters(), **kwargs)
        values = self._values = self.initial_values
        namespaces = list(values["namespaces"]) or [""]
        if len(set(namespaces)) != len(namespaces):
            raise ValueError(f"namespaces must be distinct, got {namespaces}")
        lockstep = values["mode"] == "lockstep"
        self._feeds = StationFeeds(len(namespaces), lockstep, values["angle_phasor"], values["power_analog"],
                                   values["plausible_step_rad"])
        # With the run's key each republished measurement is sealed as the plant seals its pmu (the stream itself
        # has no authentication: IEEE C37.118.2 defines none), so that a controller reading c37118/pmu acts on
        # this node's samples alone.
        key = command_auth.key_from_environment()
        mode = command_auth.LOCKSTEP_FLAG if lockstep else command_auth.REALTIME_FLAG
        self._pubs = [StampedPublisher(self, contract.TOPIC_C37118_PMU, ns, key=key, flag=mode) for ns in namespaces]
        self._client = PdcClient(values["pmu_host"], values["pmu_port"], values["pmu_idcode"], self._on_samples,
                                 max_age_ns=None if lockstep else round(values["max_age_s"] * 1e9),
                                 accept_config=self._feeds.config_fault)
        self._where = f"{values['pmu_host']}:{values['pmu_port']} (IDCODE {values['pmu_idcode']})"
        self._ready_since, self._logged_at = None, -_WAIT_LOG_S
        self._start_timer = self.create_timer(_POLL_S, self._try_start)
        self.create_timer(_EVENTS_S, self._log_events)

    def _validate(self, values: dict) -> dict:
        locked_changes(self._values, values, [spec.name for spec in parameters()], "once the node is up")
        return values

    def _install(self, values: dict) -> None:
        """Nothing changes: every parameter is read at start."""

    def _try_start(self) -> None:
        """Connect once the subscribers are there and discovery has settled."""
        wanted, now = self._values["wait_for_subscribers"], time.monotonic()
        counts = [pub.publisher.get_subscription_count() for pub in self._pubs]
        if min(counts) < wanted:
            self._ready_since = None
            if now - self._logged_at >= _WAIT_LOG_S:
                self._logged_at = now
                fewest = counts.index(min(counts))
                self.get_logger().info(f"waiting for {wanted} subscriber(s) on {self._pubs[fewest].publisher.topic_name}"
                                       f" (has {counts[fewest]}) before connecting to {self._where}")
            return
        self._ready_since = self._ready_since or now
        if now - self._ready_since < self._values["discovery_settle_s"]:
            return
        self._start_timer.cancel()
        self.get_logger().info(f"connecting to the C37.118 stream at {self._where}, {len(self._pubs)} station(s)")
        self._client.start()

    def _on_samples(self, samples) -> None:
        """One frame's samples (from the client's thread), each published at once in its station's namespace."""
        for measurement in self._feeds.take(samples, self._client.session.config, self._client.connections):
            self._pubs[measurement.index].publish(*measurement[1:])

    def _log_events(self) -> None:
        for line in self._client.events():
            self.get_logger().info(line)

    def publish_diagnostics(self) -> None:
        self.publish_status("c37118_client", *self._feeds.status(self._client.counters()))

    def close(self) -> None:
        self._client.stop()
        self._log_events()
        super().close()


def main(args=None) -> int:
    """``ros2 run nni_msgs_adapter c37118_client``."""
    return run_node(C37118ClientNode, args, prog="c37118_client")


if __name__ == "__main__":
    sys.exit(main())
