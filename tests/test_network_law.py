"""One copy of the sampled H3-hat: the network's controllers run law.sampled_step, as the SMIB's do (issue 14).

The reference is law.SampledController, the SMIB controller node's law, given
each generator's measured g_i = P_e,i(pre-fault) - P_e,i(measured) and gains
on the system base; the network's vectorised controller must give the same
floats at every generator and every sample of a saturating Kundur run.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from nni_battery_controller.controller_config import ControllerConfig
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_battery_controller.controller_core import ControllerCore
from nni_battery_controller.law import ControllerParams, SampledController, sampled_step
from nni_battery_controller.network_sim import NetworkController, NetworkLaw, simulate_network
from nni_plant_sim.cases import load_network
from nni_plant_sim.network import electrical_power
from nni_plant_sim.model import SmibParams
from nni_plant_sim.network_scenarios import BusFault


def system_base_controllers(net, law, limit_pu_mbase, period_s):
    """One SampledController per generator (its model unused: g is given), gains and limit on the system base."""
    out = []
    for i in range(net.size):
        scale = float(net.pu_of_machine(np.eye(net.size)[i])[i])
        ctrl = ControllerParams(float(law.tau_s[i]), float(law.gain_k[i]) * scale, float(law.gain_l[i]) * scale,
                                float(law.alpha[i]) * scale, limit_pu_mbase * scale)
        out.append(SampledController(SmibParams(), ctrl, period_s))
    return out


def test_the_network_law_is_the_smib_sampled_controller_at_every_generator_step_for_step():
    net = load_network("kundur_two_area")
    law = NetworkLaw.uniform(net, 0.1, 1.0, 1.1, 1.0)
    fault, period = BusFault(net, 7, 0.12, trip=(net.bus_model.branch_index(7, 8),)), 0.02
    traj = simulate_network(net, law, fault, [0.1], 3.0, 1.0 / period)
    assert traj.saturated.any() and not traj.saturated.all()  # both modes are exercised
    network = NetworkController(law, period, net.pu_of_machine(np.full(net.size, 0.1))[:, None],
                                np.zeros((net.size, 1)))
    smib = system_base_controllers(net, law, 0.1, period)
    for k, t in enumerate(traj.t_s):
        delta = traj.delta_rad[k]
        measured = electrical_power(delta, fault.network(t, net)[1])
        power, w, saturated = network.step(delta, measured)
        for i, controller in enumerate(smib):
            expected = controller.step(float(delta[i, 0] - net.delta_bar_rad[i]),
                                       float(net.p_mech_pu[i] - measured[i, 0]))
            assert (power[i, 0], w[i, 0], bool(saturated[i, 0])) == pytest.approx(expected, rel=0, abs=1e-15)
            assert network.x3[i, 0] == pytest.approx(controller.x3, rel=0, abs=1e-15)
        assert np.array_equal(power, traj.battery_power_pu[k])  # the simulation's controller is this one


def test_sampled_step_is_one_formula_for_floats_and_arrays():
    """Elementwise on arrays the same floats as on Python floats: both modes, b = inf, the non-finite guard."""
    x3 = np.array([0.05, -0.3, 0.0, 1e308])
    dev = np.array([0.2, 1.5, -0.1, math.nan])
    g = np.array([0.01, 0.4, -0.02, 0.0])
    limit = np.array([0.3, 0.2, math.inf, 0.5])
    arrays = sampled_step(x3, dev, g, 1.0, 1.1, limit, math.exp(-0.2), math.exp(-0.02))
    for j in range(x3.size):
        floats = sampled_step(float(x3[j]), float(dev[j]), float(g[j]), 1.0, 1.1, float(limit[j]), math.exp(-0.2),
                              math.exp(-0.02))
        assert all(isinstance(v, (float, bool)) for v in floats)
        assert tuple(a[j] for a in arrays) == pytest.approx(floats, rel=0, abs=0, nan_ok=True)
    assert arrays[1][2] == -0.1 * -1.1 + 0.02 + 0.0 * 1  # unsaturated (b = inf): w = x3 - L d - g
    assert arrays[0][3] == 0.0 and arrays[3][3] == 0.0  # w not finite: zero power, x3 restarts


def controller_values(**changes) -> dict:
    """The controller node's parameter values: the shipped defaults with ``changes``."""
    return {**controller_defaults(), **changes}


def test_a_controller_with_g_measured_answers_as_the_network_law_for_its_generator():
    """restoring_power measured: g = p_mech_pu - P_E and d = delta - reference_angle_rad, gains on one base."""
    net = load_network("kundur_two_area")
    law = NetworkLaw.uniform(net, 0.1, 1.0, 1.1, 1.0)
    fault, period = BusFault(net, 8, 0.2), 0.02
    traj = simulate_network(net, law, fault, [0.2], 2.0, 1.0 / period)
    assert traj.saturated[:, 2].any() and not traj.saturated[:, 2].all()
    i, scale = 2, float(net.mbase_mva[2] / net.base_mva)
    core = ControllerCore(ControllerConfig(controller_values(
        restoring_power="measured", reference_angle_rad=float(net.delta_bar_rad[i]),
        p_mech_pu=float(net.p_mech_pu[i]) / scale, battery_limit_pu=0.2, sample_rate_hz=1.0 / period,
        stamp_tolerance_s=1e9)))
    for k, t in enumerate(traj.t_s):
        measured = electrical_power(traj.delta_rad[k], fault.network(t, net)[1])[i, 0] / scale
        answer = core.measurement(round(t * 1e9), float(traj.delta_rad[k, i, 0]), 0.0, round(t * 1e9), 0, measured)
        assert answer.power_pu * scale == pytest.approx(traj.battery_power_pu[k, i, 0], rel=1e-12, abs=1e-14)
        assert answer.saturated == traj.saturated[k, i, 0]
        assert math.isnan(answer.w_hat)  # the SMIB's W_hat is not defined for a generator in a network
    assert core.measurement(round(9e9), 0.3, 0.0, round(9e9), 0, math.nan) is None
    assert core.gate.counts["non_finite"] == 1


def test_the_smib_default_is_unchanged_and_a_wrong_reference_angle_is_refused():
    config = ControllerConfig(controller_values())
    core = ControllerCore(config)
    delta = config.plant.delta_bar_rad + 0.4
    expected = SampledController(config.plant, config.ctrl, config.period_s).step(delta - config.plant.delta_bar_rad)
    answer = core.measurement(0, delta, 0.0, 0, 0, 123.0)  # P_E unused by the model
    assert (answer.power_pu, answer.w, answer.saturated) == expected
    with pytest.raises(ValueError, match="measured needs reference_angle_rad"):
        ControllerCore(ControllerConfig(controller_values(restoring_power="measured")))
    with pytest.raises(ValueError, match="applies to restoring_power measured only"):
        ControllerCore(ControllerConfig(controller_values(reference_angle_rad=0.2)))
