"""The verdicts on one SMIB run: in synchronism (no pole slip), settled, stable; and the words a table prints.

:func:`assess` summarises a :class:`~nni_battery_controller.simulate.Trajectory`
(offline, or a recording's samples) as an :class:`Outcome`, the keys of
``nni-simulate --json`` and of ``nni-demo``'s summary; :func:`verdict_text`
is its verdict in words.

Pure numpy: no ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nni_battery_controller.law import last_saturated
from nni_battery_controller.simulate import Trajectory
from nni_plant_sim.model import SmibParams

#: A pole slip: the rotor angle delta against the infinite bus passes +-pi (180 degrees).
POLE_SLIP_RAD = math.pi
#: Band around equilibrium that counts as "returned", rad (about 1 degree).
SETTLE_BAND_RAD = 0.02
#: Decimal places (1 ns, the resolution of ROS time) that reported grid instants are snapped to.
INSTANT_DECIMALS = 9


def settle_hold_s(plant: SmibParams) -> float:
    """Half the period of the machine's small swing about delta_bar, pi sqrt(M / (P_max cos delta_bar)), s.

    How long |d| must stay within the band before the end of a run to call it
    settled, and so the shortest run that can be judged: an oscillation wider
    than the band spends less than half of each period inside it, and the
    swing is the loop's slowest oscillation (the battery's angle feedback only
    stiffens it). Paper case: 0.647 s. inf when P_M = P_max.
    """
    stiffness = plant.p_max_pu * math.cos(plant.delta_bar_rad)
    return math.pi * math.sqrt(plant.inertia_m / stiffness) if stiffness > 0 else math.inf


def pole_slip_instant(t_s: np.ndarray, delta_rad: np.ndarray) -> float | None:
    """First instant the rotor angle delta passes +-pi (180 degrees against the infinite bus), s.

    What out-of-step protection sees: the angle across the machine's
    connection reaching half a turn. Interpolated linearly between the samples
    around the crossing; a run that diverged (a non-finite angle) slips at its
    first non-finite sample. None if the angle stays within +-pi.
    """
    beyond = np.flatnonzero(~(np.abs(delta_rad) <= POLE_SLIP_RAD))
    if beyond.size == 0:
        return None
    i = beyond[0]
    if i == 0 or not math.isfinite(delta_rad[i]) or delta_rad[i] * delta_rad[i - 1] <= 0:
        return float(t_s[i])
    before, after = abs(float(delta_rad[i - 1])), abs(float(delta_rad[i]))
    return float(t_s[i - 1] + (t_s[i] - t_s[i - 1]) * (POLE_SLIP_RAD - before) / (after - before))


@dataclass(frozen=True)
class Outcome:
    """Summary of one run, the keys of ``nni-simulate --json`` and ``nni-demo``'s summary.

    Two separate verdicts, and ``stable`` for both:

    in_synchronism: the rotor angle delta never passed +-pi (a pole slip, as
        out-of-step protection sees it); ``pole_slip_s`` is the first instant it
        did (None if never).
    settled: |d| = |delta - delta_bar| ended within ``settle_band_rad`` of zero
        and stayed there for at least ``settle_hold_s`` (half a swing period,
        :func:`settle_hold_s`) before the end; ``settling_time_s`` is the first
        instant after which it stays within the band (None if the run ends outside).
    stable: in_synchronism and settled (the run returned to its equilibrium).
    too_short_to_judge: the run ended before ``settle_hold_s`` without a pole
        slip: it can be neither settled nor called unsettled (settled and stable
        are false, and the verdict says "too short to judge").
    equilibrium_moved: the scenario's change was still in force at the end (a
        permanent mechanical power step): the equilibrium is no longer delta_bar,
        so the run cannot settle at d = 0 even when it is in synchronism.
    last_saturated_s: last instant with |w| >= b (None if never).
    Grid instants are snapped to 1 ns (:func:`_instant`), without float noise.
    """

    b: float
    stable: bool
    in_synchronism: bool
    pole_slip_s: float | None
    settled: bool
    settling_time_s: float | None
    settle_band_rad: float
    settle_hold_s: float
    too_short_to_judge: bool
    equilibrium_moved: bool
    duration_s: float
    final_angle_dev_rad: float
    final_battery_power_pu: float
    max_abs_angle_dev_rad: float
    max_abs_battery_power_pu: float
    last_saturated_s: float | None

    def to_json(self) -> dict:
        """JSON-ready dict; b = inf is written as the string "inf"."""
        out = dict(self.__dict__)
        out["b"] = "inf" if math.isinf(self.b) else self.b
        return out


def _instant(t_s) -> float | None:
    """``t_s`` as a float, its float noise removed: snapped to the nanosecond when within 1e-12 s of one.

    Grid instants (k / rate, k * 1 ms) then read as configured (0.3355, not
    0.33549999999999996); located instants (events, interpolated slips) keep
    every digit.
    """
    if t_s is None:
        return None
    snapped = round(float(t_s), INSTANT_DECIMALS)
    return snapped if abs(snapped - float(t_s)) < 1e-12 else float(t_s)


def assess(traj: Trajectory, settle_band_rad: float = SETTLE_BAND_RAD, scenario=None) -> Outcome:
    """Summarise a trajectory: synchronism, settling, peaks and saturation (see :class:`Outcome`).

    ``scenario`` (the run's) tells whether its change is still in force at the
    end (``equilibrium_moved``); without it the network is taken as restored.
    """
    dev = traj.angle_dev_rad
    outside = np.flatnonzero(~(np.abs(dev) <= settle_band_rad))
    settled_from = 0.0 if outside.size == 0 else (
        traj.t_s[outside[-1] + 1] if outside[-1] + 1 < dev.size else None
    )
    duration = float(traj.t_s[-1] - traj.t_s[0])
    slip = pole_slip_instant(traj.t_s, traj.delta_rad)
    hold = settle_hold_s(traj.plant)
    settled = slip is None and settled_from is not None and float(traj.t_s[-1] - settled_from) >= hold
    moved = scenario is not None and tuple(scenario.network(float(traj.t_s[-1]), traj.plant)) != (
        traj.plant.p_mech_pu, traj.plant.p_max_pu)
    # |w| = b at a located switch, which the rule counts as saturated.
    saturated_instants = np.concatenate((traj.t_s[traj.saturated], traj.switch_times_s))
    return Outcome(
        b=traj.ctrl.battery_limit_pu,
        stable=slip is None and bool(settled),
        in_synchronism=slip is None,
        pole_slip_s=_instant(slip),
        settled=bool(settled),
        settling_time_s=_instant(settled_from),
        settle_band_rad=settle_band_rad,
        settle_hold_s=round(hold, 3),
        too_short_to_judge=slip is None and duration < hold,
        equilibrium_moved=bool(moved),
        duration_s=_instant(duration),
        final_angle_dev_rad=float(dev[-1]),
        final_battery_power_pu=float(traj.battery_power_pu[-1]),
        max_abs_angle_dev_rad=float(np.max(np.abs(dev))),
        max_abs_battery_power_pu=float(np.max(np.abs(traj.battery_power_pu))),
        last_saturated_s=_instant(last_saturated(saturated_instants, traj.ctrl.battery_limit_pu)),
    )


def verdict_text(outcome: dict) -> str:
    """The words a table prints for one run, from its :meth:`Outcome.to_json` dict."""
    if not outcome["in_synchronism"]:
        return f"POLE SLIP at {outcome['pole_slip_s']:.3f} s"
    if outcome["too_short_to_judge"]:
        return f"too short to judge (under {outcome['settle_hold_s']:g} s)"
    if outcome["stable"]:
        return f"stable, settled at {outcome['settling_time_s']:.2f} s"
    if outcome["equilibrium_moved"]:
        return (f"in sync, NEW EQUILIBRIUM (permanent step): d -> {outcome['final_angle_dev_rad']:+.3f} rad, "
                f"P_ST {outcome['final_battery_power_pu']:+.3f} pu")
    if outcome["settling_time_s"] is not None:
        return f"in sync, NOT SETTLED (in band only since {outcome['settling_time_s']:.2f} s)"
    return f"in sync, NOT SETTLED (|d| {abs(outcome['final_angle_dev_rad']):.3f} rad at the end)"


def number_or_dash(value, fmt: str = "{:.3f}") -> str:
    """``value`` formatted with ``fmt``, or ``-`` where there is none (a table's empty cell)."""
    return "-" if value is None else fmt.format(value)
