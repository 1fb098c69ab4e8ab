"""Controller node: the sampled-data saturated NNI law (H3-hat) on PMU measurements.

Each valid measurement is one sample of :class:`nni_battery_controller.law.SampledController`
(the law the offline sampled simulation runs); the answer goes out at once on
``battery/command``, stamped with the measurement it answers, and the internal
signals on ``controller/state``. The subscription callback is the controller's
update step: event-driven sampling, O(1) work, nothing else on that path.

Input hygiene (counted, reported in diagnostics): malformed, non-finite or
implausible measurements, duplicates and out-of-order stamps are dropped. With no
measurement for ``stale_after_periods`` periods of wall time the controller
commands zero battery power once and reports STALE. When data returns with a
gap of more than that many periods in its own stamps (realtime: wall time;
lockstep: simulated time) the law's state is reset, so the output restarts from
the steady state instead of jumping; a lockstep plant that merely paused (wall
time passed, simulated time did not) resumes with its state intact.
"""

from __future__ import annotations

import math
import sys

from rclpy.node import Node

from nni_battery_controller.law import ControllerParams, SampledController, closed_loop_lyapunov
from nni_msgs_adapter import contract
from nni_msgs_adapter.node_main import run_node
from nni_msgs_adapter.ros_params import Spec, load_defaults, current_values, declare, install_validation
from nni_plant_sim.model import SmibParams

DEFAULTS = load_defaults("nni_battery_controller", "controller.yaml", "controller")

PARAMETERS = (
    Spec("tau_s", DEFAULTS["tau_s"], "Phase-lead time constant tau, s.", 1e-4, 100.0),
    Spec("gain_k", DEFAULTS["gain_k"], "Gain K, pu/rad (must be < gain_l).", 1e-6, 100.0),
    Spec("gain_l", DEFAULTS["gain_l"], "Gain L, pu/rad (must be > gain_k: stability condition K - L < 0).", 1e-6, 100.0),
    Spec("alpha", DEFAULTS["alpha"], "Saturated-mode decay factor alpha (x3' = -(alpha/K) x3).", 1e-6, 100.0),
    Spec("battery_limit_pu", DEFAULTS["battery_limit_pu"], "Battery power limit b, pu; .inf for unlimited, 0 for none.",
         0.0, math.inf),
    Spec("p_mech_pu", DEFAULTS["p_mech_pu"], "Model of the plant: pre-fault mechanical power P_M, pu.", 0.0, 1e3),
    Spec("p_max_pu", DEFAULTS["p_max_pu"], "Model of the plant: maximum transfer P_max, pu.", 1e-6, 1e3),
    Spec("inertia_h_s", DEFAULTS["inertia_h_s"], "Model of the plant: inertia H, s (for W_hat only).", 1e-3, 1e3),
    Spec("f0_hz", DEFAULTS["f0_hz"], "Model of the plant: nominal frequency, Hz (for W_hat only).", 1.0, 1e3),
    Spec("sample_rate_hz", DEFAULTS["sample_rate_hz"], "PMU reporting rate the law is discretised for, frames/s.", 10.0, 1000.0),
    Spec("stale_after_periods", DEFAULTS["stale_after_periods"], "Measurements missing for this many periods: zero power, STALE.", 1, 10000),
)


#: Measurements beyond these are sensor faults, not a generator (a machine that
#: slips poles for minutes stays far below 1e6 rad); they are dropped and counted.
MAX_PLAUSIBLE_ANGLE_RAD = 1e6
MAX_PLAUSIBLE_SPEED_RAD_S = 1e4


class ControllerConfig:
    """Validated configuration built from parameter values (ValueError names the problem)."""

    def __init__(self, values: dict):
        self.ctrl = ControllerParams(values["tau_s"], values["gain_k"], values["gain_l"], values["alpha"],
                                     values["battery_limit_pu"])
        self.plant = SmibParams(values["inertia_h_s"], 0.0, values["p_mech_pu"], values["p_max_pu"],
                                values["f0_hz"])
        self.period_s = 1.0 / values["sample_rate_hz"]
        self.stale_after_s = values["stale_after_periods"] * self.period_s


class ControllerNode(Node):
    """Answers every PMU measurement with a battery power command."""

    def __init__(self, **kwargs):
        super().__init__("controller", **kwargs)
        declare(self, PARAMETERS)
        self._config = ControllerConfig(current_values(self, PARAMETERS))
        self._law = SampledController(self._config.plant, self._config.ctrl, self._config.period_s)
        install_validation(self, PARAMETERS, self._apply_config)
        self._warm_up()

        self._last_stamp_ns = None
        self._last_arrival_ns = None
        self._stale = False
        self.counts = {"samples": 0, "malformed": 0, "non_finite": 0, "duplicate": 0, "out_of_order": 0,
                       "implausible": 0, "stale_episodes": 0, "resets": 0}

        self._command_pub = self.create_publisher(*contract.endpoint(contract.TOPIC_BATTERY_COMMAND))
        self._state_pub = self.create_publisher(*contract.endpoint(contract.TOPIC_CONTROLLER_STATE))
        self._diag_pub = self.create_publisher(*contract.endpoint(contract.TOPIC_DIAGNOSTICS))
        pmu_type, pmu_topic, pmu_qos = contract.endpoint(contract.TOPIC_PMU)
        self.create_subscription(pmu_type, pmu_topic, self._on_measurement, pmu_qos)
        # Fires only after stale_after_s without a measurement: every measurement
        # restarts it. Profiled: a timer at the sample rate doubled the executor's
        # wake-ups (one timer callback per measurement, ~0.1 ms each at 1000/s)
        # and, at the plant's own rate, could fire just as a measurement arrived.
        self._stale_timer = self.create_timer(self._config.stale_after_s, self._check_stale)
        self.create_timer(1.0, self._publish_diagnostics)

    def _warm_up(self) -> None:
        """Run the answer path once on a throwaway law and messages, publishing nothing.

        Profiled: the first pass costs ~5 ms (first JointState construction,
        numpy's first calls), which the first real sample would otherwise pay
        as latency (and, above 200 frames/s, as a deadline miss).
        """
        config = self._config
        _, delta, speed = contract.pmu_from_message(contract.pmu_message(0, config.plant.delta_bar_rad, 0.0, 0.0))
        power, w, saturated = SampledController(config.plant, config.ctrl, config.period_s).step(0.0)
        w_hat = float(closed_loop_lyapunov(0.0, speed, 0.0, config.plant, config.ctrl))
        contract.command_message(0, power)
        contract.controller_state_message(0, 0.0, 0.0, w, power, saturated, w_hat, config.ctrl.battery_limit_pu)

    def _apply_config(self, values: dict) -> None:
        config = ControllerConfig(values)
        if config.period_s != self._config.period_s:
            raise ValueError("sample_rate_hz cannot change while running (it fixes the discretisation)")
        if config.stale_after_s != self._config.stale_after_s:
            self._stale_timer.timer_period_ns = round(config.stale_after_s * 1e9)
        self._config = config
        self._law = SampledController(config.plant, config.ctrl, config.period_s, x3=self._law.x3)

    def _on_measurement(self, msg) -> None:
        try:
            stamp_ns, delta, speed = contract.pmu_from_message(msg)
        except contract.ContractError as exc:
            self.counts["non_finite" if "non-finite" in str(exc) else "malformed"] += 1
            return
        if abs(delta) > MAX_PLAUSIBLE_ANGLE_RAD or abs(speed) > MAX_PLAUSIBLE_SPEED_RAD_S:
            self.counts["implausible"] += 1
            return
        if self._last_stamp_ns is not None and stamp_ns <= self._last_stamp_ns:
            self.counts["duplicate" if stamp_ns == self._last_stamp_ns else "out_of_order"] += 1
            return
        gap_s = None if self._last_stamp_ns is None else (stamp_ns - self._last_stamp_ns) * 1e-9
        self._last_stamp_ns = stamp_ns
        if gap_s is not None and gap_s > self._config.stale_after_s:
            # Data went missing in its own time base: the state no longer describes
            # the plant, so restart from steady state rather than jump.
            self._law.reset()
            self.counts["resets"] += 1
        angle_dev = delta - self._config.plant.delta_bar_rad
        x3 = self._law.x3
        power, w, saturated = self._law.step(angle_dev)
        self._command_pub.publish(contract.command_message(stamp_ns, power))
        # Bookkeeping after the answer is out: none of it changes the command.
        self._last_arrival_ns = self.get_clock().now().nanoseconds
        self._stale_timer.reset()
        self._stale = False
        self.counts["samples"] += 1
        w_hat = float(closed_loop_lyapunov(angle_dev, speed, x3, self._config.plant, self._config.ctrl))
        self._state_pub.publish(contract.controller_state_message(
            stamp_ns, angle_dev, x3, w, power, saturated, w_hat, self._config.ctrl.battery_limit_pu))

    def _check_stale(self) -> None:
        if self._stale or self._last_arrival_ns is None:
            return
        silent_ns = self.get_clock().now().nanoseconds - self._last_arrival_ns
        silent_s = silent_ns * 1e-9
        if silent_s > self._config.stale_after_s:
            self._stale = True
            self.counts["stale_episodes"] += 1
            # It answers no measurement: stamped in the measurements' time base (simulated
            # time in lockstep) at the instant the silence was noticed, after the last one.
            self._command_pub.publish(contract.command_message(self._last_stamp_ns + silent_ns, 0.0))
            self.get_logger().warning(f"no measurement for {silent_s:.3f} s: battery power set to zero")

    def _publish_diagnostics(self) -> None:
        level, message = (b"\x03", "STALE") if self._stale else (b"\x00", "OK")
        values = {"x3": self._law.x3, "battery_limit_pu": self._config.ctrl.battery_limit_pu, **self.counts}
        self._diag_pub.publish(contract.diagnostics_message(
            self.get_clock().now().nanoseconds, "controller", self.get_fully_qualified_name(), level, message,
            values))

    def close(self) -> None:
        """Final diagnostics before the node goes."""
        self._publish_diagnostics()


def main(args=None) -> int:
    """``ros2 run nni_battery_controller controller_node``."""
    return run_node(ControllerNode, args, prog="controller_node")


if __name__ == "__main__":
    sys.exit(main())
