"""The controller's loop without ROS: the input gate in front of the sampled law.

:class:`ControllerCore` takes a measurement (its stamp, values, the reference
clock and the wall time of arrival) and returns the :class:`Answer` to
publish, or None when the gate dropped it (:mod:`.input_gate` counts why).
The controller node only translates messages and timers: each PMU message
goes to :meth:`ControllerCore.receive` with the number of writers on its topic.

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

The angle reference (parameter ``reference``, :mod:`.controller_config`):
``pmu`` uses the own PMU's angle alone; ``coi`` (issue 14) measures d against
the centre of inertia delta_COI = sum_j M_j delta_j / sum_j M_j of the
generators in ``coi_namespaces`` (:class:`CentreOfInertia`), as
``nni-simulate --case ... --reference coi`` does. A sample is answered only
once every listed generator's measurement of the same stamp has arrived; the
own measurement then goes through the gate (stamps, duplicates, gaps, the
stale watchdog) as in pmu mode, so a neighbour that falls silent leaves the
controller without answers and, after ``stale_after_periods``, standing down
(zero power, STALE), never answering on a partial centre of inertia. Counted
(diagnostics, WARN while they grow): ``coi_incomplete`` (a stamp given up
without every generator's sample: a later stamp was complete first, or more
than :data:`MAX_PENDING_STAMPS` were waiting), ``coi_rejected`` (a neighbour's
message malformed, non-finite or implausible, or any generator's repeated sample of
a stamp still waiting) and ``coi_untrusted`` (a message
on a topic with other than exactly one writer: rclpy does not say which writer
sent a message, so a second writer on any listed pmu topic makes every message
on it unattributable, as the plant treats its command topic).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from nni_battery_controller.input_gate import MAX_PLAUSIBLE_ANGLE_RAD, InputGate, Verdict
from nni_battery_controller.law import ControllerParams, closed_loop_lyapunov
from nni_plant_sim.model import SmibParams


class Answer(NamedTuple):
    """One step of the law: the command (power, pu) and the internal signals behind it.

    A NamedTuple, not a frozen dataclass: one is made per measurement, on the controller's
    critical path (as :class:`nni_plant_sim.reporting.Report`: about 0.5 us against 2 us).
    """

    stamp_ns: int
    power_pu: float
    angle_dev_rad: float
    speed_rad_s: float
    x3: float  # before the step, the state the output came from
    w: float
    saturated: bool
    plant: SmibParams | None  # None: g was measured (a generator in a network), W_hat is not defined
    ctrl: ControllerParams
    law: str = "nni"  # W_hat is the nni law's Lyapunov candidate: NaN for the others

    @property
    def w_hat(self) -> float:
        """The closed-loop Lyapunov candidate W_hat at this sample (computed after the command is out); NaN for g measured
        and for the laws other than nni (it is that law's certificate)."""
        if self.plant is None or self.law != "nni":
            return math.nan
        return float(closed_loop_lyapunov(self.angle_dev_rad, self.speed_rad_s, self.x3, self.plant, self.ctrl))

    def signals(self) -> tuple:
        """``(stamp_ns, angle_dev, x3, w, battery_power, saturated, w_hat, battery_limit)``: controller/state's fields."""
        return (self.stamp_ns, self.angle_dev_rad, self.x3, self.w, self.power_pu, self.saturated, self.w_hat,
                self.ctrl.battery_limit_pu)


#: The counters of inputs that are not the plant's (authentication hmac): any non-zero one is an ERROR on the
#: controller's diagnostics and makes the run compromised. ``unauthenticated_measurements``: a measurement whose seal
#: is missing or does not verify under its topic's key; ``replayed_measurements``: one that verifies on a sequence
#: already seen (captured and sent again); ``unauthenticated_statuses``: a claim that the plant's run ended that is
#: not sealed by the plant; ``foreign_clock_writers``: more writers on ``/clock`` than the lockstep plant (one) or
#: any in realtime (rosgraph_msgs/Clock has no field for a seal, so a tick cannot be attributed: the controller
#: takes none of its time from /clock when it authenticates, and names the writers).
TRUST_COUNTERS = ("unauthenticated_measurements", "replayed_measurements", "unauthenticated_statuses",
                  "foreign_clock_writers")

#: Stamps of the centre of inertia waiting for their samples at most (the oldest is given up beyond).
MAX_PENDING_STAMPS = 4
#: The counters of the coi reference, beside the gate's.
COI_COUNTERS = ("coi_incomplete", "coi_rejected", "coi_untrusted")


class CentreOfInertia:
    """Collects one stamp's angles from every generator of the centre of inertia; weights M_j / sum M."""

    def __init__(self, weights: tuple, own: int):
        self.weights, self.own = weights, own
        #: stamp -> [one angle per generator (None: not yet), the own measurement]; in arrival order.
        self.pending: dict[int, list] = {}
        self.counts = dict.fromkeys(COI_COUNTERS, 0)

    def add(self, index: int, stamp_ns: int, delta_rad: float, own=None, speed_rad_s: float = 0.0) -> tuple | None:
        """Generator ``index``'s angle and speed at ``stamp_ns`` (``own``: the own measurement, kept with its stamp).

        ``(delta_COI, own, speed_COI)`` once the stamp is complete, else None.
        """
        if index != self.own and not (math.isfinite(delta_rad) and abs(delta_rad) <= MAX_PLAUSIBLE_ANGLE_RAD
                                      and math.isfinite(speed_rad_s)):
            self.counts["coi_rejected"] += 1
            return None
        entry = self.pending.pop(stamp_ns, None) or [[None] * len(self.weights), None, [0.0] * len(self.weights)]
        if entry[0][index] is not None:  # a repeated sample of a stamp still waiting: the first one stands
            self.counts["coi_rejected"] += 1
            self.pending[stamp_ns] = entry
            return None
        entry[0][index] = delta_rad
        entry[2][index] = speed_rad_s
        if index == self.own:
            entry[1] = own
        if None in entry[0]:
            self.pending[stamp_ns] = entry
            if len(self.pending) > MAX_PENDING_STAMPS:
                self.give_up(next(iter(self.pending)))
            return None
        for older in list(self.pending):  # every stamp that began before this one and is still short of samples
            self.give_up(older)
        return (math.fsum(w * delta for w, delta in zip(self.weights, entry[0])), entry[1],
                math.fsum(w * speed for w, speed in zip(self.weights, entry[2])))

    def give_up(self, stamp_ns: int) -> None:
        """Drop a stamp that will not be answered (counted)."""
        del self.pending[stamp_ns]
        self.counts["coi_incomplete"] += 1


class ControllerCore:
    """Gate and law for a :class:`~nni_battery_controller.controller_config.ControllerConfig`."""

    def __init__(self, config):
        self._configure(config)
        self.law = config.law.sampled(config.plant, config.period_s, config.omega0_rad_s)
        self.gate = InputGate(*config.gate_bounds)
        self.coi = None if config.coi is None else CentreOfInertia(*config.coi[1:])
        self._reported = {}  # the coi counters at the last status
        #: Inputs that were not the plant's (:data:`TRUST_COUNTERS`), counted only with authentication hmac.
        self.trust = dict.fromkeys(TRUST_COUNTERS, 0)
        #: The plant said its run has ended, and no measurement came since: the silence is no fault.
        self.run_ended = False

    def _configure(self, config) -> None:
        self._reference_rad = config.reference_rad
        self.measures_power = config.measures_power
        self.config = config

    @staticmethod
    def warm_up(config) -> None:
        """One answer and its signals from a throwaway core, before the node's first sample.

        Profiled: the first pass costs ~5 ms (numpy's first calls; the first JointState: contract.warm_up),
        which sample 0 would otherwise pay as latency (above 200/s, as a deadline miss).
        """
        ControllerCore(config).measurement(0, config.reference_rad, 0.0, 0, 0, config.p_mech_pu).signals()

    @property
    def active(self) -> bool:
        """It has answered a measurement: a run is going on."""
        return self.gate.counts["samples"] > 0

    def reconfigure(self, config) -> None:
        """New gains or bounds; the law's state is kept (the angle reference never changes: read at start)."""
        self._configure(config)
        state = self.law
        self.law = config.law.sampled(config.plant, config.period_s, config.omega0_rad_s, x3=state.x3)
        if config.law.uses_speed and state.spec.name == config.law.name:
            self.law.z = state.z
        self.gate.configure(*config.gate_bounds)

    def receive(self, index: int, reading: tuple | None, effort, writers: int, arrival_ns: int,
                clock_ns: int | None, clock_writers) -> Answer | None:
        """A PMU message of generator ``index`` (0: the own in pmu mode; coi_namespaces' order for coi).

        ``reading``: ``(stamp_ns, delta, speed)``, None if the message was malformed; ``effort``: its
        efforts (P_E); ``writers``: how many writers its topic has; ``arrival_ns``: wall time. Stamps are
        checked against /clock (``clock_ns``, the latest, None before any) when a plant publishes it
        (``clock_writers()`` > 0: 0 before its first tick), else against wall time. The answer, or None.
        """
        reference_ns = clock_ns if clock_ns is not None else 0 if clock_writers() > 0 else arrival_ns
        if self.coi is not None and writers != 1:
            self.coi.counts["coi_untrusted"] += 1
            return None
        own = self.coi is None or index == self.coi.own
        if own and (reading is None or (self.measures_power and len(effort) != 1)):  # g measured: P_E is needed
            self.gate.malformed()
            return None
        p_elec = effort[0] if own and self.measures_power else math.nan
        if self.coi is None:
            return self.measurement(*reading, reference_ns, arrival_ns, p_elec)
        if reading is None:
            self.coi.counts["coi_rejected"] += 1
            return None
        complete = self.coi.add(index, reading[0], reading[1], (reading, p_elec) if own else None, reading[2])
        if complete is None:
            return None
        coi_rad, ((stamp_ns, delta_rad, speed_rad_s), p_elec), coi_speed = complete
        return self.measurement(stamp_ns, delta_rad, speed_rad_s, reference_ns, arrival_ns, p_elec, coi_rad,
                                coi_speed)

    def measurement(self, stamp_ns: int, delta_rad: float, speed_rad_s: float, reference_ns: int,
                    arrival_ns: int, p_elec_pu: float = math.nan, coi_rad: float = 0.0,
                    coi_speed_rad_s: float = 0.0) -> Answer | None:
        """The answer to one measurement, or None if the gate dropped it.

        ``p_elec_pu``, the measured electrical power, is used when g is measured (and must then be finite);
        ``coi_rad``, ``coi_speed_rad_s``: the centre of inertia's angle and speed that d and the speed
        laws' input are measured against (reference coi).
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
        angle_dev, x3 = delta_rad - coi_rad - self._reference_rad, self.law.x3
        speed = speed_rad_s - coi_speed_rad_s
        if self.measures_power:
            power, w, saturated = self.law.step(angle_dev, speed, self.config.p_mech_pu - p_elec_pu)
            return Answer(stamp_ns, power, angle_dev, speed_rad_s, x3, w, saturated, None, self.config.ctrl,
                          self.config.law.name)
        power, w, saturated = self.law.step(angle_dev, speed)
        return Answer(stamp_ns, power, angle_dev, speed_rad_s, x3, w, saturated, self.config.plant, self.config.ctrl,
                      self.config.law.name)

    def end_of_run(self) -> bool:
        """The plant says its run has ended; True if that is news (a run was going on and had not ended)."""
        news = self.active and not self.run_ended and not self.gate.stale
        self.run_ended = True
        return news

    def silence(self, wall_ns: int, lockstep_clock: bool = False) -> int | None:
        """A stale episode starts: the stamp of the zero command to send, else None (also after a normal end).

        ``lockstep_clock``: a plant publishes ``/clock``. Its simulated time stands still between
        measurements (the plant waits for this answer), so wall-clock silence is no loss of data
        and nothing stands down; once that plant is gone (its /clock writer left), the wall clock counts.
        """
        return None if self.run_ended or lockstep_clock else self.gate.silence(wall_ns)

    def status(self) -> tuple[str, str, dict]:
        """``(level, message, values)`` of the diagnostics: STALE, else WARN while a coi counter grew since the last.

        The message names the coi counters that grew (after ``STALE; `` when stale: often their cause).
        """
        coi = {} if self.coi is None else dict(self.coi.counts)
        grew = [name for name, count in coi.items() if count > self._reported.get(name, 0)]
        self._reported = coi
        foreign = [f"{count} {name.replace('_', ' ')}" for name, count in self.trust.items() if count]
        level = "ERROR" if foreign else "STALE" if self.gate.stale else "WARN" if grew else "OK"
        message = "; ".join(([f"inputs not from the plant, dropped: {', '.join(foreign)}"] if foreign else [])
                            + (["STALE"] if self.gate.stale and foreign else [])
                            + ([level] if level in ("OK", "STALE") else [])
                            + ([f"centre of inertia: {', '.join(grew)}"] if grew else []))
        values = {"x3": self.law.x3, "battery_limit_pu": self.config.ctrl.battery_limit_pu, **self.gate.counts, **coi}
        if self.config.authenticated:
            values.update(self.trust)
        return level, message, values
