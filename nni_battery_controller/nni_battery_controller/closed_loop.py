"""The closed loop of the SMIB plant (H1) and the continuous-time H3-hat, as one system ``f(t, x, u, params)``.

Written as python-control's ``nlsys`` update function, so that
:func:`nni_plant_sim.integrators.rk4` steps it (the region-of-attraction sweep)
and an adaptive solver can take it piecewise by mode (the continuous
simulation, :func:`nni_battery_controller.simulate.simulate_continuous`):

* state ``x = (delta rad, speed deviation rad/s, x3 pu)``: floats, or arrays of
  one shape (one entry per trajectory);
* input ``u = (P_M pu, P_max pu)``: the network in force, what a scenario's
  ``network(t, plant)`` gives (the fault is the loop's exogenous input);
* ``params``: a :class:`LoopParams` (plant, controller, and which mode of the
  switching law is in force).

    delta'  = speed
    speed'  = (P_M + P_ST - P_max sin(delta) - D speed) / M
    x3'     = (K d - x3) / tau  unsaturated,   -(alpha / K) x3  saturated
    P_ST    = w unsaturated,  +-b saturated,   w = x3 - L d - g(d),  d = delta - delta_bar

The loop is the interconnection of the plant's system
(:func:`nni_plant_sim.model.plant_rate`, input P_ST) and the law's pieces
(:mod:`nni_battery_controller.law`); nothing is written twice here. Pure
numpy: no ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nni_battery_controller.law import ControllerParams, is_saturated, saturate, saturation_input, x3_rate
from nni_plant_sim.model import SmibParams, plant_rate

#: The law's mode decided by each state's own w (|w| >= b saturated): what the law does off the switching surface.
BY_STATE = "by state"
#: Modes held by a caller that locates the switches itself (the continuous simulation).
UNSATURATED, SATURATED, SLIDING = "unsaturated", "saturated", "sliding"


@dataclass(frozen=True)
class LoopParams:
    """Parameters of :func:`closed_loop_rate`.

    Attributes
    ----------
    plant : SmibParams
        The generator (and the law's model of it: delta_bar and P_max in g(d)).
    ctrl : ControllerParams
        Gains and the battery limit b.
    mode : str
        :data:`BY_STATE` (the default), or a mode held whatever the state:
        :data:`UNSATURATED` (P_ST = w), :data:`SATURATED` (P_ST = side b, x3
        decays) or :data:`SLIDING` (P_ST = side b, x3 moves so that w stays on
        the surface |w| = b: the Filippov solution).
    side : float
        +1 or -1: the sign of the saturated power in the held modes SATURATED and SLIDING.
    """

    plant: SmibParams
    ctrl: ControllerParams
    mode: str = BY_STATE
    side: float = 0.0


def surface_drift(delta_rad, speed_rad_s, ctrl: ControllerParams, plant: SmibParams):
    """``(L + g'(d)) d'`` in pu/s, with ``g'(d) = -P_max cos(delta)``: the part of w' that does not come from x3'.

    ``w' = x3' - surface_drift``; on the switching surface a sliding motion has
    ``x3' = surface_drift`` (w constant). Floats or arrays.
    """
    cosine = math.cos(delta_rad) if isinstance(delta_rad, float) else np.cos(delta_rad)
    return (ctrl.gain_l - plant.p_max_pu * cosine) * speed_rad_s


def closed_loop_rate(t: float, x: tuple, u: tuple, params: LoopParams) -> tuple:
    """Time derivative of the closed loop's state, ``(delta' rad/s, speed' rad/s^2, x3' pu/s)``, shaped as ``x``.

    ``t`` (s) is unused (the network in force is the input ``u``, constant over a
    step); see the module's docstring for ``x``, ``u`` and the equations.
    """
    delta, speed, x3 = x
    plant, ctrl, mode = params.plant, params.ctrl, params.mode
    angle_dev = delta - plant.delta_bar_rad
    b = ctrl.battery_limit_pu
    if mode == BY_STATE and b == 0.0:  # no battery: saturated whatever w, no power (w need not be computed)
        power, x3_dot = 0.0, x3_rate(x3, angle_dev, True, ctrl)
    elif mode == BY_STATE:
        w = saturation_input(x3, angle_dev, ctrl, plant)
        power, x3_dot = saturate(w, b), x3_rate(x3, angle_dev, is_saturated(w, b), ctrl)
    elif mode == UNSATURATED:
        power, x3_dot = saturation_input(x3, angle_dev, ctrl, plant), x3_rate(x3, angle_dev, False, ctrl)
    elif mode == SATURATED:
        power, x3_dot = params.side * b, x3_rate(x3, angle_dev, True, ctrl)
    elif mode == SLIDING:
        power, x3_dot = params.side * b, surface_drift(delta, speed, ctrl, plant)
    else:
        raise ValueError(f"unknown mode {mode!r}")
    return (*plant_rate(t, (delta, speed), power, (plant, u)), x3_dot)
