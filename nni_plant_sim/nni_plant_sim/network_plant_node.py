"""Network plant node: every generator of a multi-machine case in one process, each reporting like the SMIB plant.

One coupled physical system (:mod:`.network`, :mod:`.network_scenarios`,
:func:`.integrators.advance`) integrated in lockstep by the reporting core
(:class:`.reporting.LockstepStepper`, one :class:`.reporting.CommandChannel`
per generator). Generator i (case order) lives under the namespace ``/gen<i>``
(``gen1`` .. ``genN``; the log names which machine is which) and has the SMIB
plant's message contract there: ``/gen<i>/pmu``, ``/gen<i>/plant/state``,
``/gen<i>/battery/command``, and its own status ``gen<i>/plant`` on
``/diagnostics``. Powers on the wire (P_E, P_ST, the battery rating) are in
pu of the machine's rating, so one generator's topics look like a SMIB's;
angles are the case's (the slack's reference at the load flow).

Lockstep: a sample advances only when every generator's controller has
answered it; each missing answer times out after ``lockstep_timeout_s`` (zero
power for that generator, counted in its ``deadline_misses``). Realtime
(:class:`.reporting.RealtimeReporter`): the PMU grid on the wall clock as for
the SMIB, each generator's command in force from its arrival, one older than
``command_timeout_s`` decays to zero. Scenarios: ``bus_fault`` and ``line_trip``
(the offline ``nni-simulate --case`` option names as parameters), starting
at t = 0 from the pre-fault equilibrium. No PMU noise.
"""

from __future__ import annotations

import json
import math
import sys

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.ros.ros_params import Spec, check_choices, current_values, declare, install_validation, locked_changes
from nni_plant_sim.cases import CASES, load_network
from nni_plant_sim.integrators import advance
from nni_plant_sim.network import electrical_power
from nni_plant_sim.network_scenarios import BusFault, LineTrip
from nni_plant_sim.plant_config import link_from, link_parameters
from nni_plant_sim.reporting import CommandChannel, LockstepStepper, RealtimeReporter, SubscriberWait

#: Prefix of the JSON line with every generator's final diagnostics values, printed at exit.
SUMMARY_PREFIX = "network_plant_node summary: "

PARAMETERS = (
    Spec("case", "kundur_two_area", "Shipped test system.", choices=tuple(CASES)),
    Spec("mode", "lockstep", "Time mode: lockstep (simulated /clock) or realtime (wall clock).",
         choices=("lockstep", "realtime")),
    Spec("scenario", "bus_fault", "Disturbance at t = 0.", choices=("bus_fault", "line_trip")),
    Spec("fault_bus", 7, "bus_fault: the faulted bus (case numbering).", 1, 100000),
    Spec("fault_r", 0.0, "bus_fault: fault resistance, pu (system base).", 0.0, 1e6),
    Spec("fault_x", 0.0, "bus_fault: fault reactance, pu (system base).", -1e6, 1e6),
    Spec("clearing_time", 0.1, "bus_fault: clearing time, s.", 1e-6, 1e3),
    Spec("trip_line", "", "Branch that opens (at clearing, or at t = 0 for line_trip): 'FROM TO [CIRCUIT]'; "
         "empty for none."),
    Spec("pmu_rate_hz", 50.0, "PMU reporting rate, frames/s.", 10.0, 1000.0),
    Spec("integration_step_s", 1e-3, "Largest RK4 step, s.", 1e-6, 0.1),
    Spec("duration_s", 10.0, "Simulated seconds to run, then exit.", 1e-3, 1e9),
    Spec("battery_rating_pu", 1.0, "Battery inverter rating at each generator, pu of its machine rating: commands are "
         "clipped to +-rating.", 0.0, 1e3),
    Spec("command_timeout_s", 0.1, "realtime: a battery command older than this (from its measurement's instant) is "
         "dropped, and the one in force decays to zero, s.", 1e-3, 100.0),
    Spec("lockstep_timeout_s", 1.0, "Wall time to wait for a generator's command before applying zero, s.", 1e-3, 100.0),
    Spec("wait_for_subscribers", 1, "Start when every generator's pmu has this many subscribers and its "
         "battery/command a publisher.", 1, 100),
    Spec("wait_timeout_s", 60.0, "Give up (error, non-zero exit) after waiting this long for them, s.", 0.1, 1e6),
    Spec("discovery_settle_s", 0.5, "Once they are there, wait this long for the rest of discovery, s.", 0.0, 10.0),
    *link_parameters({"link_delay_s": 0.0, "link_jitter_s": 0.0, "link_loss": 0.0, "link_seed": 0}),  # every generator
)


def parameters() -> tuple:
    """The node's parameter table (what ``--help`` lists)."""
    return PARAMETERS


#: The parameters of a bus fault only: given (not at their default) with another scenario, they are refused.
BUS_FAULT_ONLY = ("fault_bus", "fault_r", "fault_x", "clearing_time")


def scenario_from(net, values: dict):
    """The disturbance the parameters describe (ValueError names what is wrong or does not apply)."""
    if values["scenario"] != "bus_fault":
        defaults = {spec.name: spec.default for spec in PARAMETERS}
        given = [name for name in BUS_FAULT_ONLY if values[name] != defaults[name]]
        if given:
            raise ValueError(f"not for scenario {values['scenario']}: {', '.join(given)} (bus_fault only)")
    words = values["trip_line"].split()
    if len(words) not in (0, 2, 3) or not all(w.isdigit() for w in words):
        raise ValueError(f"trip_line takes 'FROM TO [CIRCUIT]', got {values['trip_line']!r}")
    trip = (net.bus_model.branch_index(*map(int, words)),) if words else ()
    if values["scenario"] == "line_trip":
        if not trip:
            raise ValueError("scenario line_trip needs trip_line")
        return LineTrip(net, trip)
    net.bus_model.bus_index(values["fault_bus"])
    return BusFault(net, values["fault_bus"], values["clearing_time"], complex(values["fault_r"], values["fault_x"]),
                    trip)


class NetworkPlantNode(Node):
    """Integrates the network; publishes per generator in its namespace; steps when every controller answered."""

    def __init__(self, **kwargs):
        super().__init__("network_plant", **kwargs)
        declare(self, PARAMETERS)
        values = self._values = current_values(self, PARAMETERS)
        check_choices(values, PARAMETERS)
        self._lockstep = values["mode"] == "lockstep"
        self._net = load_network(values["case"])
        self._scenario = scenario_from(self._net, values)
        self._scale = self._net.mbase_mva / self._net.base_mva  # pu of machine rating -> pu of the system base
        self.namespaces = tuple(f"gen{i + 1}" for i in range(self._net.size))
        self._period_s = 1.0 / values["pmu_rate_hz"]
        self.done, self._loop, self._t0_ns, self._finished_ns, self._gave_up = Future(), None, None, None, False
        self._writer_counts = [-1] * self._net.size
        self._channels = [CommandChannel(values["battery_rating_pu"], round(values["command_timeout_s"] * 1e9))
                          for _ in self.namespaces]
        self._pmu_pubs, self._state_pubs, self._command_subs = [], [], []
        for i, ns in enumerate(self.namespaces):
            self._pmu_pubs.append(self._publisher(ns, contract.TOPIC_PMU))
            self._state_pubs.append(self._publisher(ns, contract.TOPIC_PLANT_STATE))
            msg_class, topic, qos = contract.endpoint(contract.TOPIC_BATTERY_COMMAND)
            self._command_subs.append(self.create_subscription(
                msg_class, f"/{ns}/{topic}", lambda msg, index=i: self._on_command(index, msg), qos))
        self._diag_pub = self.create_publisher(*contract.endpoint(contract.TOPIC_DIAGNOSTICS))
        self._clock_pub = self.create_publisher(*contract.endpoint(contract.TOPIC_CLOCK)) if self._lockstep else None
        self._wait = SubscriberWait(values["wait_for_subscribers"], values["discovery_settle_s"],
                                    values["wait_timeout_s"], self._now_ns())
        self.get_logger().info(", ".join(f"/{ns}: {name}" for ns, name in zip(self.namespaces, self._net.names)))
        # Everything is read at start (the case, its namespaces, the physics): a later change is rejected, not ignored.
        install_validation(self, PARAMETERS, lambda proposed: locked_changes(
            self._values, proposed, [spec.name for spec in PARAMETERS], "once the node is up (read at start)"),
            lambda prepared: None)
        self._start_timer = self.create_timer(0.01, self._try_start)
        self._run_timers = [self.create_timer(1.0, self._publish_diagnostics)]

    def _publisher(self, namespace: str, topic: str):
        msg_class, name, qos = contract.endpoint(topic)
        return self.create_publisher(msg_class, f"/{namespace}/{name}", qos)

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _integrate(self, t0_s: float, t1_s: float, x, powers: tuple):
        """The network over one period, each battery's power (pu of its machine) held, on the system base."""
        battery = (np.array(powers) * self._scale)[:, None]
        return advance(t0_s, t1_s, x, battery, self._net, self._scenario, self._values["integration_step_s"])

    # --- start ---------------------------------------------------------------------------

    def _try_start(self) -> None:
        readers = [pub.get_subscription_count() for pub in self._pmu_pubs]
        writers = [sub.get_publisher_count() for sub in self._command_subs]
        fewest, silent = int(np.argmin(readers)), int(np.argmin(writers))
        state, level, text = self._wait.poll(self._now_ns(), readers[fewest], writers[silent],
                                             self._pmu_pubs[fewest].topic_name, self._command_subs[silent].topic_name)
        if text is not None:
            contract.log_at(self.get_logger(), level, text)
        self._gave_up = state == "give_up"
        if state != "start":
            return self.done.set_result(True) if self._gave_up else None
        self._start_timer.cancel()
        values = self._values
        self.get_logger().info(f"started in {values['mode']} mode at {values['pmu_rate_hz']:g} frames/s, "
                               f"{self._net.size} generators")
        self._check_writers()
        # The state carries one run (shape (2, N, 1)), as the offline network simulation's batch of runs does.
        state = self._scenario.initial_state(self._net)[:, :, None]
        timer = self.create_timer(min(0.05, values["lockstep_timeout_s"] / 4) if self._lockstep else self._period_s,
                                  self._on_timer)
        self._run_timers.append(timer)
        # Realtime, the reporting grid is the timer's own (its whole-ns period and phase), as in the SMIB plant.
        self._t0_ns = self._now_ns() + (0 if self._lockstep else timer.time_until_next_call() - timer.timer_period_ns)
        self._loop = (LockstepStepper(self._integrate, state, self._channels, values["duration_s"], self._period_s,
                                      values["lockstep_timeout_s"], link_from(values)) if self._lockstep
                      else RealtimeReporter(self._integrate, state, self._channels, values["duration_s"], self._t0_ns,
                                            timer.timer_period_ns, values["command_timeout_s"], link_from(values)))
        self._publish(self._loop.start(self._now_ns()))

    # --- publishing ----------------------------------------------------------------------

    def _publish(self, output) -> None:
        """Every generator's measurement (lockstep: then /clock), then the true states."""
        if output is None:
            return
        sample = output.measurement
        if sample is not None:
            x = sample.state
            measured = electrical_power(x[0], self._scenario.network(sample.t_s, self._net)[1])[:, 0] / self._scale
            for i, pub in enumerate(self._pmu_pubs):
                pub.publish(contract.pmu_message(sample.stamp_ns, float(x[0, i, 0]), float(x[1, i, 0]),
                                                 float(measured[i])))
            if self._lockstep:
                self._loop.sent(self._now_ns())
                self._clock_pub.publish(Clock(clock=contract.time_from_ns(sample.stamp_ns)))
        for report in output.states:
            x = report.state
            for i, pub in enumerate(self._state_pubs):
                pub.publish(contract.plant_state_message(report.stamp_ns, float(x[0, i, 0]), float(x[1, i, 0]),
                                                         report.powers[i]))
        if output.done:
            for timer in self._run_timers:
                timer.cancel()
            self._finished_ns = self._now_ns()
            self._publish_diagnostics()
            self.done.set_result(True)

    # --- timers and commands -------------------------------------------------------------

    def _on_timer(self) -> None:
        """Realtime: the reporting tick; lockstep: the watchdog of the handshake (zero for the silent at the timeout)."""
        self._check_writers()
        self._publish(self._loop.on_timer(self._now_ns()))

    def _check_writers(self) -> None:
        """Tell each channel who writes on its battery/command when that changed (alarms go out at once)."""
        for i, (sub, channel) in enumerate(zip(self._command_subs, self._channels)):
            count = sub.get_publisher_count()
            if count == self._writer_counts[i] and channel.paired is not None:
                continue
            writers, unlisted = contract.writers_on(self, sub.topic_name, count)
            self._writer_counts[i] = -1 if unlisted or contract.UNNAMED_WRITER in writers.values() else count
            channel.writers(writers, unlisted)
        self._report_events()

    def _report_events(self) -> None:
        for ns, channel in zip(self.namespaces, self._channels):
            for alarm, text in channel.take_events():
                contract.log_at(self.get_logger(), "error" if alarm else "info", f"/{ns}: {text}")
                if alarm:
                    self._publish_diagnostics()

    def _on_command(self, index: int, msg) -> None:
        arrival_ns = self._now_ns()
        if self._loop is None:
            return
        self._check_writers()
        try:
            stamp_ns, power = contract.command_from_message(msg)
        except contract.ContractError:
            stamp_ns, power = 0, math.nan  # malformed: invalid, as a non-finite power is
        self._publish(self._loop.command(index, stamp_ns, power, arrival_ns)[1])
        self._report_events()

    # --- diagnostics ---------------------------------------------------------------------

    def _generator_values(self) -> list[dict]:
        """Per generator: the run's simulated and wall time and samples, its channel's counters, the power in force."""
        run = {"mode": self._values["mode"], "sim_time_s": 0.0, "samples": 0, "run_wall_s": 0.0}
        if self._loop is not None:
            run.update(sim_time_s=self._loop.t_s, samples=self._loop.sample,
                       run_wall_s=((self._finished_ns or self._now_ns()) - self._t0_ns) * 1e-9)
        return [{**run, "machine": name, "battery_power_pu": channel.power_pu, **channel.summary(),
                 **(self._loop.link_summary(i) if self._loop is not None else {})}
                for i, (name, channel) in enumerate(zip(self._net.names, self._channels))]

    def _publish_diagnostics(self) -> list[dict]:
        """One status per generator, named ``gen<i>/plant``; returns their values."""
        generators = self._generator_values()
        for ns, channel, values in zip(self.namespaces, self._channels, generators):
            level, message = channel.health(self._loop is not None, self._wait.text)
            self._diag_pub.publish(contract.diagnostics_message(
                self._now_ns(), "plant", f"/{ns}/plant", getattr(DiagnosticStatus, level), message, values))
        return generators

    def close(self) -> None:
        """Final diagnostics, also printed as one JSON line ``{namespace: values}``."""
        generators = self._publish_diagnostics()
        print(SUMMARY_PREFIX + json.dumps(dict(zip(self.namespaces, generators))), flush=True)
        if self._gave_up:
            raise SystemExit(1)


def main(args=None) -> int:
    """``ros2 run nni_plant_sim network_plant_node``."""
    return run_node(NetworkPlantNode, args, prog="network_plant_node")


if __name__ == "__main__":
    sys.exit(main())
