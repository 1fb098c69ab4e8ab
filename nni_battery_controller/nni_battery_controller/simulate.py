"""Offline closed-loop simulation of the SMIB generator with the battery controller.

Two time models of the same loop:

* :func:`simulate_continuous`: the paper's continuous-time H3-hat, the closed
  loop of :mod:`nni_battery_controller.closed_loop`. The switching rule is
  discontinuous at |w| = b, so the switching instants are located as events of
  an adaptive integrator (scipy's DOP853) and the mode changes there.
* :func:`simulate_sampled`: what runs in the controller node: the law sampled at
  ``rate_hz`` (mode and output held between samples, x3 discretised exactly), the
  plant integrated with the fixed-step RK4 of :mod:`nni_plant_sim.integrators`
  that the plant node uses too; optionally through a communication link
  (:mod:`nni_plant_sim.link`: each command takes effect at t_k + d_k or is lost),
  as the plant's reporting core applies it.

:func:`delay_margins` finds the largest fixed measurement-to-command delay
that keeps a run in synchronism.

Pure numpy/scipy: no ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from nni_battery_controller.closed_loop import (
    SATURATED,
    SLIDING,
    UNSATURATED,
    LoopParams,
    closed_loop_rate,
    surface_drift,
)
from nni_battery_controller.law import (
    ControllerParams,
    SampledController,
    closed_loop_lyapunov,
    saturation_input,
    x3_rate,
)
from nni_plant_sim.integrators import advance
from nni_plant_sim.link import NO_LINK, DelayLine, Link, integrate_through
from nni_plant_sim.model import SmibParams

#: A pole slip: the rotor angle delta against the infinite bus passes +-pi (180 degrees).
POLE_SLIP_RAD = math.pi
#: Band around equilibrium that counts as "returned", rad (about 1 degree).
SETTLE_BAND_RAD = 0.02
#: A run that switches mode more often than this is chattering (a sliding mode
#: the event-located simulation does not resolve); it stops with an error.
MAX_SWITCHES = 10_000
#: A continuous run that needs more right-hand side evaluations than this stops
#: with an error (a few tens of seconds of work, some 40 MB of dense output):
#: the bound on work and memory when an estimate before the run was too kind.
MAX_RHS_EVALUATIONS = 3_000_000


@dataclass(frozen=True)
class Trajectory:
    """Closed-loop samples on a time grid. Arrays share shape (n,).

    Attributes
    ----------
    t_s : time since the fault, s.
    delta_rad : rotor angle delta, rad.
    speed_rad_s : speed deviation delta' = omega - omega0, rad/s.
    x3 : controller state, pu.
    battery_power_pu : battery power change P_ST applied from this instant, pu (sampled runs
        through a link: the power in force at the instant, which may change between samples).
    w : saturation variable (what the law asks the battery for), pu.
    saturated : mode |w| >= b in force from this instant.
    switch_times_s : instants where the mode changed, located as events
        (continuous runs; |w| = b there). Empty for sampled runs, whose mode
        changes only at samples.
    """

    plant: SmibParams
    ctrl: ControllerParams
    t_s: np.ndarray
    delta_rad: np.ndarray
    speed_rad_s: np.ndarray
    x3: np.ndarray
    battery_power_pu: np.ndarray
    w: np.ndarray
    saturated: np.ndarray
    switch_times_s: np.ndarray

    @property
    def angle_dev_rad(self) -> np.ndarray:
        """Angle deviation d = delta - delta_bar, rad."""
        return self.delta_rad - self.plant.delta_bar_rad

    @property
    def w_hat(self) -> np.ndarray:
        """Closed-loop Lyapunov candidate W_hat along the trajectory, pu*rad."""
        return closed_loop_lyapunov(
            self.angle_dev_rad, self.speed_rad_s, self.x3, self.plant, self.ctrl, saturated=self.saturated
        )


def simulate_continuous(
    plant: SmibParams,
    ctrl: ControllerParams,
    scenario,
    duration_s: float,
    output_step_s: float = 1e-3,
    rtol: float = 1e-10,
    atol: float = 1e-12,
) -> Trajectory:
    """Continuous-time closed loop with the mode switches located as events.

    Within a mode the right-hand side is smooth; the integration stops at each
    event and restarts in the new mode. Three modes, ``s`` the side (+1 for
    w >= b, -1 for w <= -b):

    * unsaturated (|w| < b): P_ST = w, x3' = (K d - x3)/tau; leaves when |w| reaches b;
    * saturated (|w| > b): P_ST = s b, x3' = -(alpha/K) x3; leaves when |w| falls to b;
    * sliding on |w| = b, when each mode's field points into the other (the
      law would chatter there; a sampled-data law does, at its rate). P_ST = s b
      (both modes agree on the surface) and x3 moves along the surface, the
      Filippov solution that the sampled law converges to as its rate grows.
      Leaves when either field turns back to its own side.

    The paper's rule counts |w| = b as saturated, so sliding is reported as
    saturated. Scenario breakpoints also stop the integration. Outputs are the
    dense interpolants sampled every ``output_step_s``; the battery power is the
    mode's own (exactly +-b when saturated or sliding).

    solve_ivp looks for events only as sign changes between its steps (which
    grow to 0.1 s and more in a smooth mode), so a brief excursion of w across
    +-b inside one step would go unnoticed. Each step is therefore also scanned
    on its dense output every ``SCAN_STEP_S`` and at every output instant, and
    the first crossing found is located by root finding and handled like an
    event: no output sample is left in a mode the law does not allow there.
    """
    b = ctrl.battery_limit_pu
    delta_bar = plant.delta_bar_rad
    grid = np.linspace(0.0, duration_s, int(round(duration_s / output_step_s)) + 1)

    def w_of(z):
        return saturation_input(z[2], z[0] - delta_bar, ctrl, plant)

    def w_rates(z):
        """dw/dt under the unsaturated and the saturated x3 law, pu/s."""
        drift = surface_drift(z[0], z[1], ctrl, plant)
        return x3_rate(z[2], z[0] - delta_bar, False, ctrl) - drift, x3_rate(z[2], z[0] - delta_bar, True, ctrl) - drift

    evaluations = [0]

    def rhs(t, z, params, network):
        """The closed loop (:func:`closed_loop_rate`) in the held mode, for solve_ivp."""
        evaluations[0] += 1
        if evaluations[0] > MAX_RHS_EVALUATIONS:
            raise RuntimeError(f"more than {MAX_RHS_EVALUATIONS} right-hand side evaluations by t={t:.6f} s: "
                               f"the loop is too stiff for this run (see --help on bounds)")
        return np.array(closed_loop_rate(t, (z[0], z[1], z[2]), network, params))

    def events_for(mode, side):
        """Terminal events that end ``mode``; None when b makes switching impossible."""
        if not 0.0 < b < math.inf:
            return None
        if mode == UNSATURATED:
            upper = _event(lambda t, z, *_: w_of(z) - b, direction=1)
            lower = _event(lambda t, z, *_: w_of(z) + b, direction=-1)
            return [upper, lower]
        if mode == SATURATED:
            return [_event(lambda t, z, *_: w_of(z) - side * b, direction=-side)]
        # Sliding ends when the unsaturated field points inward (side*w'_u < 0) or
        # the saturated field points outward (side*w'_s > 0).
        return [
            _event(lambda t, z, *_: side * w_rates(z)[0], direction=-1),
            _event(lambda t, z, *_: side * w_rates(z)[1], direction=1),
        ]

    def mode_at(z, arriving_from):
        """Mode to continue in from state z; on the surface |w| = b the fields decide.

        Off the surface the sign of |w| - b decides (only at the start). On it,
        unsaturated if that field points inside, saturated if that one points
        outside, sliding if neither; when both do (a repelling surface, or a
        grazing touch) the run keeps the mode it arrives from.
        """
        w = w_of(z)
        if b == 0.0:
            return SATURATED, 1.0
        if b == math.inf:
            return UNSATURATED, 0.0
        side = 1.0 if w >= 0 else -1.0
        if arriving_from is None and abs(w) != b:
            return (UNSATURATED, 0.0) if abs(w) < b else (SATURATED, side)
        rate_unsat, rate_sat = w_rates(z)
        inward_unsat, outward_sat = side * rate_unsat < 0, side * rate_sat > 0
        if inward_unsat and outward_sat and arriving_from in (UNSATURATED, SATURATED):
            return (UNSATURATED, 0.0) if arriving_from == UNSATURATED else (SATURATED, side)
        if outward_sat:
            return SATURATED, side
        if inward_unsat:
            return UNSATURATED, 0.0
        return SLIDING, side

    z = np.concatenate((scenario.initial_state(plant), [0.0]))
    t = 0.0
    mode, side = mode_at(z, None)
    stops = sorted({*(tb for tb in scenario.breakpoints() if 0 < tb < duration_s), duration_s})
    pieces_t, pieces_z, pieces_sat, pieces_side, switches = [], [], [], [], []
    while t < duration_s:
        stop = next(s for s in stops if s > t)
        sol = solve_ivp(
            rhs, (t, stop), z, method="DOP853", rtol=rtol, atol=atol, dense_output=True,
            events=events_for(mode, side), args=(LoopParams(plant, ctrl, mode, side), scenario.network(t, plant)),
        )
        if sol.status < 0:
            raise RuntimeError(f"integration failed at t={t:.6f} s: {sol.message}")
        t_end = sol.t[-1]
        crossing = _first_crossing(sol, t, t_end, events_for(mode, side) if mode != SLIDING else None, grid)
        if crossing is not None:
            t_end = crossing
            sol.status, sol.y = 1, sol.sol(crossing)[:, None]
        inside = grid[(grid >= t) & (grid < t_end)] if t_end < duration_s else grid[grid >= t]
        if inside.size:
            pieces_t.append(inside)
            pieces_z.append(sol.sol(inside))
            pieces_sat.append(np.full(inside.shape, mode != UNSATURATED))
            pieces_side.append(np.full(inside.shape, side))
        z, t = sol.y[:, -1], t_end
        if sol.status == 1:  # a mode boundary was reached
            if mode == SLIDING:
                # The event that fired says which field turned; at its root that
                # rate is zero, so it must not be re-read from the state.
                new_mode, side = (UNSATURATED, 0.0) if sol.t_events[0].size else (SATURATED, side)
            else:
                new_mode, side = mode_at(z, mode)
            if (new_mode == UNSATURATED) != (mode == UNSATURATED):
                switches.append(t)
            mode = new_mode
            if len(switches) > MAX_SWITCHES:
                raise RuntimeError(
                    f"more than {MAX_SWITCHES} mode switches by t={t:.6f} s: the loop chatters at |w| = b"
                )
    t_all = np.concatenate(pieces_t)
    z_all = np.concatenate(pieces_z, axis=1)
    sat_all = np.concatenate(pieces_sat)
    w = saturation_input(z_all[2], z_all[0] - delta_bar, ctrl, plant)
    power = w.copy()
    power[sat_all] = np.concatenate(pieces_side)[sat_all] * b
    return Trajectory(plant, ctrl, t_all, z_all[0], z_all[1], z_all[2], power, w, sat_all, np.array(switches))


#: Spacing of the scan for mode boundaries crossed inside one integrator step, s.
SCAN_STEP_S = 2.5e-4


def _first_crossing(sol, t0: float, t1: float, events, grid: np.ndarray) -> float | None:
    """First instant in (t0, t1) where one of ``events`` changes sign in its direction.

    Scans ``sol``'s dense output at ``SCAN_STEP_S`` spacing and at the output
    instants of ``grid`` in the interval, then locates the crossing with brentq.
    None when no event function is given or none is crossed inside the interval
    (a crossing at t1 itself is solve_ivp's own event).
    """
    if not events or t1 <= t0:
        return None
    scan = np.union1d(np.linspace(t0, t1, int(math.ceil((t1 - t0) / SCAN_STEP_S)) + 1),
                      grid[(grid > t0) & (grid < t1)])
    states = sol.sol(scan)
    first = None
    for event in events:
        values = event(scan, states)  # the unsaturated and saturated events are vectorised
        crossed = (values[:-1] * event.direction < 0) & (values[1:] * event.direction > 0)
        crossed[-1] = False  # the step's own end: solve_ivp's event, already located
        # A run that has just switched starts on the surface, within rounding of it.
        crossed[0] &= abs(values[0]) > 1e-12
        hits = np.flatnonzero(crossed)
        if hits.size:
            i = hits[0]
            root = brentq(lambda tau: event(tau, sol.sol(tau)), scan[i], scan[i + 1], xtol=1e-15, rtol=1e-15)
            first = root if first is None else min(first, root)
    return first


def _event(fun, direction: int):
    """A terminal solve_ivp event function with the given crossing direction."""
    fun.terminal = True
    fun.direction = direction
    return fun


def simulate_sampled(
    plant: SmibParams,
    ctrl: ControllerParams,
    scenario,
    duration_s: float,
    rate_hz: float,
    max_step_s: float = 1e-3,
    link: Link = NO_LINK,
) -> Trajectory:
    """Sampled-data closed loop at ``rate_hz``: the controller node's law, offline.

    At each sample t_k = k/rate_hz the controller reads d(t_k), outputs P_ST held
    over [t_k, t_k+1) and advances x3 exactly; the plant is integrated over the
    period by :func:`nni_plant_sim.integrators.advance` (RK4, steps <= max_step_s),
    the very call the plant node makes. Returns the samples t_0 .. t_n.

    ``link``: the answer to sample k takes effect at t_k + d_k, or is lost (the
    command in force stays); the plant is integrated piecewise between those
    instants, as the plant's reporting core does (:class:`nni_plant_sim.link.DelayLine`).
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"controller rate must be finite and positive, got {rate_hz}")
    period = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    t = np.arange(n + 1) * period
    x = scenario.initial_state(plant)
    law = SampledController(plant, ctrl, period)
    states = np.empty((n + 1, 3))
    outputs = np.empty((n + 1, 3))
    line = DelayLine(link, [0.0])

    def piece(start, stop, x, powers):
        return advance(start, stop, x, powers[0], plant, scenario, max_step_s)

    for k in range(n + 1):
        angle_dev = float(x[0]) - plant.delta_bar_rad
        if not math.isfinite(angle_dev):
            # The run diverged (an unstable design overflowed): no state from here on, no battery power.
            states[k:] = np.nan
            outputs[k:] = (0.0, np.nan, 0.0)
            break
        x3 = law.x3
        power, w, saturated = law.step(angle_dev)
        line.send(0, k, float(t[k]), power, float(t[k]))
        states[k] = (x[0], x[1], x3)
        outputs[k] = (line.powers[0], w, saturated)
        if k < n:
            x = integrate_through(line, piece, float(t[k]), float(t[k + 1]), x)
    return Trajectory(
        plant, ctrl, t, states[:, 0], states[:, 1], states[:, 2],
        outputs[:, 0], outputs[:, 1], outputs[:, 2].astype(bool), np.empty(0),
    )


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
        last_saturated_s=_instant(saturated_instants.max()) if saturated_instants.size else None,
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


#: Precision of the critical clearing time search, s.
CCT_TOLERANCE_S = 1e-3


@dataclass(frozen=True)
class ClearingTime:
    """Critical clearing time of a transfer-limit fault for one b, bracketed by bisection.

    The run stays in synchronism (over ``duration_s``) when the fault clears at
    ``in_sync_s`` and slips when it clears at ``slips_s``; ``slips_s - in_sync_s``
    <= the tolerance. ``cct_s`` is ``in_sync_s``, the longest clearing time
    shown to keep synchronism. ``slips_s`` is None (and cct_s the search's
    upper end) when no clearing time up to that end slipped.
    """

    b: float
    cct_s: float
    in_sync_s: float
    slips_s: float | None
    runs: int

    def to_json(self) -> dict:
        """JSON-ready dict; b = inf is written as the string "inf"."""
        return {"b": "inf" if math.isinf(self.b) else self.b, "cct_s": self.cct_s,
                "bracket_s": [self.in_sync_s, self.slips_s], "runs": self.runs}


def critical_clearing_time(in_sync, b: float, upper_s: float, tolerance_s: float = CCT_TOLERANCE_S) -> ClearingTime:
    """Bisection for the longest clearing time ``t`` with ``in_sync(t)`` true.

    ``in_sync(t)`` runs the fault cleared at ``t`` s and says whether the
    machine stayed in synchronism. The bracket starts at [0, tolerance] (no
    fault keeps the equilibrium) and doubles its upper end until a run slips
    (or ``upper_s`` is reached), then halves to ``tolerance_s``. Instants are
    rounded to 1 ns.
    """
    low, high, runs = 0.0, tolerance_s, 0
    while True:
        runs += 1
        if not in_sync(high):
            break
        if high >= upper_s:
            return ClearingTime(b, round(high, INSTANT_DECIMALS), round(high, INSTANT_DECIMALS), None, runs)
        low, high = high, min(2.0 * high, upper_s)
    while high - low > tolerance_s:
        mid = 0.5 * (low + high)
        runs += 1
        low, high = (mid, high) if in_sync(mid) else (low, mid)
    low, high = round(low, INSTANT_DECIMALS), round(high, INSTANT_DECIMALS)
    return ClearingTime(b, low, low, high, runs)


#: Precision of the delay margin search, s.
DELAY_MARGIN_TOLERANCE_S = 1e-3


@dataclass(frozen=True)
class DelayMargin:
    """The delay margin of one b: the largest fixed measurement-to-command delay shown to keep synchronism.

    ``margin_s``: the longest delay tried that kept the run in synchronism,
    and no shorter one tried slipped; ``slips_s``: the shortest that slipped
    (``slips_s - margin_s`` <= the tolerance). ``margin_s`` None: the run slips
    even without delay (no margin at all). ``slips_s`` None: no delay tried up
    to ``upper_s`` slipped ("no margin found up to upper_s"; ``margin_s`` is
    then the last delay tried, a lower bound, not the margin, and the JSON's
    ``delay_margin_s`` is null).
    """

    b: float
    margin_s: float | None
    slips_s: float | None
    upper_s: float
    runs: int

    def to_json(self) -> dict:
        """JSON-ready dict; b = inf is written as the string "inf"."""
        found = self.slips_s is not None
        return {"b": "inf" if math.isinf(self.b) else self.b, "delay_margin_s": self.margin_s if found else None,
                "bracket_s": [self.margin_s, self.slips_s], "slip_found": found,
                "in_synchronism_up_to_s": self.margin_s, "searched_up_to_s": self.upper_s, "runs": self.runs}

    def text(self) -> str:
        """The table cell: the margin, or what the search found instead."""
        if self.margin_s is None:
            return "none: out of synchronism even without delay"
        if self.slips_s is None:
            return f"no margin found up to {self.upper_s:g} s (in synchronism at every delay tried)"
        return f"{self.margin_s * 1e3:.1f} ms (slips at {self.slips_s * 1e3:.1f} ms)"


#: Step of the delay margin's scan when not given, s.
DELAY_SCAN_STEP_S = 0.05


def delay_margins(in_sync, limits, scan_step_s: float, upper_s: float,
                  tolerance_s: float = DELAY_MARGIN_TOLERANCE_S) -> list[DelayMargin]:
    """The first loss of synchronism as the delay grows, per battery limit: scan, then bisect.

    ``in_sync(delay_s, indices)`` runs the loop with a fixed delay of
    ``delay_s`` s for the limits ``limits[i]``, i in ``indices`` (one batch),
    and says for each whether it stayed in synchronism. Delay 0 first (a run
    that slips there has no margin), then d = j ``scan_step_s`` for j = 1, 2,
    ... up to ``upper_s`` until each limit's run slips, then bisection of
    [last in sync, first slip] to ``tolerance_s``. As for any such search,
    synchronism is assumed monotone between the delays tried (it need not be:
    a finer scan can find an earlier loss). Delays rounded to 1 ns.
    """
    n = len(limits)
    runs = [1] * n
    at_zero = list(in_sync(0.0, list(range(n))))
    low, high = [0.0] * n, [None if ok else 0.0 for ok in at_zero]
    j = 1
    while (delay := round(j * scan_step_s, INSTANT_DECIMALS)) <= upper_s + 1e-12:
        undecided = [i for i in range(n) if high[i] is None]
        if not undecided:
            break
        for i, ok in zip(undecided, in_sync(delay, undecided)):
            runs[i] += 1
            low[i], high[i] = (delay, None) if ok else (low[i], delay)
        j += 1
    for i in range(n):
        while at_zero[i] and high[i] is not None and high[i] - low[i] > tolerance_s:
            mid = round(0.5 * (low[i] + high[i]), INSTANT_DECIMALS)
            runs[i] += 1
            low[i], high[i] = (mid, high[i]) if in_sync(mid, [i])[0] else (low[i], mid)
    return [DelayMargin(limits[i], low[i] if at_zero[i] else None, high[i], upper_s, runs[i]) for i in range(n)]


def equal_area_clearing_time_s(plant: SmibParams) -> float:
    """Critical clearing time of a bolted fault (P_max = 0 while it lasts), no battery, D = 0.

    During the fault M delta'' = P_M, so delta - delta_bar = P_M t^2 / (2 M).
    Equal areas of acceleration (delta_bar to delta_cr, P_M) and deceleration
    (delta_cr to the unstable equilibrium pi - delta_bar, P_max sin delta - P_M)
    give cos(delta_cr) = (pi - 2 delta_bar) sin(delta_bar) - cos(delta_bar), and
    t_cr = sqrt(2 M (delta_cr - delta_bar) / P_M). Paper case: 0.1127 s.
    """
    delta_bar = plant.delta_bar_rad
    delta_cr = math.acos((math.pi - 2.0 * delta_bar) * math.sin(delta_bar) - math.cos(delta_bar))
    return math.sqrt(2.0 * plant.inertia_m * (delta_cr - delta_bar) / plant.p_mech_pu)


def fastest_rate_per_s(plant: SmibParams, ctrl: ControllerParams) -> float:
    """A bound on the loop's fastest rate, 1/s: what an explicit integrator's step must resolve.

    The largest of the controller's 1/tau and alpha/K, the swing's natural
    frequency with the battery's angle feedback sqrt((P_max + L) / M), and the
    damping's D / M. Used to refuse, before any work, a run out of reach.
    """
    m = plant.inertia_m
    return max(1.0 / ctrl.tau_s, ctrl.alpha / ctrl.gain_k,
               math.sqrt((abs(plant.p_max_pu) + ctrl.gain_l) / m), abs(plant.damping_pu) / m)
