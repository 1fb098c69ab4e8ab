"""The one fixed-step integrator: classical RK4 of a system ``x' = f(t, x, u, params)``.

A system is written as python-control's ``nlsys`` update function: ``rate(t, x,
u, params)`` returns the time derivative of the state ``x`` (a tuple of its
components, each a float for one trajectory or an array for many, all of one
shape) for an input ``u`` held over the step. :func:`rk4` steps any such system,
e.g. the closed loop of plant and H3-hat
(:func:`nni_battery_controller.closed_loop.closed_loop_rate`, in the
region-of-attraction sweep). The plant's own system
(:func:`nni_plant_sim.model.plant_rate`) is stepped by the same RK4 written out
for its two states (the plant's per-sample path, where the generic step's
overhead shows), the same sums in the same order: bit for bit the same result.

:func:`advance` integrates the plant over one controller period with the
battery power held: the plant node and the offline sampled-data simulations
make the same call, so the distributed lockstep loop reproduces the offline run
to rounding error. One RK4 for the SMIB (``plant`` a :class:`SmibParams`) and
for a network of generators (``plant`` a :class:`nni_plant_sim.network.Network`,
whose scenarios give ``(P_m vector, Coupling)`` where the SMIB's give
``(P_M, P_max)``); a network's is compiled (:mod:`.network_rk4`: the same
sums, the swing equations summed in their own order). Pure python, numpy and,
for a network, numba: no ROS import.
"""

from __future__ import annotations

import math

import numpy as np

from nni_plant_sim.model import held_acceleration, plant_rate
from nni_plant_sim.network import Network


def rk4(rate, t: float, x: tuple, h: float, u, params) -> tuple:
    """One classical Runge-Kutta step of ``x' = rate(t, x, u, params)`` over ``h`` s, ``u`` held.

    ``x`` is a sequence of state components (floats, or arrays of one shape for
    a batch of trajectories; ``rate`` gets the stages as lists); returns the
    state at ``t + h``, a tuple. The sums are those of
    ``x + h/6 (k1 + 2 k2 + 2 k3 + k4)``, componentwise.
    """
    half = 0.5 * h
    k1 = rate(t, x, u, params)
    k2 = rate(t + half, [xi + half * ki for xi, ki in zip(x, k1)], u, params)
    k3 = rate(t + half, [xi + half * ki for xi, ki in zip(x, k2)], u, params)
    k4 = rate(t + h, [xi + h * ki for xi, ki in zip(x, k3)], u, params)
    sixth = h / 6.0
    return tuple([xi + sixth * (a + 2.0 * b + 2.0 * c + d) for xi, a, b, c, d in zip(x, k1, k2, k3, k4)])


def rk4_step(t: float, x, h: float, battery_power_pu, plant, scenario) -> np.ndarray:
    """One RK4 step of the plant (:func:`plant_rate`), battery power held.

    ``x`` is ``[delta (rad), speed deviation (rad/s)]``, shape (2,) or (2, N);
    returns the same shape. The network is evaluated at the step's start
    (callers split steps at the scenario's breakpoints, so it is constant inside).
    """
    p_mech, network = scenario.network(t, plant)
    delta, speed = _components(x)
    return np.array(_rk4_swing(delta, speed, h, held_acceleration(plant, p_mech, network, battery_power_pu, delta)))


def _components(x) -> tuple:
    """``(delta, speed)`` of a state ``x``: Python floats for one trajectory, arrays for a batch.

    One trajectory runs on floats: numpy's per-call overhead on a 2-vector made
    RK4 cost 13 us a step (measured); floats take about 2. A network's state
    ``[delta, speed]`` has shape (2, N) or (2, N, R) and stays in arrays.
    """
    x = np.asarray(x, dtype=float)
    return (float(x[0]), float(x[1])) if x.ndim == 1 else (x[0], x[1])


def _rk4_swing(delta, speed, h, acceleration) -> tuple:
    """:func:`rk4` of :func:`~nni_plant_sim.model.plant_rate` written out: the same sums in the same order.

    The SMIB plant's path, the node's (20 to 50 steps a sample, on floats) and
    the batches' (arrays; a network's steps are :mod:`.network_rk4`'s): the
    generic step's lists and rate calls cost more than the arithmetic on two
    floats (2.5x, timings in the notes on issue 12). Stage k_i = (k_i delta, k_i speed) = (speed
    at the stage, acceleration at the stage), as plant_rate gives them;
    ``acceleration(delta, speed)`` is :func:`~nni_plant_sim.model.held_acceleration`.
    """
    k1_delta, k1_speed = speed, acceleration(delta, speed)
    k2_delta = speed + 0.5 * h * k1_speed
    k2_speed = acceleration(delta + 0.5 * h * k1_delta, k2_delta)
    k3_delta = speed + 0.5 * h * k2_speed
    k3_speed = acceleration(delta + 0.5 * h * k2_delta, k3_delta)
    k4_delta = speed + h * k3_speed
    k4_speed = acceleration(delta + h * k3_delta, k4_delta)
    return (delta + (h / 6.0) * (k1_delta + 2.0 * k2_delta + 2.0 * k3_delta + k4_delta),
            speed + (h / 6.0) * (k1_speed + 2.0 * k2_speed + 2.0 * k3_speed + k4_speed))


def advance(
    t0_s: float,
    t1_s: float,
    x,
    battery_power_pu,
    plant,
    scenario,
    max_step_s: float = 1e-3,
) -> np.ndarray:
    """Integrate from ``t0_s`` to ``t1_s`` with the battery power held constant.

    The interval is split at the scenario's breakpoints, then each piece into
    equal RK4 steps no longer than ``max_step_s``. Between breakpoints the
    scenario's network is constant, so it is read once per piece (not per
    step: the plant node's float path saves a call per step). Times are seconds since the
    fault started; ``x`` is ``[delta (rad), speed deviation (rad/s)]``, shape
    (2,) or (2, N) for the SMIB, (2, N) or (2, N, R) for a network of N
    generators (R runs; ``battery_power_pu`` then broadcasts against (N, R));
    returns the same shape.
    """
    if not max_step_s > 0:
        raise ValueError(f"max_step_s must be positive, got {max_step_s}")
    t0_s, t1_s = float(t0_s), float(t1_s)  # numpy scalars (np.arange times) would make every stage numpy
    cuts = [t0_s, *(tb for tb in scenario.breakpoints() if t0_s < tb < t1_s), t1_s]
    delta, speed = _components(x)
    power = float(battery_power_pu) if np.ndim(battery_power_pu) == 0 else battery_power_pu
    for start, stop in zip(cuts[:-1], cuts[1:]):
        steps = max(1, math.ceil((stop - start) / max_step_s - 1e-9))
        h = (stop - start) / steps
        p_mech, network = scenario.network(start, plant)
        if isinstance(plant, Network):
            # Imported here: numba (0.2 s) only for a network, never on the SMIB's paths.
            from nni_plant_sim.network_rk4 import rk4_network

            delta, speed = rk4_network(delta, speed, steps, h, plant, p_mech, network, power)
            continue
        acceleration = held_acceleration(plant, p_mech, network, power, delta)
        for _ in range(steps):
            try:
                delta, speed = _rk4_swing(delta, speed, h, acceleration)
            except ValueError:  # the float form's math.sin at an infinite angle: numpy's NaN, as everywhere else
                acceleration = held_acceleration(plant, p_mech, network, power, None)
                delta, speed = _rk4_swing(delta, speed, h, acceleration)
    return np.array((delta, speed))
