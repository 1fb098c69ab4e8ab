"""The link model in the distributed loop: plant and controller processes over real DDS, lockstep (SMIB and Kundur).

The plant applies each answer at t_k + d_k in simulated time (nni_plant_sim.link
through the reporting core); the offline sampled simulation with the same link
must give the same trajectory, and the offline delay margin must predict what
the distributed loop does on either side of it.
"""

from __future__ import annotations

import numpy as np
import pytest

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.margins import delay_margins
from nni_battery_controller.network_sim import NetworkLaw, simulate_network
from nni_battery_controller.simulate import simulate_sampled
from nni_battery_controller.verdicts import assess, pole_slip_instant
from nni_msgs_adapter.ros import contract
from nni_plant_sim.cases import load_network
from nni_plant_sim.link import Link
from nni_plant_sim.model import SmibParams
from nni_plant_sim.network_scenarios import BusFault
from nni_plant_sim.scenarios import InitialAngle
from test_distributed_loop import run_loop, states_array
from test_network_loop import run_network

pytestmark = pytest.mark.ros

RATE_HZ = 50.0


def link_params(link: Link) -> dict:
    """The plant node parameters of a one-generator link."""
    return {"link_delay_s": link.delay_s[0], "link_jitter_s": link.jitter_s[0], "link_loss": link.loss[0],
            "link_seed": link.seed}


def offline(b: float, duration_s: float, link: Link):
    return simulate_sampled(SmibParams(), ControllerParams(battery_limit_pu=b), InitialAngle(), duration_s, RATE_HZ,
                            1e-3, link)


def assert_equals_offline(states: np.ndarray, traj, until_s: float = np.inf) -> None:
    """The recorded plant states are the offline samples (to 1e-12: the same operations in the same order)."""
    assert states.shape[0] == traj.t_s.size, "one plant state per sample, t_0 .. t_n"
    np.testing.assert_allclose(states[:, 0], traj.t_s, rtol=0, atol=1e-9)
    upto = traj.t_s <= until_s
    np.testing.assert_allclose(states[upto, 1], traj.delta_rad[upto], rtol=0, atol=1e-12)
    np.testing.assert_allclose(states[upto, 2], traj.speed_rad_s[upto], rtol=0, atol=1e-12)
    # The power in force at each sample (the last state's too: it is in force at t_n).
    np.testing.assert_allclose(states[upto, 3], traj.battery_power_pu[upto], rtol=0, atol=1e-12)


def test_lockstep_through_a_delaying_jittering_lossy_link_equals_the_offline_run_with_that_link(tmp_path):
    """Delay 1.5 periods plus jitter of one period (answers overtake each other) and 10 % loss, seeded."""
    b, duration = 0.3, 4.0
    link = Link(0.03, 0.02, 0.1, seed=11)
    recorded, _ = run_loop(tmp_path, "lockstep", b, duration, RATE_HZ, timeout_s=180.0,
                           plant_params=link_params(link))
    traj = offline(b, duration, link)
    assert_equals_offline(states_array(recorded[contract.TOPIC_PLANT_STATE]), traj)
    lost = sum(link.draw(0, k) is None for k in range(int(duration * RATE_HZ)))
    plant = [v for m in recorded[contract.TOPIC_DIAGNOSTICS] if (v := contract.diagnostic_values(m, "plant"))]
    values = plant[-1]
    assert values[contract.RUN_ENDED] == "True", "the plant's diagnostics at the end of its run"
    assert int(values["link_lost"]) == lost > 0, "the plant lost exactly the answers the model draws as lost"
    assert int(values["deadline_misses"]) == 0, "a lost answer completes the handshake: no timeout"


def test_a_delay_the_offline_margin_calls_safe_is_safe_in_the_distributed_loop_and_one_it_calls_unsafe_is_not(
        tmp_path):
    b, duration = 0.3, 10.0
    margin, = delay_margins(
        lambda delay, indices: [assess(offline(b, duration, Link(delay))).in_synchronism for _ in indices],
        [b], 0.05, 1.0)
    assert margin.margin_s is not None and margin.slips_s is not None, margin
    safe, unsafe = round(0.5 * margin.margin_s, 9), round(1.5 * margin.margin_s, 9)
    assert assess(offline(b, duration, Link(safe))).in_synchronism
    assert not assess(offline(b, duration, Link(unsafe))).in_synchronism, "the premise: offline slips at 1.5 d*"
    for delay, expect_in_sync in ((safe, True), (unsafe, False)):
        (tmp_path / f"d{delay}").mkdir()
        recorded, _ = run_loop(tmp_path / f"d{delay}", "lockstep", b, duration, RATE_HZ, timeout_s=240.0,
                               plant_params=link_params(Link(delay)))
        states = states_array(recorded[contract.TOPIC_PLANT_STATE])
        slip = pole_slip_instant(states[:, 0], states[:, 1])
        assert (slip is None) == expect_in_sync, f"delay {delay} s: distributed pole slip at {slip}"
        traj = offline(b, duration, Link(delay))
        assert_equals_offline(states, traj, until_s=slip if slip is not None else np.inf)


def test_kundur_lockstep_through_a_link_equals_the_offline_network_simulation_with_that_link(tmp_path):
    """Network plant + 4 controller processes, every generator's answers through its own draws of one link.

    Tolerance 1e-12 as in test_network_loop (the powers' base on the wire rounds an ulp now and then).
    """
    net, b, duration = load_network("kundur_two_area"), 0.1, 2.0
    link = Link(0.03, 0.02, 0.1, seed=5)
    recorded, plant_summary = run_network(tmp_path, net, b, plant_extra={**link_params(link), "duration_s": duration})
    law = NetworkLaw.uniform(net, 0.1, 1.0, 1.1, 1.0)
    fault = BusFault(net, 7, 0.1, trip=(net.bus_model.branch_index(7, 8),))
    offline = simulate_network(net, law, fault, [b], duration, RATE_HZ, link=link)
    scale = net.mbase_mva / net.base_mva
    for i, states in enumerate(recorded):
        assert states.shape[0] == offline.t_s.size, f"gen{i + 1}: one plant state per sample"
        np.testing.assert_allclose(states[:, 1], offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(states[:, 2], offline.speed_rad_s[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(states[:, 3], offline.battery_power_pu[:, i, 0] / scale[i], rtol=0, atol=1e-12)
        lost = sum(link.draw(i, k) is None for k in range(int(duration * RATE_HZ)))
        assert plant_summary[f"gen{i + 1}"]["deadline_misses"] == 0
        assert plant_summary[f"gen{i + 1}"]["link_lost"] == lost, f"gen{i + 1}: its own draws"
    assert len({plant_summary[f"gen{i + 1}"]["link_lost"] for i in range(net.size)}) > 1, "generators draw apart"
