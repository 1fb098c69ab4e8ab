"""Region of attraction of the battery-controlled SMIB generator, vectorised across initial conditions.

For a battery limit b, every initial condition ``(angle_dev0 rad, speed0 rad/s)``
(the fault has just cleared; the controller state starts at x3 = 0, its pre-fault
value) gets one outcome:

* ``RETURNS``: the trajectory provably returns to the equilibrium (0, 0, 0);
* ``STAYS``: it provably stays in synchronism but does not return (b = 0 with
  D = 0: the undamped, uncontrolled machine oscillates forever inside Omega);
* ``SLIPS``: the rotor angle against the infinite bus passed +-pi, |delta| > pi
  (a pole slip as out-of-step protection sees it, the criterion of
  :func:`nni_battery_controller.verdicts.assess`; an initial condition with
  |delta0| > pi has slipped at t = 0);
* ``UNDECIDED``: none of these within the horizon (reported, never guessed).

Time model. The paper's continuous-time law (what
:func:`~nni_battery_controller.simulate.simulate_continuous` solves with located
switching events and Filippov sliding), integrated by classical RK4 at a fixed
10 ms step with the law's right-hand side taken as it stands at each stage (the
mode from that stage's own w: :func:`~nni_battery_controller.closed_loop.closed_loop_rate`
stepped by :func:`nni_plant_sim.integrators.rk4`, the RK4 whose written-out form
steps the plant node). Away from a switch
this is 4th-order accurate (the fastest closed-loop rates, |lambda| = 5.7/s and
1/tau = 10/s, times the step are at most 0.1); a step that straddles a switch,
or a sliding motion whose stages fall on both sides of |w| = b, makes an O(h)
local error of either sign. Holding the mode over each step instead (decided at
its start) delays every switch by up to a step, an error of one sign: on the
paper's case, against simulate_continuous on the basins' boundary cells, the
held mode at 5 ms disagreed on about 0.15 % of a 200 x 200 grid, the stage-wise
mode at 10 ms on about 0.05 % (0.03 % at 1 ms). We model the continuous law
rather than the 1 kHz sampled law of the controller node so that the
cross-check against simulate_continuous measures numerical error, not a
difference of systems (the 1 kHz sampled loop's basin differs from the
continuous one on about 0.07 % of the cells, all on the boundary).

Early exits, so that only undecided trajectories are integrated further (the
active set shrinks as the run goes):

* a pole slip is final: |delta| > pi at a step's end, or at the extremum of
  delta inside a step whose speed changes sign (:func:`step_peak_angle`: a
  trajectory grazing delta = pi turns round within a few ms, between two step ends);
* b > 0: in the unsaturated mode the closed loop is linear (``M d'' + D d' =
  x3 - L d``) and the paper's W = 1/2 [d', d, x3] Q1 [d', d, x3]^T does not
  increase along it (W' = -D d'^2 - (K d - x3)^2 / (K tau) <= 0). A sublevel set
  of W that lies inside |w| < b and |delta| < pi is therefore invariant and the
  loop, linear and asymptotically stable in it, converges: entering it is a
  certificate of RETURNS. :func:`returns_level` finds the largest such level;
* b = 0: no battery, the plant alone. The paper's invariant set Omega (W of the
  plant <= c, |d| <= pi - 2 delta_bar) is never left (W' = -D d'^2 <= 0): a
  trajectory in it stays in synchronism; with D > 0 it also returns (LaSalle:
  the origin is the only equilibrium inside Omega); with D = 0 W is constant,
  the machine oscillates on a closed orbit and never returns (STAYS).

The dynamics are the one closed-loop system
(:mod:`nni_battery_controller.closed_loop`) applied to states whose components
have shape (N,); there is no second copy of the physics here. Pure numpy (scipy
for the per-trajectory baseline): no ROS import.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from nni_battery_controller.closed_loop import LoopParams, closed_loop_rate
from nni_battery_controller.law import ControllerParams, q1_matrix, saturation_input
from nni_battery_controller.simulate import simulate_continuous
from nni_battery_controller.verdicts import POLE_SLIP_RAD
from nni_plant_sim.integrators import rk4
from nni_plant_sim.model import (
    SmibParams,
    critical_angles_rad,
    in_invariant_set,
    invariant_set_boundary,
    invariant_set_level,
)
from nni_plant_sim.scenarios import InitialAngle

#: The network after the fault has cleared (pre-fault P_M and P_max), as the sweep assumes.
POST_FAULT = InitialAngle()

RETURNS, STAYS, SLIPS, UNDECIDED = 2, 1, 0, -1
#: Only from the per-trajectory baseline: simulate_continuous raised (e.g. a chattering run).
FAILED = -2
OUTCOME_NAMES = {RETURNS: "returns", STAYS: "stays", SLIPS: "slips", UNDECIDED: "undecided"}
OUTCOME_MEANINGS = {
    "returns": "provably returns to the equilibrium (entered a certified region)",
    "stays": "provably stays in synchronism without returning (inside Omega, no battery, D = 0)",
    "slips": "the rotor angle passed +-pi (180 degrees against the infinite bus): a pole slip",
    "undecided": "none of these within the horizon",
}

#: RK4 step of the sweep, s (see "Time model" above for the error it costs).
STEP_S = 1e-2
#: Longest simulated time per trajectory, s. The slowest decided trajectory of
#: the paper's case takes about 11 s (b = 0.2, entering the small certificate).
HORIZON_S = 30.0
#: How often the early exits are checked, s (the pole-slip check runs every step).
CHECK_EVERY_S = 0.05
#: The certificate level used is this fraction of the largest one found, a margin
#: for the sampled search of the level and the step's rounding.
LEVEL_MARGIN = 0.9


@dataclass(frozen=True)
class RoaGrid:
    """A cell-centred grid of initial conditions in the (angle deviation, speed deviation) plane.

    Parameters
    ----------
    angle_min_rad, angle_max_rad : float
        Range of the initial angle deviation d0 = delta0 - delta_bar, rad.
    speed_min_rad_s, speed_max_rad_s : float
        Range of the initial speed deviation d0' = omega - omega0, rad/s.
    n_angle, n_speed : int
        Number of cells along each axis (each >= 2).
    """

    angle_min_rad: float = -math.pi
    angle_max_rad: float = math.pi
    speed_min_rad_s: float = -10.0
    speed_max_rad_s: float = 10.0
    n_angle: int = 200
    n_speed: int = 200

    def __post_init__(self) -> None:
        for name in ("angle_min_rad", "angle_max_rad", "speed_min_rad_s", "speed_max_rad_s"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)}")
        if not self.angle_min_rad < self.angle_max_rad:
            raise ValueError(f"angle range must satisfy min < max, got [{self.angle_min_rad}, {self.angle_max_rad}]")
        if not self.speed_min_rad_s < self.speed_max_rad_s:
            raise ValueError(
                f"speed range must satisfy min < max, got [{self.speed_min_rad_s}, {self.speed_max_rad_s}]")
        for name in ("n_angle", "n_speed"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 2:
                raise ValueError(f"{name} must be an integer >= 2, got {getattr(self, name)}")

    @property
    def angle_centres_rad(self) -> np.ndarray:
        """Cell centres along the angle axis, rad, shape (n_angle,)."""
        width = (self.angle_max_rad - self.angle_min_rad) / self.n_angle
        return self.angle_min_rad + width * (np.arange(self.n_angle) + 0.5)

    @property
    def speed_centres_rad_s(self) -> np.ndarray:
        """Cell centres along the speed axis, rad/s, shape (n_speed,)."""
        width = (self.speed_max_rad_s - self.speed_min_rad_s) / self.n_speed
        return self.speed_min_rad_s + width * (np.arange(self.n_speed) + 0.5)

    @property
    def cell_area(self) -> float:
        """Area of one cell, rad * rad/s."""
        return ((self.angle_max_rad - self.angle_min_rad) / self.n_angle
                * (self.speed_max_rad_s - self.speed_min_rad_s) / self.n_speed)

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_speed, n_angle)``: rows are speeds, columns angles (as for imshow / contour)."""
        return self.n_speed, self.n_angle

    def initial_conditions(self) -> tuple[np.ndarray, np.ndarray]:
        """``(angle_dev0 rad, speed0 rad/s)``, each flat of size n_speed * n_angle, row-major in :attr:`shape`."""
        angle, speed = np.meshgrid(self.angle_centres_rad, self.speed_centres_rad_s)
        return angle.ravel(), speed.ravel()


def linear_loop_lyapunov(angle_dev_rad, speed_rad_s, x3, plant: SmibParams, ctrl: ControllerParams):
    """W = 1/2 [d', d, x3] Q1 [d', d, x3]^T of the unsaturated (linear) loop, pu * rad; vectorised.

    The paper's W_hat with the unsaturated F (Theorem 2's Q1), whatever the mode at the state.
    """
    q1 = q1_matrix(plant.inertia_m, ctrl.gain_k, ctrl.gain_l)
    return 0.5 * (q1[0, 0] * np.square(speed_rad_s) + q1[1, 1] * np.square(angle_dev_rad)
                  + 2.0 * q1[1, 2] * angle_dev_rad * x3 + q1[2, 2] * np.square(x3))


def returns_level(plant: SmibParams, ctrl: ControllerParams, angles: int = 720, radii: int = 64) -> float:
    """Largest level r with {W <= r} inside {|w| < b} and {|delta| < pi}, pu * rad (0 for b = 0).

    W's sublevel set projects on the (d, x3) plane as the ellipse
    ``L d^2 / 2 - d x3 + x3^2 / (2K) <= r`` (d' = 0 minimises W); ``w`` depends
    on (d, x3) only. The constraints are checked on a polar grid filling the
    ellipse (``angles`` x ``radii`` points): the largest of |delta| / pi and
    |w| / b there grows with r (the ellipse scales with sqrt(r)), and r is the
    root of that margin minus one (brentq).
    """
    from scipy.optimize import brentq  # with the search, not the module: see simulate's docstring

    b = ctrl.battery_limit_pu
    if b == 0.0:
        return 0.0
    # Points of the ellipse at level 1/2, from the centre out: B^(-1/2) u for |u| <= 1.
    quad = np.array([[ctrl.gain_l, -1.0], [-1.0, 1.0 / ctrl.gain_k]])
    eigenvalues, eigenvectors = np.linalg.eigh(quad)
    inverse_root = eigenvectors @ np.diag(eigenvalues ** -0.5) @ eigenvectors.T
    theta = np.linspace(0.0, 2.0 * math.pi, angles, endpoint=False)
    unit = inverse_root @ np.stack((np.cos(theta), np.sin(theta)))
    filling = (unit[:, :, np.newaxis] * np.linspace(0.0, 1.0, radii + 1)[1:]).reshape(2, -1)

    def margin(level: float) -> float:
        """Above zero once the ellipse at ``level`` reaches |delta| = pi or |w| = b."""
        angle_dev, x3 = filling * math.sqrt(2.0 * level)
        return max(float(np.max(np.abs(angle_dev + plant.delta_bar_rad))) / POLE_SLIP_RAD,
                   float(np.max(np.abs(saturation_input(x3, angle_dev, ctrl, plant)))) / b) - 1.0

    high = 1.0
    while margin(high) < 0.0:  # |delta| < pi bounds the level even for b = inf
        high *= 2.0
    return brentq(margin, 0.0, high, xtol=1e-12, rtol=1e-9)


def decide(angle_dev_rad, speed_rad_s, x3, slipped, plant: SmibParams, ctrl: ControllerParams, level: float):
    """Outcome codes decided at these states, UNDECIDED where none applies yet; vectorised.

    ``slipped`` says whether |delta| has exceeded pi up to now; ``level`` is the
    certificate level for b > 0 (from :func:`returns_level`, with margin).
    """
    outcome = np.full(np.shape(angle_dev_rad), UNDECIDED, dtype=np.int8)
    if ctrl.battery_limit_pu > 0:
        outcome[linear_loop_lyapunov(angle_dev_rad, speed_rad_s, x3, plant, ctrl) <= level] = RETURNS
    else:
        outcome[in_invariant_set(angle_dev_rad, speed_rad_s, plant)] = RETURNS if plant.damping_pu > 0 else STAYS
    outcome[slipped] = SLIPS
    return outcome


def closed_loop_step(state: tuple, step_s: float, params: LoopParams) -> tuple:
    """One RK4 step of the post-fault closed loop, the law's mode taken at each stage; vectorised.

    ``state`` is ``(delta rad, speed deviation rad/s, x3 pu)``, arrays of shape
    (N,); :func:`~nni_battery_controller.closed_loop.closed_loop_rate` stepped by
    the one integrator, :func:`nni_plant_sim.integrators.rk4`.
    """
    return rk4(closed_loop_rate, 0.0, state, step_s, POST_FAULT.network(0.0, params.plant), params)


def classify(plant: SmibParams, ctrl: ControllerParams, angle_dev0_rad, speed0_rad_s,
             step_s: float = STEP_S, horizon_s: float = HORIZON_S, on_check=None) -> tuple[np.ndarray, np.ndarray]:
    """Outcome of every initial condition, integrated together as one (3, N) state.

    Parameters
    ----------
    angle_dev0_rad, speed0_rad_s : array_like, shape (N,)
        Initial angle deviation (rad) and speed deviation (rad/s); x3(0) = 0.
    step_s, horizon_s : float
        RK4 step and longest simulated time, s.
    on_check : callable, optional
        ``on_check(simulated_s, undecided)`` after each decision check (every
        CHECK_EVERY_S simulated), e.g. for progress reports.

    Returns
    -------
    outcome : numpy.ndarray of int8, shape (N,)
        RETURNS, STAYS, SLIPS or UNDECIDED.
    decided_at_s : numpy.ndarray, shape (N,)
        Simulated time of the decision, s (NaN if undecided).
    """
    angle_dev0 = np.asarray(angle_dev0_rad, dtype=float).ravel()
    speed0 = np.asarray(speed0_rad_s, dtype=float).ravel()
    if angle_dev0.shape != speed0.shape:
        raise ValueError(f"initial angles and speeds must have the same size, got {angle_dev0.size} and {speed0.size}")
    if not (np.all(np.isfinite(angle_dev0)) and np.all(np.isfinite(speed0))):
        raise ValueError("initial conditions must be finite")
    if not (math.isfinite(step_s) and step_s > 0 and math.isfinite(horizon_s) and horizon_s > 0):
        raise ValueError(f"step and horizon must be finite and positive, got {step_s} and {horizon_s}")
    delta_bar = plant.delta_bar_rad
    level = LEVEL_MARGIN * returns_level(plant, ctrl)
    outcome = np.full(angle_dev0.size, UNDECIDED, dtype=np.int8)
    decided_at = np.full(angle_dev0.size, np.nan)

    active = np.arange(angle_dev0.size)  # indices of the trajectories still integrated
    state = (angle_dev0 + delta_bar, speed0, np.zeros_like(angle_dev0))
    params = LoopParams(plant, ctrl)
    max_abs_delta = np.abs(angle_dev0 + delta_bar)  # the rotor angle, for the pole-slip rule
    check_every = max(1, round(CHECK_EVERY_S / step_s))
    steps = math.ceil(horizon_s / step_s - 1e-9)
    for k in range(steps + 1):
        if k % check_every == 0 or k == steps:
            now = decide(state[0] - delta_bar, state[1], state[2], max_abs_delta > POLE_SLIP_RAD, plant, ctrl, level)
            done = now != UNDECIDED
            if done.any():
                outcome[active[done]] = now[done]
                decided_at[active[done]] = k * step_s
                keep = ~done
                active, state, max_abs_delta = active[keep], tuple(c[keep] for c in state), max_abs_delta[keep]
            if on_check is not None:
                on_check(k * step_s, active.size)
            if active.size == 0 or k == steps:
                break
        previous, state = state, closed_loop_step(state, step_s, params)
        np.maximum(max_abs_delta, np.abs(state[0]), out=max_abs_delta)
        turned = np.flatnonzero(previous[1] * state[1] < 0.0)  # the speed changed sign: a peak of d inside
        if turned.size:
            peak = step_peak_angle(previous[0][turned], previous[1][turned], state[0][turned], state[1][turned],
                                   step_s)
            max_abs_delta[turned] = np.maximum(max_abs_delta[turned], np.abs(peak))
    return outcome, decided_at


def step_peak_angle(angle_start, speed_start, angle_end, speed_end, step_s: float):
    """Extremum of the angle inside a step whose speed changes sign, from the cubic Hermite interpolant.

    The step ends alone would miss a pole slip whose peak |d| > pi falls between
    them (a trajectory grazing d = pi turns round within a few ms). The cubic
    through both ends' angles and speeds is 4th-order accurate, as the RK4 step.
    Vectorised; angles in rad, speeds in rad/s.
    """
    h = step_s
    # p'(s) / h for s in [0, 1]: the speed along the interpolant, a quadratic a s^2 + b s + c.
    a = 3.0 * (2.0 * (angle_start - angle_end) + h * (speed_start + speed_end))
    b = -6.0 * (angle_start - angle_end) - h * (4.0 * speed_start + 2.0 * speed_end)
    c = h * speed_start
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))
        # The root in [0, 1] where the speed changes sign (the one of the stable form of the quadratic formula).
        s = np.where(np.abs(a) > 1e-12 * (np.abs(b) + np.abs(c)), (-b - np.sign(b) * root) / (2.0 * a), -c / b)
        s_other = c / (a * s)
        s = np.where((s >= 0.0) & (s <= 1.0), s, s_other)
    s = np.clip(np.nan_to_num(s, nan=0.0), 0.0, 1.0)
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * angle_start + h10 * h * speed_start + h01 * angle_end + h11 * h * speed_end


def classify_trajectory(traj, plant: SmibParams, ctrl: ControllerParams) -> tuple[int, float]:
    """Outcome of one computed trajectory (e.g. from ``simulate_continuous``) by the same rules.

    Returns ``(outcome, decided_at_s)``: the first sample where :func:`decide`
    applies (UNDECIDED, NaN if none).
    """
    angle_dev = traj.angle_dev_rad
    slipped = np.maximum.accumulate(np.abs(traj.delta_rad)) > POLE_SLIP_RAD
    level = LEVEL_MARGIN * returns_level(plant, ctrl)
    now = decide(angle_dev, traj.speed_rad_s, traj.x3, slipped, plant, ctrl, level)
    first = np.flatnonzero(now != UNDECIDED)
    if first.size == 0:
        return UNDECIDED, math.nan
    return int(now[first[0]]), float(traj.t_s[first[0]])


def classify_continuous(plant: SmibParams, ctrl: ControllerParams, angle_dev0_rad, speed0_rad_s,
                        horizon_s: float = HORIZON_S, first_try_s: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """The per-trajectory baseline: :func:`simulate_continuous` for each initial condition, one at a time.

    Each run has located switching events and Filippov sliding (the reference
    for the continuous law). It first runs ``first_try_s`` seconds and only the
    undecided ones again over the full horizon (simulate_continuous has no
    early exit). Returns ``(outcome, decided_at_s)`` like :func:`classify`;
    FAILED where simulate_continuous raised RuntimeError.
    """

    angle_dev0 = np.asarray(angle_dev0_rad, dtype=float).ravel()
    speed0 = np.asarray(speed0_rad_s, dtype=float).ravel()
    outcome = np.full(angle_dev0.size, UNDECIDED, dtype=np.int8)
    decided_at = np.full(angle_dev0.size, np.nan)
    for i, (angle_dev, speed) in enumerate(zip(angle_dev0, speed0)):
        scenario = InitialAngle(angle_dev + plant.delta_bar_rad, speed)
        for duration in (min(first_try_s, horizon_s), horizon_s):
            try:
                traj = simulate_continuous(plant, ctrl, scenario, duration)
            except RuntimeError:  # the event-located run gave up (chattering at |w| = b)
                outcome[i] = FAILED
                break
            outcome[i], decided_at[i] = classify_trajectory(traj, plant, ctrl)
            if outcome[i] != UNDECIDED or duration >= horizon_s:
                break
    return outcome, decided_at


@dataclass(frozen=True)
class Basin:
    """The outcome of every cell of a grid for one battery limit.

    Attributes
    ----------
    b : battery limit, pu.
    outcome : int8 array shaped ``grid.shape`` (rows speeds, columns angles).
    decided_at_s : decision times, s, same shape (NaN if undecided).
    elapsed_s : wall time of the classification, s.
    """

    grid: RoaGrid
    b: float
    outcome: np.ndarray
    decided_at_s: np.ndarray
    elapsed_s: float

    def count(self, code: int) -> int:
        """Number of cells with this outcome."""
        return int(np.count_nonzero(self.outcome == code))

    def summary(self) -> dict:
        """Areas (rad * rad/s) and grid fractions of 'returns' and 'in synchronism' (not slipped), counts."""
        cells = self.outcome.size
        returns = self.count(RETURNS)
        synchronism = cells - self.count(SLIPS)
        return {
            "b": "inf" if math.isinf(self.b) else self.b,
            "returns_area_rad2_per_s": returns * self.grid.cell_area,
            "returns_fraction": returns / cells,
            "synchronism_area_rad2_per_s": synchronism * self.grid.cell_area,
            "synchronism_fraction": synchronism / cells,
            "cells": {name: self.count(code) for code, name in OUTCOME_NAMES.items()},
            "slowest_decision_s": (float(np.nanmax(self.decided_at_s))
                                   if np.any(np.isfinite(self.decided_at_s)) else None),
            "elapsed_s": self.elapsed_s,
        }


def sweep(plant: SmibParams, ctrls, grid: RoaGrid, step_s: float = STEP_S, horizon_s: float = HORIZON_S,
          progress=None, on_check=None) -> list[Basin]:
    """One :class:`Basin` per controller (one per battery limit) on ``grid``.

    ``progress(index, total, basin)`` is called after each, e.g. to report on stderr;
    ``on_check(index, simulated_s, undecided)`` during each (see :func:`classify`).
    """
    angle_dev0, speed0 = grid.initial_conditions()
    basins = []
    for index, ctrl in enumerate(ctrls):
        started = time.perf_counter()
        check = None if on_check is None else (lambda t, n, index=index: on_check(index, t, n))
        outcome, decided_at = classify(plant, ctrl, angle_dev0, speed0, step_s, horizon_s, check)
        basin = Basin(grid, ctrl.battery_limit_pu, outcome.reshape(grid.shape), decided_at.reshape(grid.shape),
                      time.perf_counter() - started)
        basins.append(basin)
        if progress is not None:
            progress(index, len(ctrls), basin)
    return basins


def boundary_cells(outcome: np.ndarray) -> np.ndarray:
    """Cells with a 4-neighbour of a different outcome (the basin boundary on the grid); boolean."""
    edge = np.zeros(outcome.shape, dtype=bool)
    vertical = outcome[1:, :] != outcome[:-1, :]
    horizontal = outcome[:, 1:] != outcome[:, :-1]
    edge[1:, :] |= vertical
    edge[:-1, :] |= vertical
    edge[:, 1:] |= horizontal
    edge[:, :-1] |= horizontal
    return edge


def report(plant: SmibParams, ctrls, grid: RoaGrid, basins, step_s: float = STEP_S,
           horizon_s: float = HORIZON_S) -> dict:
    """JSON-ready description of a sweep: grid, time model, Omega, EAC and one summary per basin."""
    angle_dev0, speed0 = grid.initial_conditions()
    omega_cells = int(np.count_nonzero(in_invariant_set(angle_dev0, speed0, plant)))
    boundary = invariant_set_boundary(plant, points=4000)
    omega_area = 0.5 * abs(float(np.dot(boundary[:-1, 0], boundary[1:, 1]) - np.dot(boundary[1:, 0], boundary[:-1, 1])))
    delta0_low, delta0_high = critical_angles_rad(plant)
    ctrl = ctrls[0]
    return {
        "grid": {
            "angle_dev_rad": [grid.angle_min_rad, grid.angle_max_rad],
            "speed_rad_s": [grid.speed_min_rad_s, grid.speed_max_rad_s],
            "n_angle": grid.n_angle, "n_speed": grid.n_speed,
            "cell_area_rad2_per_s": grid.cell_area,
            "initial_x3_pu": 0.0,
        },
        "time_model": {
            "law": "continuous H3-hat, fixed-step RK4 with the law's mode taken at each stage",
            "step_s": step_s, "horizon_s": horizon_s,
            "pole_slip": "|rotor angle delta| > pi (180 degrees against the infinite bus)",
        },
        "outcomes": OUTCOME_MEANINGS,
        "plant": {"inertia_h_s": plant.inertia_h_s, "damping_pu": plant.damping_pu, "p_mech_pu": plant.p_mech_pu,
                  "p_max_pu": plant.p_max_pu, "f0_hz": plant.f0_hz, "delta_bar_rad": plant.delta_bar_rad},
        "controller": {"tau_s": ctrl.tau_s, "gain_k": ctrl.gain_k, "gain_l": ctrl.gain_l, "alpha": ctrl.alpha},
        "invariant_set": {
            "level_c": invariant_set_level(plant),
            "area_rad2_per_s": omega_area,
            "grid_cells": omega_cells,
        },
        "eac": {
            "critical_delta0_rad": [delta0_low, delta0_high],
            "critical_angle_dev_rad": [delta0_low - plant.delta_bar_rad, delta0_high - plant.delta_bar_rad],
            "meaning": "released at rest with no battery and D = 0, the machine stays in synchronism "
                       "for delta0 strictly between these angles",
        },
        "basins": [basin.summary() for basin in basins],
    }
