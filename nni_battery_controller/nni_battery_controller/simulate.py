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

The bounds on a run's work: :data:`MAX_SWITCHES` and :data:`MAX_RHS_EVALUATIONS`
stop a run that went out of reach, :func:`fastest_rate_per_s` estimates one
before it starts. A run is judged by :mod:`nni_battery_controller.verdicts`;
the searches over many runs (critical clearing time, delay margin) are in
:mod:`nni_battery_controller.margins`.

Pure numpy/scipy: no ROS import. scipy is imported where the continuous loop
runs, not with the module: the demos and nodes that only use the sampled loop
and :class:`Trajectory` start without it (half a second of CPU each).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

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
    closed_loop_lyapunov,
    saturation_input,
    x3_rate,
)
from nni_battery_controller.laws import Law
from nni_plant_sim.integrators import advance
from nni_plant_sim.battery import EnergyStore
from nni_plant_sim.link import NO_LINK, DelayLine, Link, integrate_through
from nni_plant_sim.model import SmibParams

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
    charge_pu_s : a battery of finite energy's charge at each sample, pu s from empty (None: no energy limit).
    empty_at_s : when that battery first ran empty (None: it did not, or no limit).
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
    law: str = "nni"
    charge_pu_s: np.ndarray | None = None
    empty_at_s: float | None = None

    @property
    def angle_dev_rad(self) -> np.ndarray:
        """Angle deviation d = delta - delta_bar, rad."""
        return self.delta_rad - self.plant.delta_bar_rad

    @property
    def w_hat(self) -> np.ndarray:
        """Closed-loop Lyapunov candidate W_hat along the trajectory, pu*rad (the nni law's; NaN for the others)."""
        if self.law != "nni":
            return np.full(self.t_s.shape, np.nan)
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
    from scipy.integrate import solve_ivp

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
    from scipy.optimize import brentq

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
    law: Law | None = None,
    battery_energy_pu_s: float = math.inf,
) -> Trajectory:
    """Sampled-data closed loop at ``rate_hz``: the controller node's law, offline.

    ``law``: the battery law (:mod:`.laws`; its battery limit is ``ctrl``'s);
    None is the saturated NNI law of ``ctrl``. ``x3`` of a speed law's
    trajectory is its filter's first state.

    At each sample t_k = k/rate_hz the controller reads d(t_k), outputs P_ST held
    over [t_k, t_k+1) and advances x3 exactly; the plant is integrated over the
    period by :func:`nni_plant_sim.integrators.advance` (RK4, steps <= max_step_s),
    the very call the plant node makes. Returns the samples t_0 .. t_n.

    ``link``: the answer to sample k takes effect at t_k + d_k, or is lost (the
    command in force stays); the plant is integrated piecewise between those
    instants, as the plant's reporting core does (:class:`nni_plant_sim.link.DelayLine`).

    ``battery_energy_pu_s``: a battery of that much energy to deliver and as much room to absorb
    (:mod:`nni_plant_sim.battery`; inf: no limit); an empty battery delivers nothing. The trajectory's
    ``battery_power_pu`` is then what the battery gives at each sample and ``charge_pu_s`` its charge.
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"controller rate must be finite and positive, got {rate_hz}")
    store = None if math.isinf(battery_energy_pu_s) else EnergyStore([battery_energy_pu_s])
    period = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    t = np.arange(n + 1) * period
    x = scenario.initial_state(plant)
    spec = Law("nni", ctrl) if law is None else replace(law, ctrl=replace(law.ctrl, battery_limit_pu=ctrl.battery_limit_pu))
    law = spec.sampled(plant, period)
    states = np.empty((n + 1, 3))
    outputs = np.empty((n + 1, 3))
    line = DelayLine(link, [0.0], store=store)
    charge = None if store is None else np.full(n + 1, np.nan)

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
        power, w, saturated = law.step(angle_dev, float(x[1]))
        line.send(0, k, float(t[k]), power, float(t[k]))
        states[k] = (x[0], x[1], x3)
        outputs[k] = (line.applied_powers()[0], w, saturated)
        if store is not None:
            charge[k] = store.charge_pu_s[0]
        if k < n:
            x = integrate_through(line, piece, float(t[k]), float(t[k + 1]), x)
    return Trajectory(
        plant, spec.ctrl, t, states[:, 0], states[:, 1], states[:, 2],
        outputs[:, 0], outputs[:, 1], outputs[:, 2].astype(bool), np.empty(0), spec.name,
        charge, None if store is None else store.empty_at_s[0],
    )


def fastest_rate_per_s(plant: SmibParams, ctrl: ControllerParams) -> float:
    """A bound on the loop's fastest rate, 1/s: what an explicit integrator's step must resolve.

    The largest of the controller's 1/tau and alpha/K, the swing's natural
    frequency with the battery's angle feedback sqrt((P_max + L) / M), and the
    damping's D / M. Used to refuse, before any work, a run out of reach.
    """
    m = plant.inertia_m
    return max(1.0 / ctrl.tau_s, ctrl.alpha / ctrl.gain_k,
               math.sqrt((abs(plant.p_max_pu) + ctrl.gain_l) / m), abs(plant.damping_pu) / m)
