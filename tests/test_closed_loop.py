"""The one closed-loop system and the one RK4: equations, held modes, order, and the plant's float fast path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nni_battery_controller.closed_loop import (
    SATURATED,
    SLIDING,
    UNSATURATED,
    LoopParams,
    closed_loop_rate,
    surface_drift,
)
from nni_battery_controller.law import ControllerParams
from nni_plant_sim.integrators import advance, rk4
from nni_plant_sim.model import SmibParams, plant_rate
from nni_plant_sim.scenarios import TransferLimitFault

PLANT = SmibParams(inertia_h_s=4.0, damping_pu=0.05, p_mech_pu=0.8, p_max_pu=1.0, f0_hz=50.0)
NETWORK = (0.8, 1.0)


def paper_equations(delta, speed, x3, ctrl, p_mech=0.8, p_max=1.0):
    """The loop written from the paper's equations, independently of the code under test."""
    m = 2.0 * 4.0 / (2.0 * math.pi * 50.0)
    delta_bar = math.asin(0.8 / 1.0)
    d = delta - delta_bar
    w = x3 - ctrl.gain_l * d - (math.sin(delta_bar) - math.sin(delta))
    b = ctrl.battery_limit_pu
    if abs(w) < b:
        power, x3_dot = w, (ctrl.gain_k * d - x3) / ctrl.tau_s
    else:
        power, x3_dot = math.copysign(b, w), -(ctrl.alpha / ctrl.gain_k) * x3
    return speed, (p_mech + power - p_max * math.sin(delta) - 0.05 * speed) / m, x3_dot


@pytest.mark.parametrize("b", [0.0, 0.2, math.inf])
@pytest.mark.parametrize("state", [(0.3, 2.0, 0.1), (1.5, -4.0, -0.2), (2.9, 0.5, 0.0), (0.93, 0.0, 0.05)])
def test_closed_loop_rate_is_the_papers_loop_for_floats_and_arrays(state, b):
    ctrl = ControllerParams(battery_limit_pu=b)
    expected = paper_equations(*state, ctrl)
    scalar = [float(r) for r in closed_loop_rate(0.0, state, NETWORK, LoopParams(PLANT, ctrl))]
    assert scalar == pytest.approx(expected, rel=1e-12, abs=1e-12)
    batch = closed_loop_rate(0.0, tuple(np.array([c, c]) for c in state), NETWORK, LoopParams(PLANT, ctrl))
    for got, want in zip(batch, expected):
        assert np.asarray(got).shape == (2,) or np.ndim(got) == 0
        np.testing.assert_allclose(np.broadcast_to(got, (2,)), want, rtol=1e-12, atol=1e-12)


def test_a_held_mode_is_the_law_in_that_mode_whatever_the_state():
    ctrl = ControllerParams(battery_limit_pu=0.2)
    state = (1.5, 1.0, 0.0)  # w = -0.43 < -b here: the law by state saturates
    def rate(params):
        return [float(r) for r in closed_loop_rate(0.0, state, NETWORK, params)]

    by_state = rate(LoopParams(PLANT, ctrl))
    assert rate(LoopParams(PLANT, ctrl, SATURATED, -1.0)) == pytest.approx(by_state, rel=1e-15)
    unlimited = paper_equations(*state, ControllerParams(battery_limit_pu=math.inf))
    assert rate(LoopParams(PLANT, ctrl, UNSATURATED)) == pytest.approx(unlimited, rel=1e-12)
    with pytest.raises(ValueError, match="unknown mode"):
        closed_loop_rate(0.0, state, NETWORK, LoopParams(PLANT, ctrl, "chattering"))


def test_sliding_keeps_w_on_the_surface():
    ctrl = ControllerParams(battery_limit_pu=0.2)
    params = LoopParams(PLANT, ctrl, SLIDING, 1.0)
    delta_bar = PLANT.delta_bar_rad

    def w(x):
        return x[2] - ctrl.gain_l * (x[0] - delta_bar) - (math.sin(delta_bar) - math.sin(x[0]))

    x = (1.1, 0.7, 0.4)
    rate = closed_loop_rate(0.0, x, NETWORK, params)
    h = 1e-6
    ahead = tuple(xi + h * ri for xi, ri in zip(x, rate))
    assert abs(w(ahead) - w(x)) / h < 1e-4  # w' = 0 up to the finite difference's error
    assert rate[2] == pytest.approx(surface_drift(x[0], x[1], ctrl, PLANT))
    m = 2.0 * 4.0 / (2.0 * math.pi * 50.0)
    assert rate[1] == pytest.approx((0.8 + 0.2 - math.sin(x[0]) - 0.05 * x[1]) / m, rel=1e-12)  # P_ST = +b


def test_rk4_is_fourth_order():
    def rate(t, x, u, params):
        return (x[1], -params * x[0] + u)

    def error(h):
        x = (1.0, 0.0)
        for _ in range(round(1.0 / h)):
            x = rk4(rate, 0.0, x, h, 0.0, 4.0)
        return abs(x[0] - math.cos(2.0))

    ratio = error(0.02) / error(0.01)
    assert 14.0 < ratio < 18.0  # 2^4 = 16


@pytest.mark.parametrize("batch", [False, True])
def test_the_plants_written_out_rk4_is_the_generic_rk4_of_plant_rate_to_the_bit(batch):
    scenario = TransferLimitFault(p_max_fault_pu=0.2, clearing_time_s=0.5)
    x = np.array([[0.95, 1.2], [0.3, -2.0]]) if batch else np.array([0.95, 0.3])
    power = np.array([0.1, -0.05]) if batch else 0.1
    steps = 50
    got = advance(0.0, 0.05, x, power, PLANT, scenario)  # the plant node's call: no breakpoint inside
    h = 0.05 / steps  # advance's step for this interval
    state = (x[0], x[1]) if batch else (float(x[0]), float(x[1]))
    for _ in range(steps):
        state = rk4(plant_rate, 0.0, state, h, power, (PLANT, scenario.network(0.0, PLANT)))
    assert got.tolist() == np.array(state).tolist()
