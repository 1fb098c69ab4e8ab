"""Controller node: the sampled-data saturated NNI law (H3-hat) on PMU measurements.

Only translates between ROS and :class:`~nni_battery_controller.controller_core.ControllerCore`
(the input gate, the centre of inertia for reference coi, the law the offline sampled simulation runs).
"""

from __future__ import annotations

import sys

from rclpy.node import Node

from nni_battery_controller.controller_config import ControllerConfig, parameters, prepared
from nni_battery_controller.controller_core import ControllerCore
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.ros.ros_params import declared_values, install_validation


class ControllerNode(Node):
    """Answers every PMU measurement that passes the gate with a battery power command."""

    def __init__(self, **kwargs):
        super().__init__("controller", **kwargs)
        config = ControllerConfig(declared_values(self, parameters()), self.get_namespace())
        self._core, self._clock_ns = ControllerCore(config), None
        self._clock = self.get_clock()
        self._command_bytes, self._state_bytes = contract.command_bytes(), contract.controller_state_bytes()
        warm = ControllerCore.warm_up(config)
        self._command_bytes.pack(0, warm.power_pu), self._state_bytes.pack(*warm.signals()), contract.warm_up()
        self._command_pub, self._state_pub, self._diag_pub = contract.publishers(
            self, contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_CONTROLLER_STATE, contract.TOPIC_DIAGNOSTICS)
        self._pmu_subs = [contract.subscribe(self, contract.TOPIC_PMU, lambda data, i=i: self._on_pmu(i, data), ns,
                                             raw=True) for i, ns in enumerate(config.pmu_namespaces)]
        self._clock_sub = contract.subscribe(self, contract.TOPIC_CLOCK,
                                             lambda msg: setattr(self, "_clock_ns", contract.ns_from_time(msg.clock)))
        contract.subscribe(self, contract.TOPIC_DIAGNOSTICS, self._on_diagnostics)
        # Restarted by each measurement: it fires only on silence (profiled: one at the sample rate doubled wake-ups).
        self._stale_timer = self.create_timer(config.stale_after_s, self._check_stale)
        install_validation(self, parameters(), lambda values: prepared(
            self._core.config.values, values, self.get_namespace(), self._core.active), self._install)
        self.create_timer(1.0, self._publish_diagnostics)

    def _install(self, config: ControllerConfig) -> None:
        self._core.reconfigure(config)
        self._stale_timer.timer_period_ns = config.gate_bounds[0]

    def _on_pmu(self, index: int, data: bytes) -> None:
        arrival_ns = contract.now_ns(self._clock)
        try:
            reading, effort = contract.pmu_from_bytes(data)
        except contract.ContractError:
            reading, effort = None, ()
        answer = self._core.receive(index, reading, effort, self._pmu_subs[index].get_publisher_count(),
                                    arrival_ns, self._clock_ns, self._clock_sub.get_publisher_count)
        if answer is not None:
            self._command_pub.publish(self._command_bytes.pack(answer.stamp_ns, answer.power_pu))
            self._stale_timer.reset()  # bookkeeping after the answer is out: none of it changes the command
            self._state_pub.publish(self._state_bytes.pack(*answer.signals()))

    def _on_diagnostics(self, msg) -> None:
        if contract.plant_run_ended(msg, self.get_namespace()) and self._core.end_of_run():
            self.get_logger().info(f"the plant's run ended after {self._core.gate.counts['samples']} answered "
                                   "measurements: waiting for the next run")

    def _check_stale(self) -> None:
        stamp_ns = self._core.silence(contract.now_ns(self._clock), self._clock_sub.get_publisher_count() > 0)
        if stamp_ns is not None:
            self._command_pub.publish(self._command_bytes.pack(stamp_ns, 0.0))
            self.get_logger().warning(f"no measurement for {self._core.config.stale_after_s:g} s: battery power set to zero")

    def _publish_diagnostics(self) -> None:
        level, message, values = self._core.status()
        self._diag_pub.publish(contract.diagnostics_message(contract.now_ns(self._clock), "controller",
                                                            self.get_fully_qualified_name(), level, message, values))

    def close(self) -> None:
        """Final diagnostics before the node goes."""
        self._publish_diagnostics()


def main(args=None) -> int:
    """``ros2 run nni_battery_controller controller_node``."""
    return run_node(ControllerNode, args, prog="controller_node")


if __name__ == "__main__":
    sys.exit(main())
