"""Fixed-step integration shared by the offline sampled-data simulation and the plant node.

Both call :func:`advance` over one controller period with the same arguments, so
the distributed lockstep loop reproduces the offline run to rounding error.
Pure numpy: no ROS import.
"""

from __future__ import annotations

import math

import numpy as np

from nni_plant_sim.model import SmibParams, swing_rhs


def rk4_step(t: float, x: np.ndarray, h: float, battery_power_pu, plant: SmibParams, scenario) -> np.ndarray:
    """One classical Runge-Kutta step of the swing equation, battery power held.

    ``x`` has shape (2,) or (2, N); the network is evaluated at the step's start
    (callers split steps at the scenario's breakpoints, so it is constant inside).
    """
    p_mech, p_max = scenario.network(t, plant)
    k1 = swing_rhs(x, battery_power_pu, plant, p_mech, p_max)
    k2 = swing_rhs(x + 0.5 * h * k1, battery_power_pu, plant, p_mech, p_max)
    k3 = swing_rhs(x + 0.5 * h * k2, battery_power_pu, plant, p_mech, p_max)
    k4 = swing_rhs(x + h * k3, battery_power_pu, plant, p_mech, p_max)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def advance(
    t0_s: float,
    t1_s: float,
    x,
    battery_power_pu,
    plant: SmibParams,
    scenario,
    max_step_s: float = 1e-3,
) -> np.ndarray:
    """Integrate from ``t0_s`` to ``t1_s`` with the battery power held constant.

    The interval is split at the scenario's breakpoints, then each piece into
    equal RK4 steps no longer than ``max_step_s``. Times are seconds since the
    fault started; ``x`` is ``[delta (rad), speed deviation (rad/s)]``, shape
    (2,) or (2, N).
    """
    if not max_step_s > 0:
        raise ValueError(f"max_step_s must be positive, got {max_step_s}")
    cuts = [t0_s, *(tb for tb in scenario.breakpoints() if t0_s < tb < t1_s), t1_s]
    x = np.asarray(x, dtype=float)
    for start, stop in zip(cuts[:-1], cuts[1:]):
        steps = max(1, math.ceil((stop - start) / max_step_s - 1e-9))
        h = (stop - start) / steps
        for i in range(steps):
            x = rk4_step(start + i * h, x, h, battery_power_pu, plant, scenario)
    return x
