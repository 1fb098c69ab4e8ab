"""Plant node: the SMIB generator with a battery, publishing PMU-style measurements.

Only translates between ROS (timers, messages, the graph) and the cores: the
physics (:mod:`.model`, :mod:`.scenarios`, :mod:`.integrators`) and the reporting
loop with its command path (:mod:`.reporting`). Topics and QoS: :mod:`nni_msgs_adapter.ros.contract`.
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
from std_srvs.srv import Trigger

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.ros.ros_params import check_choices, current_values, declare, install_validation, locked_changes
from nni_plant_sim.integrators import advance
from nni_plant_sim.model import electrical_power, invariant_set_boundary
from nni_plant_sim.plant_config import link_from, locked_during_run, parameters, plant_from
from nni_plant_sim.scenarios import from_values
from nni_plant_sim.reporting import CommandChannel, LockstepStepper, PmuSensor, RealtimeReporter, SubscriberWait
from nni_plant_sim.scenarios import PRE_FAULT, StartingAt

#: Prefix of the JSON line with the final diagnostics values printed at exit.
SUMMARY_PREFIX = "plant_node summary: "


class PlantNode(Node):
    """The generator: integrates the swing equation and reports like a PMU."""

    def __init__(self, **kwargs):
        super().__init__("plant", **kwargs)
        declare(self, parameters())
        values = current_values(self, parameters())
        check_choices(values, parameters())
        self._configure(values)
        install_validation(self, parameters(), self._validate, self._configure)
        self._lockstep, self.done, self._scenario = values["mode"] == "lockstep", Future(), PRE_FAULT
        self._loop = None  # the reporting core, from the start of the run
        self._wait = SubscriberWait(values["wait_for_subscribers"], values["discovery_settle_s"],
                                    values["wait_timeout_s"], self._now_ns())
        self._writer_count, self._t0_ns, self._finished_ns, self._gave_up = -1, None, None, False
        self._pmu_pub, self._state_pub, self._diag_pub = contract.publishers(
            self, contract.TOPIC_PMU, contract.TOPIC_PLANT_STATE, contract.TOPIC_DIAGNOSTICS)
        self._clock_pub = self.create_publisher(*contract.endpoint(contract.TOPIC_CLOCK)) if self._lockstep else None
        self._command_sub = contract.subscribe(self, contract.TOPIC_BATTERY_COMMAND, self._on_command)
        self.create_service(Trigger, contract.SERVICE_START_FAULT, self._on_start_fault)
        self.create_publisher(*contract.endpoint(contract.TOPIC_INVARIANT_SET)).publish(
            contract.invariant_set_message(self._now_ns(), invariant_set_boundary(self._plant)))
        # Warm the sample path once, publishing nothing. Profiled: the first pass costs ~5 ms (first
        # JointState construction, numpy's first calls), which sample 0 would otherwise pay as latency.
        x = self._fault.initial_state(self._plant)
        self._integrate(0.0, 1.0 / self._values["pmu_rate_hz"], x, (0.0,))
        contract.pmu_message(0, float(x[0]), float(x[1]), float(electrical_power(x[0], 1.0)))
        self._start_timer = self.create_timer(0.01, self._try_start)
        self._run_timers = [self.create_timer(1.0, self._publish_diagnostics)]

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _validate(self, values: dict) -> dict:
        if self._loop is not None:
            locked_changes(self._values, values, locked_during_run())
        locked_changes(self._values, values, ("mode",), "once the node is up (it chose its publishers)")
        plant_from(values), from_values(values), link_from(values)
        return values

    def _configure(self, values: dict) -> None:
        self._values, self._plant, self._fault = values, plant_from(values), from_values(values)
        self._pmu = PmuSensor(values["noise_angle_std_rad"], values["noise_speed_std_rad_s"],
                              values["quantisation_rad"], values["noise_seed"])
        self._channel = CommandChannel(values["battery_rating_pu"], round(values["command_timeout_s"] * 1e9))

    def _integrate(self, t0_s: float, t1_s: float, x, powers: tuple):
        return advance(t0_s, t1_s, x, powers[0], self._plant, self._scenario, self._values["integration_step_s"])

    # --- start ---------------------------------------------------------------------------

    def _try_start(self) -> None:
        state, level, text = self._wait.poll(self._now_ns(), self._pmu_pub.get_subscription_count(),
                                             self._command_sub.get_publisher_count(), self._pmu_pub.topic_name,
                                             self._command_sub.topic_name)
        if text is not None:
            contract.log_at(self.get_logger(), level, text)
        self._gave_up = state == "give_up"
        if state != "start":
            return self.done.set_result(True) if self._gave_up else None
        self._start_timer.cancel()
        # Logged before sample 0: rclpy's first log call is slow (caller lookup); after it, sample 0 took 17-19 ms.
        self.get_logger().info(f"started in {self._values['mode']} mode at {self._values['pmu_rate_hz']:g} frames/s")
        values, state = self._values, np.array([self._plant.delta_bar_rad, 0.0])
        self._check_writers()
        timer = self.create_timer(min(0.05, values["lockstep_timeout_s"] / 4) if self._lockstep
                                  else 1.0 / values["pmu_rate_hz"], self._on_timer)
        self._run_timers.append(timer)
        # Realtime, the reporting grid is the timer's own, its period in whole ns and its phase, so that a
        # tick never comes before its instant and the two never drift apart (60 frames/s: 16,666,666 ns).
        self._t0_ns = self._now_ns() + (0 if self._lockstep else timer.time_until_next_call() - timer.timer_period_ns)
        self._loop = (LockstepStepper(self._integrate, state, [self._channel], values["duration_s"],
                                      1.0 / values["pmu_rate_hz"], values["lockstep_timeout_s"], link_from(values))
                      if self._lockstep
                      else RealtimeReporter(self._integrate, state, [self._channel], values["duration_s"],
                                            self._t0_ns, timer.timer_period_ns, values["command_timeout_s"],
                                            link_from(values)))
        if values["fault_at_start"]:
            self._start_fault_now()
        self._publish(self._loop.start(self._now_ns()))

    def _start_fault_now(self) -> None:
        self._scenario = StartingAt(self._fault, self._loop.t_s)
        self._loop.replace_state(self._fault.initial_state(self._plant))

    def _on_start_fault(self, request, response):
        response.success = self._loop is not None and self._scenario is PRE_FAULT
        if response.success:
            self._publish(self._loop.interrupt(self._now_ns()))
            self._start_fault_now()
        response.message = (f"fault started at t = {self._loop.t_s:.6f} s" if response.success else
                            "the run has not started (waiting for subscribers)" if self._loop is None else
                            "the fault has already started")
        return response

    # --- publishing ----------------------------------------------------------------------

    def _publish(self, output) -> None:
        """What the core says to publish: the measurement (lockstep: then /clock) first, then true states."""
        if output is None:
            return
        sample = output.measurement
        if sample is not None:
            delta, speed = self._pmu.read(float(sample.state[0]), float(sample.state[1]))
            _, p_max = self._scenario.network(sample.t_s, self._plant)
            self._pmu_pub.publish(contract.pmu_message(sample.stamp_ns, delta, speed,
                                                       float(electrical_power(delta, p_max))))
            if self._lockstep:  # /clock after the measurement: the controller answers before it reads the clock
                self._loop.sent(self._now_ns())
                self._clock_pub.publish(Clock(clock=contract.time_from_ns(sample.stamp_ns)))
        for state in output.states:
            self._state_pub.publish(contract.plant_state_message(
                state.stamp_ns, float(state.state[0]), float(state.state[1]), state.powers[0]))
        if output.done:
            for timer in self._run_timers:
                timer.cancel()
            self._finished_ns = self._now_ns()
            self._publish_diagnostics()
            self.done.set_result(True)

    # --- timers and commands -------------------------------------------------------------

    def _on_timer(self) -> None:
        """Realtime: the reporting tick; lockstep: the watchdog of the handshake."""
        self._check_writers()
        self._publish(self._loop.on_timer(self._now_ns()))

    def _check_writers(self) -> None:
        """Tell the channel who writes on battery/command when that changed (an alarm goes out at once)."""
        count = self._command_sub.get_publisher_count()
        if count == self._writer_count and self._channel.paired is not None:
            return
        writers, unlisted = contract.writers_on(self, self._command_sub.topic_name, count)
        self._writer_count = -1 if unlisted or contract.UNNAMED_WRITER in writers.values() else count
        self._channel.writers(writers, unlisted)
        self._report_events()

    def _report_events(self) -> None:
        """Pairings on the log; alarms on the log at ERROR and in diagnostics at once."""
        for alarm, text in self._channel.take_events():
            contract.log_at(self.get_logger(), "error" if alarm else "info", text)
            if alarm:
                self._publish_diagnostics()

    def _on_command(self, msg) -> None:
        arrival_ns = self._now_ns()
        if self._loop is None:
            return
        self._check_writers()
        try:
            stamp_ns, power = contract.command_from_message(msg)
        except contract.ContractError:
            stamp_ns, power = 0, math.nan  # malformed: invalid, as a non-finite power is
        self._publish(self._loop.command(0, stamp_ns, power, arrival_ns)[1])
        self._report_events()

    # --- diagnostics ---------------------------------------------------------------------

    def _publish_diagnostics(self) -> dict:
        """Publish the plant's status; returns its values."""
        level, message = self._channel.health(self._loop is not None, self._wait.text)
        values = {"mode": self._values["mode"], "sim_time_s": 0.0, "samples": 0, "run_wall_s": 0.0,
                  "battery_power_pu": 0.0, **self._channel.summary(), contract.RUN_ENDED: self._finished_ns is not None}
        if self._loop is not None:
            values.update(self._loop.summary(), run_wall_s=((self._finished_ns or self._now_ns()) - self._t0_ns) * 1e-9)
        self._diag_pub.publish(contract.diagnostics_message(
            self._now_ns(), "plant", self.get_fully_qualified_name(), getattr(DiagnosticStatus, level), message, values))
        return values

    def close(self) -> None:
        """Final diagnostics before the node goes (SIGINT/SIGTERM or end of run), also printed as one JSON line."""
        if self._loop is not None and self._finished_ns is None:
            self._finished_ns = self._now_ns()  # stopped: the run ends here, and its status says so
        print(SUMMARY_PREFIX + json.dumps(self._publish_diagnostics()), flush=True)
        if self._gave_up:
            raise SystemExit(1)  # nobody to run with (node_main returns 0 after a node's normal end)


def main(args=None) -> int:
    """``ros2 run nni_plant_sim plant_node``."""
    return run_node(PlantNode, args, prog="plant_node")


if __name__ == "__main__":
    sys.exit(main())
