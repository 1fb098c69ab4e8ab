"""The controller's loop without ROS: the input gate in front of the sampled law.

:class:`ControllerCore` takes a measurement (its stamp, values, the reference
clock and the wall time of arrival) and returns the :class:`Answer` to
publish, or None when the gate dropped it (:mod:`.input_gate` counts why).
The controller node only translates messages and timers.

Where g comes from (parameter ``restoring_power``):

* ``model`` (default, the SMIB): g(d) = P_max (sin(delta_bar) - sin(d + delta_bar))
  from the controller's model, d = delta - delta_bar with delta_bar = asin(P_M/P_max);
* ``measured`` (a generator in a network, issue 13's g_i): g = P_M - P_E, the
  pre-fault electrical power minus the one the PMU measured (its message's
  effort), d = delta - ``reference_angle_rad`` (the generator's pre-fault angle
  from the load flow). The pre-fault P_E is the parameter ``p_mech_pu``: at the
  pre-fault equilibrium P_E = P_M. Not the first measurement's: in lockstep
  the first sample is taken at the fault's instant, with the faulted network
  already in force, and a controller (re)started mid-run would take a
  disturbed value as its reference for good. W_hat is the SMIB's Lyapunov
  candidate: it is not defined for a generator in a network, and is NaN there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from nni_battery_controller.input_gate import InputGate, Verdict
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
    plant: SmibParams | None  # None: g was measured (a generator in a network), W_hat is not defined
    ctrl: ControllerParams

    @property
    def w_hat(self) -> float:
        """The closed-loop Lyapunov candidate W_hat at this sample (computed after the command is out); NaN for g measured."""
        if self.plant is None:
            return math.nan
        return float(closed_loop_lyapunov(self.angle_dev_rad, self.speed_rad_s, self.x3, self.plant, self.ctrl))

    def signals(self) -> tuple:
        """``(stamp_ns, angle_dev, x3, w, battery_power, saturated, w_hat, battery_limit)``: controller/state's fields."""
        return (self.stamp_ns, self.angle_dev_rad, self.x3, self.w, self.power_pu, self.saturated, self.w_hat,
                self.ctrl.battery_limit_pu)


RESTORING_POWER = ("model", "measured")


def reference_angle(values: dict, plant: SmibParams) -> float:
    """The angle d is measured from: the SMIB model's delta_bar, or ``reference_angle_rad`` for g measured.

    ValueError (the reason a parameter change is rejected) when
    ``reference_angle_rad`` is missing where it is needed (.inf, the default:
    not set; not NaN, which would differ from itself in the run's lockdown
    check) or given where it does not apply.
    """
    given = values["reference_angle_rad"]
    if values["restoring_power"] == "measured":
        if not math.isfinite(given):
            raise ValueError("restoring_power measured needs reference_angle_rad (the generator's pre-fault angle)")
        return given
    if given != math.inf:
        raise ValueError("reference_angle_rad applies to restoring_power measured only (the model's is asin(P_M/P_max))")
    return plant.delta_bar_rad


class ControllerCore:
    """Gate and law for a configuration with ``plant``, ``ctrl``, ``period_s``, ``gate_bounds`` and ``values``."""

    def __init__(self, config):
        self._configure(config)
        self.law = SampledController(config.plant, config.ctrl, config.period_s)
        self.gate = InputGate(*config.gate_bounds)
        #: The plant said its run has ended, and no measurement came since: the silence is no fault.
        self.run_ended = False

    def _configure(self, config) -> None:
        self._reference_rad = reference_angle(config.values, config.plant)
        self.measures_power = config.values["restoring_power"] == "measured"
        self.config = config

    @property
    def active(self) -> bool:
        """It has answered a measurement: a run is going on."""
        return self.gate.counts["samples"] > 0

    def reconfigure(self, config) -> None:
        """New gains or bounds; the law's state is kept."""
        self._configure(config)
        self.law = SampledController(config.plant, config.ctrl, config.period_s, x3=self.law.x3)
        self.gate.configure(*config.gate_bounds)

    def measurement(self, stamp_ns: int, delta_rad: float, speed_rad_s: float, reference_ns: int,
                    arrival_ns: int, p_elec_pu: float = math.nan) -> Answer | None:
        """The answer to one measurement, or None if the gate dropped it.

        ``p_elec_pu``, the measured electrical power, is used when g is measured (and must then be finite).
        """
        if self.measures_power and not math.isfinite(p_elec_pu):
            self.gate.counts[Verdict.NON_FINITE.value] += 1
            return None
        verdict = self.gate.check(stamp_ns, delta_rad, speed_rad_s, reference_ns, arrival_ns)
        if not verdict.accepted:
            return None
        self.run_ended = False
        if verdict.resets:  # the law's state no longer describes the plant: restart from steady state
            self.law.reset()
        angle_dev, x3 = delta_rad - self._reference_rad, self.law.x3
        if self.measures_power:
            power, w, saturated = self.law.step(angle_dev, self.config.plant.p_mech_pu - p_elec_pu)
            return Answer(stamp_ns, power, angle_dev, speed_rad_s, x3, w, saturated, None, self.config.ctrl)
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
