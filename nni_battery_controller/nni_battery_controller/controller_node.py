"""Controller node: the sampled-data saturated NNI law (H3-hat) on PMU measurements.

Only translates between ROS and :class:`~nni_battery_controller.controller_core.ControllerCore`
(the input gate in front of the law the offline sampled simulation runs).
"""

from __future__ import annotations

import math
import sys

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node

from nni_battery_controller.controller_config import ControllerConfig, locked_when_active, parameters
from nni_battery_controller.controller_core import ControllerCore, reference_angle
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.ros.ros_params import current_values, declare, install_validation, locked_changes


class ControllerNode(Node):
    """Answers every PMU measurement that passes the gate with a battery power command."""

    def __init__(self, **kwargs):
        super().__init__("controller", **kwargs)
        declare(self, parameters())
        config = ControllerConfig(current_values(self, parameters()))
        self._core, self._clock_ns = ControllerCore(config), None
        # Warm the answer path once, publishing nothing. Profiled: the first pass costs ~5 ms (first JointState,
        # numpy's first calls), which sample 0 would otherwise pay as latency (above 200/s, as a deadline miss).
        warm = ControllerCore(config).measurement(0, config.plant.delta_bar_rad, 0.0, 0, 0, config.plant.p_mech_pu)
        contract.command_message(0, warm.power_pu), contract.controller_state_message(*warm.signals())
        self._command_pub, self._state_pub, self._diag_pub = contract.publishers(
            self, contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_CONTROLLER_STATE, contract.TOPIC_DIAGNOSTICS)
        contract.subscribe(self, contract.TOPIC_PMU, self._on_measurement)
        self._clock_sub = contract.subscribe(self, contract.TOPIC_CLOCK,
                                             lambda msg: setattr(self, "_clock_ns", contract.ns_from_time(msg.clock)))
        contract.subscribe(self, contract.TOPIC_DIAGNOSTICS, self._on_diagnostics)
        # Restarted by each measurement: it fires only on silence (profiled: one at the sample rate doubled wake-ups).
        self._stale_timer = self.create_timer(config.stale_after_s, self._check_stale)
        install_validation(self, parameters(), self._validate, self._install)
        self.create_timer(1.0, self._publish_diagnostics)

    def _validate(self, values: dict) -> ControllerConfig:
        locked_changes(self._core.config.values, values, locked_when_active() if self._core.active else ())
        config = ControllerConfig(values)
        reference_angle(values, config.plant)
        return config

    def _install(self, config: ControllerConfig) -> None:
        self._core.reconfigure(config)
        self._stale_timer.timer_period_ns = config.gate_bounds[0]

    def _on_measurement(self, msg) -> None:
        arrival_ns = self.get_clock().now().nanoseconds
        try:
            stamp_ns, delta, speed = contract.pmu_from_message(msg)
        except contract.ContractError:
            self._core.gate.malformed()
            return
        if self._core.measures_power and len(msg.effort) != 1:  # g measured: P_E is needed
            self._core.gate.malformed()
            return
        # Stamps are checked against /clock when a plant publishes it (0 before its first tick), else wall time.
        simulated = self._clock_ns is not None or self._clock_sub.get_publisher_count() > 0
        answer = self._core.measurement(stamp_ns, delta, speed, (self._clock_ns or 0) if simulated else arrival_ns,
                                        arrival_ns, msg.effort[0] if self._core.measures_power else math.nan)
        if answer is not None:
            self._command_pub.publish(contract.command_message(stamp_ns, answer.power_pu))
            self._stale_timer.reset()  # bookkeeping after the answer is out: none of it changes the command
            self._state_pub.publish(contract.controller_state_message(*answer.signals()))

    def _on_diagnostics(self, msg) -> None:
        if contract.plant_run_ended(msg, self.get_namespace()) and self._core.end_of_run():
            self.get_logger().info(f"the plant's run ended after {self._core.gate.counts['samples']} answered "
                                   "measurements: waiting for the next run")

    def _check_stale(self) -> None:
        stamp_ns = self._core.silence(self.get_clock().now().nanoseconds)
        if stamp_ns is not None:
            self._command_pub.publish(contract.command_message(stamp_ns, 0.0))
            self.get_logger().warning(f"no measurement for {self._core.config.stale_after_s:g} s: battery power set to zero")

    def _publish_diagnostics(self) -> None:
        core = self._core
        level, message = (DiagnosticStatus.STALE, "STALE") if core.gate.stale else (DiagnosticStatus.OK, "OK")
        values = {"x3": core.law.x3, "battery_limit_pu": core.config.ctrl.battery_limit_pu, **core.gate.counts}
        self._diag_pub.publish(contract.diagnostics_message(self.get_clock().now().nanoseconds, "controller",
                                                            self.get_fully_qualified_name(), level, message, values))

    def close(self) -> None:
        """Final diagnostics before the node goes."""
        self._publish_diagnostics()


def main(args=None) -> int:
    """``ros2 run nni_battery_controller controller_node``."""
    return run_node(ControllerNode, args, prog="controller_node")


if __name__ == "__main__":
    sys.exit(main())
