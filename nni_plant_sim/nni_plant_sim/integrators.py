"""Fixed-step integration shared by the offline sampled-data simulations and the plant node.

Both call :func:`advance` over one controller period with the same arguments, so
the distributed lockstep loop reproduces the offline run to rounding error.
The region-of-attraction sweep calls :func:`rk4_step` on arrays of states.
One RK4 for the SMIB (``plant`` a :class:`SmibParams`) and for a network of
generators (``plant`` a :class:`nni_plant_sim.network.Network`, whose scenarios
give ``(P_m vector, Coupling)`` where the SMIB's give ``(P_M, P_max)``).
Pure python and numpy: no ROS import.
"""

from __future__ import annotations

import math

import numpy as np

from nni_plant_sim.model import SmibParams, swing_acceleration
from nni_plant_sim.network import network_acceleration


def rk4_step(t: float, x, h: float, battery_power_pu, plant, scenario) -> np.ndarray:
    """One classical Runge-Kutta step of the swing equation, battery power held.

    ``x`` is ``[delta (rad), speed deviation (rad/s)]``, shape (2,) or (2, N);
    returns the same shape. The network is evaluated at the step's start
    (callers split steps at the scenario's breakpoints, so it is constant inside).
    """
    return np.array(_rk4(*_components(x), h, battery_power_pu, plant, scenario.network(t, plant),
                         _acceleration_of(plant)))


def _acceleration_of(plant):
    """The swing equation of a SMIB (:class:`SmibParams`) or of a network of generators."""
    return swing_acceleration if isinstance(plant, SmibParams) else network_acceleration


def _components(x) -> tuple:
    """``(delta, speed)`` of a state ``x``: Python floats for one trajectory, arrays for a batch.

    One trajectory runs on floats: numpy's per-call overhead on a 2-vector made
    RK4 cost 13 us a step (measured); floats take about 2. A network's state
    ``[delta, speed]`` has shape (2, N) or (2, N, R) and stays in arrays.
    """
    x = np.asarray(x, dtype=float)
    return (float(x[0]), float(x[1])) if x.ndim == 1 else (x[0], x[1])


def _rk4(delta, speed, h: float, battery_power_pu, plant, network_in_force, acceleration):
    """RK4 written out for the two states: floats (one trajectory) or arrays (many) alike.

    ``acceleration(delta, speed, battery_power_pu, plant, *network_in_force)``
    is the swing equation (:func:`_acceleration_of`); ``network_in_force`` is
    ``scenario.network(t, plant)``, constant over the step.

    Stage k_i = (k_i delta, k_i speed) = (speed at the stage, swing acceleration
    at the stage); the same sums as ``x + h/6 (k1 + 2 k2 + 2 k3 + k4)`` on the
    state vector, without allocating one.
    """
    p_mech, network = network_in_force
    k1_delta, k1_speed = speed, acceleration(delta, speed, battery_power_pu, plant, p_mech, network)
    k2_delta = speed + 0.5 * h * k1_speed
    k2_speed = acceleration(delta + 0.5 * h * k1_delta, k2_delta, battery_power_pu, plant, p_mech, network)
    k3_delta = speed + 0.5 * h * k2_speed
    k3_speed = acceleration(delta + 0.5 * h * k2_delta, k3_delta, battery_power_pu, plant, p_mech, network)
    k4_delta = speed + h * k3_speed
    k4_speed = acceleration(delta + h * k3_delta, k4_delta, battery_power_pu, plant, p_mech, network)
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
    acceleration = _acceleration_of(plant)
    for start, stop in zip(cuts[:-1], cuts[1:]):
        steps = max(1, math.ceil((stop - start) / max_step_s - 1e-9))
        h = (stop - start) / steps
        network_in_force = scenario.network(start, plant)
        for _ in range(steps):
            delta, speed = _rk4(delta, speed, h, power, plant, network_in_force, acceleration)
    return np.array((delta, speed))
