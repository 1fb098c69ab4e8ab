"""The controller's loop without ROS: the input gate in front of the sampled law.

:class:`ControllerCore` takes a measurement (its stamp, values, the reference
clock and the wall time of arrival) and returns the :class:`Answer` to
publish, or None when the gate dropped it (:mod:`.input_gate` counts why).
The controller node only translates messages and timers.
"""

from __future__ import annotations

from dataclasses import dataclass

from nni_battery_controller.input_gate import InputGate
from nni_battery_controller.law import ControllerParams, SampledController, closed_loop_lyapunov
from nni_plant_sim.model import SmibParams


@dataclass(frozen=True)
class Answer:
    """One step of the law: the command (power, pu) and the internal signals behind it."""

    stamp_ns: int
    power_pu: float
    angle_dev_rad: float
    speed_rad_s: float
    x3: float  # before the step, the state the output came from
    w: float
    saturated: bool
    plant: SmibParams
    ctrl: ControllerParams

    @property
    def w_hat(self) -> float:
        """The closed-loop Lyapunov candidate W_hat at this sample (computed after the command is out)."""
        return float(closed_loop_lyapunov(self.angle_dev_rad, self.speed_rad_s, self.x3, self.plant, self.ctrl))

    def signals(self) -> tuple:
        """``(stamp_ns, angle_dev, x3, w, battery_power, saturated, w_hat, battery_limit)``: controller/state's fields."""
        return (self.stamp_ns, self.angle_dev_rad, self.x3, self.w, self.power_pu, self.saturated, self.w_hat,
                self.ctrl.battery_limit_pu)


class ControllerCore:
    """Gate and law for a configuration with ``plant``, ``ctrl``, ``period_s`` and ``gate_bounds``."""

    def __init__(self, config):
        self.config = config
        self.law = SampledController(config.plant, config.ctrl, config.period_s)
        self.gate = InputGate(*config.gate_bounds)
        #: The plant said its run has ended, and no measurement came since: the silence is no fault.
        self.run_ended = False

    @property
    def active(self) -> bool:
        """It has answered a measurement: a run is going on."""
        return self.gate.counts["samples"] > 0

    def reconfigure(self, config) -> None:
        """New gains or bounds; the law's state is kept."""
        self.config = config
        self.law = SampledController(config.plant, config.ctrl, config.period_s, x3=self.law.x3)
        self.gate.configure(*config.gate_bounds)

    def measurement(self, stamp_ns: int, delta_rad: float, speed_rad_s: float, reference_ns: int,
                    arrival_ns: int) -> Answer | None:
        """The answer to one measurement, or None if the gate dropped it."""
        verdict = self.gate.check(stamp_ns, delta_rad, speed_rad_s, reference_ns, arrival_ns)
        if not verdict.accepted:
            return None
        self.run_ended = False
        if verdict.resets:  # the law's state no longer describes the plant: restart from steady state
            self.law.reset()
        angle_dev, x3 = delta_rad - self.config.plant.delta_bar_rad, self.law.x3
        power, w, saturated = self.law.step(angle_dev)
        return Answer(stamp_ns, power, angle_dev, speed_rad_s, x3, w, saturated, self.config.plant, self.config.ctrl)

    def end_of_run(self) -> bool:
        """The plant says its run has ended; True if that is news (a run was going on and had not ended)."""
        news = self.active and not self.run_ended and not self.gate.stale
        self.run_ended = True
        return news

    def silence(self, wall_ns: int) -> int | None:
        """A stale episode starts: the stamp of the zero command to send, else None (also after a normal end)."""
        return None if self.run_ended else self.gate.silence(wall_ns)
